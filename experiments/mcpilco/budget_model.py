"""The budget's cost model measured: seconds per policy-optimisation step against particles,
horizon, GP size and state size, the fit of its constants, and the shipped task files
checked against the run's time budget (console script ``mcpilco-bench-budget``).

Each row times one optimisation step (:func:`~mcpilco.experiments.mcpilco.timing.time_opt_step`:
the eager particle rollout, its backward and an Adam step, one thread, the median CPU seconds
of a few steps) on a task spec, ``M`` particles and a GP fitted on ``N`` random-exploration
transitions. :func:`~mcpilco.agents.mc_pilco.budget.fit_step_constants` fits ``c_0``,
``c_1`` of ``t_step = M H E (c_0 + c_1 N D)`` to all rows; the report lists each row with the
model's prediction (with the fitted and with the constants in use), the constants, and the
derived budget of every shipped task file (:func:`~mcpilco.agents.mc_pilco.budget.
shipped_budgets`). Writes ``results/mcpilco_budget.json`` and ``.md``.
"""

from __future__ import annotations

import json
import platform
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

RESULTS_NAME = "mcpilco_budget"  # results/<name>.json and .md
DEFAULT_ENVS = ("mcpilco/CartpoleSwingUp-v0", "Pendulum-v1", "InvertedDoublePendulum-v5")
DEFAULT_PARTICLES = (100, 400)  # M of the measured steps
DEFAULT_POINTS = (60, 180, 300)  # N of the measured steps


def measure_steps(
    env_ids: Sequence[str] = DEFAULT_ENVS,
    particles: Sequence[int] = DEFAULT_PARTICLES,
    points: Sequence[int] = DEFAULT_POINTS,
    repeats: int = 3,
) -> list[dict[str, Any]]:
    """One row per task spec, ``M`` and ``N``: the model's variables and the measured CPU
    and wall seconds per step."""
    from mcpilco.agents.mc_pilco import TaskSpec
    from mcpilco.experiments.mcpilco.timing import time_opt_step

    rows = []
    for env_id in env_ids:
        task = TaskSpec.for_env(env_id)
        for m in particles:
            for n in points:
                t = time_opt_step(n, m, env_id=env_id, threads=1, repeats=repeats)
                rows.append(
                    {
                        "env_id": env_id,
                        "particles": int(m),
                        "horizon": task.horizon,
                        "outputs": len(task.output_idx),
                        "inputs": task.feature_dim + task.action_dim,
                        "points": int(n),
                        "seconds": t["s_per_step_cpu"],
                        "wall_seconds": t["s_per_step_wall"],
                    }
                )
    return rows


def budget_model_part(
    out_dir: Path, rows: list[dict[str, Any]] | None = None, command: str = ""
) -> dict[str, Any]:
    """Measure (unless ``rows`` are given), fit, check the shipped task files and write
    ``out_dir/mcpilco_budget.{json,md}``; returns the results."""
    from mcpilco.agents.mc_pilco import budget

    rows = measure_steps() if rows is None else rows
    c0, c1 = budget.fit_step_constants(rows)
    for r in rows:
        base = r["particles"] * r["horizon"] * r["outputs"]
        r["fitted_s"] = base * (c0 + c1 * r["points"] * r["inputs"])
        r["model_s"] = base * (budget.C0_S + budget.C1_S * r["points"] * r["inputs"])
    results = {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "command": command,
        "machine": f"{platform.machine()}, {platform.python_version()}",
        "fitted": {"c0_s": c0, "c1_s": c1},
        "in_use": {"c0_s": budget.C0_S, "c1_s": budget.C1_S},
        "opt_time_budget_s": budget.OPT_TIME_BUDGET_S,
        "run_time_budget_s": budget.RUN_TIME_BUDGET_S,
        "rows": rows,
        "shipped": budget.shipped_budgets(),
    }
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / f"{RESULTS_NAME}.json").write_text(json.dumps(results, indent=1))
    (out_dir / f"{RESULTS_NAME}.md").write_text(report(results))
    return results


def report(results: dict[str, Any]) -> str:
    """The Markdown report of :func:`budget_model_part`'s results."""
    fit, use = results["fitted"], results["in_use"]
    md = [
        "# MC-PILCO budget: seconds per policy-optimisation step",
        "",
        f"`{results['command']}` ({results['date']}; {results['machine']}).",
        "",
        "Model: `t_step = M H E (c_0 + c_1 N D)` (M particles, H horizon, E GP outputs, "
        "N GP points, D GP inputs: state features and actions); measured: the eager step "
        "(rollout, backward, Adam) on one thread, median CPU seconds.",
        "",
        f"Fitted here: c_0 = {fit['c0_s']:.3g} s, c_1 = {fit['c1_s']:.3g} s. In use "
        f"(`mcpilco.agents.mc_pilco.budget`): c_0 = {use['c0_s']:.3g} s, "
        f"c_1 = {use['c1_s']:.3g} s.",
        "",
        "| task | M | H | E | D | N | measured [s] | fitted model [s] | model in use [s] |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results["rows"]:
        md.append(
            f"| {r['env_id']} | {r['particles']} | {r['horizon']} | {r['outputs']} | "
            f"{r['inputs']} | {r['points']} | {r['seconds']:.3f} | {r['fitted_s']:.3f} | "
            f"{r['model_s']:.3f} |"
        )
    opt_min = results["opt_time_budget_s"] / 60
    run_min = results["run_time_budget_s"] / 60
    md += [
        "",
        f"## Shipped task files: derived budget for 5 policy trials (optimisation <= "
        f"{opt_min:.0f} min of a {run_min:.0f}-minute run on 2 cores, model in use)",
        "",
        "| task | states | actions | E | H | M | steps | N max | predicted [min] | fits |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for s in results["shipped"]:
        md.append(
            f"| {s['env_id']} | {s['states']} | {s['actions']} | {s['outputs']} | "
            f"{s['horizon']} | {s['num_particles']} | {s['opt_steps']} | {s['max_points']} | "
            f"{s['predicted_s'] / 60:.1f} | {'yes' if s['fits'] else 'no'} |"
        )
    return "\n".join(md) + "\n"

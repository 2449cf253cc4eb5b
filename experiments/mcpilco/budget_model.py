"""The budget's cost model measured: seconds per policy-optimisation step against particles,
horizon, GP size and state size, the fit of its constants, and the shipped task files
checked against the run's time budget (console script ``mcpilco-bench-budget``).

Each row times one optimisation step (:func:`~mcpilco.experiments.mcpilco.timing.time_opt_step`:
the eager particle rollout, its backward and an Adam step, one thread, the median CPU seconds
of a few steps) on a task spec, ``M`` particles and a GP fitted on ``N`` random-exploration
transitions. :func:`~mcpilco.agents.mc_pilco.budget.fit_step_constants` fits ``c_H``,
``c_0``, ``c_1`` of ``t_step = H (c_H + E M (c_0 + c_1 N D))`` to all rows; the report
lists each row with the model's prediction (with the fitted and with the constants in
use), the constants, the machine's load, and the derived budget of every shipped task file
(:func:`~mcpilco.agents.mc_pilco.budget.shipped_budgets`). Writes
``results/mcpilco_budget.json`` and ``.md``.
"""

from __future__ import annotations

import os
import platform
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from mcpilco.experiments.results import ResultLayout, read_result, write_result

RESULTS_NAME = "mcpilco_budget"  # results/<name>.json and .md
DEFAULT_ENVS = ("mcpilco/CartpoleSwingUp-v0", "Pendulum-v1", "InvertedDoublePendulum-v5")
DEFAULT_PARTICLES = (100, 400)  # M of the measured steps
DEFAULT_POINTS = (60, 180, 300)  # N of the measured steps

RESULT_LAYOUTS = (
    ResultLayout(
        "budget", config=("in_use", "opt_time_budget_s", "run_time_budget_s"),
        cases=("rows", "shipped"),
    ),
)  # fmt: skip
"""The layout of ``mcpilco_budget.json`` (:mod:`mcpilco.experiments.results`)."""
HEADLINES = ()  # the fit is a calibration, not a headline figure


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


def measurement(
    env_ids: Sequence[str] = DEFAULT_ENVS,
    particles: Sequence[int] = DEFAULT_PARTICLES,
    points: Sequence[int] = DEFAULT_POINTS,
    repeats: int = 3,
    command: str = "",
) -> dict[str, Any]:
    """:func:`measure_steps` with its provenance: the UTC date, the command, the machine and
    its 1-minute load average before and after (CPU seconds grow on a busy machine)."""
    load_before = os.getloadavg()[0]
    rows = measure_steps(env_ids, particles, points, repeats)
    return {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "command": command or None,
        "machine": f"{platform.machine()}, {platform.python_version()}, {os.cpu_count()} CPUs",
        "load_average": [round(load_before, 2), round(os.getloadavg()[0], 2)],
        "rows": rows,
    }


def read_measurement(path: Path) -> dict[str, Any]:
    """The measurement (rows and provenance) of a result file written before, to fit again
    without measuring again."""
    res = read_result(path)
    data = {**res.config, **res.summary, **res.cases}
    keys = ("particles", "horizon", "outputs", "inputs", "points", "seconds", "wall_seconds")
    return {
        "date": data.get("measured", res.date),
        "command": res.command,
        "machine": res.machine,
        "load_average": data["load_average"],
        "rows": [{"env_id": r["env_id"], **{k: r[k] for k in keys}} for r in data["rows"]],
    }


def budget_model_part(out_dir: Path, measured: dict[str, Any]) -> dict[str, Any]:
    """Fit the measurement ``measured`` (:func:`measurement`), check the shipped task files
    and write ``out_dir/mcpilco_budget.{json,md}``; returns the results."""
    from mcpilco.agents.mc_pilco import budget

    rows = [dict(r) for r in measured["rows"]]
    fitted = budget.fit_step_constants(rows)
    keys = ("particles", "horizon", "outputs", "inputs", "points")
    for r in rows:
        r["fitted_s"] = budget.model_seconds(*(r[k] for k in keys), constants=fitted)
        r["model_s"] = budget.model_seconds(*(r[k] for k in keys))
    results = {
        "date": measured["date"],
        "measured": measured["date"],
        "command": measured["command"],
        "machine": measured["machine"],
        "load_average": measured["load_average"],
        "fitted": dict(zip(("ch_s", "c0_s", "c1_s"), fitted, strict=True)),
        "in_use": {"ch_s": budget.CH_S, "c0_s": budget.C0_S, "c1_s": budget.C1_S},
        "opt_time_budget_s": budget.OPT_TIME_BUDGET_S,
        "run_time_budget_s": budget.RUN_TIME_BUDGET_S,
        "rows": rows,
        "shipped": budget.shipped_budgets(),
    }
    out_dir.mkdir(parents=True, exist_ok=True)
    payload = {k: v for k, v in results.items() if k not in ("date", "command")}
    path = out_dir / f"{RESULTS_NAME}.json"
    write_result(path, RESULT_LAYOUTS[0], payload, seeds=(), command=results["command"])
    (out_dir / f"{RESULTS_NAME}.md").write_text(report(results))
    return results


def report(results: dict[str, Any]) -> str:
    """The Markdown report of :func:`budget_model_part`'s results."""
    fit, use = results["fitted"], results["in_use"]
    md = [
        "# MC-PILCO budget: seconds per policy-optimisation step",
        "",
        f"`{results['command'] or 'budget_model_part'}` ({results['date']}; "
        f"{results['machine']}; 1-minute load "
        f"average {results['load_average'][0]} before, {results['load_average'][1]} after "
        "the measurement).",
        "",
        "Model: `t_step = H (c_H + E M (c_0 + c_1 N D))` (M particles, H horizon, E GP "
        "outputs, N GP points, D GP inputs: state features and actions); measured: the eager "
        "step (rollout, backward, Adam) on one thread, median CPU seconds.",
        "",
        f"Fitted here: c_H = {fit['ch_s']:.3g} s, c_0 = {fit['c0_s']:.3g} s, "
        f"c_1 = {fit['c1_s']:.3g} s. In use (`mcpilco.agents.mc_pilco.budget`): "
        f"c_H = {use['ch_s']:.3g} s, c_0 = {use['c0_s']:.3g} s, c_1 = {use['c1_s']:.3g} s.",
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

"""MC-PILCO judged on evaluation episodes (``mcpilco-bench-eval``): per seed, the policy after
each trial runs ``E`` episodes from the task's evaluation start (``eval_init``, e.g. a pendulum
hanging at rest) over the env's own episode length, none of them experience
(:meth:`~mcpilco.agents.mc_pilco.trainer.Trainer.evaluate_policy`).

A seed *solves* the task at trial ``k`` when every one of its ``E`` evaluation episodes after
trial ``k`` succeeds (the task's success test, e.g. within 0.3 rad of upright for the last
second). Per trial: the seeds solved, with the 95 % Wilson interval, and the evaluation
episodes that succeeded over all seeds; the headline is the last trial within the
experience budget (``--budget-s``). The runs use the package's derived defaults and the
shipped task file, with only the number of trials and ``E`` set; seeds run one after the
other, each resumable (a finished seed is read back).

Writes ``results/mcpilco_eval_<env>[_<label>].{json,md,png}``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.experiments.results import (
    DEVELOPMENT_SEEDS,
    ResultLayout,
    rate,
    read_result,
    seed_ranges,
    write_result,
)

RESULT_LAYOUTS = (
    ResultLayout(
        "mcpilco_eval",
        config=("env_id", "trials", "eval_episodes", "budget_s", "run_config"),
        cases=("per_seed",),
    ),
)  # fmt: skip
"""The layout of ``mcpilco_eval_*.json`` (:mod:`mcpilco.experiments.results`)."""
HEADLINES = ()  # reported in its own Markdown file and the MC-PILCO docs page


def eval_config(env_id: str, trials: int, eval_episodes: int, seed: int):
    """The run config of one seed: the env's derived defaults (:func:`load_config`) with
    ``trials`` policy trials, ``eval_episodes`` evaluation episodes after each, one thread."""
    from mcpilco.agents.mc_pilco import load_config

    cfg = load_config(env_id, overrides={"num_trials": trials, "eval_episodes": eval_episodes})
    return dataclasses.replace(cfg, seed=int(seed), torch_threads=1)


def run_seeds(
    env_id: str,
    seeds: Sequence[int],
    trials: int,
    eval_episodes: int,
    runs_dir: Path,
    log: Callable[[str], None] = print,
    on_seed: Callable[[list[dict[str, Any]]], None] | None = None,
) -> list[dict[str, Any]]:
    """Each seed's run in ``runs_dir/seed<s>`` (:func:`~mcpilco.experiments.mcpilco.bench.
    run_seed`: a finished run is read back, a killed one resumed), one after the other;
    ``on_seed(runs so far)`` after each (e.g. to write the report of the seeds finished)."""
    from mcpilco.experiments.mcpilco.bench import run_seed

    runs = []
    for s in seeds:
        cfg = eval_config(env_id, trials, eval_episodes, s)
        run = run_seed(cfg.to_dict(), str(Path(runs_dir) / f"seed{s}"))
        runs.append(run)
        last = run["records"][-1]
        log(
            f"seed {s}: eval {last.get('eval_successes')}/{last.get('eval_counted')} after "
            f"{last['experience_s']:.0f} s of experience ({run['seconds']:.0f} s)"
        )
        if on_seed is not None:
            on_seed(runs)
    return runs


def per_seed(run: dict[str, Any]) -> dict[str, Any]:
    """One seed's trials: experience, evaluation successes of ``counted`` episodes, whether
    all succeeded (``solved``), the trial's own success and start, the rollout dtype, the
    trial's horizon (steps; it grows over trials where the task lets it)."""
    rows = []
    for r in run["records"]:
        if r["kind"] != "policy":
            continue
        counted, ok = r.get("eval_counted") or 0, r.get("eval_successes") or 0
        rows.append(
            {
                "trial": r["index"],
                "experience_s": r["experience_s"],
                "eval_successes": ok,
                "eval_counted": counted,
                "solved": bool(counted) and ok == counted,
                "trial_success": bool(r["success"]) and not r.get("started_in_goal", False),
                "rollout_dtype": r.get("rollout_dtype"),
                "horizon": r.get("horizon"),
            }
        )
    return {"seed": run["seed"], "seconds": run["seconds"], "trials": rows}


def per_trial(seeds: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per policy trial over the seeds: seeds solved (95 % Wilson) and evaluation episodes
    that succeeded (95 % Wilson, episodes pooled over seeds). Seeds whose horizons grew
    differently reach a trial with different experience: the row's ``experience_s`` is the
    most of them (the trial's rates hold by that much experience), ``experience_min_s``
    the least."""
    n_trials = min(len(s["trials"]) for s in seeds)
    rows = []
    for k in range(n_trials):
        ts = [s["trials"][k] for s in seeds]
        ok = sum(t["eval_successes"] for t in ts)
        counted = sum(t["eval_counted"] for t in ts)
        rows.append(
            {
                "trial": ts[0]["trial"],
                "experience_s": max(t["experience_s"] for t in ts),
                "experience_min_s": min(t["experience_s"] for t in ts),
                "seeds_solved": rate(sum(t["solved"] for t in ts), len(ts)),
                "episodes": rate(ok, counted) if counted else None,
                "float64_rollouts": sum(t["rollout_dtype"] == "float64" for t in ts),
            }
        )
    return rows


def at_budget(rows: list[dict[str, Any]], budget_s: float) -> dict[str, Any] | None:
    """The last trial row with at most ``budget_s`` seconds of experience (None: none)."""
    within = [r for r in rows if r["experience_s"] <= budget_s + 1e-9]
    return within[-1] if within else None


def make_payload(
    env_id: str,
    runs: list[dict[str, Any]],
    trials: int,
    eval_episodes: int,
    budget_s: float,
    command: str | None = None,
    planned: Sequence[int] | None = None,
) -> dict[str, Any]:
    """The result payload of ``runs`` (:func:`run_seeds`); ``planned``: the seeds asked for
    (the report says which of them have not finished)."""
    seeds = [per_seed(r) for r in runs]
    rows = per_trial(seeds)
    cfg = eval_config(env_id, trials, eval_episodes, 0).to_dict()
    cfg.pop("seed")
    payload = {
        "env_id": env_id,
        "trials": trials,
        "eval_episodes": eval_episodes,
        "budget_s": budget_s,
        "run_config": cfg,
        "seeds": [s["seed"] for s in seeds],
        "per_trial": rows,
        "headline": at_budget(rows, budget_s),
        "per_seed": seeds,
        "seeds_planned": [int(s) for s in (planned or payload_seeds(seeds))],
    }
    if command is not None:
        payload["command"] = command
    return payload


def payload_seeds(seeds: list[dict[str, Any]]) -> list[int]:
    """The seeds of :func:`per_seed` rows."""
    return [int(s["seed"]) for s in seeds]


def report(payload: dict[str, Any]) -> str:
    """The Markdown report of a payload (:func:`make_payload`)."""
    seeds = payload["seeds"]
    dev = [s for s in seeds if s in DEVELOPMENT_SEEDS]
    kind = "development seed(s) (defaults chosen on them)" if dev else "report seed(s), run once"
    cfg = payload["run_config"]
    md = [
        f"# MC-PILCO on {payload['env_id']}: evaluation episodes",
        "",
        f"{len(seeds)} {kind}: {seed_ranges(seeds)}. Derived defaults and the shipped task "
        f"file ({cfg['num_particles']} particles, {cfg['opt']['max_steps']} opt steps, "
        f"N <= {cfg['max_points']} GP points); {payload['eval_episodes']} evaluation "
        "episodes after each policy trial, from the task's evaluation start over the env's "
        "own episode length, not experience. A seed is solved when all its evaluation "
        "episodes succeed.",
        "",
        *_unfinished(payload),
        "| experience | seeds solved [95 % Wilson] | evaluation episodes [95 % Wilson] "
        "| float64 rollouts |",
        "|---|---|---|---|",
    ]
    for r in payload["per_trial"]:
        s, e = r["seeds_solved"], r["episodes"]
        ep = "-" if e is None else f"{e['k']}/{e['n']} [{_pct(e['ci95'])}]"
        lo_s = r.get("experience_min_s", r["experience_s"])
        when = (
            f"{r['experience_s']:.0f} s"
            if lo_s == r["experience_s"]
            else (f"{lo_s:.0f}-{r['experience_s']:.0f} s")
        )
        md.append(
            f"| {when} | {s['k']}/{s['n']} [{_pct(s['ci95'])}] | {ep} | {r['float64_rollouts']} |"
        )
    h = payload["headline"]
    md += ["", f"Within {payload['budget_s']:.0f} s of experience: "]
    if h is None:
        md[-1] += "no policy trial fits the budget."
    else:
        s = h["seeds_solved"]
        md[-1] += (
            f"{s['k']} of {s['n']} seeds solved ({100 * s['rate']:.0f} %, 95 % CI "
            f"{_pct(s['ci95'])}) after {h['experience_s']:.0f} s."
        )
        if h is payload["per_trial"][-1] and h["experience_s"] < payload["budget_s"] - 1e-9:
            after = next_trial_ends(payload["per_seed"])
            if after is not None and after > payload["budget_s"] + 1e-9:
                md[-1] += (
                    f" A further trial would end at {after:.1f} s or later on every seed (it "
                    "lasts at least as long as the seed's last: the horizon never shrinks), "
                    "past the budget."
                )
            else:
                md[-1] += (
                    f" The runs end there, short of the budget: nothing is known of the "
                    f"trials up to {payload['budget_s']:.0f} s."
                )
    md += ["", "Per seed (evaluation successes after each policy trial):", ""]
    for s in payload["per_seed"]:
        cells = ", ".join(
            f"{t['experience_s']:.0f} s: {t['eval_successes']}/{t['eval_counted']}"
            + (f" (H = {t['horizon']})" if t.get("horizon") else "")
            for t in s["trials"]
        )
        md.append(f"- seed {s['seed']}: {cells} ({s['seconds']:.0f} s)")
    return "\n".join(md) + "\n"


def next_trial_ends(seeds: list[dict[str, Any]]) -> float | None:
    """The earliest experience [s] at which any seed's next policy trial could end: each
    seed's last trial end plus that trial's length (a horizon never shrinks); ``None`` when
    a seed has fewer than two policy trials (its last trial's length is not known)."""
    ends = []
    for s in seeds:
        t = [float(x["experience_s"]) for x in s["trials"]]
        if len(t) < 2:
            return None
        ends.append(2.0 * t[-1] - t[-2])
    return min(ends) if ends else None


def _unfinished(payload: dict[str, Any]) -> list[str]:
    """A paragraph naming the planned seeds that have not finished (none: nothing)."""
    missing = sorted(set(payload.get("seeds_planned", [])) - set(payload["seeds"]))
    if not missing:
        return []
    return [
        f"Not finished: seeds {seed_ranges(missing)} of the {len(payload['seeds_planned'])} "
        "planned; the rates below are over the finished seeds only.",
        "",
    ]


def _pct(ci: Sequence[float]) -> str:
    return f"{100 * ci[0]:.0f}-{100 * ci[1]:.0f} %"


def results_stem(env_id: str, label: str = "") -> str:
    """``mcpilco_eval_<env>[_<label>]`` (the env id's last part, ``-`` as ``_``)."""
    name = env_id.split("/")[-1].replace("-", "_").replace(".", "_")
    return f"mcpilco_eval_{name}" + (f"_{label}" if label else "")


def write_report(payload: dict[str, Any], out_dir: Path, label: str = "") -> Path:
    """The JSON (result schema), Markdown and PNG of ``payload`` in ``out_dir``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = results_stem(payload["env_id"], label)
    path = write_result(out_dir / f"{stem}.json", RESULT_LAYOUTS[0], payload)
    (out_dir / f"{stem}.md").write_text(report(payload))
    replot(read_result(path), path)
    return path


def replot(result: Any, json_path: Path) -> list[Path]:
    """Seeds solved (with the 95 % interval) against experience, from the result file."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = result["per_trial"]
    t = np.array([r["experience_s"] for r in rows])
    k = np.array([100 * r["seeds_solved"]["rate"] for r in rows])
    lo = np.array([100 * r["seeds_solved"]["ci95"][0] for r in rows])
    hi = np.array([100 * r["seeds_solved"]["ci95"][1] for r in rows])
    fig, ax = plt.subplots(figsize=(5, 3.5))
    ax.errorbar(t, k, yerr=[k - lo, hi - k], fmt="o-", capsize=3)
    ax.axvline(result["budget_s"], color="grey", ls="--", lw=1, label="experience budget")
    ax.set(
        xlabel="experience [s]",
        ylabel="seeds solved [%] (95 % Wilson)",
        ylim=(-5, 105),
        title=f"{result['env_id']}: evaluation from the task's start",
    )
    ax.legend(loc="lower right")
    fig.tight_layout()
    png = Path(json_path).with_suffix(".png")
    fig.savefig(png, dpi=120)
    plt.close(fig)
    return [png]

"""Compare MC-PILCO with PILCO and SB3 SAC / TD3 / PPO (console script ``mcpilco-compare``).

Runs (or collects) every method over S seeds on one registered task env and writes
``results/compare_<env>[_<tag>].json``, a Markdown table (``.md``) and one PNG: success rate
vs seconds of experience (log x-axis), one curve per method, mean over seeds with a band of
+-1 standard error of the mean.

Glossary
--------
experience ``T``
    seconds of real interaction: env steps x control period (0.05 s on the cartpoles);
    MC-PILCO / PILCO: ``3 (k + 1)`` s after trial ``k`` (exploration included).
``p_m(T)``
    success rate of method ``m`` at ``T``: mean over seeds of each seed's last evaluation at
    or before ``T`` (sample and hold; 0 before its first evaluation), up to the shortest
    seed's budget. An evaluation is the trial's episode (MC-PILCO / PILCO) or 10
    deterministic episodes (SB3); success = ``info["success"]`` at the end of the episode.
``T90_m``
    the first ``T`` with ``p_m(T) >= 0.9`` (headline); when never reached, only
    ``T90_m > T_max`` (the budget) is known.
ratio
    ``T90_m / T90_MC-PILCO``: how much more experience method ``m`` needs. Goal of the
    issue: ratio >= 100 for the best SB3 method and > 1 for PILCO.

Where results come from, per method and seed: ``RUNS/<env>/<method>/seed<s>/curve.json``
when it exists and covers the budget; otherwise the run is started (or resumed from its
checkpoint). ``--collect-only`` runs nothing. ``--mcpilco-json`` takes MC-PILCO's
per-seed successes from ``mcpilco-bench-mcpilco``'s JSON instead of running it.
``--inputs`` adds learning-curve files (``mcpilco-curve/1`` format, or a compare JSON).

Usage::

    mcpilco-compare --seeds 5 --jobs 2                             # all methods, full budgets
    mcpilco-compare --methods sac td3 --seeds 10 --ray auto        # on a Ray cluster
    mcpilco-compare --methods mcpilco sac --seeds 3 --steps sac=30000
    mcpilco-compare --env mcpilco/DMCCartpoleSwingUp-v0 --methods ppo --steps 50000
    mcpilco-compare --collect-only --inputs a.json b.json --tag mine
"""

from __future__ import annotations

import argparse
import ast
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.agents.baselines.common import (
    check_task_env,
    load_curves,
    make_curve,
    save_curve,
    trial_records_to_points,
)
from mcpilco.agents.baselines.pilco import OPTIMIZERS
from mcpilco.agents.common.cli import console_main
from mcpilco.agents.mc_pilco.loop import DEFAULT_ENV_ID, load_config
from mcpilco.agents.mc_pilco.task import TaskSpec
from mcpilco.experiments.sweep import Job, SweepError, add_sweep_arguments, runner_from_args
from mcpilco.models.device import retain_host_memory

SB3_METHODS = ("sac", "td3", "ppo")
METHODS = ("mcpilco", "pilco", *SB3_METHODS)
LABELS = {
    "mcpilco": "MC-PILCO",
    "pilco": "PILCO (TorchRL)",
    "sac": "SAC",
    "td3": "TD3",
    "ppo": "PPO",
}
SUCCESS_LEVEL = 0.9
GOAL_SB3_RATIO = 100.0


# ------------------------------------------------------------------------ aggregation
def _hold(points: list[dict[str, Any]], grid: np.ndarray) -> np.ndarray:
    """Success rate of one run at each grid time: its last evaluation at or before it."""
    t = np.array([p["experience_s"] for p in points], dtype=float)
    v = np.array([p["success_rate"] for p in points], dtype=float)
    idx = np.searchsorted(t, grid, side="right") - 1
    return np.where(idx >= 0, v[np.clip(idx, 0, None)], 0.0)


def first_reach(times: np.ndarray, values: np.ndarray, level: float = SUCCESS_LEVEL):
    """First time with ``value >= level`` (None when never reached)."""
    hit = np.nonzero(np.asarray(values) >= level - 1e-12)[0]
    return float(times[hit[0]]) if hit.size else None


def aggregate_method(curves: list[dict[str, Any]]) -> dict[str, Any]:
    """Mean success curve over seeds, its standard error, ``T90`` and per-seed summaries."""
    if not curves:
        raise ValueError("aggregate_method needs at least one learning curve")
    curves = [c for c in curves if c["points"]]
    if not curves:
        raise ValueError("all learning curves of this method are empty (no evaluation yet)")
    t_max = min(c["points"][-1]["experience_s"] for c in curves)
    grid = np.unique(
        [p["experience_s"] for c in curves for p in c["points"] if p["experience_s"] <= t_max]
    )
    runs = np.stack([_hold(c["points"], grid) for c in curves])
    mean = runs.mean(axis=0)
    sem = runs.std(axis=0, ddof=1) / math.sqrt(len(curves)) if len(curves) > 1 else 0 * mean
    per_seed = []
    for c in curves:
        t = np.array([p["experience_s"] for p in c["points"]])
        v = np.array([p["success_rate"] for p in c["points"]])
        per_seed.append(
            {
                "seed": c["seed"],
                "t90_s": first_reach(t, v),
                "final_success": float(v[-1]),
                "budget_s": float(t[-1]),
            }
        )
    reached = [s["t90_s"] for s in per_seed if s["t90_s"] is not None]
    cpu = [
        c["cpu_s"] / c["steps_done"] * 1000
        for c in curves
        if c.get("cpu_s") and c.get("steps_done")
    ]
    wall = [c["wall_s"] for c in curves if c.get("wall_s")]
    return {
        "seeds": [c["seed"] for c in curves],
        "experience_s": grid.tolist(),
        "success_mean": mean.tolist(),
        "success_sem": np.asarray(sem).tolist(),
        "t90_s": first_reach(grid, mean),
        "budget_s": float(t_max),
        "final_success": float(mean[-1]),
        "best_success": float(mean.max()),
        "per_seed": per_seed,
        "seeds_reaching_90": len(reached),
        "median_seed_t90_s": float(np.median(reached)) if reached else None,
        "cpu_s_per_1k_steps": float(np.mean(cpu)) if cpu else None,
        "wall_s_per_run": float(np.mean(wall)) if wall else None,
    }


def _ratio(agg: dict[str, Any], t_ref: float | None) -> dict[str, Any]:
    """``T90 / T90_ref``; a lower bound (``budget / T90_ref``) when 90% was not reached."""
    if t_ref is None:
        return {"value": None, "lower_bound": None}
    if agg["t90_s"] is not None:
        return {"value": agg["t90_s"] / t_ref, "lower_bound": None}
    return {"value": None, "lower_bound": agg["budget_s"] / t_ref}


def headline(aggs: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """Ratios to MC-PILCO and the two goals of the issue (met / not met / undetermined)."""
    ref = aggs.get("mcpilco")
    t_ref = ref["t90_s"] if ref else None
    ratios = {m: _ratio(a, t_ref) for m, a in aggs.items()}
    goal: dict[str, Any] = {}
    if ref is None:
        goal["note"] = "MC-PILCO is not part of this comparison"
    elif t_ref is None:
        goal["note"] = f"MC-PILCO did not reach 90% success within {ref['budget_s']:.0f} s"
    else:
        sb3 = {m: ratios[m] for m in SB3_METHODS if m in aggs}
        if sb3:
            # the best SB3 method needs the least experience; unreached ones only bound it
            vals = {
                m: r["value"] if r["value"] is not None else r["lower_bound"]
                for m, r in sb3.items()
            }
            best_m = min(vals, key=vals.get)
            best_val, exact = vals[best_m], sb3[best_m]["value"] is not None
            if best_val >= GOAL_SB3_RATIO:
                status = "met"
            elif exact:
                status = "not met"
            else:
                status = "undetermined (SB3 budget too small to reach 90%)"
            goal["sb3"] = {
                "best_method": best_m,
                "ratio": best_val,
                "ratio_is_lower_bound": not exact,
                "target": GOAL_SB3_RATIO,
                "status": status,
            }
        if "pilco" in aggs:
            r = ratios["pilco"]
            val = r["value"] if r["value"] is not None else r["lower_bound"]
            # not reached within budget B means T90 > B, so a lower bound of 1 already wins
            if val > 1.0 or (r["value"] is None and val >= 1.0):
                status = "met"
            elif r["value"] is not None:
                status = "not met"
            else:
                status = "undetermined (PILCO budget too small to reach 90%)"
            goal["pilco"] = {
                "ratio": val,
                "ratio_is_lower_bound": r["value"] is None,
                "target": 1.0,
                "status": status,
            }
    return {"mcpilco_t90_s": t_ref, "ratios": ratios, "goal": goal}


# ------------------------------------------------------------------------------ report
def _fmt_s(v: float | None) -> str:
    return "-" if v is None else f"{v:,.0f} s" if v >= 10 else f"{v:.1f} s"


def _fmt_ratio(r: dict[str, Any]) -> str:
    if r["value"] is not None:
        return f"{r['value']:,.1f}x"
    if r["lower_bound"] is not None:
        return f"> {r['lower_bound']:,.1f}x"
    return "-"


def markdown(report: dict[str, Any]) -> str:
    env_id, aggs, head = report["env_id"], report["methods"], report["headline"]
    lines = [
        f"# MC-PILCO vs baselines on {env_id}"
        + (f" ({report['tag']})" if report.get("tag") else ""),
        "",
    ]
    if report.get("note"):
        lines += [report["note"], ""]
    lines += [
        "Success = the task's success test at the episode end (`envs/tasks/`). "
        "Experience = env steps x the control period (MC-PILCO / PILCO: the steps of each "
        "trial, exploration included). Success rate: mean over seeds (MC-PILCO / PILCO: the "
        "trial's episode; SB3: 10 deterministic evaluation episodes every K steps).",
        "",
        "| method | seeds | budget | final success | best success | experience to 90% "
        "| ratio to MC-PILCO | seeds reaching 90% (median) | compute |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for m, a in aggs.items():
        t90 = (
            _fmt_s(a["t90_s"])
            if a["t90_s"] is not None
            else f"not reached (> {_fmt_s(a['budget_s'])})"
        )
        comp = []
        if a.get("cpu_s_per_1k_steps") is not None:
            comp.append(f"{a['cpu_s_per_1k_steps']:.1f} CPU s / 1k steps")
        if a.get("wall_s_per_run") is not None:
            comp.append(f"{a['wall_s_per_run']:.0f} s wall / run")
        lines.append(
            f"| {LABELS.get(m, m)} | {len(a['seeds'])} | {_fmt_s(a['budget_s'])} "
            f"| {100 * a['final_success']:.0f}% | {100 * a['best_success']:.0f}% | {t90} "
            f"| {_fmt_ratio(head['ratios'][m])} "
            f"| {a['seeds_reaching_90']}/{len(a['seeds'])} ({_fmt_s(a['median_seed_t90_s'])}) "
            f"| {'; '.join(comp) or '-'} |"
        )
    for f in report.get("failed", []):
        lines.append(
            f"| {LABELS.get(f['method'], f['method'])} | seed {f['seed']} FAILED: "
            f"{f['error'][:200]} |||||||"
        )
    goal = head["goal"]
    lines += ["", "Goals:", ""]
    if "note" in goal:
        lines.append(f"- {goal['note']}: ratios are undefined.")
    if "sb3" in goal:
        g = goal["sb3"]
        lines.append(
            f"- MC-PILCO needs >= {g['target']:.0f}x less experience than the best SB3 method "
            f"({LABELS[g['best_method']]}): measured ratio "
            f"{'> ' if g['ratio_is_lower_bound'] else ''}{g['ratio']:,.1f}x -> **{g['status']}**."
        )
    if "pilco" in goal:
        g = goal["pilco"]
        lines.append(
            f"- MC-PILCO needs less experience than TorchRL's PILCO: measured ratio "
            f"{'> ' if g['ratio_is_lower_bound'] else ''}{g['ratio']:,.2f}x -> **{g['status']}**."
        )
    return "\n".join(lines) + "\n"


def plot(report: dict[str, Any], path: Path) -> Path:
    """Success rate [%] vs experience [s] on a log x-axis, mean +- s.e.m. band per method."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 4.2))
    styles = {
        "mcpilco": ("o", "-"),
        "pilco": ("s", "-"),
        "sac": ("^", "--"),
        "td3": ("v", "-."),
        "ppo": ("D", ":"),
    }
    for m, a in report["methods"].items():
        t = np.asarray(a["experience_s"], dtype=float)
        mean = 100 * np.asarray(a["success_mean"])
        sem = 100 * np.asarray(a["success_sem"])
        keep = t > 0
        t, mean, sem = t[keep], mean[keep], sem[keep]
        if t.size == 0:
            continue
        n = len(a["seeds"])
        label = f"{LABELS.get(m, m)} ({n} seed{'s' if n > 1 else ''})"
        marker, ls = styles.get(m, ("o", "-"))
        (line,) = ax.plot(
            t, mean, drawstyle="steps-post", marker=marker, ls=ls, ms=4, lw=1.5, label=label
        )
        if len(a["seeds"]) > 1:
            ax.fill_between(
                t,
                np.clip(mean - sem, 0, 100),
                np.clip(mean + sem, 0, 100),
                step="post",
                alpha=0.2,
                color=line.get_color(),
            )
        if a["t90_s"] is not None:
            ax.axvline(a["t90_s"], color=line.get_color(), ls=":", lw=1)
    ax.axhline(100 * SUCCESS_LEVEL, color="k", ls="--", lw=0.8, label="90%")
    ax.set_xscale("log")
    ax.set_xlabel("experience [s] (log scale)")
    ax.set_ylabel("success rate [%]")
    ax.set_ylim(-3, 103)
    ax.set_title(f"{report['env_id']}" + (f" ({report['tag']})" if report.get("tag") else ""))
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def unique_curves(curves: list[dict[str, Any]]) -> tuple[list[dict[str, Any]], list[str]]:
    """One curve per ``(env, method, seed)``: a run passed twice (``--inputs`` and the runs
    folder) must count once. Keeps the curve reaching the most experience (the first of
    equals); returns the kept curves in input order and a line per dropped duplicate."""
    best: dict[tuple, int] = {}

    def reach(c: dict[str, Any]) -> float:
        return c["points"][-1]["experience_s"] if c["points"] else -1.0

    for i, c in enumerate(curves):
        key = (c["env_id"], c["method"], c["seed"])
        if key not in best or reach(c) > reach(curves[best[key]]):
            best[key] = i
    keep = set(best.values())
    dropped = [
        f"{c['method']} seed {c['seed']} ({reach(c):,.0f} s) duplicates a kept curve "
        f"({reach(curves[best[(c['env_id'], c['method'], c['seed'])]]):,.0f} s)"
        for i, c in enumerate(curves)
        if i not in keep
    ]
    return [c for i, c in enumerate(curves) if i in keep], dropped


def build_report(
    env_id: str, curves: list[dict[str, Any]], tag: str | None = None, note: str | None = None
) -> dict[str, Any]:
    """Aggregate the curves of ``env_id`` per method (order of :data:`METHODS`); a seed given
    more than once counts once (:func:`unique_curves`)."""
    curves, dropped = unique_curves(curves)
    by_method: dict[str, list[dict[str, Any]]] = {}
    for c in curves:
        if c["env_id"] == env_id:
            by_method.setdefault(c["method"], []).append(c)
    if not by_method:
        raise ValueError(f"no learning curves for {env_id}; run methods or pass --inputs")
    order = [m for m in METHODS if m in by_method] + sorted(set(by_method) - set(METHODS))
    aggs = {m: aggregate_method(by_method[m]) for m in order}
    return {
        "env_id": env_id,
        "tag": tag,
        "note": note,
        "methods": aggs,
        "headline": headline(aggs),
        "duplicates_dropped": dropped,
        "curves": [c for m in order for c in by_method[m]],
    }


def write_report(report: dict[str, Any], out_dir: Path) -> dict[str, Path]:
    """``compare_<env>[_<tag>].json / .md / .png`` in ``out_dir``."""
    stem = (
        "compare_"
        + report["env_id"].split("/")[-1]
        + (f"_{report['tag']}" if report.get("tag") else "")
    )
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {
        "json": out_dir / f"{stem}.json",
        "md": out_dir / f"{stem}.md",
        "png": out_dir / f"{stem}.png",
    }
    paths["json"].write_text(json.dumps(report, indent=1))
    paths["md"].write_text(markdown(report))
    plot(report, paths["png"])
    return paths


# ----------------------------------------------------------------------------- running
def curve_path(runs_dir: Path, env_id: str, method: str, seed: int) -> Path:
    return runs_dir / env_id.split("/")[-1] / method / f"seed{seed}" / "curve.json"


def run_method(
    method: str, env_id: str, seed: int, out_dir: str | Path, opts: dict[str, Any]
) -> dict[str, Any]:
    """Run (or resume) one method on one seed; writes and returns its learning curve.

    ``opts``: ``trials`` (MC-PILCO / PILCO policy trials), ``mcpilco_preset``, ``pilco``
    (PilcoConfig overrides), ``steps`` (per SB3 algorithm), ``eval_every``,
    ``eval_episodes``, ``sb3_preset``, ``sb3_hp`` (per algorithm), ``threads``, ``progress``.
    """
    import torch

    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; valid methods: {', '.join(METHODS)}")
    check_task_env(env_id)
    threads = opts.get("threads", 1)
    if threads:
        torch.set_num_threads(int(threads))
    retain_host_memory()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    progress = bool(opts.get("progress", False))
    log = print if opts.get("log", True) else None
    if method in SB3_METHODS:
        from mcpilco.agents.baselines.sb3 import SB3Config, run_sb3

        cfg = SB3Config(
            algo=method,
            env_id=env_id,
            steps=opts.get("steps", {}).get(method),
            eval_every=int(opts.get("eval_every", 2000)),
            eval_episodes=int(opts.get("eval_episodes", 10)),
            preset=opts.get("sb3_preset"),
            overrides=opts.get("sb3_hp", {}).get(method, {}),
            seed=seed,
            torch_threads=threads,
        )
        resume = (out / "curve.json").is_file() and json.loads(
            (out / "curve.json").read_text()
        ).get("checkpoint") is not None
        return run_sb3(cfg, out, resume=resume, progress=progress, log=log)
    t_cpu = time.process_time()
    trials = opts.get("trials")
    if method == "mcpilco":
        from mcpilco.agents.mc_pilco import run_mcpilco

        base = load_config(env_id, preset=opts.get("mcpilco_preset", "bench"))
        over: dict[str, Any] = {"seed": seed, "torch_threads": threads}
        if trials is not None:
            over["num_trials"] = trials
        cfg_m = base.with_overrides(**over)
        summary = run_mcpilco(
            cfg_m,
            out,
            resume=(out / "checkpoint.pt").is_file(),
            overwrite=not (out / "checkpoint.pt").is_file(),  # the run's own folder
            progress=progress,
            log=log,
            write_rrd=False,
        )
        horizon = cfg_m.task_spec().horizon
    else:
        from mcpilco.agents.baselines.pilco import PilcoConfig, run_pilco

        mc = load_config(env_id, preset=opts.get("mcpilco_preset", "bench"))
        over = {
            "env_id": env_id,
            "seed": seed,
            "torch_threads": threads,
            "explore_hold": mc.explore_hold,  # the same exploration trial as MC-PILCO's
            "cost_length_scales": mc.cost_length_scales,  # MC-PILCO's optimisation cost
            **opts.get("pilco", {}),
        }
        over["num_trials"] = trials if trials is not None else mc.num_trials
        cfg_p = PilcoConfig(**over)
        summary = run_pilco(
            cfg_p, out, resume=(out / "checkpoint.pt").is_file(), progress=progress, log=log
        )
        horizon = cfg_p.horizon or mc.task_spec().horizon
    points = trial_records_to_points(summary.records, horizon)
    dt = summary.records[0]["experience_s"] / max(1, summary.records[0].get("steps", horizon))
    curve = make_curve(
        method,
        env_id,
        seed,
        dt,
        points,
        config=summary.config,
        horizon=horizon,
        steps_done=points[-1]["steps"],
        wall_s=float(sum(r["wall_s"] for r in summary.records)),
        cpu_s_this_call=time.process_time() - t_cpu,
        complete=True,
    )
    save_curve(out / "curve.json", curve)
    return curve


def run_job(method: str, env_id: str, seed: int, out: str, opts: dict[str, Any]) -> Job:
    """The sweep job of one run (:func:`run_method`), keyed ``<method>/seed<s>``: its result
    file is ``<method>/seed<s>.json`` next to the run folder ``out``."""
    kwargs = {"method": method, "env_id": env_id, "seed": seed, "out_dir": out, "opts": opts}
    return Job(f"{method}/seed{seed}", run_method, kwargs, cpus=int(opts.get("threads") or 1))


def _covers(curve: dict[str, Any], method: str, opts: dict[str, Any]) -> bool:
    """Whether an existing curve already covers the requested budget."""
    if not curve.get("complete"):
        return False
    if method in SB3_METHODS:
        want = opts.get("steps", {}).get(method)
        from mcpilco.agents.baselines.sb3 import DEFAULT_STEPS

        return curve.get("budget_steps", 0) >= (want or DEFAULT_STEPS[method])
    trials = opts.get("trials")
    if trials is None:
        trials = load_config(curve["env_id"], preset=opts.get("mcpilco_preset", "bench")).num_trials
    return len(curve["points"]) >= trials + 1


def curves_from_bench_json(path: Path, env_id: str, label: str = "") -> list[dict[str, Any]]:
    """MC-PILCO curves from ``mcpilco-bench-mcpilco``'s JSON (per-seed success per trial);
    ``label``: the section written with ``mcpilco-bench-mcpilco --label LABEL``."""
    from mcpilco.scripts.bench_mcpilco import section_key

    data = json.loads(Path(path).read_text())
    key = section_key(env_id, label)
    section = data.get("runs", {}).get(key)
    if section is None:
        raise ValueError(
            f"{path} has no MC-PILCO runs {key!r} (sections: {sorted(data.get('runs', {}))}); "
            f"run mcpilco-bench-mcpilco --parts runs --env {env_id}"
            + (f" --label {label}" if label else "")
            + " first"
        )
    horizon = int(section["config"].get("horizon") or TaskSpec.for_env(env_id).horizon)
    times = [r["experience_s"] for r in section["per_trial"]]
    dt = times[0] / horizon
    curves = []
    for s in section["per_seed"]:
        recs = [
            {"index": k, "experience_s": (k + 1) * horizon * dt, "success": ok}
            for k, ok in enumerate(s["success"])
        ]
        curves.append(
            make_curve(
                "mcpilco",
                env_id,
                s["seed"],
                dt,
                trial_records_to_points(recs, horizon),
                source=str(path),
                wall_s=s.get("seconds"),
                complete=True,
            )
        )
    return curves


# -------------------------------------------------------------------------------- CLI
def _parse_steps(tokens: list[str] | None) -> dict[str, int]:
    steps: dict[str, int] = {}
    for tok in tokens or []:
        if "=" in tok:
            algo, _, val = tok.partition("=")
            algos = [algo]
        else:
            val, algos = tok, list(SB3_METHODS)
        for a in algos:
            if a not in SB3_METHODS:
                raise ValueError(
                    f"--steps: unknown SB3 method {a!r}; valid: {', '.join(SB3_METHODS)}"
                )
        try:
            n = int(float(val))
        except ValueError as err:
            raise ValueError(f"--steps: {tok!r} is not an integer number of env steps") from err
        if n < 1:
            raise ValueError(f"--steps: must be >= 1 env step, got {n}")
        for a in algos:
            steps[a] = n
    return steps


def _parse_hp(tokens: list[str] | None) -> dict[str, dict[str, Any]]:
    hp: dict[str, dict[str, Any]] = {}
    for tok in tokens or []:
        key, sep, val = tok.partition("=")
        algo, dot, name = key.partition(".")
        if not sep or not dot or algo not in SB3_METHODS or not name:
            raise ValueError(
                f"--sb3-hp: {tok!r} must look like ALGO.KEY=VALUE with ALGO in "
                f"{', '.join(SB3_METHODS)} (e.g. sac.learning_starts=1000)"
            )
        try:
            value = ast.literal_eval(val)
        except (ValueError, SyntaxError):
            value = val
        hp.setdefault(algo, {})[name] = value
    return hp


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="mcpilco-compare", description=__doc__, formatter_class=argparse.RawTextHelpFormatter
    )
    p.add_argument("--env", default=DEFAULT_ENV_ID, help="registered env id with a task")
    p.add_argument(
        "--methods", nargs="+", default=list(METHODS), help=f"any of {', '.join(METHODS)}"
    )
    p.add_argument("--seeds", type=int, default=5, help="number of seeds S (first-seed ... )")
    p.add_argument("--first-seed", type=int, default=0)
    p.add_argument(
        "--steps",
        nargs="+",
        help="SB3 budget in env steps: N (all) or ALGO=N; "
        "default sac=200000 td3=200000 ppo=1000000",
    )
    p.add_argument(
        "--eval-every", type=int, default=2000, help="K: SB3 env steps between evaluations"
    )
    p.add_argument("--eval-episodes", type=int, default=10, help="episodes per SB3 evaluation")
    p.add_argument(
        "--sb3-preset",
        choices=("swingup", "pendulum"),
        help="rl-baselines3-zoo hyper-parameter set (default: the env's in "
        "agents/baselines/conf/sb3.yaml; SB3's defaults for an env without one)",
    )
    p.add_argument(
        "--sb3-hp", nargs="+", help="override ALGO.KEY=VALUE (e.g. sac.learning_starts=1000)"
    )
    p.add_argument(
        "--trials", type=int, help="MC-PILCO / PILCO policy trials (default: bench preset, 4)"
    )
    p.add_argument(
        "--mcpilco-preset", default="bench", help="preset of the env's MC-PILCO config file"
    )
    p.add_argument(
        "--mcpilco-json", type=Path, help="collect MC-PILCO from mcpilco-bench-mcpilco's JSON"
    )
    p.add_argument(
        "--mcpilco-label",
        default="",
        help="with --mcpilco-json: the section's --label (e.g. K2); default: unlabelled",
    )
    p.add_argument("--pilco-max-points", type=int, help="PILCO GP points (default 180)")
    p.add_argument(
        "--pilco-opt-steps",
        type=int,
        help="PILCO evaluations of J (L-BFGS) or Adam steps per trial (default 150)",
    )
    p.add_argument(
        "--pilco-optimizer",
        choices=OPTIMIZERS,
        help="PILCO policy optimiser (default lbfgs, as PILCO's own line-search optimiser)",
    )
    p.add_argument("--pilco-basis", type=int, help="PILCO RBF centres (default 50)")
    p.add_argument(
        "--inputs", nargs="+", type=Path, default=[], help="extra learning-curve JSON files"
    )
    p.add_argument(
        "--collect-only", action="store_true", help="run nothing; collect existing curves"
    )
    p.add_argument(
        "--rerun", action="store_true", help="ignore complete curves (resume / extend runs)"
    )
    add_sweep_arguments(p)  # --jobs N (local processes, 1 torch thread each), --ray [ADDRESS]
    p.add_argument("--runs-dir", type=Path, default=Path("runs/compare"))
    p.add_argument("--out", type=Path, default=Path("results"))
    p.add_argument("--tag", help="suffix of the output names (e.g. reduced)")
    p.add_argument("--note", help="a line of text put above the table (e.g. the budget used)")
    p.add_argument("--no-progress", action="store_true")
    return p


@console_main("mcpilco-compare")
def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    bad = [m for m in args.methods if m not in METHODS]
    if bad:
        parser.error(
            f"unknown method(s) {', '.join(map(repr, bad))}; valid methods: {', '.join(METHODS)}"
        )
    try:
        check_task_env(args.env)
    except ValueError as err:
        parser.error(str(err))
    if args.seeds < 1 or args.eval_every < 1 or args.eval_episodes < 1:
        parser.error("--seeds, --eval-every and --eval-episodes must be >= 1")
    try:
        runner = runner_from_args(args, progress=not args.no_progress)
    except SweepError as err:
        parser.error(str(err))
    if args.trials is not None and args.trials < 0:
        parser.error(f"--trials must be >= 0, got {args.trials}")
    try:
        steps = _parse_steps(args.steps)
        sb3_hp = _parse_hp(args.sb3_hp)
    except ValueError as err:
        parser.error(str(err))
    pilco_over = {
        k: v
        for k, v in (
            ("max_points", args.pilco_max_points),
            ("opt_steps", args.pilco_opt_steps),
            ("optimizer", args.pilco_optimizer),
            ("num_basis", args.pilco_basis),
        )
        if v is not None
    }
    opts = {
        "trials": args.trials,
        "mcpilco_preset": args.mcpilco_preset,
        "pilco": pilco_over,
        "steps": steps,
        "eval_every": args.eval_every,
        "eval_episodes": args.eval_episodes,
        "sb3_preset": args.sb3_preset,
        "sb3_hp": sb3_hp,
        "threads": 1,
        "progress": not args.no_progress and runner.in_process,
        "log": runner.in_process,
    }
    curves: list[dict[str, Any]] = []
    for path in args.inputs:
        try:
            curves += load_curves(path)
        except (OSError, ValueError, TypeError) as err:
            parser.error(f"--inputs {path}: {err}")
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    methods = list(args.methods)
    if args.mcpilco_json is not None and "mcpilco" in methods:
        try:
            curves += curves_from_bench_json(args.mcpilco_json, args.env, args.mcpilco_label)
        except (OSError, ValueError) as err:
            parser.error(f"--mcpilco-json: {err}")
        methods.remove("mcpilco")
    jobs = []
    for m in methods:
        for s in seeds:
            path = curve_path(args.runs_dir, args.env, m, s)
            if path.is_file():
                c = load_curves(path)[0]
                if args.collect_only or (not args.rerun and _covers(c, m, opts)):
                    curves.append(c)
                    continue
            if not args.collect_only:
                jobs.append(run_job(m, args.env, s, str(path.parent), opts))
    t0 = time.perf_counter()
    failed = []
    if jobs:
        print(f"running {len(jobs)} job(s): {', '.join(j.key for j in jobs)}")
        # the runs to do were chosen above from their curves (a killed run resumes from its
        # checkpoint), so the sweep reruns every job it is given
        sweep = runner.run(jobs, args.runs_dir / args.env.split("/")[-1], rerun=True, desc="runs")
        for curve in sweep.results.values():  # a run on another node wrote its curve there
            path = curve_path(args.runs_dir, args.env, curve["method"], curve["seed"])
            if not path.is_file():
                save_curve(path, curve)
            curves.append(curve)
        failed = [
            {
                "failed": True,
                "method": f.kwargs["method"],
                "seed": f.kwargs["seed"],
                "out": f.kwargs["out_dir"],
                "error": f.error,
                "traceback": str(f.error_path),
            }
            for f in sweep.failed
        ]
        if failed:
            print(sweep.summary(), file=sys.stderr)
    try:
        report = build_report(args.env, curves, tag=args.tag, note=args.note)
    except ValueError as err:
        parser.error(str(err) + (f" ({len(failed)} run(s) failed, see above)" if failed else ""))
    report["failed"] = failed
    for line in report["duplicates_dropped"]:
        print(f"note: {line}: counted once", file=sys.stderr)
    if "mcpilco" not in report["methods"] and any(f["method"] == "mcpilco" for f in failed):
        report["headline"]["goal"]["note"] = "MC-PILCO has no finished run (it failed, see above)"
    report["settings"] = {
        "methods": args.methods,
        "seeds": seeds,
        "opts": {k: v for k, v in opts.items() if k not in ("progress", "log")},
        "wall_s_this_call": time.perf_counter() - t0,
    }
    paths = write_report(report, args.out)
    print(markdown(report))
    print(f"wrote {paths['json']}, {paths['md']} and {paths['png']}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())

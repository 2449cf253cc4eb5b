"""MC-PILCO against PILCO and SB3 SAC / TD3 / PPO on one task env: runs, learning curves
aggregated over seeds, and the report of ``mcpilco-compare``.

Every run yields a learning curve (``mcpilco-curve/1``, :mod:`mcpilco.agents.baselines.common`):
success rate against seconds of experience. Per method, :func:`aggregate_method` holds each
seed's last evaluation between evaluations (0 before the first), averages over seeds up to
the shortest seed's budget, and reads ``T90``, the first experience with a mean success rate
>= 0.9, and ``T100``, the first experience at which every seed's last evaluation succeeds.
:func:`headline` divides each method's ``T90`` (and ``T100``) by MC-PILCO's and checks the
two data-efficiency targets: the best SB3 method needs >= :data:`GOAL_SB3_RATIO` times
MC-PILCO's experience, PILCO more than MC-PILCO. A method that never reaches 0.9 within its
budget ``B`` has ``T90 > B``, so its ratio is a lower bound.

:func:`run_method` runs (or resumes) one method on one seed; :func:`compare` collects the
existing curves, runs the missing ones as sweep jobs and builds the report; :func:`write_report`
writes ``compare_<env>[_<tag>].json``, ``.md`` and ``.png``.
"""

from __future__ import annotations

import json
import math
import sys
import time
from collections.abc import Callable, Sequence
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
from mcpilco.agents.mc_pilco.config import load_config
from mcpilco.agents.mc_pilco.trainer import check_dynamics_task
from mcpilco.envs.tasks.spec import TaskSpec
from mcpilco.envs.yaml_files import parse_yaml
from mcpilco.experiments.infra.sweep import Job, SweepRunner
from mcpilco.experiments.results import (
    Headline,
    Result,
    ResultLayout,
    over_seeds,
    rate,
    read_result,
    seed_ranges,
    write_result,
)
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
SUCCESS_LEVEL = 0.9  # the success rate whose first crossing is T90
ALL_LEVEL = 1.0  # the success rate of every seed: its first crossing is T100
GOAL_SB3_RATIO = 100.0  # target: the best SB3 method needs this many times MC-PILCO's T90


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
    """Mean success curve over seeds, its standard error, ``T90``, ``T100`` (every seed's
    last evaluation a success), per-seed summaries, and ``final_info_median``: per figure
    that every seed's last point carries (the env's final ``info`` scalars, median over its
    evaluation episodes, e.g. the marker camera's ``position_error``) the median over
    seeds. The share of seeds reaching 90 % comes with its 95 % Wilson interval, the median
    seed's ``T90`` with its 95 % bootstrap interval over those seeds."""
    if not curves:
        raise ValueError("aggregate_method needs at least one learning curve")
    curves = [c for c in curves if c["points"]]
    if not curves:
        raise ValueError("all learning curves of this method are empty (no evaluation yet)")
    # a seed whose last evaluation failed holds that failure past its budget (a success
    # needs a later evaluation, hence more experience), so only seeds ending in a success
    # cut the common budget (every seed's when none does)
    ends = [c["points"][-1] for c in curves]
    limiting = [e for e in ends if e["success_rate"] > 0] or ends
    t_max = min(e["experience_s"] for e in limiting)
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
    finals = [c["points"][-1].get("final_info_median") or {} for c in curves]
    common = set.intersection(*(set(f) for f in finals))
    return {
        "seeds": [c["seed"] for c in curves],
        "experience_s": grid.tolist(),
        "success_mean": mean.tolist(),
        "success_sem": np.asarray(sem).tolist(),
        "t90_s": first_reach(grid, mean),
        "t100_s": first_reach(grid, mean, ALL_LEVEL),
        "budget_s": float(t_max),
        "final_success": float(mean[-1]),
        "best_success": float(mean.max()),
        "per_seed": per_seed,
        "seeds_reaching_90": len(reached),
        "median_seed_t90_s": float(np.median(reached)) if reached else None,
        "median_seed_t90_ci95": over_seeds(reached)["ci95"] if reached else None,
        "seeds_reaching_90_ci95": rate(len(reached), len(curves))["ci95"],
        "cpu_s_per_1k_steps": float(np.mean(cpu)) if cpu else None,
        "wall_s_per_run": float(np.mean(wall)) if wall else None,
        "final_info_median": {k: float(np.median([f[k] for f in finals])) for k in sorted(common)},
    }


def _ratio(agg: dict[str, Any], t_ref: float | None, key: str = "t90_s") -> dict[str, Any]:
    """``T / T_ref`` of ``key`` (``"t90_s"`` or ``"t100_s"``); a lower bound
    (``budget / T_ref``) when the level was not reached."""
    if t_ref is None:
        return {"value": None, "lower_bound": None}
    if agg.get(key) is not None:
        return {"value": agg[key] / t_ref, "lower_bound": None}
    return {"value": None, "lower_bound": agg["budget_s"] / t_ref}


def headline(aggs: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """Ratios to MC-PILCO and the two data-efficiency targets (``goal``: met, not met, or
    undetermined when a budget was too small to tell)."""
    ref = aggs.get("mcpilco")
    t_ref = ref["t90_s"] if ref else None
    ratios = {m: _ratio(a, t_ref) for m, a in aggs.items()}
    t100_ref = ref.get("t100_s") if ref else None
    ratios_100 = {m: _ratio(a, t100_ref, "t100_s") for m, a in aggs.items()}
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
    return {
        "mcpilco_t90_s": t_ref,
        "ratios": ratios,
        "mcpilco_t100_s": t100_ref,
        "ratios_100": ratios_100,
        "goal": goal,
    }


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
    """The report as Markdown: one table row per method (seeds, budget, final and best
    success, T90, ratio to MC-PILCO, compute), failed runs, then the targets met or not."""
    env_id, aggs, head = report["env_id"], report["methods"], report["headline"]
    lines = [
        f"# MC-PILCO vs baselines on {env_id}"
        + (f" ({report['tag']})" if report.get("tag") else ""),
        "",
    ]
    if report.get("note"):
        lines += [report["note"], ""]
    if report.get("command"):
        lines += [f"Command: `{report['command']}` ({report.get('measured', 'undated')})", ""]
    lines += [
        "Success = the task's success test at the episode end (`envs/tasks/`). "
        "Experience = env steps x the control period (MC-PILCO / PILCO: the steps of each "
        "trial, exploration included). Success rate: mean over seeds (MC-PILCO / PILCO: the "
        "trial's episode; SB3: 10 deterministic evaluation episodes every K steps).",
        "",
        "| method | seeds | budget | final success | best success | experience to 90% "
        "| ratio to MC-PILCO | experience to 100% (all seeds) | ratio (100%) "
        "| seeds reaching 90% (median) | compute |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for m, a in aggs.items():
        t90, t100 = (
            _fmt_s(a[key]) if a.get(key) is not None else f"not reached (> {_fmt_s(a['budget_s'])})"
            for key in ("t90_s", "t100_s")
        )
        r100 = head.get("ratios_100", {}).get(m, {"value": None, "lower_bound": None})
        comp = []
        if a.get("cpu_s_per_1k_steps") is not None:
            comp.append(f"{a['cpu_s_per_1k_steps']:.1f} CPU s / 1k steps")
        if a.get("wall_s_per_run") is not None:
            comp.append(f"{a['wall_s_per_run']:.0f} s wall / run")
        lines.append(
            f"| {LABELS.get(m, m)} | {len(a['seeds'])} | {_fmt_s(a['budget_s'])} "
            f"| {100 * a['final_success']:.0f}% | {100 * a['best_success']:.0f}% | {t90} "
            f"| {_fmt_ratio(head['ratios'][m])} | {t100} | {_fmt_ratio(r100)} "
            f"| {a['seeds_reaching_90']}/{len(a['seeds'])} ({_fmt_s(a['median_seed_t90_s'])}) "
            f"| {'; '.join(comp) or '-'} |"
        )
    for f in report.get("failed", []):
        lines.append(
            f"| {LABELS.get(f['method'], f['method'])} | seed {f['seed']} FAILED: "
            f"{f['error'][:200]} |||||||||"
        )
    finals = [set(a["final_info_median"]) for a in aggs.values()]
    keys = sorted(set.intersection(*finals)) if finals else []
    if keys:
        lines += [
            "",
            "At each method's last evaluation, the env's final `info` (median over the "
            "episodes of a seed, then over seeds):",
            "",
            "| method | experience | " + " | ".join(keys) + " |",
            "|---|---|" + "---|" * len(keys),
        ]
        for m, a in aggs.items():
            cells = " | ".join(f"{a['final_info_median'][k]:.4g}" for k in keys)
            lines.append(f"| {LABELS.get(m, m)} | {_fmt_s(a['budget_s'])} | {cells} |")
    goal = head["goal"]
    lines += ["", "Data-efficiency targets:", ""]
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
    write_result(paths["json"], RESULT_LAYOUTS[0], report)
    paths["md"].write_text(markdown(report))
    plot(report, paths["png"])
    return paths


# ----------------------------------------------------------------------------- running
def curve_path(runs_dir: Path, env_id: str, method: str, seed: int) -> Path:
    """Where the learning curve of a run is kept: ``runs_dir/<env>/<method>/seed<s>/``."""
    return runs_dir / env_id.split("/")[-1] / method / f"seed{seed}" / "curve.json"


def mcpilco_preset(env_id: str, preset: str | None = None) -> str | None:
    """The preset of the env's MC-PILCO config file that a comparison runs: ``preset`` when
    given, else ``"bench"`` (the benchmarks' budget) when the file has it, else None (the
    file's config as it is)."""
    from mcpilco.agents.mc_pilco.config import config_files
    from mcpilco.envs.yaml_files import read_yaml

    if preset is not None:
        return preset
    path = config_files().get(env_id)
    data = read_yaml(path, "MC-PILCO config file") if path is not None else {}
    return "bench" if "bench" in (data.get("presets") or {}) else None


def run_method(
    method: str, env_id: str, seed: int, out_dir: str | Path, opts: dict[str, Any]
) -> dict[str, Any]:
    """Run (or resume) one method on one seed; writes and returns its learning curve.

    ``opts``: ``trials`` (MC-PILCO / PILCO policy trials), ``mcpilco_preset``,
    ``mcpilco_set`` (MC-PILCO config overrides, nested), ``pilco`` (PilcoConfig overrides),
    ``steps`` (per SB3 algorithm), ``eval_every``, ``eval_episodes``, ``sb3_preset``,
    ``sb3_hp`` (per algorithm), ``threads``, ``progress``.
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
        from mcpilco.agents.mc_pilco import Trainer

        base = load_config(
            env_id,
            preset=mcpilco_preset(env_id, opts.get("mcpilco_preset")),
            overrides=opts.get("mcpilco_set"),
        )
        over: dict[str, Any] = {"seed": seed, "torch_threads": threads}
        if trials is not None:
            over["num_trials"] = trials
        cfg_m = base.with_overrides(**over)
        summary = Trainer(
            cfg_m,
            out,
            resume=(out / "checkpoint.pt").is_file(),
            overwrite=not (out / "checkpoint.pt").is_file(),  # the run's own folder
            progress=progress,
            log=log,
            write_rrd=False,
        ).run()
        horizon = cfg_m.task_spec().horizon
    else:
        from mcpilco.agents.baselines.pilco import pilco_config, run_pilco

        # defaults, MC-PILCO's exploration hold and cost, the env's PILCO settings, options
        over = {"seed": seed, "torch_threads": threads, **opts.get("pilco", {})}
        if trials is not None:
            over["num_trials"] = trials
        cfg_p = pilco_config(
            env_id,
            over,
            mcpilco_preset=mcpilco_preset(env_id, opts.get("mcpilco_preset")),
            mcpilco_overrides=opts.get("mcpilco_set"),
        )
        summary = run_pilco(
            cfg_p, out, resume=(out / "checkpoint.pt").is_file(), progress=progress, log=log
        )
        horizon = cfg_p.horizon or TaskSpec.for_env(env_id).horizon
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


def covers(curve: dict[str, Any], method: str, opts: dict[str, Any]) -> bool:
    """Whether an existing curve already covers the requested budget."""
    if not curve.get("complete"):
        return False
    if method in SB3_METHODS:
        want = opts.get("steps", {}).get(method)
        from mcpilco.agents.baselines.sb3 import DEFAULT_STEPS

        return curve.get("budget_steps", 0) >= (want or DEFAULT_STEPS[method])
    trials = opts.get("trials")
    if trials is None:
        trials = load_config(
            curve["env_id"],
            preset=mcpilco_preset(curve["env_id"], opts.get("mcpilco_preset")),
            overrides=opts.get("mcpilco_set"),
        ).num_trials
    return len(curve["points"]) >= trials + 1


def curves_from_bench_json(path: Path, env_id: str, label: str = "") -> list[dict[str, Any]]:
    """MC-PILCO curves from ``mcpilco-bench-mcpilco``'s JSON (per-seed success per trial;
    ``label``: the section written with ``mcpilco-bench-mcpilco --label LABEL``) or from the
    reaching study of ``mcpilco-bench-kinematics --reaching-seeds``
    (``kinematics_reaching.json``,
    :func:`~mcpilco.experiments.kinematics.reaching.reaching_curves`)."""
    from mcpilco.experiments.mcpilco.bench import section_key

    data = read_result(path).payload()
    if isinstance(data.get("rows"), list) and all("mcpilco" in r for r in data["rows"]):
        from mcpilco.experiments.kinematics.reaching import reaching_curves

        if label:
            raise ValueError(f"{path} is a reaching study: it has no sections (drop the label)")
        return reaching_curves(data, env_id, source=str(path))
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


# ------------------------------------------------------------------------- options
def parse_steps(tokens: list[str] | None) -> dict[str, int]:
    """SB3 budgets from ``["N"]`` (every SB3 method) or ``["sac=N", ...]``: method -> env
    steps.

    Raises:
        ValueError: an unknown method, a value that is not an integer >= 1.
    """
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


def parse_sb3_hp(tokens: list[str] | None) -> dict[str, dict[str, Any]]:
    """SB3 hyperparameter overrides from ``["sac.learning_starts=1000", ...]``: method ->
    {key: value}, each value read by the package's YAML loader
    (:func:`mcpilco.envs.yaml_files.parse_yaml`: numbers, booleans, lists, null; else text).

    Raises:
        ValueError: a token that is not ``ALGO.KEY=VALUE`` with an SB3 method.
    """
    hp: dict[str, dict[str, Any]] = {}
    for tok in tokens or []:
        key, sep, val = tok.partition("=")
        algo, dot, name = key.partition(".")
        if not sep or not dot or algo not in SB3_METHODS or not name:
            raise ValueError(
                f"--sb3-hp: {tok!r} must look like ALGO.KEY=VALUE with ALGO in "
                f"{', '.join(SB3_METHODS)} (e.g. sac.learning_starts=1000)"
            )
        hp.setdefault(algo, {})[name] = parse_yaml(val, f"--sb3-hp {key}")
    return hp


# ----------------------------------------------------------------------------- compare
def compare(
    env_id: str,
    methods: Sequence[str],
    seeds: Sequence[int],
    opts: dict[str, Any],
    runner: SweepRunner,
    runs_dir: Path,
    *,
    curves: Sequence[dict[str, Any]] = (),
    mcpilco_json: Path | None = None,
    mcpilco_label: str = "",
    collect_only: bool = False,
    rerun: bool = False,
    tag: str | None = None,
    note: str | None = None,
    warn: Callable[[str], None] = lambda line: print(line, file=sys.stderr),
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """The comparison report of ``methods`` x ``seeds`` on ``env_id`` (:func:`build_report`,
    with ``failed`` runs and the ``settings``).

    Curves come from ``curves`` (e.g. files a user passed), MC-PILCO's from ``mcpilco_json``
    (``mcpilco-bench-mcpilco``'s JSON, section ``mcpilco_label``) when given, and per method
    and seed from ``runs_dir/<env>/<method>/seed<s>/curve.json`` when it covers the budget
    (:func:`covers`; any curve found with ``collect_only``, none with ``rerun``); the other
    runs are run (or resumed from their checkpoints) as sweep jobs of ``runner``
    (:func:`run_job`), unless ``collect_only``. ``opts``: see :func:`run_method`.

    Raises:
        ValueError: ``mcpilco_json`` lacks the section, or no curve of ``env_id`` is left.
    """
    curves, runs_dir = list(curves), Path(runs_dir)
    methods = list(methods)
    requested = list(methods)
    if mcpilco_json is None and "mcpilco" in methods:
        check_dynamics_task(TaskSpec.for_env(env_id))
    if mcpilco_json is not None and "mcpilco" in methods:
        try:
            curves += curves_from_bench_json(mcpilco_json, env_id, mcpilco_label)
        except (OSError, ValueError) as err:
            raise ValueError(f"--mcpilco-json: {err}") from None
        methods.remove("mcpilco")
    jobs = []
    for m in methods:
        for s in seeds:
            path = curve_path(runs_dir, env_id, m, s)
            if path.is_file():
                c = load_curves(path)[0]
                if collect_only or (not rerun and covers(c, m, opts)):
                    curves.append(c)
                    continue
            if not collect_only:
                jobs.append(run_job(m, env_id, s, str(path.parent), opts))
    t0 = time.perf_counter()
    failed = []
    if jobs:
        log(f"running {len(jobs)} job(s): {', '.join(j.key for j in jobs)}")
        # the runs to do were chosen above from their curves (a killed run resumes from its
        # checkpoint), so the sweep reruns every job it is given
        sweep = runner.run(jobs, runs_dir / env_id.split("/")[-1], rerun=True, desc="runs")
        for curve in sweep.results.values():  # a run on another node wrote its curve there
            path = curve_path(runs_dir, env_id, curve["method"], curve["seed"])
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
            warn(sweep.summary())
    try:
        report = build_report(env_id, curves, tag=tag, note=note)
    except ValueError as err:
        if failed:
            raise ValueError(f"{err} ({len(failed)} run(s) failed, see above)") from None
        raise
    report["failed"] = failed
    for line in report["duplicates_dropped"]:
        warn(f"note: {line}: counted once")
    if "mcpilco" not in report["methods"] and any(f["method"] == "mcpilco" for f in failed):
        report["headline"]["goal"]["note"] = "MC-PILCO has no finished run (it failed, see above)"
    report["settings"] = {
        "methods": requested,
        "seeds": list(seeds),
        "opts": {k: v for k, v in opts.items() if k not in ("progress", "log")},
        "wall_s_this_call": time.perf_counter() - t0,
    }
    return report


# -- result file and headline rows of the results index -----------------------------------

RESULT_LAYOUTS = (
    ResultLayout(
        "compare",
        config=("env_id", "tag", "note", "settings"),
        cases=("curves",),
        failures=("failed",),
        seeds=lambda p: [c["seed"] for c in p.get("curves", []) if "seed" in c],
    ),
)
"""The layout of ``compare_<env>[_<tag>].json`` (:mod:`mcpilco.experiments.results`)."""


def _per_method_seeds(r: Result) -> str:
    return "; ".join(
        f"{name} {seed_ranges(m['seeds'])}" for name, m in r["methods"].items() if m["seeds"]
    )


def _ratio_text(r: Result, name: str) -> str:
    """Method ``name``'s experience to 90 % success over MC-PILCO's, or its lower bound."""
    x = r["headline"]["ratios"][name]
    value, bound = x["value"], x["lower_bound"]
    if value is not None:
        return f"{value:,.0f}x"
    return f"> {bound:,.0f}x" if bound >= 10 else f"> {bound:.2f}x"


def _cartpole_row(r: Result) -> str:
    return (
        f"experience to 90 % success: MC-PILCO {r['headline']['mcpilco_t90_s']:.0f} s; "
        f"SAC needs {_ratio_text(r, 'sac')} as much, TD3 {_ratio_text(r, 'td3')}, "
        f"PPO {_ratio_text(r, 'ppo')}, TorchRL PILCO {_ratio_text(r, 'pilco')}"
    )


def _tracking_row(r: Result) -> str:
    sac = r["methods"]["sac"]
    return (
        "experience until every joint's tracking error is halved in 90 % of the seeds: "
        f"MC-PILCO {r['headline']['mcpilco_t90_s']:.0f} s; SAC needs {_ratio_text(r, 'sac')} "
        f"as much (best success rate {100 * sac['best_success']:.0f} % within "
        f"{sac['budget_s']:,.0f} s)"
    )


def _reaching_row(r: Result) -> str:
    m, sac = r["methods"]["mcpilco"], r["methods"]["sac"]
    pos = {k: 1e3 * a["final_info_median"]["position_error"] for k, a in (("m", m), ("s", sac))}
    return (
        "experience until 90 % of the targets are reached (1 cm, 0.05 rad), identification "
        f"frames included: MC-PILCO {r['headline']['mcpilco_t90_s']:.0f} s; SAC needs "
        f"{_ratio_text(r, 'sac')} as much (best success rate {100 * sac['best_success']:.0f} % "
        f"within {sac['budget_s']:,.0f} s; final position error {pos['s']:.0f} mm against "
        f"MC-PILCO's {pos['m']:.1f} mm)"
    )


def _balance_row(r: Result) -> str:
    def t100(method: str) -> str:
        t = r["methods"][method]["t100_s"]
        return "not reached" if t is None else f"{t:.1f} s"

    m = r["methods"]["mcpilco"]
    line = (
        f"experience until all {len(m['seeds'])} seeds balance at once: MC-PILCO {t100('mcpilco')}"
    )
    if "pilco" in r["methods"]:
        return line + f", TorchRL PILCO {t100('pilco')} (its example's settings)"
    return line + "; TorchRL PILCO not measured"


def _row(capability: str, stem: str, figure: Callable[[Result], str]) -> Headline:
    return Headline(capability, f"{stem}.json", figure, f"{stem}.md", seeds=_per_method_seeds)


HEADLINES = (
    _row(
        "MC-PILCO, Gymnasium InvertedPendulum-v5 (terminating episodes)",
        "compare_InvertedPendulum-v5_seeds1000",
        _balance_row,
    ),
    _row(
        "MC-PILCO against TorchRL PILCO, InvertedPendulum-v5",
        "compare_InvertedPendulum-v5_noisefloor110",
        _balance_row,
    ),
    _row("Baselines (SB3, TorchRL PILCO)", "compare_CartpoleSwingUp-v0_hold2_sb3", _cartpole_row),
    _row("Baselines, UR10 tracking (SB3 SAC)", "compare_UR10-v0_positions", _tracking_row),
    _row(
        "Baselines, marker-camera reaching (SB3 SAC)",
        "compare_MarkerCameraReach-v0",
        _reaching_row,
    ),
)
"""The comparison's rows of the results index."""


def replot(result: Result, json_path: Path) -> list[Path]:
    """Redraw a comparison's figure (``.png`` next to its result file) from the file."""
    return [plot(result.payload(), Path(json_path).with_suffix(".png"))]

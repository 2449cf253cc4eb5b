"""MC-PILCO against PILCO and SB3 SAC / TD3 / PPO on one task env: one run of a method on one
seed as a learning curve, the curves aggregated over seeds, and the data-efficiency ratios.

Every run yields a learning curve (``mcpilco-curve/1``, :mod:`mcpilco.agents.baselines.common`):
success rate against seconds of experience. Per method, :func:`aggregate_method` holds each
seed's last evaluation between evaluations (0 before the first), averages over seeds up to
the shortest seed's budget, and reads ``T90``, the first experience with a mean success rate
>= 0.9, and ``T100``, the first experience at which every seed's last evaluation succeeds.
:func:`headline` divides each method's ``T90`` (and ``T100``) by MC-PILCO's and checks the
two data-efficiency targets: the best SB3 method needs >= :data:`GOAL_SB3_RATIO` times
MC-PILCO's experience, PILCO more than MC-PILCO. A method that never reaches 0.9 within its
budget ``B`` has ``T90 > B``, so its ratio is a lower bound.

:func:`run_method` runs (or resumes) one method on one seed and keeps its curve at
:func:`curve_path`; :func:`build_report` aggregates the curves of one env. The benchmark face
(the sweep over seeds, the result file, its Markdown and figure; ``mcpilco-compare``) is
:mod:`mcpilco.experiments.mcpilco.compare`.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.agents.baselines.common import (
    check_task_env,
    make_curve,
    save_curve,
    trial_records_to_points,
)
from mcpilco.agents.mc_pilco.config import load_config
from mcpilco.envs.tasks.spec import TaskSpec
from mcpilco.models.device import retain_host_memory
from mcpilco.models.stats import bootstrap_interval, wilson_interval

SB3_METHODS = ("sac", "td3", "ppo")  # the model-free methods, stable-baselines3's names
METHODS = ("mcpilco", "pilco", *SB3_METHODS)  # every method, in the reports' order
LABELS = {  # a method's name in tables and legends
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
        "median_seed_t90_ci95": list(bootstrap_interval(reached, "median")) if reached else None,
        "seeds_reaching_90_ci95": list(wilson_interval(len(reached), len(curves))),
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


# ------------------------------------------------------------------------------ curves
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

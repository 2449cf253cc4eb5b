"""The diagnosis benchmark: top-1 / top-3 accuracy on many random hidden-effect cases.

Each case (:func:`mcpilco.experiments.hidden_effects.make_case`, SCARA or UR10, seed ``s``):
one random effect on a random joint with a random magnitude (every ``control_every``-th
case: no effect; every ``multi_every``-th: two effects at once). A start model (nominal
physics, or a GIP / RBF GP learned on the training files; :func:`make_start`) is fitted and
:func:`~mcpilco.models.diagnosis.diagnose` ranks the candidates; a case counts for top-k
when the true ``key:joint`` is among the first k candidates of the ranking (significant
first, then by evidence). Then the ranked effects are added one by one
(:func:`~mcpilco.models.diagnosis.auto_improve`: add the best, refit, re-diagnose) until none
is significant. Recorded (:func:`run_case`): whether the first verdict names a true effect
(the missing effect, else, on a learned start, the refinement inside the start kernel's
span that the loop adds first), the held-out RMSE / noise of the affected joints before and
after, false alarms on the control cases (a *missing* effect named) and, apart, controls
where an in-span refinement was suggested, seconds per case. :func:`summarise` aggregates
the records; :func:`run_benchmark` runs the cases as sweep jobs and writes the JSON and
Markdown report.
"""

from __future__ import annotations

import datetime
import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.experiments.hidden_effects import make_case
from mcpilco.experiments.sweep import Job, SweepRunner


def _affected_joints(effect: dict[str, Any]) -> list[int]:
    """0-based joints an injected effect changes by at least one noise std."""
    if effect["joint"] is None:
        return [j for j, size in enumerate(effect["size_over_noise"]) if size >= 1.0]
    return [effect["joint"] - 1]


def make_start(kind: str, case: Any, iters: int) -> Any:
    """The start model of a case: nominal physics from the case's robot file, or a GIP/RBF
    GP learned on the training files (the robot file then only serves the payload columns)."""
    from mcpilco.models.diagnosis import LEARNED_STARTS, NominalStart

    if kind == "nominal":
        return NominalStart(case.nominal_xml)
    if kind not in LEARNED_STARTS:
        raise ValueError(f"start must be nominal or one of {sorted(LEARNED_STARTS)}, got {kind!r}")
    return LEARNED_STARTS[kind](
        case.joint_types, robot=case.nominal_xml, adam_iters=iters, lbfgs_iters=max(iters // 3, 1)
    )


def run_case(
    robot: str,
    seed: int,
    n_effects: int,
    duration: float,
    start: str = "nominal",
    max_points: int = 600,
    iters: int = 100,
    train_files: int = 2,
    max_steps: int = 4,
) -> dict[str, Any]:
    """Generate a case, diagnose it, add the ranked effects until none is significant.

    ``n_effects = 0`` is a control case. Top-k counts, for each injected effect, whether it is
    among the first k candidates of the first diagnosis (single-effect cases: the usual top-k;
    with several effects each must be in the first ``k + n_effects - 1``). After
    :func:`auto_improve` the held-out RMSE of the affected joints is divided by the noise std.
    """
    from mcpilco.models.diagnosis import DiagnosisModel, as_trajectories, auto_improve, heldout_rmse

    t0 = time.perf_counter()
    case = make_case(
        robot,
        [] if n_effects == 0 else None,
        n_effects=max(n_effects, 1),
        seed=seed,
        n_train=train_files,
        duration=duration,
    )
    test = as_trajectories(case.datasets("test"))
    model = DiagnosisModel(make_start(start, case, iters), max_points=max_points)
    model.fit(case.datasets("train"))
    versions, diags = auto_improve(model, test, max_steps=max_steps)
    first = diags[0]
    ranking = [c.label for c in first.candidates]
    truth = case.truth()
    added = [e.label for e in versions[-1].effects]
    rec: dict[str, Any] = {
        "robot": robot,
        "start": start,
        "seed": seed,
        "truth": truth,
        "effect": case.effects,
        "verdict": None if first.best is None else first.best.label,
        "refinement": None if first.refinement is None else first.refinement.label,
        "ranking": ranking[:5],
        "deltas": [round(c.delta, 1) for c in first.candidates[:5]],
        "added": added,
        "start_rounds": getattr(model.start, "rounds_", None),
    }
    if truth:
        ranks = [ranking.index(t) + 1 if t in ranking else None for t in truth]
        extra = len(truth) - 1
        rec.update(
            rank=ranks[0] if len(ranks) == 1 else ranks,
            top1=all(r is not None and r <= 1 + extra for r in ranks),
            top3=all(r is not None and r <= 3 + extra for r in ranks),
            verdict_correct=(first.lead is not None and first.lead.label in truth),
            all_found=set(truth) <= set(added),
        )
        rmse0 = heldout_rmse(versions[0], test) / case.noise_std
        rmse = heldout_rmse(versions[-1], test) / case.noise_std
        joints = sorted({j for e in case.effects for j in _affected_joints(e)})
        rec["rmse_over_noise_before"] = float(np.max(rmse0[joints]))
        rec["rmse_over_noise_after"] = float(np.max(rmse[joints]))
    else:
        rec["false_alarm"] = first.best is not None  # a *missing* effect named
        rec["refined"] = first.refinement is not None  # an in-span refinement suggested
    rec["seconds"] = time.perf_counter() - t0
    return rec


ABSORBED = 1.5
"""An injected effect is *absorbed* by the start model when the start model's held-out RMSE
on the affected joints is already within this many noise stds (a learned GIP start spans
e.g. armature and payload torques): nothing is missing, so such cases are left out of the
top-k accuracy and counted apart."""


def summarise(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Top-k over visible single-effect cases; all-found over visible multi-effect cases;
    RMSE after the loop over every effect case; false alarms over the control cases."""
    visible = [r for r in records if r["truth"] and r["rmse_over_noise_before"] > ABSORBED]
    absorbed = [r for r in records if r["truth"] and r["rmse_over_noise_before"] <= ABSORBED]
    eff = [r for r in visible if len(r["truth"]) == 1]
    multi = [r for r in visible if len(r["truth"]) > 1]
    ctl = [r for r in records if not r["truth"]]
    after = [r["rmse_over_noise_after"] for r in records if r["truth"]]
    by_key: dict[str, list[bool]] = {}
    for r in eff:
        by_key.setdefault(r["truth"][0].split(":")[0], []).append(bool(r["top1"]))
    return {
        "n_absorbed_by_start_model": len(absorbed),
        "absorbed": [", ".join(r["truth"]) for r in absorbed],
        "n_effect_cases": len(eff),
        "n_multi_effect_cases": len(multi),
        "n_control_cases": len(ctl),
        "top1": float(np.mean([r["top1"] for r in eff])) if eff else None,
        "top3": float(np.mean([r["top3"] for r in eff])) if eff else None,
        "verdict_correct": float(np.mean([r["verdict_correct"] for r in eff])) if eff else None,
        "multi_all_found": float(np.mean([r["all_found"] for r in multi])) if multi else None,
        "within_1p5_noise_after_add": float(np.mean(np.array(after) <= 1.5)) if after else None,
        "false_alarm_rate": float(np.mean([r["false_alarm"] for r in ctl])) if ctl else None,
        "controls_with_in_span_refinement": (
            f"{sum(bool(r.get('refined')) for r in ctl)}/{len(ctl)}" if ctl else None
        ),
        "top1_by_effect": {k: f"{sum(v)}/{len(v)}" for k, v in sorted(by_key.items())},
        "seconds_per_case": float(np.mean([r["seconds"] for r in records])),
    }


def case_effects(cases: int, control_every: int, multi_every: int) -> list[int]:
    """Number of injected effects of each case: 0 for every ``control_every``-th case (from
    the first), 2 for every ``multi_every``-th other case, else 1 (0 turns either off)."""
    n_effects = []
    for k in range(cases):
        if control_every > 0 and k % control_every == 0:
            n_effects.append(0)
        elif multi_every > 0 and k % multi_every == multi_every - 1:
            n_effects.append(2)
        else:
            n_effects.append(1)
    return n_effects


def markdown(records: list[dict[str, Any]], summary: dict[str, Any], title: str) -> str:
    """The report: the summary table, then one row per case."""
    lines = [f"# {title}", "", "| metric | value |", "|---|---|"]
    for k, v in summary.items():
        lines.append(f"| {k} | {v if not isinstance(v, float) else round(v, 3)} |")
    lines += [
        "",
        "| seed | truth | missing effect | in-span refinement | rank | added "
        "| RMSE/noise before | after |",
        "|---|---|---|---|---|---|---|---|",
    ]

    def num(r: dict[str, Any], k: str) -> str:
        return f"{r[k]:.2f}" if k in r else ""

    for r in records:
        lines.append(
            f"| {r['seed']} | {', '.join(r['truth']) or 'none'} | {r['verdict']} | "
            f"{r.get('refinement') or ''} | {r.get('rank', '')} | {', '.join(r['added']) or '-'} | "
            f"{num(r, 'rmse_over_noise_before')} | {num(r, 'rmse_over_noise_after')} |"
        )
    return "\n".join(lines) + "\n"


def run_benchmark(
    runner: SweepRunner,
    *,
    cases: int = 30,
    robot: str = "scara",
    first_seed: int = 1000,
    control_every: int = 5,
    multi_every: int = 0,
    start: str = "nominal",
    max_points: int = 600,
    iters: int = 100,
    duration: float = 12.0,
    train_files: int = 2,
    out: str | Path = "results/diagnosis",
    runs_dir: str | Path = "runs/bench_diagnosis",
    config: dict[str, Any] | None = None,
) -> dict[str, Any] | None:
    """Run ``cases`` cases (seeds ``first_seed ...``; :func:`case_effects`) as sweep jobs of
    ``runner``, each record kept in ``runs_dir/<robot>/<start>/seed<s>.json`` (a rerun
    computes only the cases without one), and write ``out`` + ``.json`` (``config``, the
    summary, every record, the failed cases) and ``.md``.

    Returns ``{"summary", "records", "markdown", "sweep"}``, or None when no case finished.
    """
    seeds = [first_seed + k for k in range(cases)]
    n_effects = case_effects(cases, control_every, multi_every)
    case = {
        "robot": robot,
        "duration": duration,
        "start": start,
        "max_points": max_points,
        "iters": iters,
        "train_files": train_files,
    }
    jobs = [
        Job(f"seed{s}", run_case, {**case, "seed": s, "n_effects": n})
        for s, n in zip(seeds, n_effects, strict=True)
    ]
    sweep = runner.run(jobs, Path(runs_dir) / robot / start, desc="cases")
    print(sweep.summary())
    records = list(sweep.results.values())
    if not records:
        return None
    summary = summarise(records)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    payload = {"config": config, "summary": summary, "cases": records}
    if sweep.failed:
        payload["failed"] = [f.key for f in sweep.failed]
    out.with_suffix(".json").write_text(json.dumps(payload, indent=1, default=str))
    title = (
        f"Diagnosis benchmark ({robot}, {len(records)} cases, seeds "
        f"{seeds[0]}..{seeds[-1]}, {start} start)"
    )
    text = markdown(records, summary, title)
    out.with_suffix(".md").write_text(text)
    return {"summary": summary, "records": records, "markdown": text, "sweep": sweep}


# ----------------------------------------------------------------------------- speed

SPEED_EFFECT = ("damping", 2, 0.5)
"""Hidden effect of the speed case: viscous damping 0.5 N m s/rad on joint 2."""


def speed_case(
    directory: str | Path,
    seed: int = 0,
    n_joints: int = 3,
    train_files: int = 3,
    duration: float = 10.0,
) -> dict[str, Any]:
    """Write the speed case: a rigid random arm (``n_joints`` revolute joints, arm seed
    ``seed``) with :data:`SPEED_EFFECT`, simulated by
    :func:`~mcpilco.envs.robot_logs.simulate_log` (position-only files: ``t, q, tau``);
    ``train_files`` training logs of ``duration`` s (seeds ``seed..``; 3 x 10 s at 4 ms:
    7,503 rows) and one held-out log, and the nominal MJCF (no friction).

    Returns:
        ``{"train": [paths], "test": [path], "model": path, "joint_types", "rows"}``
        (``rows``: training rows).
    """
    from mcpilco.envs.arm_builder import arm_to_xml
    from mcpilco.envs.arms import random_arm
    from mcpilco.envs.robot_logs import HiddenEffect, simulate_log, write_log

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    arm = random_arm(n_joints, seed=seed, joint_types="R" * n_joints).rigid()
    xml = directory / "arm.xml"
    xml.write_text(arm_to_xml(arm, friction=False))
    effect = [HiddenEffect(*SPEED_EFFECT)]
    paths, rows = [], 0
    for k in range(train_files + 1):
        log = simulate_log(arm, effect, duration=duration, seed=seed + k)
        paths.append(str(write_log(directory / f"log{k}.csv", log)))
        rows += len(log.table) if k < train_files else 0
    return {
        "train": paths[:-1],
        "test": paths[-1:],
        "model": str(xml),
        "joint_types": "R" * n_joints,
        "rows": rows,
    }


def time_diagnosis(case: dict[str, Any], start: str, auto: int = 3) -> dict[str, Any]:
    """Run :func:`~mcpilco.models.diagnosis.run_diagnosis` on ``case`` (:func:`speed_case`)
    with a nominal or a GIP start and ``--auto auto``, without plots; its wall and CPU
    seconds (``time.process_time``: every thread of this process), verdict and versions."""
    import tempfile
    import warnings

    from mcpilco.models.diagnosis import run_diagnosis

    learned = None if start == "nominal" else (start, case["joint_types"])
    with tempfile.TemporaryDirectory() as out, warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # position-only files: estimated qd
        t0, c0 = time.perf_counter(), time.process_time()
        summary = run_diagnosis(
            case["train"],
            case["test"],
            model=case["model"],
            learned=learned,
            auto=auto,
            out=out,
            plots=False,
            rerun=False,
            log=lambda text: None,
        )
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    robot = Path(case["model"])
    return {
        "start": start,
        "wall_s": wall,
        "cpu_s": cpu,
        "versions": [v.replace(str(robot), robot.name) for v in summary["versions"]],
        "rmse_over_floor": summary["rmse_over_floor"][-1],
        "verdict": summary["verdict"],
    }


def run_speed(
    out: str | Path = "results/diagnosis_speed",
    seed: int = 0,
    starts: tuple[str, ...] = ("nominal", "gip"),
    auto: int = 3,
    workdir: str | Path | None = None,
    train_files: int = 3,
    duration: float = 10.0,
) -> dict[str, Any]:
    """Time the diagnosis loop on the speed case (:func:`speed_case`: 3 joints, 7,503
    training rows) with each start in ``starts`` (:func:`time_diagnosis`) and write ``out``
    ``.json`` and ``.md``. The targets: nominal start under 10 s, GIP start under 60 s
    (``train_files``, ``duration``: a smaller case, :func:`speed_case`).

    Returns:
        ``{"case", "records", "markdown"}``.
    """
    import platform
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        case = speed_case(workdir or tmp, seed=seed, train_files=train_files, duration=duration)
        records = [time_diagnosis(case, s, auto=auto) for s in starts]
    info = {
        "seed": seed,
        "effect": list(SPEED_EFFECT),
        "joints": len(case["joint_types"]),
        "training_rows": case["rows"],
        "auto": auto,
        "cpu_count": os.cpu_count(),
        "load_average_1min": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
        "machine": platform.processor() or platform.machine(),
    }
    text = speed_markdown(info, records)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "command": "mcpilco-bench-diagnosis --speed",
        "seeds": [seed],
        "measured": datetime.date.today().isoformat(),
        "case": info,
        "records": records,
    }
    out.with_suffix(".json").write_text(json.dumps(payload, indent=1, default=float))
    out.with_suffix(".md").write_text(text)
    return {"case": info, "records": records, "markdown": text}


def speed_markdown(info: dict[str, Any], records: list[dict[str, Any]]) -> str:
    """The speed report of :func:`run_speed` (``info``: its case, ``records``: one per
    start) as Markdown."""
    load = info["load_average_1min"]
    lines = [
        f"# Diagnosis speed ({info['joints']} joints, {info['training_rows']} training rows, "
        f"seed {info['seed']})",
        "",
        f"Hidden effect: {info['effect'][0]} {info['effect'][2]} on joint {info['effect'][1]}; "
        f"`run_diagnosis(..., auto={info['auto']}, plots=False)`; {info['cpu_count']} cores, "
        f"load average {'n/a' if load is None else f'{load:.1f}'} when it ended (wall time "
        "depends on the other jobs; CPU time less so).",
        "",
        "| start | wall [s] | CPU [s] | versions | RMSE / floor (last) | verdict |",
        "|---|---|---|---|---|---|",
    ]
    for r in records:
        added = r["versions"][-1].split(" + ", 1)[-1]
        ratio = ", ".join(f"{x:.2f}" for x in r["rmse_over_floor"])
        lines.append(
            f"| {r['start']} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} | {len(r['versions'])} "
            f"({added}) | {ratio} | {r['verdict'].split(':', 1)[-1].split(' (')[0].strip()} |"
        )
    return "\n".join(lines) + "\n"

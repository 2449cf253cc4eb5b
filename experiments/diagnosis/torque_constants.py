"""Motor-current logs: are the torque constants' intervals right, and does the loop still
name unit mismatches as effects?

Each case (seed ``s``): a random 3-joint arm (:func:`~mcpilco.envs.arms.random_arm`, joint
types drawn, rigid), torque constants drawn per joint, ``|k_t| = 10^U(-1, 0.5)`` N m/A (or
N/A) with a random sign (a motor mounted reversed), two position-and-current logs of
``duration`` s (:func:`~mcpilco.envs.robot_logs.simulate_log`, log seeds ``2 s`` for training
and ``2 s + 1`` held out, current noise :data:`CURRENT_NOISE`) written as files and loaded as
a user's would be. Every ``control_every``-th case has no hidden effect; the others a hidden
damping on a random joint (``U(0.2, 1)`` N m s/rad or N s/m).

Per case (:func:`run_case`): the constants estimated on the training log
(:func:`~mcpilco.models.diagnosis.currents_to_torque`); joints it finds not identifiable
(the loop would diagnose them in A) are recorded and then given their true constant (as a
user would from a datasheet) while the others are estimated; ``z = (k_hat - k) / sd(k)`` of
every estimated joint. Then
:func:`~mcpilco.models.diagnosis.diagnose` of the nominal (true) rigid-body model in torque
units: the missing effect it names, the significant candidates of the kinds a unit mismatch
looks like (:data:`UNIT_KINDS`), the held-out RMSE over the noise floor; for damping cases
whether ``viscous:j`` is named and its ``F_v`` interval holds the truth. For contrast, the
held-out RMSE over the floor of the same model on the currents read in amperes.
:func:`summarise` aggregates; :func:`run_benchmark` runs the cases as sweep jobs and writes
the JSON and Markdown report.
"""

from __future__ import annotations

import tempfile
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.experiments.infra.sweep import Job, SweepRunner
from mcpilco.experiments.results import Headline, Result, ResultLayout, write_result
from mcpilco.models.stats import Z95

CURRENT_NOISE = 0.01
"""Standard deviation of the logged currents' noise [A]."""
UNIT_KINDS = ("spring", "offset", "cogging", "payload", "armature", "deadzone")
"""Candidate kinds that a scaled copy of a joint's torque (a unit mismatch) is named as."""


def run_case(seed: int, duration: float = 4.0, control: bool = False) -> dict[str, Any]:
    """One case (module docstring): its constants, their errors and the diagnosis."""
    from mcpilco.envs.arm_builder import arm_to_xml
    from mcpilco.envs.arms import random_arm
    from mcpilco.envs.robot_logs import HiddenEffect, simulate_log, write_log
    from mcpilco.models.diagnosis import (
        DiagnosisModel,
        NominalStart,
        currents_to_torque,
        diagnose,
        floor_check,
        load_trajectories,
    )

    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    arm = random_arm(3, seed=seed).rigid()
    k_true = 10 ** rng.uniform(-1.0, 0.5, 3) * rng.choice([-1.0, 1.0], 3)
    effects = []
    if not control:
        joint = int(rng.integers(1, 4))
        effects = [HiddenEffect("damping", joint, float(rng.uniform(0.2, 1.0)))]
    with tempfile.TemporaryDirectory() as folder, warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        trajs = []
        for k in (0, 1):
            log = simulate_log(
                arm,
                effects,
                duration=duration,
                seed=2 * seed + k,
                torque_constants=k_true,
                current_noise=CURRENT_NOISE,
            )
            trajs.append(load_trajectories([write_log(Path(folder) / f"log{k}.csv", log)]))
    train_i, test_i = trajs
    start = NominalStart(arm_to_xml(arm, friction=False))
    train, test, constants = currents_to_torque(train_i, test_i, start)
    refused = [int(j) + 1 for j in np.flatnonzero(constants.in_current)]
    if refused:
        given = [float(k_true[j - 1]) if j in refused else None for j in range(1, 4)]
        train, test, constants = currents_to_torque(train_i, test_i, start, given)
    estimated = ~constants.given
    z = (constants.value - k_true)[estimated] / constants.std[estimated]
    d = diagnose(DiagnosisModel(start, constants.effects()).fit(train), test)
    amps = floor_check(DiagnosisModel(start).fit(train_i), test_i)
    unit_named = [c.label for c in d.candidates if c.significant and c.effect.key in UNIT_KINDS]
    rec: dict[str, Any] = {
        "seed": seed,
        "joint_types": arm.joint_types,
        "k_true": k_true.tolist(),
        "k_hat": constants.value.tolist(),
        "ci95": constants.ci95.tolist(),
        "refused": refused,
        "z": z.tolist(),
        "truth": [f"viscous:{e.joint}" for e in effects],
        "value": [e.value for e in effects],
        "missing": None if d.best is None else d.best.label,
        "unit_named": unit_named,
        "ratio": d.base.ratio.tolist(),
        "ratio_in_amps": amps.ratio.tolist(),
        "verdict": d.verdict(),
    }
    if effects:
        best = d.best
        found = best is not None and best.label == rec["truth"][0]
        rec["found"] = found
        if found:
            (f_v,) = best.estimates
            rec["f_v"] = [f_v.value, f_v.ci95]
            rec["f_v_covered"] = bool(abs(f_v.value - effects[0].value) <= f_v.ci95)
    rec["seconds"] = time.perf_counter() - t0
    return rec


def summarise(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Coverage of the 95% intervals over every estimated joint, refusals, false alarms and
    unit-like effects on the controls, damping found (and its ``F_v`` covered)."""
    z = np.concatenate([np.asarray(r["z"], dtype=float) for r in records])
    rel = np.concatenate([np.asarray(r["ci95"]) / np.abs(np.asarray(r["k_hat"])) for r in records])
    rel = rel[rel > 0]
    controls = [r for r in records if not r["truth"]]
    damped = [r for r in records if r["truth"]]
    found = [r for r in damped if r["found"]]
    joints = sum(len(r["k_true"]) for r in records)
    return {
        "cases": len(records),
        "estimated_joints": int(z.size),
        "ci95_coverage": float(np.mean(np.abs(z) <= Z95)) if z.size else None,
        "z_rms": float(np.sqrt(np.mean(z**2))) if z.size else None,
        "median_relative_ci95": float(np.median(rel)) if rel.size else None,
        "refused_joints": f"{sum(len(r['refused']) for r in records)}/{joints}",
        "controls": len(controls),
        "controls_missing_effect_named": sum(r["missing"] is not None for r in controls),
        "controls_unit_like_effect_significant": sum(bool(r["unit_named"]) for r in controls),
        "controls_at_floor": sum(max(r["ratio"]) <= 1.2 for r in controls),
        "cases_off_floor_in_amps": sum(max(r["ratio_in_amps"]) > 1.2 for r in records),
        "damping_cases": len(damped),
        "damping_named": len(found),
        "damping_f_v_covered": sum(bool(r.get("f_v_covered")) for r in found),
        "seconds_per_case": float(np.mean([r["seconds"] for r in records])),
    }


def markdown(records: list[dict[str, Any]], summary: dict[str, Any], title: str) -> str:
    """The report: the summary table, then one row per case."""
    lines = [f"# {title}", "", "| metric | value |", "|---|---|"]
    for k, v in summary.items():
        lines.append(f"| {k} | {round(v, 3) if isinstance(v, float) else v} |")
    lines += [
        "",
        "| seed | joints | k_t true | k_t estimated ± 95% | refused | hidden | named "
        "| unit-like significant | RMSE/floor | in A |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in records:
        est = ", ".join(
            f"{k:.4g} ± {c:.2g}" if c > 0 else f"{k:.4g} (given)"
            for k, c in zip(r["k_hat"], r["ci95"], strict=True)
        )
        lines.append(
            f"| {r['seed']} | {r['joint_types']} | "
            f"{', '.join(f'{k:.4g}' for k in r['k_true'])} | {est} | "
            f"{', '.join(map(str, r['refused'])) or '-'} | "
            f"{', '.join(r['truth']) or 'none'} | {r['missing'] or '-'} | "
            f"{', '.join(r['unit_named']) or '-'} | {max(r['ratio']):.2f} | "
            f"{max(r['ratio_in_amps']):.3g} |"
        )
    return "\n".join(lines) + "\n"


def run_benchmark(
    runner: SweepRunner,
    *,
    cases: int = 20,
    first_seed: int = 100,
    control_every: int = 2,
    duration: float = 4.0,
    out: str | Path = "results/torque_constants",
    runs_dir: str | Path = "runs/bench_torque_constants",
    config: dict[str, Any] | None = None,
) -> dict[str, Any] | None:
    """Run ``cases`` cases (seeds ``first_seed ...``; every ``control_every``-th, from the
    first, without a hidden effect) as sweep jobs, each record kept in
    ``runs_dir/seed<s>.json`` (a rerun computes only the missing ones), and write ``out`` +
    ``.json`` (config, command, seeds, summary, records) and ``.md``.

    Returns ``{"summary", "records", "markdown", "sweep"}``, or None when no case finished.
    """
    if cases < 1 or control_every < 1 or not duration > 0:
        raise ValueError(
            f"need cases >= 1, control_every >= 1 and duration > 0; got {cases}, "
            f"{control_every}, {duration}"
        )
    seeds = [first_seed + k for k in range(cases)]
    jobs = [
        Job(
            f"seed{s}",
            run_case,
            {"seed": s, "duration": duration, "control": k % control_every == 0},
        )
        for k, s in enumerate(seeds)
    ]
    sweep = runner.run(jobs, Path(runs_dir), desc="cases")
    print(sweep.summary())
    records = [sweep.results[j.key] for j in jobs if j.key in sweep.results]
    if not records:
        return None
    summary = summarise(records)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "config": config,
        "command": (
            f"mcpilco-bench-torque-constants --cases {cases} "
            f"--first-seed {first_seed} "
            f"--control-every {control_every} --duration {duration:g}"
        ),
        "seeds": seeds,
        "measured": time.strftime("%Y-%m-%d"),
        "summary": summary,
        "cases": records,
    }
    if sweep.failed:
        payload["failed"] = [f.key for f in sweep.failed]
    write_result(out.with_suffix(".json"), RESULT_LAYOUTS[0], payload)
    title = (
        f"Torque constants of motor-current logs ({len(records)} random 3-joint arms, seeds "
        f"{seeds[0]}..{seeds[-1]}, {duration:g} s logs)"
    )
    text = markdown(records, summary, title)
    out.with_suffix(".md").write_text(text)
    return {"summary": summary, "records": records, "markdown": text, "sweep": sweep}


# -- result file and headline rows of the results index -----------------------------------

RESULT_LAYOUTS = (ResultLayout("torque_constants", config=("config", "seeds"), cases=("cases",)),)
"""The layout of ``torque_constants.json`` (:mod:`mcpilco.experiments.results`)."""


def _torque_constants_row(r: Result) -> str:
    s = r["summary"]
    covered = round(s["ci95_coverage"] * s["estimated_joints"])
    return (
        f"k_t 95% intervals hold the truth on {covered}/{s['estimated_joints']} joints; "
        f"{s['controls_missing_effect_named']}/{s['controls']} controls name an effect; "
        f"damping named in {s['damping_named']}/{s['damping_cases']}"
    )


HEADLINES = (
    Headline(
        "Diagnosis of motor-current logs (torque constants)",
        "torque_constants.json",
        _torque_constants_row,
        "torque_constants.md",
    ),
)
"""The torque-constant benchmark's row of the results index."""

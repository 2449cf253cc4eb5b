"""Run a collision detector on a logged robot file; write the alarm intervals and a plot.

The file follows the dataset schema of :mod:`mcpilco.models.robot_data` (CSV or Parquet;
columns ``t, q1..qn, qd1..qdn, qdd1..qddn, i1..in``; the FC estimator also needs
``e_q1..e_qn, e_qd1..e_qdn, i_cmd1..i_cmdn``; an optional ``contact`` column is scored as
ground truth). The detector is either

* loaded: ``--detector FILE`` (written by ``CollisionDetector.save``, e.g. by
  ``mcpilco-bench-collision --save-detector FILE``), or
* trained here: ``--train FILE`` (collision-free log of the same robot) with the nominal
  model ``--model`` (MJCF/URDF path; default the UR10 of :mod:`mcpilco.envs.arms`); the last
  ``--calibration-fraction`` of the training file is held out to calibrate the thresholds
  (or give ``--calibrate FILE``); ``--save FILE`` keeps the detector.

Checks (clear errors, exit status 2): a missing current group ``i1..in`` (or controller
groups for FC), NaN/inf values, time not increasing (from the schema loader), a joint
count that differs from the detector's, and a sampling time other than the detector's
(median ``diff(t)`` off by more than ``--rate-tolerance``, or a non-uniform grid).

Outputs (``--out-dir``, default next to the file): ``<stem>_collisions.csv`` (one row per
alarm interval, alarms less than ``--merge-gap`` s apart merged: ``start, end, duration,
joint, peak_ratio``, the last being the largest ``|s_j| / sigma_CD,j``) and
``<stem>_collisions.png``.

Usage::

    mcpilco-detect-collisions log.csv --detector fc.pt
    mcpilco-detect-collisions log.parquet --train free.parquet --estimator FC --save fc.pt
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.agents.common.cli import console_main
from mcpilco.models.collision import (
    CollisionDetector,
    as_collision_inputs,
    evaluate_detection,
    make_estimator,
    runs,
)
from mcpilco.models.robot_data import RobotDataset, load_dataset

INTERVAL_COLUMNS = ("start", "end", "duration", "joint", "peak_ratio")


class InputError(ValueError):
    """A problem with the user's files or options (reported without a traceback)."""


def nominal_model(robot: str = "ur10") -> str:
    """MJCF text of a nominal arm of :mod:`mcpilco.envs.arms` for the rigid-body features
    (no joint limits, no friction: the estimators learn the friction)."""
    from mcpilco.envs import arms
    from mcpilco.envs.arm_builder import arm_to_xml

    factories = {"ur10": arms.ur10, "scara": arms.scara}
    if robot not in factories:
        raise InputError(f"--robot must be one of {sorted(factories)}, got {robot!r}")
    arm = factories[robot]()
    joints = tuple(dataclasses.replace(j, range=None) for j in arm.joints)
    return arm_to_xml(dataclasses.replace(arm, joints=joints).without_friction())


def load_log(path: str | Path, n_joints: int | None = None, fc: bool = False) -> RobotDataset:
    """Read and check a log (schema loader + current / controller groups)."""
    try:
        ds = load_dataset(path, n_joints=n_joints)
    except (ValueError, FileNotFoundError) as err:
        raise InputError(str(err)) from err
    n = ds.n_joints
    if ds.i is None:
        raise InputError(
            f"{path}: missing motor-current columns i1..i{n}: the detector compares measured "
            "currents with their estimate"
        )
    if fc:
        missing = [g for g in ("e_q", "e_qd", "i_cmd") if getattr(ds, g) is None]
        if missing:
            raise InputError(
                f"{path}: the FC estimator needs the controller columns "
                + ", ".join(f"{g}1..{g}{n}" for g in missing)
            )
    return ds


def check_sample_time(ds: RobotDataset, expected: float | None, tolerance: float) -> float:
    """Median ``diff(t)``; raises when it is off ``expected`` or the grid is not uniform."""
    dt = np.diff(ds.t)
    median = float(np.median(dt))
    source = ds.metadata.get("source", "data")
    if expected is not None and abs(median - expected) > tolerance * expected:
        raise InputError(
            f"{source}: wrong sample rate: median time step {median * 1e3:.3f} ms but the "
            f"detector was made for {expected * 1e3:.3f} ms ({1 / expected:.1f} Hz); resample "
            "the log or train a detector at this rate"
        )
    if np.max(np.abs(dt - median)) > 0.5 * median:
        k = int(np.argmax(np.abs(dt - median)))
        raise InputError(
            f"{source}: non-uniform sampling: step {dt[k] * 1e3:.3f} ms at row {k + 1} (median "
            f"{median * 1e3:.3f} ms); the detector needs a uniform grid (no gaps)"
        )
    return median


def train_detector(args: argparse.Namespace) -> CollisionDetector:
    fc = args.estimator == "FC"
    ds = load_log(args.train, fc=fc)
    sample_time = check_sample_time(ds, None, args.rate_tolerance)
    inputs = as_collision_inputs(ds, require_controller=fc)
    n = inputs.n_samples
    if args.calibrate:
        cal = load_log(args.calibrate, n_joints=ds.n_joints, fc=fc)
        check_sample_time(cal, sample_time, args.rate_tolerance)
        fit_rows = np.arange(n)
        cal_inputs, cal_i = as_collision_inputs(cal, require_controller=fc), cal.i
    else:
        cut = int((1.0 - args.calibration_fraction) * n)
        if cut < 10 or n - cut < 10:
            raise InputError(f"{args.train}: too few rows ({n}) to split off a calibration part")
        fit_rows = np.arange(cut)
        cal_inputs, cal_i = inputs.rows(slice(cut, None)), ds.i[cut:]
    step = max(fit_rows.size // args.gp_points, 1)
    rows = fit_rows[::step][: args.gp_points]
    model = args.model if args.model else nominal_model(args.robot)
    est = make_estimator(
        args.estimator,
        model,
        hyper_points=args.hyper_points,
        adam_iters=args.adam_iters,
        lbfgs_iters=args.lbfgs_iters,
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est.fit(inputs.rows(rows), ds.i[rows])
    det = CollisionDetector(est, args.rule, args.false_alarm_rate, args.persistence, sample_time)
    det.calibrate(cal_inputs, cal_i)
    if args.save:
        det.save(args.save)
    return det


def write_intervals(rows: list[dict[str, Any]], path: Path) -> None:
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=INTERVAL_COLUMNS)
        w.writeheader()
        for r in rows:
            w.writerow({k: r[k] for k in INTERVAL_COLUMNS})


def plot(ds: RobotDataset, result: Any, joint: int, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = ds.t
    j = joint - 1
    fig, axes = plt.subplots(2, 1, figsize=(10, 5.5), sharex=True)
    axes[0].plot(t, ds.i[:, j], color="0.4", lw=0.6, label=f"i{joint} measured")
    axes[0].plot(t, result.i_hat[:, j], color="C0", lw=0.9, label=f"i{joint} estimate")
    axes[0].set_ylabel("[A]")
    ratio = np.abs(result.s) / result.thresholds
    for k in range(ratio.shape[1]):
        axes[1].plot(t, ratio[:, k], lw=0.6, label=f"joint {k + 1}")
    axes[1].axhline(1.0, color="C3", ls="--", lw=1, label="threshold")
    axes[1].set_ylabel("|s_j| / sigma_CD,j")
    for a, b in runs(result.alarm):
        for ax in axes:
            ax.axvspan(t[a], t[b], color="C3", alpha=0.25, lw=0)
    if ds.contact is not None:
        for a, b in runs(ds.contact.astype(bool)):
            axes[0].axvspan(t[a], t[b], color="0.8", zorder=0, lw=0)
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=7, ncol=4)
    axes[1].set_xlabel("t [s] (alarms red; ground-truth contact grey, if logged)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("data", help="logged file (CSV / Parquet, dataset schema)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--detector", help="detector file (CollisionDetector.save)")
    src.add_argument("--train", help="collision-free log to train a detector on")
    p.add_argument("--estimator", default="FC", choices=("PP", "SP", "FC"))
    p.add_argument("--model", default=None, help="nominal MJCF/URDF (default: --robot)")
    p.add_argument("--robot", default="ur10", help="nominal arm when --model is not given")
    p.add_argument("--calibrate", default=None, help="collision-free log for the thresholds")
    p.add_argument("--calibration-fraction", type=float, default=0.2)
    p.add_argument("--gp-points", type=int, default=2000)
    p.add_argument("--hyper-points", type=int, default=400)
    p.add_argument("--adam-iters", type=int, default=80)
    p.add_argument("--lbfgs-iters", type=int, default=20)
    p.add_argument("--rule", default="max", choices=("max", "variance"))
    p.add_argument("--false-alarm-rate", type=float, default=0.0)
    p.add_argument("--persistence", type=int, default=None, help="override the detector's")
    p.add_argument("--save", default=None, help="write the trained detector here")
    p.add_argument("--rate-tolerance", type=float, default=0.05, help="relative")
    p.add_argument("--merge-gap", type=float, default=0.25, help="merge alarms closer [s]")
    p.add_argument("--joint", type=int, default=None, help="joint plotted (default: busiest)")
    p.add_argument("--out-dir", default=None)
    return p


def run(argv: Sequence[str] | None = None) -> dict[str, Any]:
    """Everything :func:`main` does; returns a summary (raises :class:`InputError`)."""
    args = build_parser().parse_args(argv)
    if args.train is not None:
        if args.persistence is None:
            args.persistence = 1
        det = train_detector(args)
    else:
        try:
            det = CollisionDetector.load(args.detector)
        except (OSError, ValueError, RuntimeError) as err:
            raise InputError(f"cannot read the detector {args.detector}: {err}") from err
        if args.persistence is not None:
            det.persistence = args.persistence
    fc = det.estimator.requires_controller
    ds = load_log(args.data, n_joints=det.n_joints, fc=fc)
    check_sample_time(ds, det.sample_time, args.rate_tolerance)
    result = det.detect(as_collision_inputs(ds, det.n_joints, fc), ds.i)
    intervals = result.intervals(ds.t, args.merge_gap)
    path = Path(args.data)
    out = Path(args.out_dir) if args.out_dir else path.parent
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / f"{path.stem}_collisions.csv"
    png_path = out / f"{path.stem}_collisions.png"
    write_intervals(intervals, csv_path)
    ratio = np.abs(result.s) / result.thresholds
    joint = args.joint or int(np.argmax(ratio.max(axis=0))) + 1
    if not 1 <= joint <= det.n_joints:
        raise InputError(f"--joint must be in 1..{det.n_joints}, got {joint}")
    plot(ds, result, joint, png_path)
    summary: dict[str, Any] = {
        "intervals": intervals,
        "csv": str(csv_path),
        "png": str(png_path),
        "detector": det.describe(),
    }
    if ds.contact is not None:
        ev = evaluate_detection(result.alarm, ds.contact, ds.t)
        summary["score"] = {k: v for k, v in ev.items() if k != "pushes"}
    return summary


@console_main("mcpilco-detect-collisions")
def main(argv: Sequence[str] | None = None) -> int:
    """CLI entry point: 0 on success, 2 on a bad file or option (message on stderr)."""
    try:
        summary = run(argv)
    except InputError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"{len(summary['intervals'])} alarm interval(s) -> {summary['csv']}, {summary['png']}")
    if "score" in summary:
        s = summary["score"]
        print(
            f"ground truth: {s['n_pushes']} contact(s), detection rate {s['detection_rate']:.2f}, "
            f"median latency {s['median_latency'] * 1e3:.0f} ms, "
            f"{s['false_alarms']} false alarm(s)"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

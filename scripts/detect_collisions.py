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
groups for FC), NaN/inf values, time not increasing, a joint count that differs from the
detector's, and a sampling time other than the detector's (median ``diff(t)`` off by more
than ``--rate-tolerance``, or a non-uniform grid).

Outputs (``--out-dir``, default next to the file): ``<stem>_collisions.csv`` (one row per
alarm interval, alarms less than ``--merge-gap`` s apart merged: ``start, end, duration,
joint, peak_ratio``) and ``<stem>_collisions.png``. The work is
:func:`mcpilco.models.collision.detect.detect_collisions`.

Usage::

    mcpilco-detect-collisions log.csv --detector fc.pt
    mcpilco-detect-collisions log.parquet --train free.parquet --estimator FC --save fc.pt
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from mcpilco.agents.common.cli import console_main, number_arg
from mcpilco.experiments.collision.nominal import nominal_model
from mcpilco.models.collision import InputError
from mcpilco.models.collision.detect import detect_collisions


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
    p.add_argument(
        "--calibration-fraction", type=number_arg(0, 1, lo_open=True, hi_open=True), default=0.2
    )
    p.add_argument("--gp-points", type=number_arg(10, 1_000_000, integer=True), default=2000)
    p.add_argument("--hyper-points", type=number_arg(10, 100_000, integer=True), default=400)
    p.add_argument("--adam-iters", type=number_arg(0, 1_000_000, integer=True), default=80)
    p.add_argument("--lbfgs-iters", type=number_arg(0, 1_000_000, integer=True), default=20)
    p.add_argument("--rule", default="max", choices=("max", "variance"))
    p.add_argument("--false-alarm-rate", type=number_arg(0, 1, hi_open=True), default=0.0)
    p.add_argument(
        "--persistence",
        type=number_arg(1, 10_000, integer=True),
        default=None,
        help="override the detector's",
    )
    p.add_argument("--save", default=None, help="write the trained detector here")
    p.add_argument(
        "--rate-tolerance", type=number_arg(0, 1, lo_open=True), default=0.05, help="relative"
    )
    p.add_argument(
        "--merge-gap", type=number_arg(0, 1e6), default=0.25, help="merge alarms closer [s]"
    )
    p.add_argument(
        "--joint",
        type=number_arg(1, 1_000, integer=True),
        default=None,
        help="joint plotted (default: busiest)",
    )
    p.add_argument("--out-dir", default=None)
    return p


@console_main("mcpilco-detect-collisions")
def main(argv: Sequence[str] | None = None) -> int:
    """CLI entry point: 0 on success, 2 on a bad file or option (message on stderr)."""
    options = vars(build_parser().parse_args(argv))
    robot = options.pop("robot")
    try:
        if options["train"] is not None and not options["model"]:
            options["model"] = nominal_model(robot)
        summary = detect_collisions(options.pop("data"), **options)
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

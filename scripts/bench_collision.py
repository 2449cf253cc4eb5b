"""Benchmark: proprioceptive collision detection on the simulated UR10 (thesis section 4.6).

Simulated data (:mod:`mcpilco.experiments.collision.data`): a collision-free training run of
``--train-waypoints`` random waypoints, a validation run (``--test-waypoints`` waypoints, the
tool circle, a final rest) that calibrates the thresholds, ``--push-free-minutes`` of
push-free data for the false alarms, a run of ``--push-waypoints`` waypoints with random
pushes, and the thesis Fig. 4.3 scenario (``--scenario-force`` N pushes).

Estimators PP, SP, FC (``sigma_v`` by cross-validation among ``--sigma-v-candidates``) and
PP-sign; thresholds by the thesis rule (``max``) and the variance rule; persistence ``m``
in ``--persistence``; detection against false alarms for the validation quantiles
``--alphas`` and ``--roc-persistence``
(:mod:`mcpilco.experiments.collision.bench`).

The data are kept in ``RUNS_DIR/data.pt`` (reused while the data options are the same);
the ``sigma_v`` cross-validation and each estimator are sweep jobs in ``--jobs`` local
processes or on Ray (``--ray [ADDRESS]``; a multi-node cluster needs ``--runs-dir`` on a
shared file system), each writing ``RUNS_DIR/<label>.json``: a rerun computes only the jobs
without one. By default the GPs are conditioned on 5000 rows, the thesis' size;
``--gp-points 2000 --hyper-points 600`` is a cheaper, reduced run.

Outputs (``--out-dir``, default ``results/``): ``collision.json``, ``collision.md``,
``collision_rmse.png`` (Fig. 4.2), ``collision_detection.png`` (Fig. 4.3),
``collision_roc.png``.

Usage::

    mcpilco-bench-collision                                     # thesis sizes
    mcpilco-bench-collision --gp-points 2000 --hyper-points 600
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from mcpilco.agents.common.cli import console_main
from mcpilco.experiments.collision.bench import run_benchmark
from mcpilco.experiments.collision.report import ESTIMATOR_NAMES
from mcpilco.experiments.infra.sweep import SweepError, add_sweep_arguments, runner_from_args


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--train-waypoints", type=int, default=200)
    p.add_argument("--gp-points", type=int, default=5000, help="GP conditioning rows")
    p.add_argument("--hyper-points", type=int, default=800, help="rows for hyperparameters")
    p.add_argument("--adam-iters", type=int, default=80)
    p.add_argument("--lbfgs-iters", type=int, default=20)
    p.add_argument("--test-waypoints", type=int, default=50)
    p.add_argument("--final-rest", type=float, default=10.0, help="rest after the circle [s]")
    p.add_argument("--push-free-minutes", type=float, default=10.0)
    p.add_argument("--push-waypoints", type=int, default=40)
    p.add_argument("--scenario-force", type=float, default=40.0, help="Fig. 4.3 pushes [N]")
    p.add_argument("--scenario-joint", type=int, default=1, help="joint shown in Fig. 4.3")
    p.add_argument("--estimators", default=",".join(ESTIMATOR_NAMES))
    p.add_argument("--no-pp-sign", dest="pp_sign", action="store_false")
    p.add_argument("--variance-estimators", default="FC", help="also the variance rule")
    p.add_argument("--sigma-v-candidates", default="0.003,0.01,0.03,0.1")
    p.add_argument("--cv-points", type=int, default=1000, help="CV training rows")
    p.add_argument("--cv-validation", type=int, default=5000, help="CV validation rows")
    p.add_argument("--cv-hyper-points", type=int, default=400, help="CV hyperparameter rows")
    p.add_argument("--rmse-sigma-v", type=float, default=1e-2, help="RMSE split [rad/s]")
    p.add_argument("--persistence", default="1,2,3")
    p.add_argument("--alphas", default="0,1e-5,3e-5,1e-4,3e-4,1e-3,3e-3")
    p.add_argument("--roc-persistence", default="1,2")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=1, help="torch threads")
    p.add_argument("--out-dir", default="results")
    p.add_argument("--save-detector", default=None, help="write the FC detector (max rule)")
    p.add_argument(
        "--runs-dir",
        type=Path,
        default=Path("runs/bench_collision"),
        help="simulated data (data.pt) and one result file per job, reused by a rerun",
    )
    p.add_argument("--no-progress", action="store_true")
    add_sweep_arguments(p)  # --jobs N (local processes), --ray [ADDRESS]: CV and estimators
    return p


def _list(value: str, kind: type = str) -> list:
    return [kind(v) for v in value.split(",") if v.strip()]


@console_main("mcpilco-bench-collision")
def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark; write JSON, PNGs and Markdown; print the Markdown. Returns 0 (1 when
    a job failed)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        runner = runner_from_args(args, progress=not args.no_progress)
    except SweepError as err:
        parser.error(str(err))
    args.estimators = _list(args.estimators)
    bad = [e for e in args.estimators if e not in ESTIMATOR_NAMES]
    if bad:
        raise SystemExit(f"unknown estimator(s) {bad}; choose from {ESTIMATOR_NAMES}")
    args.variance_estimators = _list(args.variance_estimators)
    args.sigma_v_candidates = _list(args.sigma_v_candidates, float)
    args.persistence = _list(args.persistence, int)
    args.alphas = _list(args.alphas, float)
    args.roc_persistence = _list(args.roc_persistence, int)
    out = run_benchmark(args, runner)
    print(out["markdown"])
    if out["failed"]:
        print(f"failed jobs (see their .error.txt in {args.runs_dir}): {out['failed']}")
    return 1 if out["failed"] else 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Volterra series identification benchmark: PK / IPK / MPK / SED-MPK (thesis section 6.5).

Experiment 1: the order-3, memory-6 system (6.36) in two setups (train and test input std 4;
train std 1, test std 4), PK, IPK and MPK estimators and a least-squares oracle on the true
monomials. Experiment 2: the Wiener system (6.38), memory 70, orders ``--orders`` at SNRs
``--snrs``, MPK and the tied SED-MPK (6.35). Metric: Fit% on the noiseless test output. The
protocol is in :mod:`mcpilco.experiments.identification.volterra`.

Every run is a sweep job with one torch thread, in ``--jobs`` worker processes or on Ray
(``--ray [ADDRESS]``); its result is kept in ``OUT_DIR/volterra_runs/``, so that a killed or
extended benchmark recomputes only the runs without one (``--rerun``: all).

Outputs (``--out-dir``, default ``results/``): ``volterra.json`` (config, every per-run Fit,
timings), ``volterra_exp1.png`` and ``volterra_exp2.png`` (boxplots), ``volterra.md``
(median / mean Fit per kernel and setup, with the run counts actually used).

Examples::

    mcpilco-bench-volterra                      # full protocol (100 / 40 runs)
    mcpilco-bench-volterra --runs 20 --runs-exp2 6 --jobs 2
    mcpilco-bench-volterra --quick              # experiment 1 only, 2 runs
    python -c "from mcpilco.experiments.identification.volterra import quick_benchmark as q; q()"
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from mcpilco.agents.common.cli import console_main
from mcpilco.experiments.identification.volterra import EXP1, EXP2, QUICK, run_benchmark
from mcpilco.experiments.infra.sweep import SweepError, add_sweep_arguments, runner_from_args


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="mcpilco-bench-volterra",
        description="Volterra identification with PK/IPK/MPK/SED-MPK GPs (thesis section 6.5).",
    )
    p.add_argument(
        "--runs",
        type=int,
        default=None,
        help=f"Monte Carlo runs of experiment 1 (default {EXP1['runs']}); also of "
        "experiment 2 unless --runs-exp2 is given",
    )
    p.add_argument(
        "--runs-exp2", type=int, default=None, help=f"runs of experiment 2 (default {EXP2['runs']})"
    )
    p.add_argument("--experiments", type=int, nargs="+", default=[1, 2], choices=[1, 2])
    p.add_argument(
        "--orders",
        type=int,
        nargs="+",
        default=None,
        help=f"experiment-2 Volterra orders (default {EXP2['orders']})",
    )
    p.add_argument(
        "--snrs",
        type=float,
        nargs="+",
        default=None,
        help=f"experiment-2 SNRs in dB (default {EXP2['snrs_db']})",
    )
    add_sweep_arguments(p)  # --jobs N (worker processes, 1 torch thread each), --ray [ADDRESS]
    p.add_argument("--base-seed", type=int, default=0, help="run i uses seed base_seed + i")
    p.add_argument("--out-dir", default="results")
    p.add_argument(
        "--quick",
        action="store_true",
        help=f"small budget for a quick check: experiments {QUICK['experiments']}, "
        f"{QUICK['runs']} runs",
    )
    p.add_argument("--no-progress", action="store_true")
    p.add_argument(
        "--rerun",
        action="store_true",
        help="recompute the runs that have a result in OUT_DIR/volterra_runs (by default "
        "they are reused, e.g. after an interrupted invocation)",
    )
    # hidden options for tests and budget studies
    for name in ("n-train", "n-test", "ml-points", "adam-iters", "lbfgs-iters"):
        p.add_argument(f"--{name}", type=int, default=None, help=argparse.SUPPRESS)
    return p


@console_main("mcpilco-bench-volterra")
def main(argv: list[str] | None = None) -> int:
    """Command-line entry point (``mcpilco-bench-volterra``)."""
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        runner = runner_from_args(args, progress=not args.no_progress)
    except SweepError as err:
        parser.error(str(err))
    experiments = tuple(args.experiments)
    runs, runs2 = args.runs, args.runs_exp2
    over1: dict[str, Any] = {}
    if args.quick:
        experiments = QUICK["experiments"]
        runs = QUICK["runs"] if runs is None else runs
        over1.update(QUICK["exp1"])
    common = {
        k: v
        for k, v in {
            "n_train": args.n_train,
            "n_test": args.n_test,
            "ml_points": args.ml_points,
            "adam_iters": args.adam_iters,
            "lbfgs_iters": args.lbfgs_iters,
        }.items()
        if v is not None
    }
    over1.update(common)
    over2 = dict(common)
    if args.orders:
        over2["orders"] = args.orders
    if args.snrs:
        over2["snrs_db"] = args.snrs
    cmd = "mcpilco-bench-volterra " + " ".join(sys.argv[1:] if argv is None else argv)
    res = run_benchmark(
        runs=runs,
        runs_exp2=runs2,
        experiments=experiments,
        out_dir=args.out_dir,
        runner=runner,
        base_seed=args.base_seed,
        exp1_overrides=over1,
        exp2_overrides=over2,
        progress=not args.no_progress,
        rerun=args.rerun,
        command=cmd.strip(),
    )
    print(Path(res["paths"]["markdown"]).read_text())
    for name, path in res["paths"].items():
        print(f"{name}: {path}")
    return 1 if res["failed"] else 0


if __name__ == "__main__":
    raise SystemExit(main())

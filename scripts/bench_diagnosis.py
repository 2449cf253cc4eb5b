"""Benchmark the diagnosis loop on many random hidden-effect cases: top-1 / top-3 accuracy.

Each case is a generated SCARA or UR10 data set with one random hidden effect (every
``--control-every``-th case: none; every ``--multi-every``-th: two); the start model
(``--start``) is fitted, the candidates are ranked and the ranked effects added until none
is significant (:mod:`mcpilco.experiments.diagnosis_bench`).

Each case is a sweep job (one thread) in ``--jobs`` local processes or on Ray
(``--ray [ADDRESS]``), its record kept in ``RUNS_DIR/<robot>/<start>/seed<s>.json``: a rerun
computes only the cases without one. Writes ``results/diagnosis.json`` and
``results/diagnosis.md``. Example (about 10-20 s per case on one core)::

    mcpilco-bench-diagnosis --cases 30 --robot scara --jobs 2

``--speed`` times the loop instead on one 3-joint case of 7,503 training rows with a nominal
and a GIP start (:func:`~mcpilco.experiments.diagnosis_bench.run_speed`) and writes
``results/diagnosis_speed.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from mcpilco.agents.common.cli import console_main
from mcpilco.experiments.diagnosis_bench import run_benchmark, run_speed
from mcpilco.experiments.sweep import SweepError, add_sweep_arguments, runner_from_args


@console_main("mcpilco-bench-diagnosis")
def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--cases", type=int, default=30)
    p.add_argument("--robot", choices=("scara", "ur10"), default="scara")
    p.add_argument("--first-seed", type=int, default=1000)
    p.add_argument("--control-every", type=int, default=5, help="every k-th case: no effect")
    p.add_argument(
        "--multi-every", type=int, default=0, help="every k-th case (not a control): 2 effects"
    )
    p.add_argument("--start", choices=("nominal", "gip", "rbf"), default="nominal")
    p.add_argument("--max-points", type=int, default=600, help="GP rows with a learned start")
    p.add_argument("--iters", type=int, default=100, help="Adam iterations of a learned start")
    p.add_argument("--duration", type=float, default=12.0, help="seconds per file")
    p.add_argument("--train-files", type=int, default=2, help="training files per case")
    p.add_argument("--out", default="results/diagnosis")
    p.add_argument(
        "--runs-dir", type=Path, default=Path("runs/bench_diagnosis"), help="per-case records"
    )
    p.add_argument("--speed", action="store_true", help="time the 3-joint speed case instead")
    add_sweep_arguments(p)  # --jobs N (local processes, 1 thread each), --ray [ADDRESS]
    args = p.parse_args(argv)
    if args.speed:
        speed = run_speed(
            "results/diagnosis_speed" if args.out == "results/diagnosis" else args.out
        )
        print(speed["markdown"])
        return 0
    try:
        runner = runner_from_args(args)
    except SweepError as err:
        p.error(str(err))
    out = run_benchmark(
        runner,
        cases=args.cases,
        robot=args.robot,
        first_seed=args.first_seed,
        control_every=args.control_every,
        multi_every=args.multi_every,
        start=args.start,
        max_points=args.max_points,
        iters=args.iters,
        duration=args.duration,
        train_files=args.train_files,
        out=args.out,
        runs_dir=args.runs_dir,
        config=vars(args),
    )
    if out is None:
        return 1
    print("\n".join(out["markdown"].splitlines()[:12]))
    return out["sweep"].exit_code


if __name__ == "__main__":
    raise SystemExit(main())

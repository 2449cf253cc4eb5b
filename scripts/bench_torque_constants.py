"""Benchmark the torque constants of motor-current logs: interval coverage and unit effects.

Each case is a random 3-joint arm logged as positions and motor currents with random torque
constants (some negative); every ``--control-every``-th case has no hidden effect, the others
a hidden damping. The constants are estimated, the nominal model diagnosed in torque units
(:mod:`mcpilco.experiments.diagnosis.torque_constants`).

Each case is a sweep job (one thread) in ``--jobs`` local processes or on Ray
(``--ray [ADDRESS]``), its record kept in ``RUNS_DIR/seed<s>.json``: a rerun computes only
the cases without one. Writes ``results/torque_constants.json`` and
``results/torque_constants.md``. Example::

    mcpilco-bench-torque-constants --cases 20 --jobs 2
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from mcpilco.agents.common.cli import console_main
from mcpilco.experiments.diagnosis.torque_constants import run_benchmark
from mcpilco.experiments.infra.sweep import SweepError, add_sweep_arguments, runner_from_args


@console_main("mcpilco-bench-torque-constants")
def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--cases", type=int, default=20)
    p.add_argument("--first-seed", type=int, default=100)
    p.add_argument("--control-every", type=int, default=2, help="every k-th case: no effect")
    p.add_argument("--duration", type=float, default=4.0, help="seconds per log")
    p.add_argument("--out", default="results/torque_constants")
    p.add_argument(
        "--runs-dir", type=Path, default=Path("runs/bench_torque_constants"), help="records"
    )
    add_sweep_arguments(p)  # --jobs N (local processes, 1 thread each), --ray [ADDRESS]
    args = p.parse_args(argv)
    try:
        runner = runner_from_args(args)
    except SweepError as err:
        p.error(str(err))
    out = run_benchmark(
        runner,
        cases=args.cases,
        first_seed=args.first_seed,
        control_every=args.control_every,
        duration=args.duration,
        out=args.out,
        runs_dir=args.runs_dir,
        config=vars(args),
    )
    if out is None:
        return 1
    print("\n".join(out["markdown"].splitlines()[:20]))
    return out["sweep"].exit_code


if __name__ == "__main__":
    raise SystemExit(main())

"""Benchmark the diagnosis loop on simulated robot logs: random arms, random hidden effects.

Each case is a random arm forward-simulated in MuJoCo under a PID joint servo + gravity
compensation with hidden effects as MuJoCo physics or applied forces, logged as ``t, q, tau`` only
(:mod:`mcpilco.experiments.diagnosis.bench`): ``--per-kind`` cases of each effect kind of
the library, ``--controls`` without an effect, ``--multi`` with two effects and
``--off-library`` with position-dependent friction (correct verdict: "unexplained"). The loop
adds the ranked effects until none is significant; scored by
:mod:`mcpilco.experiments.diagnosis.scoring` (top-1 / top-3, parameters, error against the
noise floor, false alarms, verdicts).

Each case is a sweep job (one thread) in ``--jobs`` local processes or on Ray
(``--ray [ADDRESS]``), its record kept in ``RUNS_DIR/random/<start>/seed<s>.json``: a rerun
computes only the cases without one. Writes ``OUT.json``, ``OUT.md`` and
``OUT_confusion.png``. Seeds from 1000 are the evaluation range (0-99: development).
Example::

    mcpilco-bench-diagnosis --per-kind 3 --controls 5 --multi 5 --off-library 5 --jobs 2

``--case-set panda`` runs a fixed list of cases on the Franka Emika Panda (MuJoCo Menagerie's
frames and inertials) instead: payload, rotor inertia on three joints, dry friction of 2-3 N m
on two joints, a heavier link, damping, position-dependent friction and a control, on torque
logs and again on motor-current logs with unknown torque constants (14 cases)::

    nice -n 10 mcpilco-bench-diagnosis --case-set panda --first-seed 0 --out runs/panda

``--case-set iiwa`` runs the same fourteen cases on the KUKA LBR iiwa 14 (MuJoCo Menagerie's
frames and inertials).

``--speed`` times the loop instead on one 3-joint case of 7,503 training rows with a nominal
and a GIP start (:func:`~mcpilco.experiments.diagnosis.bench.run_speed`) and writes
``results/diagnosis_speed.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import shlex
from collections.abc import Sequence
from pathlib import Path

from mcpilco.agents.common.cli import console_main
from mcpilco.experiments.diagnosis.bench import (
    CASE_SETS,
    EVALUATION_FIRST_SEED,
    run_benchmark,
    run_speed,
)
from mcpilco.experiments.infra.sweep import SweepError, add_sweep_arguments, runner_from_args


@console_main("mcpilco-bench-diagnosis")
def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--per-kind", type=int, default=3, help="single-effect cases per kind")
    p.add_argument("--controls", type=int, default=5, help="cases without a hidden effect")
    p.add_argument("--multi", type=int, default=5, help="cases with two hidden effects")
    p.add_argument(
        "--off-library", type=int, default=5, help="cases with position-dependent friction"
    )
    p.add_argument(
        "--case-set",
        choices=sorted(CASE_SETS),
        default=None,
        help="a named, fixed list of cases on one arm (panda: the Franka Emika Panda, iiwa: "
        "the KUKA LBR iiwa 14, both from MuJoCo Menagerie) instead of random arms; "
        "--per-kind, --controls, --multi, --off-library, --min-joints and --max-joints are "
        "then unused",
    )
    p.add_argument("--cases", type=int, default=None, help="run only the first N of the plan")
    p.add_argument("--first-seed", type=int, default=EVALUATION_FIRST_SEED)
    p.add_argument(
        "--seeds",
        type=int,
        nargs="+",
        default=None,
        help="run only these seeds, seed S as case (S - first seed) mod N of the N-case plan",
    )
    p.add_argument("--duration", type=float, default=5.0, help="seconds per log")
    p.add_argument("--train-files", type=int, default=2, help="training logs per case")
    p.add_argument("--min-joints", type=int, default=2)
    p.add_argument("--max-joints", type=int, default=3)
    p.add_argument("--start", choices=("nominal", "gip", "rbf"), default="nominal")
    p.add_argument("--max-points", type=int, default=600, help="GP rows with a learned start")
    p.add_argument("--iters", type=int, default=100, help="Adam iterations of a learned start")
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
        per_kind=args.per_kind,
        controls=args.controls,
        multi=args.multi,
        off_library=args.off_library,
        cases=args.cases,
        first_seed=args.first_seed,
        duration=args.duration,
        train_files=args.train_files,
        min_joints=args.min_joints,
        max_joints=args.max_joints,
        start=args.start,
        max_points=args.max_points,
        iters=args.iters,
        case_set=args.case_set,
        seeds=args.seeds,
        out=args.out,
        runs_dir=args.runs_dir,
        command=shlex.join(["mcpilco-bench-diagnosis", *(argv or [])]),
        config={k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
    )
    if out is None:
        return 1
    print("\n".join(out["markdown"].splitlines()[:30]))
    return out["sweep"].exit_code


if __name__ == "__main__":
    raise SystemExit(main())

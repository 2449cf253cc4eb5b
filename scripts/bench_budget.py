"""Measure the budget's cost model (console script ``mcpilco-bench-budget``): seconds per
policy-optimisation step over task specs, particle counts and GP sizes, the fit of its
constants, and the shipped task files' derived budgets against the run's time budget
(:mod:`mcpilco.experiments.mcpilco.budget_model`). Writes
``results/mcpilco_budget.{json,md}``.

Usage::

    mcpilco-bench-budget
    mcpilco-bench-budget --envs mcpilco/CartpoleSwingUp-v0 --particles 100 400 --points 60 300
    mcpilco-bench-budget --refit results/mcpilco_budget.json    # fit again, no timing
"""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path

from mcpilco.agents.common.cli import console_main
from mcpilco.experiments.mcpilco.budget_model import (
    DEFAULT_ENVS,
    DEFAULT_PARTICLES,
    DEFAULT_POINTS,
    budget_model_part,
    measurement,
    read_measurement,
)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="mcpilco-bench-budget", description=__doc__)
    p.add_argument("--envs", nargs="+", default=list(DEFAULT_ENVS), help="task specs timed")
    p.add_argument("--particles", type=int, nargs="+", default=list(DEFAULT_PARTICLES))
    p.add_argument("--points", type=int, nargs="+", default=list(DEFAULT_POINTS))
    p.add_argument("--repeats", type=int, default=3, help="timed steps per row (median)")
    p.add_argument("--out", type=Path, default=Path("results"))
    p.add_argument(
        "--refit", type=Path, metavar="JSON",
        help="fit the measurement of an earlier mcpilco_budget.json again (no timing)",
    )  # fmt: skip
    return p


@console_main("mcpilco-bench-budget")
def main(argv: list[str]) -> None:
    args = build_parser().parse_args(argv)
    if args.refit is not None:
        measured = read_measurement(args.refit)
    else:
        command = "mcpilco-bench-budget " + shlex.join(argv)
        measured = measurement(args.envs, args.particles, args.points, args.repeats, command)
    res = budget_model_part(args.out, measured)
    fit = res["fitted"]
    print(
        f"c_H = {fit['ch_s']:.3g} s, c_0 = {fit['c0_s']:.3g} s, c_1 = {fit['c1_s']:.3g} s "
        f"-> {args.out}"
    )


if __name__ == "__main__":
    main()

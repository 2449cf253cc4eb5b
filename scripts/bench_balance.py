"""Balance benchmark of MC-PILCO (console script ``mcpilco-bench-balance``): runs on seeds
with the derived defaults and the task file only, each trial's policy judged on the env's
own full-length episodes (:mod:`mcpilco.experiments.mcpilco.balance`). Writes
``results/balance_<env>[_<tag>].{json,md,png}``.

Usage::

    mcpilco-bench-balance --env InvertedDoublePendulum-v5 --seeds 10 --first-seed 1000
    mcpilco-bench-balance --env InvertedDoublePendulum-v5 --seeds 3 --first-seed 0 --tag dev
"""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path

from mcpilco.agents.common.cli import console_main
from mcpilco.experiments.mcpilco.balance import balance_bench


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="mcpilco-bench-balance", description=__doc__)
    p.add_argument("--env", default="InvertedDoublePendulum-v5", help="env id with a task file")
    p.add_argument("--seeds", type=int, default=10, help="number of seeds")
    p.add_argument("--first-seed", type=int, default=1000, help="first seed (0-99: development)")
    p.add_argument("--trials", type=int, default=3, help="policy trials after exploration")
    p.add_argument("--episodes", type=int, default=3, help="full-length episodes per trial")
    p.add_argument("--tag", default="", help="suffix of the result file names")
    p.add_argument("--out", type=Path, default=Path("results"))
    p.add_argument("--runs", type=Path, default=Path("runs/balance"), help="run folders")
    return p


@console_main("mcpilco-bench-balance")
def main(argv: list[str]) -> None:
    args = build_parser().parse_args(argv)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    paths = balance_bench(
        args.env, seeds, args.trials, args.episodes, args.out, args.runs, args.tag,
        command="mcpilco-bench-balance " + shlex.join(argv),
    )  # fmt: skip
    print(f"-> {paths['md']}")


if __name__ == "__main__":
    main()

"""MC-PILCO judged on evaluation episodes (console script ``mcpilco-bench-eval``): seeds of an
env with the package's derived defaults and its task file, ``--eval-episodes`` episodes from
the task's evaluation start after each policy trial, seeds solved within ``--budget-s``
seconds of experience (:mod:`mcpilco.experiments.mcpilco.evaluation`). Writes
``results/mcpilco_eval_<env>[_<label>].{json,md,png}``.

Usage::

    mcpilco-bench-eval --env Pendulum-v1 --seeds 10 --first-seed 1000 --trials 2 --budget-s 12
    mcpilco-bench-eval --env dm_control/pendulum-swingup-v0 --seeds 3 --trials 7 --budget-s 40 \\
        --label dev
    mcpilco-bench-eval --env dm_control/pendulum-swingup-v0 --seed-list 1002 1004 --trials 5 \\
        --budget-s 40 --label continued
"""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path

from mcpilco.agents.common.cli import console_main
from mcpilco.experiments.mcpilco.evaluation import make_payload, run_seeds, write_report


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="mcpilco-bench-eval", description=__doc__)
    p.add_argument("--env", required=True, help="env id with a shipped task file")
    p.add_argument("--seeds", type=int, default=10, help="number of seeds")
    p.add_argument("--first-seed", type=int, default=1000)
    p.add_argument(
        "--seed-list", type=int, nargs="+", help="these seeds instead of --seeds/--first-seed"
    )
    p.add_argument("--trials", type=int, required=True, help="policy trials per seed")
    p.add_argument("--eval-episodes", type=int, default=5, help="evaluation episodes per trial")
    p.add_argument("--budget-s", type=float, required=True, help="experience budget [s]")
    p.add_argument("--label", default="", help="suffix of the result files")
    p.add_argument("--out", type=Path, default=Path("results"))
    p.add_argument("--runs-dir", type=Path, default=Path("runs/bench_eval"))
    return p


@console_main("mcpilco-bench-eval")
def main(argv: list[str]) -> None:
    args = build_parser().parse_args(argv)
    seeds = args.seed_list or list(range(args.first_seed, args.first_seed + args.seeds))
    tag = args.env.split("/")[-1] + (f"_{args.label}" if args.label else "")
    command = "mcpilco-bench-eval " + shlex.join(argv)

    def write(runs: list[dict]) -> None:  # after every seed: the seeds finished so far
        payload = make_payload(
            args.env, runs, args.trials, args.eval_episodes, args.budget_s, command, seeds
        )
        print(f"wrote {write_report(payload, args.out, args.label)}", flush=True)

    run_seeds(
        args.env,
        seeds,
        args.trials,
        args.eval_episodes,
        args.runs_dir / tag,
        log=lambda line: print(line, flush=True),
        on_seed=write,
    )

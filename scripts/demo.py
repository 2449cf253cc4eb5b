"""``make demo``: the main job, MC-PILCO swinging up the MuJoCo cart-pole.

Runs the ``demo`` preset of the cart-pole's config file (one 3 s random-exploration trial, then
3 policy trials with the benchmark's budget: 12 s of experience), then prints whether the
pole was swung up, the time taken, and where the checkpoint, the Rerun recording
(``run.rrd``) and the PNG plots are (:mod:`mcpilco.experiments.mcpilco.demo`). On the CPU
the rollout is compiled when a C++ compiler is found; ``--eager`` skips the compilation.
With ``--device cuda`` the policy optimisation runs on a GPU.

Usage::

    mcpilco-demo [--out runs/demo] [--seed 0] [--resume | --overwrite] [--eager]
                 [--device cuda]
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from mcpilco.agents.common.cli import console_main
from mcpilco.experiments.mcpilco.demo import demo_config, demo_report, run_demo


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mcpilco-demo",
        description="MC-PILCO cart-pole swing-up, 12 s of experience (about 6 min on 2 cores).",
    )
    parser.add_argument("--out", type=Path, default=Path("runs/demo"), help="output folder")
    parser.add_argument("--seed", type=int, default=0, help="random seed")
    parser.add_argument(
        "--resume", action="store_true", help="continue a killed demo from its checkpoint"
    )
    parser.add_argument(
        "--overwrite", action="store_true", help="delete the run found in --out first"
    )
    parser.add_argument(
        "--eager",
        action="store_true",
        help="run the rollout op by op (default on the CPU: its time step compiled when a C++ "
        "compiler is found, checked against the eager step in each trial)",
    )
    parser.add_argument(
        "--device", default="cpu", help="cpu (default) or cuda[:index] for the optimisation"
    )
    return parser


@console_main("mcpilco-demo")
def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        config, note = demo_config(args.seed, args.device, args.eager)
    except ValueError as err:
        parser.error(str(err))
    if note is not None:
        print(f"note: {note}")
    summary, seconds = run_demo(config, args.out, resume=args.resume, overwrite=args.overwrite)
    print()
    print(demo_report(config, summary, seconds))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

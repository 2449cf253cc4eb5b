"""Collect a dataset on the UR10 or SCARA env and save it in the robot-data format.

Example::

    mcpilco-collect-arm-data --robot ur10 --program mixed --duration 120 \\
        --seed 0 --out results/arm_data/ur10_mixed.parquet

Programs: ``exploration`` (random waypoints with variable speed and rests), ``circle``
(tool circle, UR10: radius 30 cm at 30 mm/s), ``sinusoids``, ``rest``, ``mixed`` (all of
them). Columns and units: :mod:`mcpilco.models.robot_data`.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

from mcpilco.agents.common.cli import console_main
from mcpilco.envs.arm_data import PROGRAMS, collect
from mcpilco.models.robot_data import save_dataset


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--robot", choices=("ur10", "scara"), default="ur10")
    p.add_argument("--program", choices=PROGRAMS, default="mixed")
    p.add_argument("--duration", type=float, default=60.0, help="program length [s]")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--current-noise-std", type=float, default=None, help="[A]; env default")
    p.add_argument("--no-friction", action="store_true", help="switch joint friction off")
    p.add_argument("--out", default="results/arm_data/arm_data.parquet", help=".parquet/.csv")
    p.add_argument("--progress", action="store_true")
    return p


@console_main("mcpilco-collect-arm-data")
def main(argv: Sequence[str] | None = None) -> int:
    """Parse ``argv``, collect, save; print the file and its size. Returns 0."""
    args = build_parser().parse_args(argv)
    env_kwargs: dict = {"friction": not args.no_friction}
    if args.current_noise_std is not None:
        env_kwargs["current_noise_std"] = args.current_noise_std
    arrays, metadata = collect(
        args.robot,
        args.program,
        duration=args.duration,
        seed=args.seed,
        progress=args.progress,
        env_kwargs=env_kwargs,
    )
    path = save_dataset(arrays, args.out, metadata=metadata)
    n = arrays["t"].shape[0]
    print(f"wrote {path}: {n} samples x {arrays['q'].shape[1]} joints ({args.program})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Benchmark: marker poses from rendered images + ArUco detection against the truth.

The UR10 of ``mcpilco/MarkerCamera-v0`` follows a trajectory through 25 random waypoints;
every frame is rendered and its markers detected with OpenCV, and the detected poses are
compared with MuJoCo's (statistics: :mod:`mcpilco.experiments.kinematics.marker_detection`).

Writes ``marker_detection.json``, ``marker_detection.md``, ``marker_detection.png`` and
``marker_detection_frame.png`` under ``--out-dir``. Needs OpenCV
(``pip install 'mcpilco[vision]'``) and offscreen OpenGL (``MUJOCO_GL=egl`` or ``osmesa``).

Usage::

    MUJOCO_GL=egl mcpilco-bench-markers                 # 300 frames, ~1 min
    MUJOCO_GL=egl mcpilco-bench-markers --frames 100 --marker-size 0.2 --out-dir runs/markers
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mcpilco.agents.common.cli import console_main
from mcpilco.experiments.kinematics.marker_detection import (
    MIN_FRAMES,
    MarkerBenchSettings,
    run,
    write_outputs,
)

DEFAULTS = MarkerBenchSettings()


def _parser() -> argparse.ArgumentParser:
    d = DEFAULTS
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--frames", type=int, default=d.frames, help="frames of the trajectory")
    p.add_argument("--seed", type=int, default=d.seed)
    p.add_argument("--span", type=float, default=d.span, help="waypoints: home +- span rad")
    p.add_argument("--marker-size", type=float, default=d.marker_size, help="marker face side [m]")
    p.add_argument("--image-size", type=int, nargs=2, default=list(d.image_size), help="W H [px]")
    p.add_argument("--fovy", type=float, default=d.fovy, help="vertical field of view [deg]")
    p.add_argument(
        "--pixel-noise", type=float, default=d.pixel_noise, help="image noise std [grey levels]"
    )
    p.add_argument(
        "--facing-cone", type=float, default=d.facing_cone, help="marker facing cone [deg]"
    )
    p.add_argument("--out-dir", default="results")
    p.add_argument("--no-progress", action="store_true")
    return p


@console_main("mcpilco-bench-markers")
def main(argv: list[str] | None = None) -> int:
    """Command-line entry point; returns 0."""
    args = _parser().parse_args(argv)
    if args.frames < MIN_FRAMES:
        raise SystemExit(f"--frames must be >= {MIN_FRAMES} (one per waypoint segment)")
    settings = MarkerBenchSettings(
        frames=args.frames, seed=args.seed, span=args.span, marker_size=args.marker_size,
        image_size=tuple(args.image_size), fovy=args.fovy, pixel_noise=args.pixel_noise,
        facing_cone=args.facing_cone,
    )  # fmt: skip
    command = " ".join(["mcpilco-bench-markers", *(argv if argv is not None else sys.argv[1:])])
    res = run(settings, progress=not args.no_progress)
    print(write_outputs(res, args.out_dir, command))
    print(f"wrote {Path(args.out_dir) / 'marker_detection.json'}, .md and .png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

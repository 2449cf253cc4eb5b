"""Quasi-static friction on the simulated UR10: the thesis's Figure 4.1 experiment.

Only joint 1 moves, between rest phases at the same configuration; stiction makes the
measured current at rest depend on how the joint arrived
(:mod:`mcpilco.experiments.collision.quasi_static_friction`).

Outputs (``--out-dir``, default ``results/``): ``collision_quasi_static.png``,
``collision_quasi_static.json`` and ``.md`` (mean and std of ``i1`` in every rest phase).

Usage::

    python -m mcpilco.scripts.quasi_static_demo --seed 0
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

from mcpilco.experiments.collision.quasi_static_friction import run, write_outputs


def main(argv: Sequence[str] | None = None) -> int:
    """Run, write PNG + JSON + Markdown, print the Markdown table. Returns 0."""
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--rest-seconds", type=float, default=4.0)
    p.add_argument("--out-dir", default="results")
    args = p.parse_args(argv)
    if args.rest_seconds <= 1.0:
        raise SystemExit("--rest-seconds must be > 1 (the first second is settling)")
    print(write_outputs(run(args.seed, args.rest_seconds), args.out_dir))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

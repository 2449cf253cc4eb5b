"""Make robot data with hidden effects: nominal torques of a UR10/SCARA plus injected physics.

Writes ``train_1..N``, ``test_1..M`` (CSV or Parquet), the nominal robot file ``robot.xml``
and the hidden answer ``truth.json`` under ``--out``; the effects, their sizes and the noise
are described in :mod:`mcpilco.experiments.diagnosis.hidden_effects`.

Example (the README walk-through; a few seconds)::

    python -m mcpilco.scripts.make_hidden_effect_data --robot scara --effect coulomb:2 \\
        --seed 0 --out results/hidden_effect
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

from mcpilco.experiments.diagnosis.hidden_effects import EFFECT_KEYS, ROBOTS, make_case, write_case


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--robot", choices=sorted(ROBOTS), default="scara")
    p.add_argument(
        "--effect",
        action="append",
        default=None,
        help="effect to inject, key[:joint] (repeatable); keys: " + ", ".join(EFFECT_KEYS),
    )
    p.add_argument("--none", action="store_true", help="control case: no hidden effect")
    p.add_argument("--n-effects", type=int, default=1, help="random effects when no --effect")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--n-train", type=int, default=2)
    p.add_argument("--n-test", type=int, default=1)
    p.add_argument("--duration", type=float, default=20.0, help="per file [s]")
    p.add_argument("--sample-time", type=float, default=0.01, help="[s]")
    p.add_argument("--noise-frac", type=float, default=0.02)
    p.add_argument("--format", choices=("csv", "parquet"), default="csv")
    p.add_argument("--out", default="results/hidden_effect")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Generate one case and write it; prints the files and (hidden) truth path."""
    args = build_parser().parse_args(argv)
    effects = [] if args.none else args.effect
    case = make_case(
        args.robot,
        effects,
        n_effects=args.n_effects,
        seed=args.seed,
        n_train=args.n_train,
        n_test=args.n_test,
        duration=args.duration,
        sample_time=args.sample_time,
        noise_frac=args.noise_frac,
    )
    write_case(case, args.out, args.format)
    print(
        f"wrote {args.out}/: train_1..{args.n_train}.{args.format}, test_1..{args.n_test}."
        f"{args.format}, robot.xml (nominal model), truth.json (the hidden answer)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

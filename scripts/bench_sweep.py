"""Overhead per job of the sweep runner: local processes vs a local Ray instance
(console script ``mcpilco-bench-sweep``).

The same sweep of ``--n`` probe jobs (``--seconds`` each: ``sleep`` jobs wait, ``spin`` jobs
do a fixed amount of CPU work) runs on every backend of ``--backends`` with ``--cpus`` CPUs,
``--repeats`` times; see :mod:`mcpilco.experiments.infra.overhead` for the figures. Writes
``results/sweep_overhead.json`` and ``results/sweep_overhead.md``. The ``ray`` backend needs
``pip install 'mcpilco[cluster]'``.

Usage::

    mcpilco-bench-sweep                                  # 8 jobs of 1 s, 2 CPUs, both backends
    mcpilco-bench-sweep --backends local --kinds sleep --repeats 1
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mcpilco.experiments.infra.overhead import BACKENDS, measure, write_report
from mcpilco.experiments.infra.probe import KINDS
from mcpilco.experiments.infra.sweep import SweepError, import_ray


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="mcpilco-bench-sweep",
        description=__doc__,
        formatter_class=argparse.RawTextHelpFormatter,
    )
    p.add_argument("--backends", nargs="+", choices=BACKENDS, default=list(BACKENDS))
    p.add_argument("--kinds", nargs="+", choices=KINDS, default=list(KINDS))
    p.add_argument("--n", type=int, default=8, help="jobs per sweep")
    p.add_argument("--seconds", type=float, default=1.0, help="seconds per job")
    p.add_argument("--cpus", type=int, default=2, help="CPUs of every backend")
    p.add_argument("--repeats", type=int, default=3, help="sweeps per backend and kind")
    p.add_argument("--out", type=Path, default=Path("results"))
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if min(args.n, args.cpus, args.repeats) < 1 or args.seconds <= 0:
        parser.error("--n, --cpus and --repeats must be >= 1 and --seconds > 0")
    if "ray" in args.backends:
        try:
            import_ray(local=True)
        except SweepError as err:
            parser.error(str(err))
    result = measure(args.backends, args.kinds, args.n, args.seconds, args.cpus, args.repeats)
    command = "mcpilco-bench-sweep " + " ".join(sys.argv[1:] if argv is None else argv)
    result["command"] = command.strip()
    print(write_report(result, args.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())

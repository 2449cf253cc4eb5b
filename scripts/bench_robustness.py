"""Robustness figures: bad inputs by kind, random (fuzzed) inputs, and runs killed with SIGKILL.

For every input the outcome is one of: ``result`` (finite answer on sound input), ``clear
error`` (commands: exit 2 and one line; library calls: ``ValueError``/``TypeError`` with a
message), ``crash`` (a traceback, another exception or exit status) or ``silent wrong`` (an
answer, exit 0 or a NaN, on input that cannot support one). The kills start a small
``mcpilco-train`` run, SIGKILL it after a given time, then continue it with ``--resume``
(``--overwrite`` when no trial had finished) and count the finished trials lost. See
:mod:`mcpilco.experiments.infra.robustness`.

Usage::

    python -m mcpilco.scripts.bench_robustness --out results   # robustness.json and .md
    python -m mcpilco.scripts.bench_robustness --table-from results/robustness.json
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from mcpilco.agents.common.cli import console_main
from mcpilco.experiments.infra.robustness import (
    markdown,
    outcome_lines,
    run_robustness,
    write_result,
)
from mcpilco.experiments.results import read_result


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", type=Path, default=Path("results"), help="folder of the JSON")
    p.add_argument("--fuzz", type=int, default=200, help="random inputs per fuzzed kind")
    p.add_argument("--seed", type=int, default=0, help="seed of the fuzzed inputs")
    p.add_argument(
        "--table-from", type=Path, help="only write the Markdown tables of this robustness.json"
    )
    p.add_argument(
        "--kill-after",
        type=float,
        nargs="*",
        default=[3.0, 12.0, 30.0],
        help="seconds after which each killed run is killed",
    )
    return p


@console_main("bench_robustness")
def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.table_from is not None:
        result = read_result(args.table_from).payload()
        (args.table_from.with_suffix(".md")).write_text(markdown(result))
        print(markdown(result))
        return 0
    result = {
        "command": "python -m mcpilco.scripts.bench_robustness " + " ".join(argv or []),
        **run_robustness(args.kill_after, fuzz=args.fuzz, seed=args.seed),
    }
    write_result(result, args.out)
    for line in outcome_lines(result):
        print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

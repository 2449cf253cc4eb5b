"""Write ``results/README.md``, the index of headline figures (console script
``mcpilco-results-index``).

Reads the results JSON files registered in :data:`mcpilco.experiments.results_index.REGISTRY`
and writes one Markdown table: capability, headline figure, command, seeds, date of
measurement and the page with the details. Run it after adding or rerunning a benchmark.

Usage::

    mcpilco-results-index                    # results/README.md from results/*.json
    mcpilco-results-index --check            # exit 1 when results/README.md is out of date
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mcpilco.experiments.results_index import render_index


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="mcpilco-results-index",
        description=__doc__,
        formatter_class=argparse.RawTextHelpFormatter,
    )
    p.add_argument("--results", type=Path, default=Path("results"), help="results folder")
    p.add_argument("--out", type=Path, default=None, help="index file (default RESULTS/README.md)")
    p.add_argument("--check", action="store_true", help="compare with the file, write nothing")
    p.add_argument("--no-git", action="store_true", help="do not read dates from the git history")
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not args.results.is_dir():
        parser.error(f"--results {args.results}: no such folder")
    out = args.out if args.out is not None else args.results / "README.md"
    try:
        text = render_index(args.results, use_git=not args.no_git)
    except (FileNotFoundError, ValueError) as err:
        print(f"mcpilco-results-index: error: {err}", file=sys.stderr)
        return 2
    if args.check:
        current = out.read_text() if out.is_file() else ""
        if current != text:
            print(f"{out} is out of date: run mcpilco-results-index", file=sys.stderr)
            return 1
        print(f"{out} is up to date")
        return 0
    out.write_text(text)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

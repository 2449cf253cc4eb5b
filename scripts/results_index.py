"""Write ``results/README.md``, the index of headline figures (console script
``mcpilco-results-index``).

Reads the result files of the headline rows every registered bench exports
(:mod:`mcpilco.experiments.benches`) and writes one Markdown table: capability, headline
figure, command, seeds, date of measurement and the page with the details. Run it after
adding or rerunning a benchmark. ``--convert`` rewrites result files written before the one
result schema (:mod:`mcpilco.experiments.results`) in it, their numbers unchanged;
``--replot`` redraws every bench figure from its result file (no benchmark is rerun).

Usage::

    mcpilco-results-index                    # results/README.md from results/*.json
    mcpilco-results-index --check            # exit 1 when results/README.md is out of date
    mcpilco-results-index --convert          # old result files -> the result schema
    mcpilco-results-index --replot           # redraw every bench figure from its file
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mcpilco.experiments.benches import replot_tree
from mcpilco.experiments.infra.convert_results import convert_tree
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
    p.add_argument("--convert", action="store_true", help="convert old result files first")
    p.add_argument("--replot", action="store_true", help="redraw the figures from the files")
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not args.results.is_dir():
        parser.error(f"--results {args.results}: no such folder")
    out = args.out if args.out is not None else args.results / "README.md"
    try:
        if args.convert:
            for path in convert_tree(args.results):
                print(f"converted {path}")
        if args.replot:
            for path in replot_tree(args.results):
                print(f"drew {path}")
        text = render_index(args.results)
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

"""Benchmark: cached GP predictor vs GPyTorch's own posterior ``model(x)`` in eval mode.

Times one posterior call (mean and variance) of GPyTorch, of the cached and fused predictors
in float64 and float32, and of the variance term alone (the ceiling of any exact float64
predictor); what each path is and how it is timed: :mod:`mcpilco.experiments.mcpilco.gp_predictor`.
Writes ``--out`` (JSON) and prints a Markdown table and the speed ratios.

Usage::

    mcpilco-bench-gp                       # N=500, 400 test points, d=6
    mcpilco-bench-gp --n-train 300 --repeats 5
    mcpilco-bench-gp --device cuda --out results/bench_gp_predictor_cuda.json
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from mcpilco.agents.common.cli import console_main
from mcpilco.experiments.mcpilco.gp_predictor import RESULT_LAYOUTS, markdown_table, run, summary
from mcpilco.experiments.results import write_result
from mcpilco.models.device import resolve_device, retain_host_memory


@console_main("mcpilco-bench-gp")
def main(argv: list[str] | None = None) -> int:
    """Command-line entry point (``mcpilco-bench-gp``)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n-train", type=int, default=500, help="training points N")
    parser.add_argument("--n-test", type=int, default=400, help="test points per call")
    parser.add_argument("--dim", type=int, default=6, help="input dimension d")
    parser.add_argument("--outputs", type=int, default=2, help="number of outputs m")
    parser.add_argument("--repeats", type=int, default=7, help="interleaved timing rounds (median)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--device", default="cpu", help="cpu or cuda[:index]")
    parser.add_argument("--out", type=Path, default=Path("results/bench_gp_predictor.json"))
    parser.add_argument(
        "--retain-host-memory",
        action="store_true",
        help="keep freed CPU memory in the process (retain_host_memory, as the MC-PILCO "
        "scripts do); default: glibc's adaptive allocator, as a user's process has it",
    )
    args = parser.parse_args(argv)
    try:
        resolve_device(args.device)
    except ValueError as err:
        parser.error(str(err))
    torch.set_num_threads(args.threads)
    retained = retain_host_memory() if args.retain_host_memory else False
    result = run(
        args.n_train, args.n_test, args.dim, args.outputs, args.repeats, args.seed, args.device
    )
    result["config"]["retain_host_memory"] = retained
    write_result(args.out, RESULT_LAYOUTS[0], result)
    print(markdown_table(result))
    print()
    print(summary(result))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

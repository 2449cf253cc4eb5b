"""``make demo``: the main job, MC-PILCO swinging up the MuJoCo cart-pole.

Runs the ``demo`` preset of the cart-pole's config file (one 3 s random-exploration trial, then
3 policy trials with the benchmark's budget: 12 s of experience), then prints whether the
pole was swung up, the time taken, and where the checkpoint, the Rerun recording
(``run.rrd``) and the PNG plots are.

On the CPU the rollout is compiled when a C++ compiler is found (``compile_rollout``, the
``native`` backend: the whole rollout, forward and backward through time, in the package's
C++ loop, the particles split over the threads; ``direct``, inductor-compiled time steps,
where ``native`` does not apply). Each trial checks the compiled rollout against the eager
one and runs eagerly if they disagree; ``--eager`` skips the compilation. Without a
compiler the demo says so and runs eagerly.

Usage::

    python -m mcpilco.scripts.demo [--out runs/demo] [--seed 0] [--resume | --overwrite]
                                   [--eager] [--device cuda]

With ``--device cuda`` the policy optimisation runs on a GPU, each step one replayed CUDA
graph (on an H100: 70 s for seed 0; 2.8 min with the native rollout on 2 CPU cores).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from pathlib import Path

import torch

from mcpilco.agents.common.cli import console_main
from mcpilco.agents.mc_pilco import DEFAULT_ENV_ID, load_config, run_mcpilco
from mcpilco.agents.mc_pilco.loop import check_compile_toolchain
from mcpilco.models.device import resolve_device, retain_host_memory


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


def choose_compile(device: torch.device, eager: bool) -> tuple[bool, str | None]:
    """Whether the demo compiles the rollout's time step, and a note when it cannot.

    Compiled on the CPU unless ``eager``; on a GPU each step is already one replayed CUDA
    graph, so nothing is compiled there. Without a C++ compiler the note says why the
    demo runs eagerly instead of stopping."""
    if eager or device.type != "cpu":
        return False, None
    try:
        check_compile_toolchain(device)
    except ValueError as err:
        return False, f"{err}; the demo runs the rollout eagerly (slower)"
    return True, None


def rollout_mode(records: Sequence[dict]) -> str:
    """How the policy trials' rollouts ran, from their records: e.g. ``"compiled (native
    backend, 2 shards) in 3 of 3 policy trials"``, or ``"eager"`` when none was compiled."""
    policy = [r for r in records if r.get("kind") == "policy"]
    compiled = [r for r in policy if r.get("compiled_step")]
    if not compiled:
        return "eager"
    backends = "/".join(sorted({str(r.get("compile_backend")) for r in compiled}))
    shards = sorted({int(r.get("rollout_shards") or 1) for r in compiled})
    plural = "s" if shards != [1] else ""
    how = f"{backends} backend, {'/'.join(map(str, shards))} shard{plural}"
    return f"compiled ({how}) in {len(compiled)} of {len(policy)} policy trials"


@console_main("mcpilco-demo")
def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        config = load_config(DEFAULT_ENV_ID, preset="demo").with_overrides(
            seed=args.seed, device=args.device
        )
        device = resolve_device(config.device)
    except ValueError as err:
        parser.error(str(err))
    compile_rollout, note = choose_compile(device, args.eager)
    if note is not None:
        print(f"note: {note}")
    config = config.with_overrides(compile_rollout=compile_rollout)
    retain_host_memory()  # no page faults on the rollout's freed blocks
    start = time.perf_counter()
    summary = run_mcpilco(config, args.out, resume=args.resume, overwrite=args.overwrite)
    minutes = (time.perf_counter() - start) / 60.0
    first = summary.first_success_trial
    print()
    print("MC-PILCO cart-pole swing-up demo")
    print(f"  env               : {config.env_id}")
    print(f"  device            : {config.device}")
    print(f"  rollout           : {rollout_mode(summary.records)}")
    for r in summary.records:
        print(
            f"  trial {r['index']} ({r['kind']:<11}): success {'YES' if r['success'] else 'no '}"
            f"  cost {r['cost']:.1f}"
        )
    print(f"  success (last trial): {'YES' if summary.success else 'no'}")
    if first is not None:
        seconds = 3.0 * (first + 1)  # exploration trial + `first` policy trials of 3 s
        print(f"  first success     : policy trial {first} ({seconds:.0f} s of experience)")
    print(f"  wall time         : {minutes:.1f} min")
    print(f"  checkpoint        : {summary.checkpoint}")
    print(f"  rerun recording   : {summary.rrd}  (open with: rerun {summary.rrd})")
    for png in summary.pngs:
        print(f"  plot              : {png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""The demo: MC-PILCO swinging up the MuJoCo cart-pole, and its printed summary.

:func:`demo_config` reads the ``demo`` preset of the cart-pole's config file (one 3 s
random-exploration trial, then 3 policy trials with the benchmark's budget: 12 s of
experience) and decides how the rollout runs (:func:`choose_compile`); :func:`run_demo` runs
it and :func:`demo_report` says whether the pole was swung up, the time taken, how the
rollout ran and where the checkpoint, the Rerun recording (``run.rrd``) and the PNG plots are.

On the CPU the fast rollout is used when a C++ compiler is found (``compile_rollout``, the
``native`` backend: the whole rollout, forward and backward through time, in the package's
C++ loop, the particles split over the threads). Each trial checks the fast rollout against
the eager one and runs eagerly if they disagree. Without a compiler the demo says so and runs
eagerly.
On a GPU each policy-optimisation step is one replayed CUDA graph.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path

import torch

from mcpilco.agents.common.records import RunSummary
from mcpilco.agents.mc_pilco import DEFAULT_ENV_ID, Trainer, load_config
from mcpilco.agents.mc_pilco.config import MCPilcoConfig
from mcpilco.agents.mc_pilco.trainer import check_compile_toolchain
from mcpilco.models.device import resolve_device, retain_host_memory

__all__ = ["choose_compile", "demo_config", "demo_report", "rollout_mode", "run_demo"]

# length of each trial of the demo preset [s]
TRIAL_SECONDS = 3.0


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


def demo_config(
    seed: int = 0, device: str = "cpu", eager: bool = False
) -> tuple[MCPilcoConfig, str | None]:
    """The demo preset of the cart-pole with ``seed`` and ``device``, the rollout compiled as
    :func:`choose_compile` decides; returns it and the note of :func:`choose_compile`.

    Raises:
        ValueError: when the device is not valid or not available (e.g. ``cuda`` without a
            visible GPU).
    """
    config = load_config(DEFAULT_ENV_ID, preset="demo").with_overrides(seed=seed, device=device)
    compile_rollout, note = choose_compile(resolve_device(config.device), eager)
    return config.with_overrides(compile_rollout=compile_rollout), note


def run_demo(
    config: MCPilcoConfig, out: str | Path, resume: bool = False, overwrite: bool = False
) -> tuple[RunSummary, float]:
    """Run MC-PILCO with ``config`` into ``out``
    (:class:`~mcpilco.agents.mc_pilco.trainer.Trainer`); returns its summary and the wall
    time [s]."""
    retain_host_memory()  # no page faults on the rollout's freed blocks
    start = time.perf_counter()
    summary = Trainer(config, Path(out), resume=resume, overwrite=overwrite).run()
    return summary, time.perf_counter() - start


def demo_report(config: MCPilcoConfig, summary: RunSummary, seconds: float) -> str:
    """The demo's printed summary: per-trial outcome, rollout mode, wall time, output paths."""
    lines = [
        "MC-PILCO cart-pole swing-up demo",
        f"  env               : {config.env_id}",
        f"  device            : {config.device}",
        f"  rollout           : {rollout_mode(summary.records)}",
    ]
    for r in summary.records:
        lines.append(
            f"  trial {r['index']} ({r['kind']:<11}): success {'YES' if r['success'] else 'no '}"
            f"  cost {r['cost']:.1f}"
        )
    lines.append(f"  success (last trial): {'YES' if summary.success else 'no'}")
    first = summary.first_success_trial
    if first is not None:
        experience = TRIAL_SECONDS * (first + 1)  # exploration trial + `first` policy trials
        lines.append(
            f"  first success     : policy trial {first} ({experience:.0f} s of experience)"
        )
    lines += [
        f"  wall time         : {seconds / 60.0:.1f} min",
        f"  checkpoint        : {summary.checkpoint}",
        f"  rerun recording   : {summary.rrd}  (open with: rerun {summary.rrd})",
    ]
    lines += [f"  plot              : {png}" for png in summary.pngs]
    return "\n".join(lines)

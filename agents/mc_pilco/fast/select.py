"""Which fast rollout runs a loss: the backends by name, the choice for a device, task spec
and toolchain, and its installation after the check against the eager rollout.

Backends
--------
``"native"``
    the whole rollout, forward and backward through time, in the package's C++ loop for
    any task layout (:mod:`~mcpilco.agents.mc_pilco.fast.native`, a PyTorch C++ extension
    built on first use); CPU, float32.
``"torch"``
    the same maths in plain PyTorch ops
    (:class:`~mcpilco.agents.mc_pilco.fast.chained.TorchRollout`): the parts' step protocols
    chained through time by hand, no autograd graph; runs wherever torch runs.
``"dynamo"``
    ``torch.compile`` of the loss's per-step function (any device; public API).
``"auto"``
    the first chained backend of :data:`AUTO_ORDER` that can run the loss, else
    ``"dynamo"``; for the rigid-body GP kernel
    (:mod:`~mcpilco.agents.mc_pilco.dynamics`), whose posterior has no step protocol to
    chain, the eager rollout, with a one-line warning (``"dynamo"`` can be named).

A new chained engine (another device, or an engine specialised for some task specs) is a
:class:`~mcpilco.agents.mc_pilco.fast.base.ShardedRollout` subclass plus an entry of
:data:`CHAINED_BACKENDS` (its name, why it cannot run a loss, its class); listed in
:data:`AUTO_ORDER`, ``"auto"`` tries it. Every engine passes the same check against the
eager rollout before use.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch

from mcpilco.agents.mc_pilco.fast.base import ShardedRollout, default_shards, unsupported_reason
from mcpilco.agents.mc_pilco.fast.chained import TorchRollout
from mcpilco.agents.mc_pilco.fast.check import check_against_eager, passes
from mcpilco.agents.mc_pilco.fast.native import (
    NativeRollout,
    build_error,
    native_unsupported_reason,
)


@dataclass(frozen=True)
class ChainedBackend:
    """A chained rollout engine: ``reason(policy, dynamics, cost, device)`` says why it cannot
    run a loss (None: it can; it may build what it needs to find out), ``engine`` is its
    :class:`~mcpilco.agents.mc_pilco.fast.base.ShardedRollout` class, built as
    ``engine(policy, dynamics, cost, rows, delta_dim, shards=S)``."""

    reason: Callable[..., str | None]
    engine: type[ShardedRollout]


CHAINED_BACKENDS: dict[str, ChainedBackend] = {
    "native": ChainedBackend(native_unsupported_reason, NativeRollout),
    "torch": ChainedBackend(unsupported_reason, TorchRollout),
}
"""The chained engines by name."""

AUTO_ORDER = ("native",)  # the chained backends "auto" tries, in order, before "dynamo"

BACKENDS = ("auto", *CHAINED_BACKENDS, "dynamo")  # the names use_fast_rollout takes


@dataclass
class FastRollout:
    """What :func:`use_fast_rollout` installed: ``backend`` (None: the eager rollout runs),
    ``shards`` (threads of a chained backend), ``check`` (figures of
    :func:`~mcpilco.agents.mc_pilco.fast.check.check_against_eager`, None when not verified)
    and ``error`` (the first line of a build or compilation error, if one happened)."""

    backend: str | None = None
    shards: int = 1
    check: dict[str, float] | None = None
    error: str | None = None

    @property
    def in_use(self) -> bool:
        return self.backend is not None


def choose_backend(backend: str, parts: tuple[Any, Any, Any, torch.device]) -> str:
    """The backend that runs a loss of ``parts = (policy, dynamics, cost, device)`` when
    ``backend`` is asked for: a named chained backend that cannot run it is a ``ValueError``
    naming why; ``"auto"`` gives the first of :data:`AUTO_ORDER` that can, else ``"dynamo"``
    (with a warning when the native extension failed to build)."""
    if backend in CHAINED_BACKENDS:
        reason = CHAINED_BACKENDS[backend].reason(*parts)
        if reason is not None:
            raise ValueError(f"the {backend} backend cannot run this rollout: {reason}")
        return backend
    if backend != "auto":
        return backend
    for name in AUTO_ORDER:
        reason = CHAINED_BACKENDS[name].reason(*parts)
        if reason is None:
            return name
        failed = build_error()
        if name == "native" and failed and failed in reason:
            warnings.warn(
                f"the native rollout was not used ({reason})", RuntimeWarning, stacklevel=3
            )
    return "dynamo"


def eager_only_reason(loss: Any) -> str | None:
    """Why no chained backend can run ``loss`` whatever its parts (None: they may): the
    rigid-body GP kernel has no chained backward, and a terminating task's absorbing set
    (``loss.termination``) is masked in the eager rollout's loop only. ``"auto"`` then runs
    the eager rollout; ``"dynamo"`` compiles the step, which the eager loop masks."""
    if getattr(loss.dynamics, "joint_inputs", None) is not None:
        return "the rigid-body GP kernel has no native or torch rollout"
    if getattr(loss, "termination", None) is not None:
        return "the task terminates (its absorbing set is masked by the eager rollout only)"
    return None


def use_fast_rollout(
    loss: Any,
    backend: str = "auto",
    shards: int | None = None,
    verify: bool = True,
    **compile_kwargs: Any,
) -> FastRollout:
    """Install a fast rollout into ``loss`` (an :class:`~mcpilco.agents.mc_pilco.loss.MCPilcoLoss`)
    and return what was installed (:class:`FastRollout`).

    Args:
        backend: one of :data:`BACKENDS` (module docstring).
        shards: threads a chained backend (native, torch) splits each rollout over, by
            particles; None: :func:`~mcpilco.agents.mc_pilco.fast.base.default_shards`.
        verify: build now, on the loss's shapes, and compare with the eager rollout
            (:func:`~mcpilco.agents.mc_pilco.fast.check.check_against_eager`, within
            :data:`~mcpilco.agents.mc_pilco.fast.check.COMPILE_CHECK_RTOL`); if they
            disagree, the fast rollout is removed with a warning and the eager one runs: a
            backend that returns wrong gradients would otherwise train nothing, silently. A
            build or compilation that raises is caught the same way (its first line in
            ``error``).
        compile_kwargs: passed to ``torch.compile`` (dynamo backend).

    A backend asked for by name that cannot run this loss is a ``ValueError`` naming why;
    ``"auto"`` falls back silently (with a warning when the native extension failed to
    build). ``torch.compiler.reset()`` runs first, so that graphs compiled for an earlier GP
    do not pile up to dynamo's recompile limit (beyond which it would run eagerly).
    """
    if backend not in BACKENDS:
        raise ValueError(
            f"backend must be one of {', '.join(map(repr, BACKENDS))}, got {backend!r}"
        )
    loss.set_fast_rollout(None)
    torch.compiler.reset()
    eager_reason = eager_only_reason(loss)
    if eager_reason is not None and backend != "dynamo":
        if backend != "auto":
            raise ValueError(
                f"the {backend} backend cannot run this rollout: {eager_reason} ('auto' runs "
                "it eagerly, 'dynamo' compiles its step)"
            )
        warnings.warn(
            f"rollout backend 'auto': {eager_reason}; using the eager rollout",
            RuntimeWarning,
            stacklevel=2,
        )
        return FastRollout()
    parts = (loss.policy_module, loss.dynamics, loss.cost, loss.init_mean.device)
    backend = choose_backend(backend, parts)
    m = loss.num_particles
    if shards is None:
        shards = default_shards(m) if backend != "dynamo" else 1
    elif int(shards) != shards or shards < 1 or m % shards:
        raise ValueError(f"shards must be a positive divisor of the {m} particles, got {shards}")
    elif shards > 1 and backend == "dynamo":
        raise ValueError("shards > 1 needs the native or torch backend, got 'dynamo'")
    result = FastRollout(backend=backend, shards=int(shards))
    problem = None
    try:
        if backend == "dynamo":
            loss.set_fast_rollout(step_fn=torch.compile(loss.step, **compile_kwargs))
        else:
            engine = CHAINED_BACKENDS[backend].engine
            rows = loss.num_candidates * m
            loss.set_fast_rollout(engine(*parts[:3], rows, loss.delta_dim, shards=result.shards))
        result.check = check_against_eager(loss) if verify else None
    except Exception as err:  # noqa: BLE001 (any build or compiler failure: run eagerly)
        first_line = (str(err).strip().splitlines() or [""])[0]
        result.error = f"{type(err).__name__}: {first_line}"
        problem = f"building the {backend} rollout failed ({result.error})"
    else:
        check = result.check
        if not passes(check):
            problem = (
                f"the {backend} rollout disagrees with the eager one (relative difference of "
                f"J^ {check['J_rel']:.2e}, of dJ^/dtheta {check['grad_rel']:.2e}; torch "
                f"{torch.__version__})"
            )
    if problem is not None:
        warnings.warn(f"{problem}: using the eager rollout", RuntimeWarning, stacklevel=2)
        loss.set_fast_rollout(None)
        result.backend, result.shards = None, 1
    return result


__all__ = [
    "AUTO_ORDER",
    "BACKENDS",
    "CHAINED_BACKENDS",
    "ChainedBackend",
    "FastRollout",
    "choose_backend",
    "eager_only_reason",
    "use_fast_rollout",
]

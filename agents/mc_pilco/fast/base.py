r"""The base of the chained rollouts: one autograd node for a whole rollout, split by
particles over threads, whichever engine runs each shard's loops.

The chained time step
---------------------
Every differentiable part of a time step exposes a public step protocol, a forward that
returns its output and what its backward needs, and that backward:

* the policy ``pi_theta``: :func:`~mcpilco.agents.mc_pilco.policy.squashed_rbf_forward`,
  :func:`~mcpilco.agents.mc_pilco.policy.squashed_rbf_backward`;
* the GP inputs ``x~ = [f(x), u]``: :func:`~mcpilco.agents.mc_pilco.features.gp_inputs_forward`,
  :func:`~mcpilco.agents.mc_pilco.features.gp_inputs_backward`;
* the fused GP posterior: :func:`~mcpilco.models.gp.fused.fused_posterior_forward`,
  :func:`~mcpilco.models.gp.fused.fused_posterior_backward`;
* sample, clip, integrate:
  :func:`~mcpilco.agents.mc_pilco.dynamics.sample_clip_integrate_forward`,
  :func:`~mcpilco.agents.mc_pilco.dynamics.sample_clip_integrate_backward`;
* the saturating cost ``c``: :func:`~mcpilco.agents.mc_pilco.cost.saturating_cost_forward`,
  :func:`~mcpilco.agents.mc_pilco.cost.saturating_cost_backward`.

Forward: ``(output, saved) = part_forward(inputs..., constants)``, ``saved`` a named tuple of
tensors; backward: ``input grads = part_backward(saved, output grads, constants)``.
Each part's ``autograd.Function`` (the eager rollout's one node per part and step) is a thin
adapter over its pair; the chained rollout calls the same pairs by hand:

``step_forward(x_t, eps_t, nu_t, b_t, (t, 256/t), theta) -> (x_{t+1}, c(x_{t+1}), S_t)``
    ``u_t = pi_theta(x_t + nu_t)`` with the dropout mask ``D_t = 1[b_t < t] 256 / t`` made
    from the random bytes ``b_t`` (the mask of the eager rollout), ``x~_t = [x_t, u_t]``,
    ``(mu, sigma^2) = GP(x~_t)``, ``x_{t+1} = integrate(x_t, clip(mu + sigma eps_t))``, the
    cost; ``S_t`` are the parts' saved tensors.
``step_backward(S_t, g_{x_{t+1}}, g_{c_{t+1}}, G) -> (g_{x_t}, G + dJ/dtheta|_t)``
    the parts' backward passes in reverse: ``g_{x_t} = dJ/dx_t`` (through the integration,
    the GP inputs and the policy input ``x_t + nu_t``) and the running sum ``G`` of the
    policy-parameter gradients.

So the maths of a step exists once in Python (the parts' pairs); the native engine's C++
(:mod:`~mcpilco.agents.mc_pilco.fast.native`) is its only second copy, and every engine is
checked against the eager rollout before use (:mod:`~mcpilco.agents.mc_pilco.fast.check`).

A rollout runs the forward ``H`` times, then the backward ``H`` times
(:class:`RolloutFunction`, one autograd node for the whole rollout). The particles are
independent, so a rollout can be split by particles over ``S`` threads (``shards``), each
running both loops on its share with one intra-op thread; the shards' policy gradients are
summed. An engine is a :class:`ShardedRollout` subclass that gives one shard's two loops.

Glossary: ``M`` particles per candidate, ``K`` candidates, ``KM`` rows; ``S`` shards
(threads), ``KM / S`` rows each; ``H`` horizon; ``theta = (c, log l, w)`` the policy
parameters (``(K, ...)`` for a population, else without the leading ``K``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import Any

import torch
from torch import Tensor

from mcpilco.agents.mc_pilco.cost import SaturatingCost
from mcpilco.agents.mc_pilco.dynamics import SpeedIntegrationDynamics
from mcpilco.agents.mc_pilco.policy import PolicyPopulation, SquashedRBFPolicy
from mcpilco.models.gp.fused import FusedRBFMPKPredictor

PARAM_NAMES = ("centers", "log_lengthscales", "weights")  # theta, in this order

MIN_SHARD_PARTICLES = 50  # fewest particles per candidate and thread worth a thread of their own


def unsupported_reason(policy: Any, dynamics: Any, cost: Any, device: torch.device) -> str | None:
    """Why the chained rollout (torch or native backend) cannot run this loss (None: it can).
    It chains the hand-written backward passes of the package's own parts, so it needs
    exactly those: a :class:`SquashedRBFPolicy` or :class:`PolicyPopulation` (without a
    linear feedback term),
    :class:`SpeedIntegrationDynamics` over a :class:`FusedRBFMPKPredictor`,
    :class:`SaturatingCost`, on the CPU."""
    if device.type != "cpu":
        return f"it runs on the CPU only (the rollout is on {device})"
    if type(policy) not in (SquashedRBFPolicy, PolicyPopulation):
        return f"unsupported policy {type(policy).__name__}"
    if policy.linear:
        return "the policy's linear feedback term has no chained backward"
    if type(dynamics) is not SpeedIntegrationDynamics:
        return f"unsupported dynamics {type(dynamics).__name__}"
    if dynamics.joint_inputs is not None:
        return "the rigid-body GP kernel has no hand-written posterior backward to chain"
    if not isinstance(dynamics.delta_model, FusedRBFMPKPredictor):
        return f"the GP posterior is not fused ({type(dynamics.delta_model).__name__})"
    if type(cost) is not SaturatingCost:
        return f"unsupported cost {type(cost).__name__}"
    return None


class ShardedRollout:
    """A chained rollout of one loss split over ``S`` threads by particles.

    Args:
        policy, dynamics, cost: the loss's parts (see :func:`unsupported_reason`).
        rows: ``KM``, the number of particles of every rollout it runs.
        shards: ``S``. The particles are independent, so each thread rolls out ``M / S``
            particles of every candidate (``KM / S`` rows) with one intra-op thread, and the
            policy gradients of the ``S`` shards are summed. ``S = 1``: the calling thread
            does all.

    Subclasses give one shard's loops, :meth:`forward_shard` and :meth:`backward_shard`.
    Built for the GP and cost of this loss; the policy parameters are inputs. Rollouts with
    another number of rows run eagerly (the loss decides).
    """

    def __init__(self, policy, dynamics, cost, rows: int, shards: int = 1) -> None:
        self.policy, self.dynamics, self.cost = policy, dynamics, cost
        self.rows, self.shards = int(rows), int(shards)
        self.batched = isinstance(policy, PolicyPopulation)
        self.candidates = int(getattr(policy, "num_candidates", 1))
        self._pool = None
        if self.shards < 1 or self.rows % (self.candidates * self.shards):
            raise ValueError(
                f"shards must be >= 1 and divide the {self.rows // self.candidates} particles "
                f"per candidate, got {shards}"
            )
        self.shard_rows = self.rows // self.shards
        if self.shards > 1:
            self._pool = ThreadPoolExecutor(self.shards, "rollout-shard")

    def forward_shard(self, x, noise, nu, bits, keep, theta) -> tuple[list[Tensor], Any]:
        """One shard's forward loop: its costs ``c_{t+1}`` (``H`` tensors ``(KM/S,)``) and the
        state its backward needs."""
        raise NotImplementedError

    def backward_shard(self, state, g_costs, grads) -> list[Tensor]:
        """One shard's backward loop from ``g = dJ/dcosts`` ``(H, KM/S)``: ``grads`` plus the
        shard's ``dJ/dtheta``."""
        raise NotImplementedError

    def costs(self, x: Tensor, noise: Tensor, nu: Tensor | None) -> Tensor:
        """The per-step costs ``(H, KM)`` of the rollout from ``x_0 (KM, n)`` with GP noise
        ``eps (H, KM, m)`` and policy-input noise ``nu (H, KM, n)`` (None: none),
        differentiable with respect to the policy parameters (:class:`RolloutFunction`)."""
        if nu is None:
            nu = noise.new_zeros(*noise.shape[:2], x.shape[1])
        draw_bytes = getattr(self.policy, "draw_dropout_bytes", lambda _x: None)
        theta = (getattr(self.policy, name) for name in PARAM_NAMES)
        return RolloutFunction.apply(self, draw_bytes, x, noise, nu, *theta)

    def __del__(self) -> None:
        pool = getattr(self, "_pool", None)
        if pool is not None:
            pool.shutdown(wait=False)

    def map_shards(self, fn: Callable[..., Any], *args: Sequence[Any]) -> list[Any]:
        """``[fn(a_0, b_0, ...), ..., fn(a_{S-1}, ...)]`` for ``args = (a, b, ...)`` (one entry
        per shard), each in its own worker thread (in the calling thread for ``S = 1``)."""
        if self._pool is None:
            return [fn(*a) for a in zip(*args, strict=True)]
        # a worker's set_num_threads(1) also resets process-wide settings (the default count
        # of new threads, MKL's): the caller's count is put back once all S have run
        with _intra_op_threads(torch.get_num_threads()):
            return list(self._pool.map(_shard_task(fn), *args))

    @contextmanager
    def serial_caller(self) -> Iterator[None]:
        """The calling thread's own tensor ops (drawing and splitting the rollout's inputs,
        joining its outputs) on one intra-op thread while ``S > 1`` shards use the cores.

        After each parallel op, the caller's OpenMP workers spin-wait on a core for a while
        (libgomp's default wait policy) before they sleep, competing with the shards that
        start just then; with one thread the caller's ops start no worker. ``S = 1``:
        nothing changes (the shard is the caller, with its own thread count)."""
        if self.shards == 1:
            yield
            return
        with _intra_op_threads(1):
            yield

    def split(self, t: Tensor, dim: int) -> list[Tensor]:
        """``t``'s rows (``KM`` along ``dim``, candidate-major) cut into the ``S`` shards: shard
        ``s`` holds particles ``s M/S .. (s+1) M/S - 1`` of every candidate (contiguous)."""
        if self.shards == 1:
            return [t.contiguous()]
        grouped = t.unflatten(dim, (self.candidates, -1))
        return [p.flatten(dim, dim + 1).contiguous() for p in grouped.chunk(self.shards, dim + 1)]

    def join(self, parts: Sequence[Tensor], dim: int) -> Tensor:
        """The inverse of :meth:`split`."""
        if self.shards == 1:
            return parts[0]
        grouped = [p.unflatten(dim, (self.candidates, -1)) for p in parts]
        return torch.cat(grouped, dim + 1).flatten(dim, dim + 1)

    def parameters(self) -> tuple[Tensor, Tensor, Tensor]:
        """``theta`` (detached), in :data:`PARAM_NAMES` order."""
        return tuple(getattr(self.policy, name).detach() for name in PARAM_NAMES)

    def no_dropout(self) -> tuple[Tensor, Tensor]:
        """The dropout inputs of no dropout for one shard: bytes ``(K, M/S, n_b)`` of zeros and
        ``t = 256``, a mask of ones (``phi o 1 = phi``)."""
        shape = (self.candidates, self.shard_rows // self.candidates, self.policy.num_basis)
        return torch.zeros(shape, dtype=torch.uint8), self.keep(256)

    def keep(self, t: int) -> Tensor:
        """``(t, 256 / t)`` in the policy's dtype: the threshold and scale of the dropout mask
        (:func:`~mcpilco.agents.mc_pilco.policy.mask_from_bytes`)."""
        return torch.tensor([float(t), 256.0 / t], dtype=self.policy.weights.dtype)


def _shard_task(fn: Callable[..., Any]) -> Callable[..., Any]:
    """``fn`` as one shard's task in a worker thread: one intra-op thread, autograd off.

    The count is set at each task, not once when the worker starts: a thread takes the
    process's default count (the caller's, once restored) at its first parallel op, which
    would undo a setting made at the start. Autograd: a worker thread starts with it on; the
    chained steps take the policy parameters, which require gradients, as plain inputs."""

    def run(*args: Any) -> Any:
        torch.set_num_threads(1)
        with torch.no_grad():
            return fn(*args)

    return run


@contextmanager
def _intra_op_threads(n: int) -> Iterator[None]:
    """``torch.set_num_threads(n)`` inside the block, the count before it restored after."""
    before = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(before)


class RolloutFunction(torch.autograd.Function):
    """``costs (H, KM) = rollout(theta)`` through a :class:`ShardedRollout`: the forward loop
    keeps each step's saved tensors, the backward loop returns ``dJ/dtheta`` for the
    upstream gradient ``g = dJ/dcosts``; each loop runs per shard, the shards in parallel.
    The initial state gets no gradient (it does not depend on ``theta``). The random bytes
    of the dropout masks of all ``H`` steps are drawn first, in step order
    (``draw_bytes(x_0) = (b_t, t)``, None for no dropout): the same random stream as the
    eager rollout, which draws them step by step and nothing else in between; each shard
    turns its bytes into its mask inside its step."""

    @staticmethod
    def forward(ctx, runner, draw_bytes, x, noise, nu, c, log_l, w):  # noqa: D102
        horizon = noise.shape[0]
        drawn = [draw_bytes(x) for _ in range(horizon)]  # ((K, M, n_b) uint8, t), or None
        if not drawn or drawn[0] is None:
            bits, keep = runner.no_dropout()
            bits = [[bits] * horizon] * runner.shards
        else:  # shard s gets its (K, M/S, n_b) part of each step's bytes
            keep = runner.keep(drawn[0][1])
            cut = [[p.contiguous() for p in b.chunk(runner.shards, 1)] for b, _ in drawn]
            bits = [list(steps) for steps in zip(*cut, strict=True)]
        theta = (c, log_l, w)
        shards = runner.map_shards(
            lambda *a: runner.forward_shard(*a, keep, theta),
            runner.split(x, 0), runner.split(noise, 1), runner.split(nu, 1), bits,
        )  # fmt: skip
        ctx.runner, ctx.steps = runner, [steps for _, steps in shards]
        ctx.theta_shapes = (c.shape, log_l.shape, w.shape)
        return runner.join([torch.stack(costs) for costs, _ in shards], 1)

    @staticmethod
    def backward(ctx, g_costs):  # noqa: D102
        runner, steps = ctx.runner, ctx.steps
        with runner.serial_caller():
            zeros = [[g_costs.new_zeros(shape) for shape in ctx.theta_shapes] for _ in steps]
            shards = runner.map_shards(
                lambda *a: runner.backward_shard(*a), steps, runner.split(g_costs, 1), zeros
            )
            ctx.steps = None
            grads = [sum(parts[1:], parts[0]) for parts in zip(*shards, strict=True)]
        return (None, None, None, None, None, *grads)


def default_shards(num_particles: int) -> int:
    """``torch.get_num_threads()`` where it divides the ``M`` particles into shards of at
    least :data:`MIN_SHARD_PARTICLES`, else 1."""
    threads = torch.get_num_threads()
    ok = num_particles % threads == 0 and num_particles // threads >= MIN_SHARD_PARTICLES
    return threads if ok else 1


__all__ = [
    "MIN_SHARD_PARTICLES",
    "PARAM_NAMES",
    "RolloutFunction",
    "ShardedRollout",
    "default_shards",
    "unsupported_reason",
]

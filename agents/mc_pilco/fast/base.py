r"""Fast particle rollouts for :class:`~mcpilco.agents.mc_pilco.loss.MCPilcoLoss`, chosen and
checked against the eager reference by the trainer.

The loss module itself only rolls out eagerly (one autograd graph over the horizon); it
compiles nothing. :func:`use_fast_rollout` picks a backend, installs it into the loss
(:meth:`~mcpilco.agents.mc_pilco.loss.MCPilcoLoss.set_fast_rollout`) and compares it with
the eager rollout on the same random numbers before the optimisation uses it
(:func:`check_against_eager`); a backend that disagrees or fails is dropped with a warning
and the eager rollout runs.

Backends
--------
``"native"``
    the whole rollout, forward and backward through time, in the package's C++ loop for
    any task layout (:mod:`~mcpilco.agents.mc_pilco.native_rollout`, a PyTorch C++
    extension built on first use); CPU, float32.
``"torch"``
    the same maths in plain PyTorch ops (:class:`TorchRollout`): each part's hand-written
    backward chained through time by hand, no autograd graph; runs wherever torch runs.
    It is the pure-PyTorch twin of the native loop and the reference its tests use.
``"dynamo"``
    ``torch.compile`` of the loss's per-step function (any device; public API).
``"auto"``
    ``"native"`` where it applies, else ``"dynamo"``; for the rigid-body GP kernel
    (:mod:`~mcpilco.agents.mc_pilco.dynamics`), whose posterior has no hand-written backward
    to chain, the eager rollout, with a one-line warning (``"dynamo"`` can be named).

The chained time step
---------------------
Every part of a time step has a hand-written backward (the ``autograd.Function``\ s of the
policy, the GP inputs, the fused GP posterior, the sample-clip-integrate step and the cost).
The native and torch backends chain them by hand:

``step_forward(x_t, eps_t, nu_t, b_t, (t, 256/t), theta) -> (x_{t+1}, c(x_{t+1}), S_t)``
    ``u_t = pi_theta(x_t + nu_t)`` with the dropout mask ``D_t = 1[b_t < t] 256 / t`` made
    from the random bytes ``b_t`` (the mask of the eager rollout), ``x~_t = [x_t, u_t]``,
    ``(mu, sigma^2) = GP(x~_t)``, ``x_{t+1} = integrate(x_t, clip(mu + sigma eps_t))``, the
    cost; ``S_t`` are the tensors each part saves for its backward.
``step_backward(S_t, g_{x_{t+1}}, g_{c_{t+1}}, G) -> (g_{x_t}, G + dJ/dtheta|_t)``
    the parts' backward passes in reverse: ``g_{x_t} = dJ/dx_t`` (through the integration,
    the GP inputs and the policy input ``x_t + nu_t``) and the running sum ``G`` of the
    policy-parameter gradients.

A rollout runs the forward ``H`` times, then the backward ``H`` times
(:class:`RolloutFunction`, one autograd node for the whole rollout). The particles are
independent, so a rollout can be split by particles over ``S`` threads (``shards``), each
running both loops on its share with one intra-op thread; the shards' policy gradients are
summed.

Glossary: ``M`` particles per candidate, ``K`` candidates, ``KM`` rows; ``S`` shards
(threads), ``KM / S`` rows each; ``H`` horizon; ``theta = (c, log l, w)`` the policy
parameters (``(K, ...)`` for a population, else without the leading ``K``).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from mcpilco.agents.mc_pilco.cost import SaturatingCost, _SaturatingCostFn
from mcpilco.agents.mc_pilco.dynamics import SpeedIntegrationDynamics, _SampleClipIntegrate
from mcpilco.agents.mc_pilco.features import _GPInputs
from mcpilco.agents.mc_pilco.policy import (
    PolicyPopulation,
    SquashedRBFPolicy,
    _SquashedRBF,
    mask_from_bytes,
)
from mcpilco.models.gp.fused import FusedRBFMPKPredictor, _FusedPosterior

BACKENDS = ("auto", "native", "torch", "dynamo")  # the names use_fast_rollout takes

PARAM_NAMES = ("centers", "log_lengthscales", "weights")  # theta, in this order

COMPILE_CHECK_RTOL = 0.1
"""Largest relative difference a fast rollout may show against the eager one in
:func:`check_against_eager`: ``|J_f - J_e| / |J_e|`` and ``||g_f - g_e|| / ||g_e||`` (2-norm
over all policy parameters together). A wrong gradient gives about 1 (a gradient cut through
time gives 0.97 in the tests); a false alarm only costs speed (the eager rollout runs)."""

COMPILE_CHECK_HORIZON = 10
"""Time steps of that check (at most the loss's horizon). Over a long horizon the float32
policy gradient can be chaotic (particles near an unstable equilibrium amplify rounding, so
two correct float32 implementations may differ by tens of percent); over 10 steps they agree
to about 1e-4, and every part of the step, forward and backward, still runs."""

MIN_SHARD_PARTICLES = 50  # fewest particles per candidate and thread worth a thread of their own


class _Saved:
    """Stand-in for an ``autograd.Function`` context: ``save_for_backward`` keeps the tensors
    and the other attributes (e.g. the fused posterior's ``pred``) are set as usual. Every
    input counts as needing its gradient."""

    needs_input_grad = (True,) * 8

    def save_for_backward(self, *tensors: Tensor | None) -> None:
        self.saved_tensors = tensors


def unsupported_reason(policy: Any, dynamics: Any, cost: Any, device: torch.device) -> str | None:
    """Why the chained rollout (torch or native backend) cannot run this loss (None: it can).
    It chains the hand-written backward passes of the package's own parts, so it needs
    exactly those: a :class:`SquashedRBFPolicy` or :class:`PolicyPopulation`,
    :class:`SpeedIntegrationDynamics` over a :class:`FusedRBFMPKPredictor`,
    :class:`SaturatingCost`, on the CPU."""
    if device.type != "cpu":
        return f"it runs on the CPU only (the rollout is on {device})"
    if type(policy) not in (SquashedRBFPolicy, PolicyPopulation):
        return f"unsupported policy {type(policy).__name__}"
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


class TorchRollout(ShardedRollout):
    """The chained rollout in plain PyTorch ops: ``step_forward`` and ``step_backward``
    (module docstring) built from the parts' own ``forward`` and ``backward``, called ``H``
    times each per shard. No autograd graph is built; the tensors each step saves are kept
    in that step's contexts until the backward loop.

    Args:
        policy, dynamics, cost, rows, shards: as :class:`ShardedRollout`.
        delta_dim: unused (the GP's output count comes from the dynamics); accepted so
            that every chained backend is built alike.
    """

    def __init__(
        self, policy, dynamics, cost, rows: int, delta_dim: int | None = None, shards: int = 1
    ) -> None:
        reason = unsupported_reason(policy, dynamics, cost, torch.device("cpu"))
        if reason is not None:
            raise ValueError(f"the chained rollout cannot run this loss: {reason}")
        super().__init__(policy, dynamics, cost, rows, shards)

    def forward_shard(self, x, noise, nu, bits, keep, theta):
        costs, steps = [], []
        for t in range(noise.shape[0]):
            x, cost, ctx = self.step_forward(x, noise[t], nu[t], bits[t], keep, *theta)
            costs.append(cost)
            steps.append(ctx)
        return costs, steps

    def backward_shard(self, state, g_costs, grads):
        g_x = g_costs.new_zeros(g_costs.shape[1], self.dynamics.layout.n)
        grads = tuple(grads)
        for t in reversed(range(len(state))):
            g_x, grads = self.step_backward(state[t], g_x, g_costs[t], grads)
            state[t] = None  # this step's saved tensors are no longer needed
        return list(grads)

    def _batched(self, t: Tensor) -> Tensor:
        return t if self.batched else t.unsqueeze(0)

    def step_forward(
        self,
        x: Tensor,
        eps: Tensor,
        nu: Tensor,
        bits: Tensor,
        keep: Tensor,
        c: Tensor,
        log_l: Tensor,
        w: Tensor,
    ) -> tuple[Tensor, Tensor, dict[str, _Saved]]:
        """``step_forward`` (module docstring): ``x_{t+1}``, ``c(x_{t+1})`` and the parts'
        contexts ``S_t``."""
        dyn, cost = self.dynamics, self.cost
        mask = mask_from_bytes(bits, keep[0], x.dtype, keep[1])
        ctx = {name: _Saved() for name in ("policy", "inputs", "gp", "step", "cost")}
        layout = dyn.layout
        obs = (x + nu).reshape(self.candidates, -1, layout.n)
        u = _SquashedRBF.forward(
            ctx["policy"], obs, self._batched(c), self._batched(log_l), self._batched(w),
            (self.policy.u_mid, self.policy.u_half), mask, self.policy.layout,
        ).reshape(x.shape[0], -1)  # fmt: skip
        gp_in = _GPInputs.forward(ctx["inputs"], x, u, layout)
        mean, var = _FusedPosterior.forward(ctx["gp"], gp_in, dyn.delta_model)
        if dyn.sample_noise:
            var = var + dyn.noise_variance.to(var.dtype)
        x_next = _SampleClipIntegrate.forward(
            ctx["step"], x, mean, var, eps, dyn.delta_bound, dyn.dt, layout
        )
        return x_next, _SaturatingCostFn.forward(ctx["cost"], x_next, cost), ctx

    def step_backward(
        self, ctx: dict[str, _Saved], g_x_next: Tensor, g_c_next: Tensor, grads: tuple
    ) -> tuple[Tensor, tuple]:
        """``step_backward`` (module docstring): ``g_{x_t}`` and ``G + dJ/dtheta|_t``."""
        g_x = _SaturatingCostFn.backward(ctx["cost"], g_c_next)[0] + g_x_next
        g_state, g_mean, g_var = _SampleClipIntegrate.backward(ctx["step"], g_x)[:3]
        g_in = _FusedPosterior.backward(ctx["gp"], g_mean, g_var)[0]
        g_state_in, g_u = _GPInputs.backward(ctx["inputs"], g_in)[:2]
        g_obs, *g_theta = _SquashedRBF.backward(
            ctx["policy"], g_u.reshape(self.candidates, -1, g_u.shape[-1])
        )[:4]
        if not self.batched:
            g_theta = [g.squeeze(0) for g in g_theta]
        g_prev = g_state + g_state_in + g_obs.reshape(g_state.shape[0], -1)
        return g_prev, tuple(G + g for G, g in zip(grads, g_theta, strict=True))


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


# ------------------------------------------------------------------- choosing a backend
@dataclass
class FastRollout:
    """What :func:`use_fast_rollout` installed: ``backend`` (None: the eager rollout runs),
    ``shards`` (threads of a chained backend), ``check`` (figures of
    :func:`check_against_eager`, None when not verified) and ``error`` (the first line of a
    build or compilation error, if one happened)."""

    backend: str | None = None
    shards: int = 1
    check: dict[str, float] | None = None
    error: str | None = None

    @property
    def in_use(self) -> bool:
        return self.backend is not None


def default_shards(num_particles: int) -> int:
    """``torch.get_num_threads()`` where it divides the ``M`` particles into shards of at
    least :data:`MIN_SHARD_PARTICLES`, else 1."""
    threads = torch.get_num_threads()
    ok = num_particles % threads == 0 and num_particles // threads >= MIN_SHARD_PARTICLES
    return threads if ok else 1


def use_fast_rollout(
    loss: Any,
    backend: str = "auto",
    shards: int | None = None,
    verify: bool = True,
    **compile_kwargs: Any,
) -> FastRollout:
    """Install a fast rollout into ``loss`` (an :class:`~.loss.MCPilcoLoss`) and return what
    was installed (:class:`FastRollout`).

    Args:
        backend: one of :data:`BACKENDS` (module docstring).
        shards: threads a chained backend (native, torch) splits each rollout over, by
            particles; None: :func:`default_shards`.
        verify: build now, on the loss's shapes, and compare with the eager rollout
            (:func:`check_against_eager`, within :data:`COMPILE_CHECK_RTOL`); if they
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
    from mcpilco.agents.mc_pilco.native_rollout import (
        NativeRollout,
        build_error,
        native_unsupported_reason,
    )

    if backend not in BACKENDS:
        raise ValueError(
            f"backend must be one of {', '.join(map(repr, BACKENDS))}, got {backend!r}"
        )
    loss.set_fast_rollout(None)
    torch.compiler.reset()
    if getattr(loss.dynamics, "joint_inputs", None) is not None and backend != "dynamo":
        if backend != "auto":
            raise ValueError(
                f"the {backend} backend cannot run this rollout: the rigid-body GP kernel has "
                "no chained backward ('auto' runs it eagerly, 'dynamo' compiles its step)"
            )
        warnings.warn(
            "rollout backend 'auto': the rigid-body GP kernel has no native or torch rollout; "
            "using the eager rollout",
            RuntimeWarning,
            stacklevel=2,
        )
        return FastRollout()
    parts = (loss._policy_fn, loss.dynamics, loss.cost, loss.init_mean.device)
    if backend == "torch" and (reason := unsupported_reason(*parts)) is not None:
        raise ValueError(f"the torch backend cannot run this rollout: {reason}")
    native_reason = native_unsupported_reason(*parts) if backend in ("auto", "native") else None
    if backend == "native" and native_reason is not None:
        raise ValueError(f"the native backend cannot run this rollout: {native_reason}")
    failed = build_error()
    if backend == "auto":
        if native_reason is not None and failed and failed in native_reason:
            warnings.warn(
                f"the native rollout was not used ({native_reason})", RuntimeWarning, stacklevel=2
            )
        backend = "native" if native_reason is None else "dynamo"
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
            loss.set_fast_rollout(step_fn=torch.compile(loss._step, **compile_kwargs))
        else:
            runner = NativeRollout if backend == "native" else TorchRollout
            rows = loss.num_candidates * m
            loss.set_fast_rollout(runner(*parts[:3], rows, loss.delta_dim, shards=result.shards))
        result.check = check_against_eager(loss) if verify else None
    except Exception as err:  # noqa: BLE001 (any build or compiler failure: run eagerly)
        first_line = (str(err).strip().splitlines() or [""])[0]
        result.error = f"{type(err).__name__}: {first_line}"
        problem = f"building the {backend} rollout failed ({result.error})"
    else:
        check = result.check
        if check is not None and not (check["J_rel"] <= COMPILE_CHECK_RTOL >= check["grad_rel"]):
            problem = (  # NaN fails the comparison above
                f"the {backend} rollout disagrees with the eager one (relative difference of "
                f"J^ {check['J_rel']:.2e}, of dJ^/dtheta {check['grad_rel']:.2e}; torch "
                f"{torch.__version__})"
            )
    if problem is not None:
        warnings.warn(f"{problem}: using the eager rollout", RuntimeWarning, stacklevel=2)
        loss.set_fast_rollout(None)
        result.backend, result.shards = None, 1
    return result


def check_against_eager(
    loss: Any, seed: int = 0, horizon: int | None = COMPILE_CHECK_HORIZON
) -> dict[str, float]:
    """``J^`` and ``dJ^/dtheta`` of the loss's fast rollout and of its eager rollout over the
    first ``horizon`` steps (None: the loss's horizon) from the same random numbers (torch
    seeded with ``seed`` inside a forked random state, so the caller's stream is untouched):
    ``{"J_rel": |J_f - J_e| / |J_e|, "grad_rel": ||g_f - g_e|| / ||g_e||}`` (``g`` all policy
    parameters' gradients, one vector; 0 where both are 0). The policy runs in training
    mode, with its dropout masks, as in the optimisation (its mode is restored after). The
    first call of a fresh compiled step compiles it."""
    fast = loss.fast_rollout
    if fast == (None, None):
        raise ValueError("the loss has no fast rollout: call use_fast_rollout first")
    params = [p for p in loss.parameters() if p.requires_grad]
    dev = loss.init_mean.device
    results = []
    full_horizon = loss.horizon
    loss.horizon = full_horizon if horizon is None else min(int(horizon), full_horizon)
    policy = loss._policy_fn
    was_training = policy.training
    policy.train()
    try:
        with torch.random.fork_rng(devices=[dev] if dev.type == "cuda" else []):
            for engine, step_fn in ((None, None), fast):
                loss.set_fast_rollout(engine, step_fn)
                torch.manual_seed(seed)
                J = loss()["loss_cost"]
                grads = (
                    torch.autograd.grad(J, params, allow_unused=True)
                    if J.requires_grad and params
                    else [None] * len(params)
                )
                vec = [
                    (torch.zeros_like(p) if g is None else g.detach()).flatten()
                    for g, p in zip(grads, params, strict=True)
                ]
                results.append((J.detach(), torch.cat(vec or [J.new_zeros(0)])))
    finally:
        loss.set_fast_rollout(*fast)
        loss.horizon = full_horizon
        policy.train(was_training)
    (J_e, g_e), (J_f, g_f) = results

    def rel(diff: float, scale: float) -> float:
        return 0.0 if diff == 0 else diff / scale if scale > 0 else float("inf")

    return {
        "J_rel": rel((J_f - J_e).abs().item(), J_e.abs().item()),
        "grad_rel": rel((g_f - g_e).norm().item(), g_e.norm().item()),
    }


__all__ = [
    "BACKENDS",
    "COMPILE_CHECK_HORIZON",
    "COMPILE_CHECK_RTOL",
    "FastRollout",
    "MIN_SHARD_PARTICLES",
    "PARAM_NAMES",
    "RolloutFunction",
    "ShardedRollout",
    "TorchRollout",
    "check_against_eager",
    "default_shards",
    "unsupported_reason",
    "use_fast_rollout",
]

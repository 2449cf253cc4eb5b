r"""The particle rollout compiled without dynamo or autograd: backprop through time by hand.

:meth:`~mcpilco.agents.mc_pilco.loss.MCPilcoLoss.compile_step` with ``backend="direct"``.
Every part of a time step already has a hand-written backward (the ``autograd.Function``\ s
of the policy, the GP inputs, the fused GP posterior, the sample-clip-integrate step and the
cost). Here they are chained by hand, in two functions of plain tensors:

``step_forward(x_t, eps_t, nu_t, b_t, (t, 256/t), theta) -> (x_{t+1}, c(x_{t+1}), S_t)``
    ``u_t = pi_theta(x_t + nu_t)`` with the dropout mask ``D_t = 1[b_t < t] 256 / t`` made
    from the random bytes ``b_t`` (the mask of the eager rollout), ``x~_t = [x_t, u_t]``,
    ``(mu, sigma^2) = GP(x~_t)``, ``x_{t+1} = integrate(x_t, clip(mu + sigma eps_t))``, the
    cost; ``S_t`` are the tensors each part saves for its backward.
``step_backward(S_t, g_{x_{t+1}}, g_{c_{t+1}}, G) -> (g_{x_t}, G + dJ/dtheta|_t)``
    the parts' backward passes in reverse: ``g_{x_t} = dJ/dx_t`` (through the integration,
    the GP inputs and the policy input ``x_t + nu_t``) and the running sum ``G`` of the
    policy-parameter gradients.

Each function is traced once into an FX graph (``make_fx`` on fake tensors: the GP's fitted
buffers become constants of the graph) and compiled by inductor (fused C++ kernels plus
BLAS calls) with its C++ wrapper: one compiled call per function, without the GIL, made
without AOTAutograd's Python runtime wrappers (:func:`bypass_runtime_wrappers`). A
rollout calls the compiled forward ``H`` times, then the compiled backward ``H`` times
(:class:`RolloutFunction`, one autograd node for the whole rollout). Compared with
``torch.compile`` of the time step (``backend="dynamo"``), nothing checks guards at each
call and the autograd engine does not run per time step. The particles are independent, so
a rollout can be split by particles over ``S`` threads (``shards``), each running both loops
on its share with one intra-op thread; the shards' policy gradients are summed. Measured
figures (same rounds as the eager step and ``torch.compile``, on the 2-core CPU machine) are
in ``results/mcpilco_cartpole.md`` and ``results/mcpilco_notes.md``.

Glossary: ``M`` particles per candidate, ``K`` candidates, ``KM`` rows; ``S`` shards
(threads), ``KM / S`` rows each; ``H`` horizon;
``theta = (c, log l, w)`` the policy parameters (``(K, ...)`` for a population, else without
the leading ``K``).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import Any

import torch
from torch import Tensor
from torch.utils._pytree import tree_flatten, tree_unflatten

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

PARAM_NAMES = ("centers", "log_lengthscales", "weights")
"""The policy parameters ``theta``, in this order."""


class _Saved:
    """Stand-in for an ``autograd.Function`` context: ``save_for_backward`` keeps the tensors
    and the other attributes (e.g. the fused posterior's ``pred``) are set as usual. Every
    input counts as needing its gradient."""

    needs_input_grad = (True,) * 8

    def save_for_backward(self, *tensors: Tensor | None) -> None:
        self.saved_tensors = tensors


def unsupported_reason(policy: Any, dynamics: Any, cost: Any, device: torch.device) -> str | None:
    """Why the direct path cannot compile this rollout (None: it can). It chains the
    hand-written backward passes of the package's own parts, so it needs exactly those: a
    :class:`SquashedRBFPolicy` or :class:`PolicyPopulation`, :class:`SpeedIntegrationDynamics`
    over a :class:`FusedRBFMPKPredictor`, :class:`SaturatingCost`, on the CPU."""
    if device.type != "cpu":
        return f"it runs on the CPU only (the rollout is on {device})"
    if type(policy) not in (SquashedRBFPolicy, PolicyPopulation):
        return f"unsupported policy {type(policy).__name__}"
    if type(dynamics) is not SpeedIntegrationDynamics:
        return f"unsupported dynamics {type(dynamics).__name__}"
    if not isinstance(dynamics.delta_model, FusedRBFMPKPredictor):
        return f"the GP posterior is not fused ({type(dynamics.delta_model).__name__})"
    if type(cost) is not SaturatingCost:
        return f"unsupported cost {type(cost).__name__}"
    return None


def compile_traced(
    fn: Callable[..., tuple[Tensor, ...]], inputs: list[Tensor], cpp_wrapper: bool = True
) -> Callable:
    """``fn``, a function of tensors returning a tuple of tensors, traced by ``make_fx`` on
    ``inputs`` and compiled by inductor; the result has ``fn``'s signature.

    The trace is specialised to the inputs' shapes and dtypes. It runs on fake tensors (shapes
    only, one fake mode for the whole graph); tensors ``fn`` reads from its closure are baked
    in as constants. The tracer tells inputs apart by tensor object, so an example tensor
    given for two arguments is copied for its second place (else both places would be traced
    as one input).

    ``cpp_wrapper`` (default): inductor writes the code that calls the graph's kernels in C++
    too, one compiled call per graph instead of a Python function making some 70 calls (its
    C++ entry also runs without the GIL); it takes a few seconds more to compile. If that
    compilation fails, the graph is compiled again with the Python wrapper. Either way the
    result calls the compiled graph without AOTAutograd's Python runtime wrappers when that
    is safe (:func:`bypass_runtime_wrappers`).

    ``make_fx`` and ``torch._inductor.compile`` are PyTorch internals (checked with torch
    2.13): :meth:`MCPilcoLoss.compile_step` catches their failures and checks their result
    against the eager rollout.
    """
    from torch._inductor import compile as inductor_compile
    from torch._inductor import config as inductor_config
    from torch.fx.experimental.proxy_tensor import make_fx

    examples, seen = [], set()
    for t in inputs:
        examples.append(t.clone() if id(t) in seen else t)
        seen.add(id(t))
    with torch.no_grad():
        graph = make_fx(fn, tracing_mode="fake", _allow_non_fake_inputs=True)(*examples)
        compiled = None
        if cpp_wrapper:
            try:
                with inductor_config.patch(cpp_wrapper=True):
                    compiled = inductor_compile(graph, examples)
            except Exception:  # noqa: BLE001 (any failure of the C++ wrapper: Python one)
                pass
        if compiled is None:
            compiled = inductor_compile(graph, examples)
        return bypass_runtime_wrappers(compiled, examples)


def bypass_runtime_wrappers(compiled: Callable, examples: list[Tensor]) -> Callable:
    """``compiled`` (from ``torch._inductor.compile``) called without its Python wrappers,
    if that gives the same outputs; else ``compiled`` itself.

    ``torch._inductor.compile`` wraps the compiled graph in AOTAutograd's runtime wrappers:
    they prepend the graph's constants (here the GP's fitted tensors, lifted as
    ``params_buffers_flat``), handle input mutations, regenerate outputs that alias inputs
    and record profiler ranges. The time step's functions mutate no input and run under
    ``no_grad``, so the wrappers only cost time, a noticeable share of a small call
    (``results/mcpilco_notes.md``), and a rollout makes ``2 H`` calls per shard. The bare
    call is the compiled graph's ``current_callable`` on ``[*constants, *inputs]``: the
    same compiled code, so the same outputs to the bit. It is found through PyTorch
    internals (the wrapper's closure, checked with torch 2.13), so it is used only when it
    is found, the graph mutates no input, and on ``examples`` it returns outputs equal in
    value, dtype, shape and strides to those of ``compiled``. The bare call keeps the
    wrapped one as its ``wrapped_call``.
    """
    try:
        inner = inspect.unwrap(compiled, stop=lambda f: "params_buffers_flat" in _closure_cells(f))
        cells = _closure_cells(inner)
        constants = list(cells["params_buffers_flat"])
        graph = _find_compiled_graph(cells["compiled_fn"])
        call = graph.current_callable
        if call is None or graph.mutated_inputs:
            return compiled
    except Exception:  # noqa: BLE001 (internals changed: keep the wrapped call)
        return compiled

    def bare(*args: Tensor) -> tuple[Tensor, ...]:
        return call([*constants, *args])  # the callee clears the list it is given

    try:
        with torch.no_grad():
            want, got = compiled(*examples), bare(*examples)
        same = len(want) == len(got) and all(
            a.dtype == b.dtype and a.shape == b.shape and a.stride() == b.stride()
            and torch.equal(a, b)
            for a, b in zip(want, got, strict=True)
        )  # fmt: skip
    except Exception:  # noqa: BLE001
        return compiled
    if not same:
        return compiled
    bare.wrapped_call = compiled  # type: ignore[attr-defined] (the call it stands for)
    return bare


def _closure_cells(fn: Any) -> dict[str, Any]:
    """The variables ``fn`` closes over, by name (empty cells left out; none for a callable
    that is not a Python function)."""
    code, cells = getattr(fn, "__code__", None), {}
    if code is None:
        return cells
    for name, cell in zip(code.co_freevars, fn.__closure__ or (), strict=True):
        try:
            cells[name] = cell.cell_contents
        except ValueError:
            continue
    return cells


def _find_compiled_graph(fn: Any, depth: int = 0) -> Any:
    """The ``CompiledFxGraph`` inside AOTAutograd's runtime wrappers ``fn`` (a bounded search
    of closures and ``compiled_fn`` attributes); raises ``LookupError`` if there is none."""
    from torch._inductor.output_code import CompiledFxGraph

    if isinstance(fn, CompiledFxGraph):
        return fn
    if depth < 6:
        nested = [*_closure_cells(fn).values(), getattr(fn, "compiled_fn", None)]
        for item in nested:
            if item is None or isinstance(item, type) or not callable(item):
                continue
            try:
                return _find_compiled_graph(item, depth + 1)
            except LookupError:
                continue
    raise LookupError("no CompiledFxGraph found")


class DirectRollout:
    """The compiled ``step_forward`` and ``step_backward`` (module docstring) of one loss.

    Args:
        policy, dynamics, cost: the loss's parts (see :func:`unsupported_reason`).
        rows: ``KM``, the number of particles of every rollout it runs.
        delta_dim: dimension of the GP noise ``eps_t`` per row.
        compiler: ``(fn, example_inputs) -> callable`` for a function of tensors returning a
            tuple of tensors (default :func:`compile_traced`; ``lambda fn, _: fn`` runs the
            same functions eagerly).
        shards: ``S``, the number of threads a rollout is split over. The particles are
            independent, so each thread rolls out ``M / S`` particles of every candidate
            (``KM / S`` rows, the shape the functions are compiled for) with one intra-op
            thread, and the policy gradients of the ``S`` shards are summed. Code from
            inductor's C++ wrapper runs without the GIL (with the Python-wrapper fallback the
            threads share it). ``S = 1``: the calling thread does all.

    Built for fixed shapes and for the GP and cost of this loss; the policy parameters are
    inputs. Rollouts with another number of rows run eagerly (the loss decides).
    """

    def __init__(
        self,
        policy: SquashedRBFPolicy | PolicyPopulation,
        dynamics: SpeedIntegrationDynamics,
        cost: SaturatingCost,
        rows: int,
        delta_dim: int = 2,
        compiler: Callable[[Callable, list[Tensor]], Callable] | None = None,
        shards: int = 1,
    ) -> None:
        self._init_shards(policy, dynamics, cost, rows, shards)
        pred = dynamics.delta_model
        pred.row_blocks  # noqa: B018 (its block cache is built here, outside the trace)
        self._ctx_attrs: dict[str, dict[str, Any]] = {}
        compiler = compile_traced if compiler is None else compiler
        dtype = policy.weights.dtype
        x = torch.zeros(self.shard_rows, dynamics.layout.n, dtype=dtype)
        eps = torch.zeros(self.shard_rows, int(delta_dim), dtype=dtype)
        bits, keep = self.no_dropout()
        theta = self.parameters()
        with torch.no_grad():
            x1, c1, saved = self._forward(x, eps, x, bits, keep, *theta)  # records ctx attrs
        flat, self._saved_spec = tree_flatten(saved)
        self._saved_present = [t is not None for t in flat]
        saved_tensors = [t for t in flat if t is not None]
        zeros = [torch.zeros_like(t) for t in (x1, c1, *theta)]
        with _intra_op_threads(1 if self.shards > 1 else torch.get_num_threads()):
            # a shard's kernels are compiled for one thread (inductor fixes the count)
            self.step_forward = compiler(self._forward_flat, [x, eps, x, bits, keep, *theta])
            self.step_backward = compiler(self._backward_flat, [*saved_tensors, *zeros])

    def _init_shards(self, policy, dynamics, cost, rows: int, shards: int) -> None:
        """The parts, ``KM`` rows, ``S`` shards and ``KM / S`` rows per shard (checked)."""
        self.policy, self.dynamics, self.cost = policy, dynamics, cost
        self.rows, self.shards = int(rows), int(shards)
        self.batched = isinstance(policy, PolicyPopulation)
        self.candidates = int(getattr(policy, "num_candidates", 1))
        if self.shards < 1 or self.rows % (self.candidates * self.shards):
            raise ValueError(
                f"shards must be >= 1 and divide the {self.rows // self.candidates} particles "
                f"per candidate, got {shards}"
            )
        self.shard_rows = self.rows // self.shards
        self._pool = None
        if self.shards > 1:
            self._pool = ThreadPoolExecutor(self.shards, "direct-rollout")

    def forward_shard(self, x, noise, nu, bits, keep, theta):
        """One shard's forward loop (:func:`_forward_shard`): its costs ``c_{t+1}`` (a list
        of ``H`` tensors ``(KM/S,)``) and the state its backward needs."""
        return _forward_shard(self, x, noise, nu, bits, keep, theta)

    def backward_shard(self, state, g_costs, grads):
        """One shard's backward loop (:func:`_backward_shard`) from ``g = dJ/dcosts``
        ``(H, KM/S)``: ``grads`` plus the shard's ``dJ/dtheta``."""
        return _backward_shard(self, state, g_costs, grads)

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
        (libgomp's default wait policy) before they sleep. The caller's large ops (the
        scaling of the observation noise ``nu`` and the copies of the shards' parts of it)
        would start such spins just as the shards begin, taking core time from them
        (``results/mcpilco_notes.md``). With one thread the caller's ops start no worker.
        ``S = 1``: nothing changes (the shard is the caller, with its own thread count)."""
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

    def _forward_flat(self, *args: Tensor) -> tuple[Tensor, ...]:
        """``step_forward`` on ``(x, eps, nu, D, c, log l, w)``, flat: ``(x_{t+1}, c_{t+1},
        *S_t)``, the saved tensors flattened and their Nones left out."""
        x_next, c_next, saved = self._forward(*args)
        return (x_next, c_next, *[t for t in tree_flatten(saved)[0] if t is not None])

    def _backward_flat(self, *args: Tensor) -> tuple[Tensor, ...]:
        """``step_backward`` on ``(*S_t, g_x, g_c, *G)`` (``S_t`` as ``_forward_flat`` gives
        it), flat: ``(g_{x_t}, *G')``."""
        n = sum(self._saved_present)
        it = iter(args[:n])
        saved = tree_unflatten(
            [next(it) if p else None for p in self._saved_present], self._saved_spec
        )
        g_x_next, g_c_next, *grads = args[n:]
        g_prev, new = self._backward(saved, g_x_next, g_c_next, tuple(grads))
        return (g_prev, *new)

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

    def _batched(self, t: Tensor) -> Tensor:
        return t if self.batched else t.unsqueeze(0)

    def _forward(
        self,
        x: Tensor,
        eps: Tensor,
        nu: Tensor,
        bits: Tensor,
        keep: Tensor,
        c: Tensor,
        log_l: Tensor,
        w: Tensor,
    ) -> tuple[Tensor, Tensor, tuple]:
        """``step_forward`` (module docstring), built from the parts' ``forward``."""
        dyn, cost = self.dynamics, self.cost
        mask = mask_from_bytes(bits, keep[0], x.dtype, keep[1])
        ctx = {name: _Saved() for name in ("policy", "inputs", "gp", "step", "cost")}
        layout = dyn.layout
        obs = (x + nu).reshape(self.candidates, -1, layout.n)
        u = _SquashedRBF.forward(
            ctx["policy"], obs, self._batched(c), self._batched(log_l), self._batched(w),
            (self.policy.u_mid, self.policy.u_half), mask, self.policy.layout,
        ).reshape(self.shard_rows, -1)  # fmt: skip
        gp_in = _GPInputs.forward(ctx["inputs"], x, u, layout)
        mean, var = _FusedPosterior.forward(ctx["gp"], gp_in, dyn.delta_model)
        if dyn.sample_noise:
            var = var + dyn.noise_variance.to(var.dtype)
        x_next = _SampleClipIntegrate.forward(
            ctx["step"], x, mean, var, eps, dyn.delta_bound, dyn.dt, layout
        )
        c_next = _SaturatingCostFn.forward(ctx["cost"], x_next, cost)
        self._ctx_attrs = {
            name: {k: v for k, v in vars(s).items() if k != "saved_tensors"}
            for name, s in ctx.items()
        }
        return x_next, c_next, tuple(ctx[name].saved_tensors for name in ctx)

    def _backward(
        self, saved: tuple, g_x_next: Tensor, g_c_next: Tensor, grads: tuple
    ) -> tuple[Tensor, tuple]:
        """``step_backward`` (module docstring), built from the parts' ``backward``."""
        ctx = {}
        for (name, attrs), tensors in zip(self._ctx_attrs.items(), saved, strict=True):
            ctx[name] = _Saved()
            vars(ctx[name]).update(attrs)
            ctx[name].saved_tensors = tensors
        g_x = _SaturatingCostFn.backward(ctx["cost"], g_c_next)[0] + g_x_next
        g_state, g_mean, g_var = _SampleClipIntegrate.backward(ctx["step"], g_x)[:3]
        g_in = _FusedPosterior.backward(ctx["gp"], g_mean, g_var)[0]
        g_state_in, g_u = _GPInputs.backward(ctx["inputs"], g_in)[:2]
        g_obs, *g_theta = _SquashedRBF.backward(
            ctx["policy"], g_u.reshape(self.candidates, -1, g_u.shape[-1])
        )[:4]
        if not self.batched:
            g_theta = [g.squeeze(0) for g in g_theta]
        g_prev = g_state + g_state_in + g_obs.reshape(self.shard_rows, -1)
        return g_prev, tuple(G + g for G, g in zip(grads, g_theta, strict=True))


def _shard_task(fn: Callable[..., Any]) -> Callable[..., Any]:
    """``fn`` as one shard's task in a worker thread: one intra-op thread, autograd off.

    The count is set at each task, not once when the worker starts: a thread takes the
    process's default count (the caller's, once restored) at its first parallel op, which
    would undo a setting made at the start (each shard's BLAS calls would then run on every
    core, which the other shards share). Autograd: a worker thread starts with it on; the
    compiled steps take the policy parameters, which require gradients, as plain inputs."""

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


def _forward_shard(
    runner: DirectRollout,
    x: Tensor,
    noise: Tensor,
    nu: Tensor,
    bits: list[Tensor],
    keep: Tensor,
    theta: tuple[Tensor, ...],
) -> tuple[list[Tensor], list[list[Tensor]]]:
    """One shard's forward loop: its costs ``c_{t+1}`` and saved tensors ``S_t``, t < H."""
    costs, steps = [], []
    for t in range(noise.shape[0]):
        x, cost, *saved = runner.step_forward(x, noise[t], nu[t], bits[t], keep, *theta)
        costs.append(cost)
        steps.append(saved)
    return costs, steps


def _backward_shard(
    runner: DirectRollout, steps: list[list[Tensor]], g_costs: Tensor, grads: list[Tensor]
) -> list[Tensor]:
    """One shard's backward loop from ``g = dJ/dcosts`` (H, rows): ``dJ/dtheta``."""
    g_x = g_costs.new_zeros(g_costs.shape[1], runner.dynamics.layout.n)
    for t in reversed(range(len(steps))):
        g_x, *grads = runner.step_backward(*steps[t], g_x, g_costs[t], *grads)
    return grads


class RolloutFunction(torch.autograd.Function):
    """``costs (H, KM) = rollout(theta)`` through a :class:`DirectRollout`: the forward loop
    keeps each step's saved tensors, the backward loop returns ``dJ/dtheta`` for the
    upstream gradient ``g = dJ/dcosts``; each loop runs per shard, the shards in parallel.
    The initial state gets no gradient (it does not depend on ``theta``). The random bytes
    of the dropout masks of all ``H`` steps are drawn first, in step order
    (``draw_bytes(x_0) = (b_t, t)``, None for no dropout): the same random stream as the
    eager rollout, which draws them step by step and nothing else in between; each shard
    turns its bytes into its mask inside the compiled step."""

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

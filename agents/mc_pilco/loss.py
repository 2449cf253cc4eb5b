"""Particle rollout and expected cost of MC-PILCO as a TorchRL ``LossModule``.

Glossary (thesis sections 5.4.1-5.4.2; Amadio et al. 2022, sec. III)
------------------------------------------------------------------------
``M``
    number of particles; ``H`` horizon (time steps, 60 = 3 s for the cartpole).
``x_0^(m) ~ N(mu_0, Sigma_0)``
    initial particles, ``Sigma_0 = sigma_0^2 I`` (``sigma_0 = 0.01`` like the env).
``u_t^(m) = pi_theta(x_t^(m) + sigma_obs nu_t^(m))``
    policy action; ``nu ~ N(0, I)`` optionally simulates the measurement noise the policy
    sees on the real system (``sigma_obs = 0`` turns it off).
``x_{t+1}^(m) = f(x_t^(m), u_t^(m), eps_t^(m))``
    one step of the GP particle dynamics with the reparameterisation trick,
    ``eps ~ N(0, I)`` (:class:`~mcpilco.agents.mc_pilco.dynamics.SpeedIntegrationDynamics`).
``J^(theta) = sum_{t=1}^{H} 1/M sum_m c(x_t^(m))``
    Monte Carlo estimate of the expected cumulative cost, eq. (5.8) (the ``t = 0`` term
    does not depend on ``theta`` and is left out). Its gradient is computed by backprop
    through the whole horizon (5.4.2).
``s_J``
    standard deviation over particles of the per-particle cumulative cost
    ``sum_t c(x_t^(m))`` (reported with the loss).
candidates ``k = 1..K``
    with a :class:`~mcpilco.agents.mc_pilco.policy.PolicyPopulation` the rollout carries
    ``M`` particles per candidate, stacked candidate-major (``K M`` in all);
    ``J^_k`` is the estimate (5.8) of candidate ``k`` and ``loss_cost = sum_k J^_k`` (the
    candidates' parameters are disjoint, so each gets the gradient of its own ``J^_k``).

All particles are propagated together: each time step is a handful of batched tensor ops
over ``(M, .)``; there is no Python loop over particles.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule
from torch import Tensor, nn
from torchrl.objectives import LossModule

from mcpilco.agents.mc_pilco.direct_compile import (
    PARAM_NAMES,
    DirectRollout,
    RolloutFunction,
    unsupported_reason,
)
from mcpilco.agents.mc_pilco.native_rollout import (
    NativeRollout,
    build_error,
    native_unsupported_reason,
)

COMPILE_CHECK_RTOL = 0.1
"""Largest ``|J_c - J_e| / |J_e|`` and ``||g_c - g_e|| / ||g_e||`` of the compiled against the
eager step (:meth:`MCPilcoLoss.compile_step`'s check); a wrong gradient gives about 1."""

COMPILE_CHECK_HORIZON = 10
"""Time steps of that check: few enough that float32 rounding, which particles near an unstable
equilibrium amplify over a long horizon, stays small; every part of the step still runs."""

MIN_SHARD_PARTICLES = 50
"""Fewest particles per candidate and thread for which :meth:`MCPilcoLoss.compile_step`
splits the direct rollout over threads by default (below, a thread's work is too small)."""


@dataclass
class ParticleRollout:
    """Result of :meth:`MCPilcoLoss.rollout`: ``states (M, H+1, n)``, ``actions (M, H, A)``,
    ``costs (M, H)`` (cost of ``x_1..x_H``)."""

    states: Tensor
    actions: Tensor
    costs: Tensor


class MCPilcoLoss(LossModule):
    """Expected cumulative cost of the policy under the GP particle dynamics, ``loss_cost``.

    Args:
        policy: ``TensorDictModule`` (``"observation"`` -> ``"action"``) or a plain module
            ``obs (..., n) -> action (..., A)``.
        dynamics: module ``(state, action, eps) -> next_state`` (e.g.
            :class:`~mcpilco.agents.mc_pilco.dynamics.SpeedIntegrationDynamics`); replace it
            with :meth:`set_dynamics` after each GP re-fit.
        cost: module ``state (..., n) -> cost (...)``.
        horizon: ``H``, number of simulated steps (> 0).
        num_particles: ``M`` (> 0).
        init_mean: ``mu_0`` (n,); its length sets the state size ``n``.
        init_std: ``sigma_0`` (scalar or (n,)).
        obs_noise_std: ``sigma_obs`` of the simulated measurement noise on the policy input.
        delta_dim: dimension of ``eps`` per step (number of GPs); None: the dynamics'
            ``layout.output_dim``.

    ``forward(td)`` reads optional entries ``"initial_state"`` (K M, n) and ``"noise"``
    (H, K M, delta_dim) (common random numbers, tests); otherwise it samples them. It returns
    a TensorDict with ``loss_cost`` (the differentiable ``sum_k J^_k``), ``cost_std``
    (``s_J``, mean over candidates, detached) and ``candidate_costs`` (``J^_k``, (K,),
    detached). A plain policy is ``K = 1``.
    """

    def __init__(
        self,
        policy: nn.Module,
        dynamics: nn.Module,
        cost: nn.Module,
        horizon: int,
        num_particles: int,
        init_mean: Sequence[float] | Tensor,
        init_std: float | Sequence[float] | Tensor = 0.01,
        obs_noise_std: float = 0.0,
        delta_dim: int | None = None,
    ) -> None:
        super().__init__()
        if int(horizon) != horizon or horizon < 1:
            raise ValueError(f"horizon must be a positive integer, got {horizon!r}")
        if int(num_particles) != num_particles or num_particles < 1:
            raise ValueError(
                f"num_particles must be a positive integer, got {num_particles!r}; use e.g. 400"
            )
        if obs_noise_std < 0:
            raise ValueError(f"obs_noise_std must be >= 0, got {obs_noise_std}")
        self.policy = policy
        self.dynamics = dynamics
        self.cost = cost
        self.horizon = int(horizon)
        self.num_particles = int(num_particles)
        self.obs_noise_std = float(obs_noise_std)
        if delta_dim is None:
            layout = getattr(dynamics, "layout", None)
            if layout is None:
                raise ValueError("delta_dim is needed for dynamics without a layout")
            delta_dim = layout.output_dim
        self.delta_dim = int(delta_dim)
        self.register_buffer(
            "init_mean", torch.as_tensor(init_mean, dtype=torch.float32).reshape(-1).clone()
        )
        self.state_dim = int(self.init_mean.numel())
        self.register_buffer(
            "init_std",
            torch.as_tensor(init_std, dtype=torch.float32).expand(self.state_dim).clone(),
        )
        if isinstance(policy, TensorDictModule):
            if list(policy.in_keys) != ["observation"] or list(policy.out_keys) != ["action"]:
                raise ValueError(
                    "the policy TensorDictModule must read 'observation' and write 'action', "
                    f"got in_keys={policy.in_keys}, out_keys={policy.out_keys}"
                )
            # the hot loop calls the wrapped module directly (no TensorDict per time step)
            self._policy_fn = policy.module
        else:
            self._policy_fn = policy
        self.num_candidates = int(getattr(self._policy_fn, "num_candidates", 1))
        self._compiled_step = None  # the time step torch.compile-d (backend "dynamo")
        self._direct: DirectRollout | None = None  # the rollout compiled by hand ("direct")
        self.compile_backend: str | None = None  # the backend of the compiled path in use
        self.compile_check: dict[str, float] | None = None  # figures of compile_step's check
        self.compile_error: str | None = None  # compile_step's compilation error, if any

    def _step(
        self, x: Tensor, eps: Tensor, nu: Tensor | None, mask: Tensor | None = None
    ) -> tuple[Tensor, Tensor, Tensor]:
        """One time step for all particles: ``u = pi(x + nu)``, ``x+ = f(x, u, eps)``, ``c(x+)``
        (``mask``: the policy's dropout mask for this step, drawn by the caller)."""
        obs = x if nu is None else x + nu
        u = self._policy_fn(obs) if mask is None else self._policy_fn(obs, mask=mask)
        x_next = self.dynamics(x, u, eps)
        return x_next, u, self.cost(x_next)

    def compile_step(
        self,
        enable: bool = True,
        verify: bool = True,
        backend: str = "auto",
        shards: int | None = None,
        **compile_kwargs,
    ) -> bool:
        """Compile the rollout's time step; returns whether a compiled path is in use.

        Backends:

        ``"native"``
            the whole rollout, forward and backward through time, evaluated by the package's
            C++ loop for any task layout (:mod:`~mcpilco.agents.mc_pilco.native_rollout`:
            particles in tiles of 16, the GP's constant matrices packed once per fit, no
            per-op dispatch), the same maths as ``"direct"``; a PyTorch C++ extension built
            on first use (``torch.utils.cpp_extension``, then cached). Needs what
            ``"direct"`` needs, in float32, with the package's two kernels; used like
            ``"direct"``.
        ``"direct"``
            forward and backward of a time step chained by hand from the parts' analytic
            backward passes, traced once and compiled by inductor; the rollout is one
            autograd node (:mod:`~mcpilco.agents.mc_pilco.direct_compile`). No dynamo guards
            and no autograd engine per time step. Needs the package's own policy, dynamics
            over a fused GP posterior, and cost, on the CPU; used by :meth:`forward` (the
            optimisation loss) for rollouts of ``num_particles`` per candidate.
        ``"dynamo"``
            ``torch.compile`` of the per-time-step function (``compile_kwargs`` go to it): one
            graph with the custom autograd functions (a test checks that no graph break
            creeps in); used by every rollout.
        ``"auto"`` (default)
            ``"native"`` where it applies, else ``"direct"`` where it applies, else
            ``"dynamo"``.

        ``shards`` (native and direct backends): the number of threads each rollout is split
        over, by particles, each with one intra-op thread (:class:`DirectRollout`). None
        (default): ``torch.get_num_threads()`` where that divides the ``M`` particles into
        shards of at least :data:`MIN_SHARD_PARTICLES`, else 1.

        The policy's dropout masks are drawn outside the compiled code, so the same seed
        gives the eager step's masks and noise. Enabling calls ``torch.compiler.reset()``
        first: the graphs compiled for an earlier GP (an earlier trial) are dropped instead of
        piling up to dynamo's recompile limit, beyond which it would silently run eagerly.

        ``verify`` (default): compile now, on this module's shapes, and check the compiled
        path against the eager one, ``J^`` and ``dJ^/dtheta`` over the first
        :data:`COMPILE_CHECK_HORIZON` steps from the same random numbers
        (:meth:`compare_compiled_step`, within :data:`COMPILE_CHECK_RTOL`). If they disagree
        the compiled path is dropped with a warning and the eager step is used: a compiler
        that returns wrong gradients would otherwise train nothing, silently. The check
        leaves torch's random stream where it was. ``compile_check`` holds its figures. A
        compilation that raises (no working C++ toolchain, an inductor error) is also caught
        there: a warning, the eager step, and the error's text in ``compile_error``.
        ``compile_backend`` names the backend in use (None: eager).
        """
        if backend not in ("auto", "native", "direct", "dynamo"):
            raise ValueError(
                f"backend must be 'auto', 'native', 'direct' or 'dynamo', got {backend!r}"
            )
        self.compile_check = None
        self.compile_error = None
        self._compiled_step = self._direct = self.compile_backend = None
        if not enable:
            return False
        torch.compiler.reset()
        reason = unsupported_reason(
            self._policy_fn, self.dynamics, self.cost, self.init_mean.device
        )
        if backend == "direct" and reason is not None:
            raise ValueError(f"the direct backend cannot compile this rollout: {reason}")
        native_reason = None
        if backend in ("auto", "native"):
            native_reason = native_unsupported_reason(
                self._policy_fn, self.dynamics, self.cost, self.init_mean.device
            )
        if backend == "native" and native_reason is not None:
            raise ValueError(f"the native backend cannot run this rollout: {native_reason}")
        failed = build_error()
        if backend == "auto" and native_reason is not None and failed and failed in native_reason:
            warnings.warn(
                f"the native rollout was not used ({native_reason})", RuntimeWarning, stacklevel=2
            )
        if backend == "auto":
            backend = (
                "native" if native_reason is None else "direct" if reason is None else "dynamo"
            )
        self.compile_backend = backend
        m = self.num_particles
        if shards is None:
            threads = torch.get_num_threads()
            shards = threads if m % threads == 0 and m // threads >= MIN_SHARD_PARTICLES else 1
        elif int(shards) != shards or shards < 1 or m % shards:
            raise ValueError(
                f"shards must be a positive divisor of the {m} particles, got {shards}"
            )
        elif shards > 1 and backend == "dynamo":
            raise ValueError("shards > 1 needs the native or direct backend, got 'dynamo'")
        problem = None
        try:
            if backend in ("native", "direct"):
                runner = NativeRollout if backend == "native" else DirectRollout
                self._direct = runner(
                    self._policy_fn,
                    self.dynamics,
                    self.cost,
                    self.num_candidates * self.num_particles,
                    self.delta_dim,
                    shards=shards,
                )
            else:
                self._compiled_step = torch.compile(self._step, **compile_kwargs)
            check = self.compare_compiled_step() if verify else None
        except Exception as err:  # noqa: BLE001 (any compiler failure: run eagerly)
            first_line = (str(err).strip().splitlines() or [""])[0]
            self.compile_error = f"{type(err).__name__}: {first_line}"
            problem = f"compiling the rollout step failed ({self.compile_error})"
        else:
            self.compile_check = check
            if check is not None and not (
                check["J_rel"] <= COMPILE_CHECK_RTOL >= check["grad_rel"]  # NaN fails
            ):
                problem = (
                    f"the compiled rollout step ({backend}) disagrees with the eager step "
                    f"(relative difference of J^ {check['J_rel']:.2e}, of dJ^/dtheta "
                    f"{check['grad_rel']:.2e}; torch {torch.__version__})"
                )
        if problem is not None:
            warnings.warn(f"{problem}: using the eager step", RuntimeWarning, stacklevel=2)
            self._compiled_step = self._direct = self.compile_backend = None
        return self.compile_backend is not None

    def compare_compiled_step(
        self, seed: int = 0, horizon: int | None = COMPILE_CHECK_HORIZON
    ) -> dict[str, float]:
        """``J^`` and ``dJ^/dtheta`` of the compiled and the eager step over the first
        ``horizon`` steps (None: the loss's horizon) from the same random numbers (torch
        seeded with ``seed`` inside a forked random state, so the caller's stream is
        untouched): ``{"J_rel": |J_c - J_e| / |J_e|, "grad_rel": ||g_c - g_e|| / ||g_e||}``
        (``g`` all policy parameters' gradients, one vector; 0 where both are 0). The policy
        runs in training mode, with its dropout masks, as in the optimisation (its mode is
        restored after). The first call of a fresh compiled step compiles it.
        """
        compiled = (self._compiled_step, self._direct)
        if compiled == (None, None):
            raise ValueError("compare_compiled_step needs a compiled step: call compile_step")
        params = [p for p in self.parameters() if p.requires_grad]
        dev = self.init_mean.device
        results = []
        full_horizon = self.horizon
        self.horizon = full_horizon if horizon is None else min(int(horizon), full_horizon)
        was_training = self._policy_fn.training
        self._policy_fn.train()
        try:
            with torch.random.fork_rng(devices=[dev] if dev.type == "cuda" else []):
                for self._compiled_step, self._direct in ((None, None), compiled):
                    torch.manual_seed(seed)
                    J = self()["loss_cost"]
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
            self._compiled_step, self._direct = compiled
            self.horizon = full_horizon
            self._policy_fn.train(was_training)
        (J_e, g_e), (J_c, g_c) = results

        def rel(diff: float, scale: float) -> float:
            return 0.0 if diff == 0 else diff / scale if scale > 0 else float("inf")

        return {
            "J_rel": rel((J_c - J_e).abs().item(), J_e.abs().item()),
            "grad_rel": rel((g_c - g_e).norm().item(), g_e.norm().item()),
        }

    @property
    def rollout_shards(self) -> int:
        """The number of threads the compiled rollout is split over (1 unless the direct
        backend splits it; see :meth:`compile_step`)."""
        return 1 if self._direct is None else self._direct.shards

    @property
    def functional(self) -> bool:  # the policy is used statefully (no functional params)
        return False

    def set_dynamics(self, dynamics: nn.Module) -> None:
        """Use new particle dynamics (after a GP re-fit)."""
        self.dynamics = dynamics

    def sample_initial_state(self, num_particles: int | None = None) -> Tensor:
        """``x_0^(m) ~ N(mu_0, Sigma_0)``, (K M, n) (``M`` per candidate)."""
        m = self.num_particles if num_particles is None else int(num_particles)
        eps = torch.randn(self.num_candidates * m, self.state_dim, device=self.init_mean.device)
        return self.init_mean + self.init_std * eps

    def _draw_inputs(
        self, initial_state: Tensor | None, noise: Tensor | None, num_particles: int | None
    ) -> tuple[Tensor, Tensor, Tensor | None]:
        """``x_0`` (K M, n), ``eps`` (H, K M, delta_dim) and ``sigma_obs nu`` (H, K M, n) or
        None, each sampled (in this order) where not given, and checked."""
        x = self.sample_initial_state(num_particles) if initial_state is None else initial_state
        m, n = x.shape[0], self.state_dim
        if x.ndim != 2 or x.shape[1] != n or m % self.num_candidates:
            raise ValueError(
                f"initial_state must have shape (K M, {n}) with K = {self.num_candidates}, got "
                f"{tuple(x.shape)}"
            )
        if noise is None:
            noise = torch.randn(self.horizon, m, self.delta_dim, dtype=x.dtype, device=x.device)
        if noise.shape != (self.horizon, m, self.delta_dim):
            raise ValueError(
                f"noise must have shape (H, M, {self.delta_dim}) = "
                f"({self.horizon}, {m}, {self.delta_dim}), got {tuple(noise.shape)}; the "
                "horizon of the noise must match the loss's horizon"
            )
        obs_noise = None
        if self.obs_noise_std > 0:
            obs_noise = self.obs_noise_std * torch.randn(
                self.horizon, m, n, dtype=x.dtype, device=x.device
            )
        return x, noise, obs_noise

    def rollout(
        self,
        initial_state: Tensor | None = None,
        noise: Tensor | None = None,
        num_particles: int | None = None,
        keep_states: bool = True,
    ) -> ParticleRollout:
        """Propagate ``M`` particles for ``H`` steps; differentiable w.r.t. the policy.

        Args:
            initial_state: (K M, n) ``x_0``; sampled when None.
            noise: (H, K M, delta_dim) ``eps``; sampled when None. Pass zeros for the mean
                prediction of a deterministic model.
            num_particles: ``M`` per candidate when ``initial_state`` is None (default: the
                module's).
            keep_states: also return the whole trajectory (else ``states`` holds only
                ``x_0`` and ``x_H``).
        """
        x, noise, obs_noise = self._draw_inputs(initial_state, noise, num_particles)
        states = [x]
        actions = []
        costs = []
        step = self._compiled_step if self._compiled_step is not None else self._step
        # the policy's dropout masks are drawn here, step by step, outside the (possibly
        # compiled) step: the same random stream as a policy drawing its own
        draw_mask = getattr(self._policy_fn, "draw_dropout_mask", None)
        for t in range(self.horizon):
            mask = None if draw_mask is None else draw_mask(x)
            x, u, c = step(x, noise[t], None if obs_noise is None else obs_noise[t], mask)
            costs.append(c)
            if keep_states or t == self.horizon - 1:
                states.append(x)
            actions.append(u)
        return ParticleRollout(
            states=torch.stack(states, dim=1),
            actions=torch.stack(actions, dim=1),
            costs=torch.stack(costs, dim=1),
        )

    def forward(self, tensordict: TensorDictBase | None = None) -> TensorDict:
        td = TensorDict({}, batch_size=[]) if tensordict is None else tensordict
        init, noise = td.get("initial_state", None), td.get("noise", None)
        direct = self._direct
        if direct is not None and init is not None and init.shape[:1] != (direct.rows,):
            direct = None  # built for the module's particle count only: run eagerly
        if direct is not None:
            with direct.serial_caller():
                x, noise, obs_noise = self._draw_inputs(init, noise, None)
                costs = RolloutFunction.apply(
                    direct,
                    getattr(self._policy_fn, "draw_dropout_bytes", lambda _x: None),
                    x,
                    noise,
                    noise.new_zeros(*noise.shape[:2], self.state_dim)
                    if obs_noise is None
                    else obs_noise,
                    *(getattr(self._policy_fn, name) for name in PARAM_NAMES),
                ).T  # (K M, H)
        else:
            costs = self.rollout(initial_state=init, noise=noise, keep_states=False).costs
        per_particle = costs.sum(dim=1).view(self.num_candidates, -1)  # sum_t c, (K, M)
        per_candidate = per_particle.mean(dim=1)  # J^_k
        with torch.no_grad():
            std = (
                per_particle.std(dim=1).mean()
                if per_particle.shape[1] > 1
                else per_particle.new_zeros(())
            )
        return TensorDict(
            {
                "loss_cost": per_candidate.sum(),
                "cost_std": std,
                "candidate_costs": per_candidate.detach(),
            },
            batch_size=[],
        )

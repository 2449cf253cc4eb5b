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
``J^_W`` (success window)
    with ``success_window = W`` (a task whose success keeps the state in a goal for the last
    ``W`` steps, :func:`~mcpilco.agents.mc_pilco.horizon.success_window`), the steps of the
    window count twice:
    ``J^_W = sum_{t=1}^{H} 1/M sum_m c(x_t^(m)) + sum_{t=H-W+1}^{H} 1/M sum_m c(x_t^(m))``.
    The plain sum ranks a trajectory that reaches the goal after ``H - W`` (and so fails the
    window) with one that reaches it earlier and costs the same in sum; the second count
    charges the late one its costly arrival inside the window once more. A successful
    trajectory whose cost in the goal is at most ``c_G`` has ``J^_W <= J^ + W c_G`` (the
    plateau restarts' success level adds that term,
    :func:`~mcpilco.agents.mc_pilco.trainer.success_cost_level`). A rollout shorter than
    ``W`` steps counts all its steps twice. ``W = None``: the plain sum (5.8).
``s_J``
    standard deviation over particles of the per-particle cumulative cost
    ``sum_t c(x_t^(m))`` (of ``J^_W``'s per-particle term with a success window; reported
    with the loss).
termination (an absorbing set)
    a task whose env ends an episode when the state leaves a set ``X_ok``
    (:class:`TerminationSet`, the task file's ``termination``) is rolled out with an alive
    mask ``a_t^(m) = prod_{s <= t} 1[x_s^(m) in X_ok]``:
    ``x_{t+1} = a_t f(x_t, u_t, eps_t) + (1 - a_t) x_t`` (a particle that left stays at the
    state where it left, as the env's last observation does) and
    ``c_{t+1} = a_{t+1} c(x_{t+1}) + (1 - a_{t+1}) c_max`` with ``c_max = 1``, the bound of
    the saturating cost ``c = 1 - exp(.) <= 1``: every step after the env would have ended
    costs the most a step can. A particle that leaves at step ``t`` so pays ``H - t + 1``
    on top of its earlier costs; the mask is piecewise constant, so the gradient flows
    through the costs of the particles still alive.
candidates ``k = 1..K``
    with a :class:`~mcpilco.agents.mc_pilco.policy.PolicyPopulation` the rollout carries
    ``M`` particles per candidate, stacked candidate-major (``K M`` in all);
    ``J^_k`` is the estimate (5.8) of candidate ``k`` and ``loss_cost = sum_k J^_k`` (the
    candidates' parameters are disjoint, so each gets the gradient of its own ``J^_k``).

All particles are propagated together: each time step is a handful of batched tensor ops
over ``(M, .)``; there is no Python loop over particles.

tensordict keys (TorchRL's ``set_keys`` convention)
    ``loss.set_keys(name=key)`` renames what the loss reads and writes (defaults in
    :class:`MCPilcoLoss`'s ``_AcceptedKeys``): the input's ``initial_state`` ``x_0`` and
    ``noise`` ``eps`` (both optional), the outputs ``loss_cost``, ``cost_std`` and
    ``candidate_costs``, and the keys of the parts: ``observation`` (what a policy
    ``TensorDictModule`` and the world model read as ``x_t``), ``action`` (what the policy
    writes, the world model reads) and ``next_observation`` (the world model's sampled
    ``x_{t+1}``). A part whose keys differ from the loss's is refused at :meth:`forward`,
    naming the ``set_keys`` call that fits it. :meth:`MCPilcoLoss.rollout_tensordict`
    writes the particle trajectories under the same keys.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass
from typing import Protocol

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule
from tensordict.utils import NestedKey
from torch import Tensor, nn
from torchrl.objectives import LossModule

from mcpilco.agents.mc_pilco.torchrl_parts import ParticleWorldModel


class RolloutEngine(Protocol):
    """What the loss needs of a fast rollout engine it is given
    (:meth:`MCPilcoLoss.set_fast_rollout`; built by the trainer's choice of backend):
    ``rows`` (the particle rows ``K M`` it was built for), ``shards`` (threads it splits a
    rollout over), ``serial_caller()`` (a context for the caller's own tensor ops while it
    runs) and ``costs(x_0, eps, nu)``, the per-step costs ``(H, K M)``, differentiable with
    respect to the policy parameters."""

    rows: int
    shards: int

    def serial_caller(self) -> AbstractContextManager[None]: ...

    def costs(self, x: Tensor, noise: Tensor, nu: Tensor | None) -> Tensor: ...


TERMINATION_COST = 1.0
"""``c_max``: the cost of each step a particle spends in the absorbing set (the saturating
cost's bound)."""


class TerminationSet(nn.Module):
    """``state (..., n) -> outside (...)`` (bool): whether the state lies outside the ranges
    ``lo_j <= x_j <= hi_j`` of the listed coordinates ``j`` (an angle by its wrapped value
    in ``[-pi, pi)``), where the env ends an episode.

    Args:
        idx: the coordinates ``j``; lo, hi: their ranges; angle: which of them are angles.
    """

    def __init__(
        self, idx: Sequence[int], lo: Sequence[float], hi: Sequence[float], angle: Sequence[bool]
    ) -> None:
        super().__init__()
        self.idx = [int(i) for i in idx]
        self.register_buffer("lo", torch.as_tensor(lo, dtype=torch.float32))
        self.register_buffer("hi", torch.as_tensor(hi, dtype=torch.float32))
        self.register_buffer("angle", torch.as_tensor(angle, dtype=torch.bool))

    @classmethod
    def from_task(cls, task) -> TerminationSet | None:
        """The set of a :class:`~mcpilco.envs.tasks.spec.TaskSpec`'s ``termination`` (None:
        the task declares none)."""
        if not task.termination:
            return None
        names = list(task.termination)
        return cls(
            [task.index(n) for n in names],
            [task.termination[n][0] for n in names],
            [task.termination[n][1] for n in names],
            [n in task.angles for n in names],
        )

    def forward(self, state: Tensor) -> Tensor:
        v = state[..., self.idx]
        v = torch.where(self.angle, torch.remainder(v + math.pi, 2 * math.pi) - math.pi, v)
        return ((v < self.lo.to(v.dtype)) | (v > self.hi.to(v.dtype))).any(dim=-1)


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
        policy: ``TensorDictModule`` (the loss's ``observation`` key -> its ``action`` key)
            or a plain module ``obs (..., n) -> action (..., A)``.
        dynamics: module ``(state, action, eps) -> next_state`` (e.g.
            :class:`~mcpilco.agents.mc_pilco.dynamics.SpeedIntegrationDynamics`), or the GP
            world model as a ``TensorDictModule``
            (:class:`~mcpilco.agents.mc_pilco.torchrl_parts.ParticleWorldModel`, whose
            dynamics the rollout steps); replace it with :meth:`set_dynamics` after each GP
            re-fit.
        cost: module ``state (..., n) -> cost (...)``.
        horizon: ``H``, number of simulated steps (> 0).
        num_particles: ``M`` (> 0).
        init_mean: ``mu_0`` (n,); its length sets the state size ``n``.
        init_std: ``sigma_0`` (scalar or (n,)).
        obs_noise_std: ``sigma_obs`` of the simulated measurement noise on the policy input.
        delta_dim: dimension of ``eps`` per step (number of GPs); None: the dynamics'
            ``layout.output_dim``.
        termination: module ``state (..., n) -> outside (...)`` (bool), the set where the
            env ends an episode (:class:`TerminationSet`); a particle there is absorbed
            (module glossary). None: the env never ends an episode early.
        termination_cost: ``c_max``, the cost of each absorbed step.
        success_window: ``W``, steps of the task's success window at the horizon's end: the
            loss is ``J^_W`` (module glossary); None: the plain sum ``J^``.

    ``forward(td)`` reads optional entries ``initial_state`` (K M, n) and ``noise``
    (H, K M, delta_dim) (common random numbers, tests); otherwise it samples them. It returns
    a TensorDict with ``loss_cost`` (the differentiable ``sum_k J^_k``), ``cost_std``
    (``s_J``, mean over candidates, detached) and ``candidate_costs`` (``J^_k``, (K,),
    detached). A plain policy is ``K = 1``. Every key is set by :meth:`set_keys` (module
    glossary)::

        loss.set_keys(observation="state", loss_cost="loss_mcpilco")
    """

    @dataclass
    class _AcceptedKeys:
        """The tensordict keys of the loss and their defaults (module glossary).

        Attributes:
            initial_state: ``x_0`` of the particles (K M, n) in the input; optional.
            noise: ``eps`` (H, K M, delta_dim) in the input; optional.
            observation: ``x_t``, the input key of the policy and the world model.
            action: ``u_t``, the output key of the policy, an input of the world model.
            next_observation: the world model's sampled ``x_{t+1}``.
            loss_cost: ``sum_k J^_k`` (differentiable); cost_std: ``s_J``;
            candidate_costs: ``J^_k`` (K,).
        """

        initial_state: NestedKey = "initial_state"
        noise: NestedKey = "noise"
        observation: NestedKey = "observation"
        action: NestedKey = "action"
        next_observation: NestedKey = ("next", "observation")
        loss_cost: NestedKey = "loss_cost"
        cost_std: NestedKey = "cost_std"
        candidate_costs: NestedKey = "candidate_costs"

    default_keys = _AcceptedKeys

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
        termination: nn.Module | None = None,
        termination_cost: float = TERMINATION_COST,
        success_window: int | None = None,
    ) -> None:
        super().__init__()
        if int(horizon) != horizon or horizon < 1:
            raise ValueError(f"horizon must be a positive integer, got {horizon!r}")
        if int(num_particles) != num_particles or num_particles < 1:
            raise ValueError(
                f"num_particles must be a positive integer, got {num_particles!r}; use e.g. 400"
            )
        if success_window is not None and (
            int(success_window) != success_window or not 1 <= success_window <= horizon
        ):
            raise ValueError(
                f"success_window must be an integer in 1..horizon ({horizon}) or None, got "
                f"{success_window!r}"
            )
        if obs_noise_std < 0:
            raise ValueError(f"obs_noise_std must be >= 0, got {obs_noise_std}")
        self.policy = policy
        self._world_model_keys: tuple[list, list] | None = None  # set by set_dynamics
        self.set_dynamics(dynamics)
        dynamics = self.dynamics
        self.cost = cost
        self.horizon = int(horizon)
        self.num_particles = int(num_particles)
        self.obs_noise_std = float(obs_noise_std)
        self.termination = termination
        self.termination_cost = float(termination_cost)
        self.success_window = None if success_window is None else int(success_window)
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
            if len(policy.in_keys) != 1 or len(policy.out_keys) != 1:
                raise ValueError(
                    "the policy TensorDictModule must read one key (the state) and write one "
                    f"(the action), got in_keys={policy.in_keys}, out_keys={policy.out_keys}"
                )
            # the hot loop calls the wrapped module directly (no TensorDict per time step)
            self._policy_fn = policy.module
        else:
            self._policy_fn = policy
        self.num_candidates = int(getattr(self._policy_fn, "num_candidates", 1))
        self._engine: RolloutEngine | None = None  # a chained rollout (fast package)
        self._step_fn: Callable | None = None  # a replacement of step (e.g. compiled)

    def step(
        self, x: Tensor, eps: Tensor, nu: Tensor | None, mask: Tensor | None = None
    ) -> tuple[Tensor, Tensor, Tensor]:
        """One time step for all particles: ``u = pi(x + nu)``, ``x+ = f(x, u, eps)``, ``c(x+)``
        (``mask``: the policy's dropout mask for this step, drawn by the caller)."""
        obs = x if nu is None else x + nu
        u = self._policy_fn(obs) if mask is None else self._policy_fn(obs, mask=mask)
        x_next = self.dynamics(x, u, eps)
        return x_next, u, self.cost(x_next)

    def set_fast_rollout(
        self, engine: RolloutEngine | None = None, step_fn: Callable | None = None
    ) -> None:
        """Roll out with ``engine`` (a chained rollout of this loss's parts, used by
        :meth:`forward` for rollouts of ``num_particles`` per candidate) and/or ``step_fn``
        (a function with :meth:`step`'s signature and results, e.g. ``torch.compile`` of it,
        used by :meth:`rollout`); None for both: the eager rollout. The loss does not build
        or choose them: :func:`~mcpilco.agents.mc_pilco.fast.use_fast_rollout` does,
        and checks them against the eager rollout first. An engine computes the costs of
        the whole rollout itself, without the absorbing set: with a ``termination`` only a
        ``step_fn`` is taken (``ValueError`` otherwise)."""
        if engine is not None and self.termination is not None:
            raise ValueError(
                "a chained rollout engine does not mask the absorbing set of a terminating "
                "task; use a step_fn or the eager rollout"
            )
        self._engine, self._step_fn = engine, step_fn

    @property
    def policy_module(self) -> nn.Module:
        """The policy the rollout calls (a ``TensorDictModule``'s wrapped module)."""
        return self._policy_fn

    @property
    def fast_rollout(self) -> tuple[RolloutEngine | None, Callable | None]:
        """``(engine, step_fn)`` as set by :meth:`set_fast_rollout`."""
        return self._engine, self._step_fn

    @property
    def rollout_shards(self) -> int:
        """The number of threads the rollout is split over (1 unless a chained rollout splits
        it; :meth:`set_fast_rollout`)."""
        return 1 if self._engine is None else self._engine.shards

    @property
    def functional(self) -> bool:  # the policy is used statefully (no functional params)
        return False

    def set_dynamics(self, dynamics: nn.Module) -> None:
        """Use new particle dynamics (after a GP re-fit): a module ``(state, action, eps) ->
        next_state`` or a :class:`~mcpilco.agents.mc_pilco.torchrl_parts.ParticleWorldModel`
        (its dynamics are stepped; its keys are checked at :meth:`forward`)."""
        if isinstance(dynamics, ParticleWorldModel):
            self._world_model_keys = (list(dynamics.in_keys), list(dynamics.out_keys))
            dynamics = dynamics.dynamics
        else:
            self._world_model_keys = None
        self.dynamics = dynamics

    def check_part_keys(self) -> None:
        """Raise ValueError when the policy's or the world model's tensordict keys are not the
        loss's (:meth:`set_keys`): the message names the ``set_keys`` call that fits them."""
        keys = self.tensor_keys
        if isinstance(self.policy, TensorDictModule):
            got = (self.policy.in_keys[0], self.policy.out_keys[0])
            if got != (keys.observation, keys.action):
                raise ValueError(
                    f"the policy reads {got[0]!r} and writes {got[1]!r} but the loss's keys are "
                    f"observation={keys.observation!r}, action={keys.action!r}; call "
                    f"loss.set_keys(observation={got[0]!r}, action={got[1]!r})"
                )
        if self._world_model_keys is not None:
            (obs, act, _), (nxt, _) = self._world_model_keys
            if (obs, act, nxt) != (keys.observation, keys.action, keys.next_observation):
                raise ValueError(
                    f"the world model reads {obs!r}, {act!r} and writes {nxt!r} but the loss's "
                    f"keys are observation={keys.observation!r}, action={keys.action!r}, "
                    f"next_observation={keys.next_observation!r}; call loss.set_keys("
                    f"observation={obs!r}, action={act!r}, next_observation={nxt!r})"
                )

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        """No value estimator: :meth:`set_keys` only renames the keys (LossModule hook)."""

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
        """Propagate ``M`` particles for ``H`` steps; differentiable w.r.t. the policy. With
        a ``termination`` set, particles that leave it are absorbed (module glossary).

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
        step = self._step_fn if self._step_fn is not None else self.step
        # the policy's dropout masks are drawn here, step by step, outside the (possibly
        # compiled) step: the same random stream as a policy drawing its own
        draw_mask = getattr(self._policy_fn, "draw_dropout_mask", None)
        term = self.termination
        alive = None if term is None else ~term(x)  # a_0: x_0 within the set
        for t in range(self.horizon):
            mask = None if draw_mask is None else draw_mask(x)
            x_next, u, c = step(x, noise[t], None if obs_noise is None else obs_noise[t], mask)
            if alive is not None:  # the absorbing set: a_{t+1} = a_t 1[x_{t+1} in X_ok]
                alive_next = alive & ~term(x_next)
                x_next = torch.where(alive[:, None], x_next, x)
                c = torch.where(alive_next, c, torch.full_like(c, self.termination_cost))
                alive = alive_next
            x = x_next
            costs.append(c)
            if keep_states or t == self.horizon - 1:
                states.append(x)
            actions.append(u)
        return ParticleRollout(
            states=torch.stack(states, dim=1),
            actions=torch.stack(actions, dim=1),
            costs=torch.stack(costs, dim=1),
        )

    def rollout_tensordict(
        self,
        initial_state: Tensor | None = None,
        noise: Tensor | None = None,
        num_particles: int | None = None,
    ) -> TensorDict:
        """:meth:`rollout` as a TensorDict of batch ``(K M, H)`` under the loss's keys (as a
        TorchRL collector writes a trajectory): ``observation`` ``x_t``, ``action`` ``u_t``,
        ``("next", ...)`` of ``next_observation`` ``x_{t+1}`` and ``("next", "cost")``
        ``c(x_{t+1})``; differentiable w.r.t. the policy."""
        ro = self.rollout(initial_state, noise, num_particles)
        keys = self.tensor_keys
        td = TensorDict(
            {keys.observation: ro.states[:, :-1], keys.action: ro.actions},
            batch_size=ro.costs.shape,
        )
        td.set(keys.next_observation, ro.states[:, 1:])
        td.set(("next", "cost"), ro.costs[..., None])
        return td

    def particle_costs(self, costs: Tensor) -> Tensor:
        """Per particle, the term of ``J^`` from its step costs ``(..., T)``: ``sum_t c_t``,
        and with a success window ``W`` (at most ``T``) also ``sum_{t > T-W} c_t`` (module
        glossary, ``J^_W``)."""
        total = costs.sum(dim=-1)
        if self.success_window is None:
            return total
        return total + costs[..., -min(self.success_window, costs.shape[-1]) :].sum(dim=-1)

    def forward(self, tensordict: TensorDictBase | None = None) -> TensorDict:
        keys = self.tensor_keys
        self.check_part_keys()
        td = TensorDict({}, batch_size=[]) if tensordict is None else tensordict
        init, noise = td.get(keys.initial_state, None), td.get(keys.noise, None)
        engine = self._engine
        if engine is not None and init is not None and init.shape[:1] != (engine.rows,):
            engine = None  # built for the module's particle count only: run eagerly
        if engine is not None:
            with engine.serial_caller():
                x, noise, obs_noise = self._draw_inputs(init, noise, None)
                costs = engine.costs(x, noise, obs_noise).T  # (K M, H)
        else:
            costs = self.rollout(initial_state=init, noise=noise, keep_states=False).costs
        per_particle = self.particle_costs(costs).view(self.num_candidates, -1)  # (K, M)
        per_candidate = per_particle.mean(dim=1)  # J^_k
        with torch.no_grad():
            std = (
                per_particle.std(dim=1).mean()
                if per_particle.shape[1] > 1
                else per_particle.new_zeros(())
            )
        out = TensorDict({}, batch_size=[])
        out.set(keys.loss_cost, per_candidate.sum())
        out.set(keys.cost_std, std)
        out.set(keys.candidate_costs, per_candidate.detach())
        return out

"""The chained rollout in plain PyTorch ops (``backend="torch"``): the parts' step protocols
(:mod:`~mcpilco.agents.mc_pilco.fast.base`) called by hand through time, forward then
backward, with no autograd graph. It runs wherever torch runs, and it is the pure-PyTorch
twin of the native engine (:mod:`~mcpilco.agents.mc_pilco.fast.native`) that its tests use.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from mcpilco.agents.mc_pilco.cost import (
    SaturatingCostSaved,
    saturating_cost_backward,
    saturating_cost_forward,
)
from mcpilco.agents.mc_pilco.dynamics import (
    SampleClipIntegrateSaved,
    sample_clip_integrate_backward,
    sample_clip_integrate_forward,
)
from mcpilco.agents.mc_pilco.fast.base import ShardedRollout, unsupported_reason
from mcpilco.agents.mc_pilco.features import (
    GPInputsSaved,
    gp_inputs_backward,
    gp_inputs_forward,
)
from mcpilco.agents.mc_pilco.policy import (
    PolicyStepSaved,
    mask_from_bytes,
    squashed_rbf_backward,
    squashed_rbf_forward,
)
from mcpilco.models.gp.fused import (
    FusedPosteriorSaved,
    fused_posterior_backward,
    fused_posterior_forward,
)


class StepSaved(NamedTuple):
    """``S_t``: what each part of one time step saved for its backward."""

    policy: PolicyStepSaved
    inputs: GPInputsSaved
    gp: FusedPosteriorSaved
    step: SampleClipIntegrateSaved
    cost: SaturatingCostSaved


class TorchRollout(ShardedRollout):
    """The chained rollout in plain PyTorch ops: ``step_forward`` and ``step_backward``
    (:mod:`~mcpilco.agents.mc_pilco.fast.base`) built from the parts' step protocols, called
    ``H`` times each per shard. No autograd graph is built; each step's saved tensors are kept
    until the backward loop.

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
            x, cost, saved = self.step_forward(x, noise[t], nu[t], bits[t], keep, *theta)
            costs.append(cost)
            steps.append(saved)
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
    ) -> tuple[Tensor, Tensor, StepSaved]:
        """``step_forward`` (:mod:`~mcpilco.agents.mc_pilco.fast.base`): ``x_{t+1}``,
        ``c(x_{t+1})`` and the parts' saved tensors ``S_t``."""
        dyn, policy = self.dynamics, self.policy
        mask = mask_from_bytes(bits, keep[0], x.dtype, keep[1])
        layout = dyn.layout
        obs = (x + nu).reshape(self.candidates, -1, layout.n)
        u, s_policy = squashed_rbf_forward(
            obs, self._batched(c), self._batched(log_l), self._batched(w),
            (policy.u_mid, policy.u_half), mask, policy.layout,
        )  # fmt: skip
        u = u.reshape(x.shape[0], -1)
        gp_in, s_inputs = gp_inputs_forward(x, u, layout)
        (mean, var), s_gp = fused_posterior_forward(gp_in, dyn.delta_model)
        if dyn.sample_noise:
            var = var + dyn.noise_variance.to(var.dtype)
        x_next, s_step = sample_clip_integrate_forward(
            x, mean, var, eps, dyn.delta_bound, dyn.dt, layout
        )
        cost, s_cost = saturating_cost_forward(x_next, self.cost)
        return x_next, cost, StepSaved(s_policy, s_inputs, s_gp, s_step, s_cost)

    def step_backward(
        self, saved: StepSaved, g_x_next: Tensor, g_c_next: Tensor, grads: tuple
    ) -> tuple[Tensor, tuple]:
        """``step_backward`` (:mod:`~mcpilco.agents.mc_pilco.fast.base`): ``g_{x_t}`` and
        ``G + dJ/dtheta|_t``."""
        dyn = self.dynamics
        g_x = saturating_cost_backward(saved.cost, g_c_next, self.cost) + g_x_next
        g_state, g_mean, g_var = sample_clip_integrate_backward(saved.step, g_x)
        g_in = fused_posterior_backward(saved.gp, g_mean, g_var, dyn.delta_model)
        g_state_in, g_u = gp_inputs_backward(saved.inputs, g_in, dyn.layout)
        g_obs, *g_theta = squashed_rbf_backward(
            saved.policy, g_u.reshape(self.candidates, -1, g_u.shape[-1]), self.policy.layout
        )
        if not self.batched:
            g_theta = [g.squeeze(0) for g in g_theta]
        g_prev = g_state + g_state_in + g_obs.reshape(g_state.shape[0], -1)
        return g_prev, tuple(G + g for G, g in zip(grads, g_theta, strict=True))


__all__ = ["StepSaved", "TorchRollout"]

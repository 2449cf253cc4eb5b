"""Saturating swing-up cost in torch (thesis section 5.5.1; Amadio et al. 2022, sec. VI).

Glossary
--------
``x = [q1, q1_dot, q2, q2_dot]``
    cartpole state: cart position [m], cart velocity, pole angle (0 down, +-pi up, not
    wrapped), pole angular velocity.
``wrap(q2) = atan2(sin q2, cos q2)``
    the angle mapped to ``(-pi, pi]``; differentiable with derivative 1 almost everywhere.
``c(x) = 1 - exp(-(|wrap(q2)| - pi)^2 / l_theta^2 - q1^2 / l_x^2)``
    the cost of thesis section 5.5.1 (``l1 = l_x = 1.5``, ``l2 = l_theta = 1``), the same
    definition as :func:`mcpilco.envs.cartpole_task.cartpole_cost` (numpy), which the env
    reports; the tests check that the two agree.
``c_u(x) = 1 - exp(-(|q2| - pi)^2 / l_theta^2 - q1^2 / l_x^2)``
    the unwrapped variant optimised by MC-PILCO (Amadio et al. 2022, sec. V-A, with
    ``l_theta = 3``, ``l_x = 1``): ``|q2|`` grows with every full rotation, so spinning the
    pole through the top is not rewarded. With a wide ``l_theta`` and the wrapped angle, a
    spinning policy gets a low average cost (we saw the optimiser find one); ``wrap=False``
    (the agent's default in :class:`~mcpilco.agents.mc_pilco.loop.MCPilcoConfig`) avoids it.
``J = sum_t E[c(x_t)]``
    expected cumulative cost, eq. (5.1); its Monte Carlo estimate is eq. (5.8)
    (see :mod:`mcpilco.agents.mc_pilco.loss`).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from mcpilco.envs.cartpole_task import CARTPOLE_TASK


class SwingUpCost(nn.Module):
    """Saturating swing-up cost ``c(x)`` on ``[q1, q2]`` of a cartpole state.

    Args:
        l_x: length scale of the cart-position term [m], > 0.
        l_theta: length scale of the angle term [rad], > 0.
        wrap: use ``|wrap(q2)|`` (the env's evaluation cost) instead of ``|q2|``.

    Shapes:
        ``forward(state)``: ``state (..., 4)`` -> cost ``(...)`` in ``[0, 1)``.
    """

    def __init__(
        self,
        l_x: float = float(CARTPOLE_TASK["l_x"]),
        l_theta: float = float(CARTPOLE_TASK["l_theta"]),
        wrap: bool = True,
    ) -> None:
        super().__init__()
        if not (l_x > 0 and l_theta > 0):
            raise ValueError(f"cost length scales must be > 0, got l_x={l_x}, l_theta={l_theta}")
        self.l_x = float(l_x)
        self.l_theta = float(l_theta)
        self.wrap = bool(wrap)

    def forward(self, state: Tensor) -> Tensor:
        if state.shape[-1] != 4:
            raise ValueError(
                f"state must have shape (..., 4) = [x, x_dot, theta, theta_dot], got "
                f"{tuple(state.shape)}"
            )
        return _SwingUpCostFn.apply(state, self.l_x, self.l_theta, self.wrap)

    def extra_repr(self) -> str:
        return f"l_x={self.l_x}, l_theta={self.l_theta}, wrap={self.wrap}"


class _SwingUpCostFn(torch.autograd.Function):
    """``c = 1 - E``, ``E = exp(-(d/l_theta)^2 - (q1/l_x)^2)``, ``d = |q2'| - pi`` with ``q2'`` the
    (optionally wrapped) angle; one autograd node. Backward: ``dc/dq1 = 2 E q1 / l_x^2``,
    ``dc/dq2 = 2 E d sign(q2') / l_theta^2`` (``d wrap(q2) / d q2 = 1``; ``sign(0) = 0``, the
    subgradient of ``abs`` in torch)."""

    @staticmethod
    def forward(ctx, state, l_x, l_theta, wrap):  # noqa: D102
        x = state[..., 0]
        theta = state[..., 2]
        if wrap:
            theta = torch.atan2(torch.sin(theta), torch.cos(theta))
        d_theta = theta.abs() - math.pi
        E = torch.exp(-((d_theta / l_theta) ** 2) - (x / l_x) ** 2)
        ctx.save_for_backward(x, d_theta, torch.sign(theta), E)
        ctx.scales = (l_x, l_theta)
        return 1.0 - E

    @staticmethod
    def backward(ctx, g):  # noqa: D102
        x, d_theta, sgn, E = ctx.saved_tensors
        l_x, l_theta = ctx.scales
        gE2 = 2.0 * g * E
        zero = torch.zeros_like(x)
        g_x = gE2 * x / (l_x * l_x)
        g_theta = gE2 * d_theta * sgn / (l_theta * l_theta)
        return torch.stack([g_x, zero, g_theta, zero], dim=-1), None, None, None

"""The initial gains of a regulation task's linear feedback term: the discrete-time LQR of
the learned model, linearised at the regulation point.

Glossary
--------
``x*, u*``
    the regulation point (the initial mean with the cost terms at their targets,
    :func:`~mcpilco.agents.mc_pilco.trainer.regulation_point`) and the middle of the action
    range ``u_mid``.
``A = df/dx, B = df/du``
    the Jacobians of the GP model's mean one-step prediction ``x_{t+1} = f(x_t, u_t)`` at
    ``(x*, u*)`` (autograd through the particle dynamics with ``eps = None``).
``Q = d^2 c / dx^2``
    the Hessian of the optimised cost at ``x*`` (for the saturating cost
    ``c = 1 - exp(-sum_j (d_j / l_j)^2)`` it is ``diag(2 / l_j^2)`` on the cost's states, 0
    elsewhere): the quadratic cost the saturating one is near its minimum.
``R = 2 / u_half^2``
    the action weighted as one more saturating term of width ``u_half``: a deviation of
    the whole half range costs as much as a state one length scale from its target. The
    saturating cost has no action term; without one the LQR's gains grow without bound.
``K = (R + B^T P B)^-1 B^T P A``
    the LQR gain of ``u = u* - K (x - x*)``, ``P`` the solution of the discrete algebraic
    Riccati equation.
``G = -(s / u_half) dx/dx~^T K^T``
    the same feedback in the policy's units (:mod:`~mcpilco.agents.mc_pilco.policy`,
    linear feedback: ``u_half G^T (x~ - x~*) / s``): a plain state's feature is the state;
    an angle ``psi`` with target ``psi*`` has features ``(sin psi, cos psi)``, and
    ``K_psi (cos psi*, -sin psi*)`` on them gives ``K_psi (psi - psi*)`` to first order.

``v_j = GATE_REACH min_a u_half_a / |K_aj|``
    the gate widths of a catch (:mod:`~mcpilco.agents.mc_pilco.policy`, gated linear
    feedback, for a swing-up that must end held at ``x*``): ``u_half / |K_j|`` is the
    deviation of state ``j`` at which the LQR alone reaches the action bound. The gated
    feedback ``g K d`` of one state, ``y = K d / u_half``, is ``y exp(-y^2 / (2 c^2))`` with
    ``c = GATE_REACH``: it peaks at ``y = c`` with ``c exp(-1/2)``, which reaches the bound
    (``>= 1``) for ``c >= exp(1/2) ~ 1.65``; ``c = 2`` keeps the LQR near full strength
    where it does not saturate (``g >= exp(-1/8) = 0.88`` at ``y <= 1``) and lets it act
    out to about three times that deviation, and no farther: far from ``x*`` the RBF
    network alone pumps. An angle's two features get its width (the gate is periodic).

Why: from ``G = 0`` the policy gradient of a task whose particles all fall within a few
steps (the double pendulum under ``u = 0``) points nowhere useful, and Adam's steps of
``a = 0.01`` take hundreds of steps to reach gains of order 1 even where it does. The LQR of
the learned model is where a linear feedback on the model starts to hold the state; the
optimisation of ``J^`` refines it (the saturation, the model's uncertainty, the absorbing
set). A model whose linearisation has no stabilising LQR (the Riccati equation has no
solution) leaves ``G = 0``.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import torch
from torch import Tensor

from mcpilco.agents.mc_pilco.features import StateLayout

GATE_REACH = 2.0  # gate width of a catch in units of the deviation where the LQR saturates
Q_FLOOR = 1e-6  # added to Q's diagonal (relative to its largest entry): detectability of (A, Q)


def model_jacobians(
    dynamics: Callable[[Tensor, Tensor], Tensor], x_star: np.ndarray, u_star: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``A = df/dx`` (n, n) and ``B = df/du`` (n, A) of the mean prediction
    ``f(x, u) = dynamics(x, u)`` at ``(x*, u*)``, in float64."""
    x = torch.as_tensor(x_star, dtype=torch.float32)[None]
    u = torch.as_tensor(u_star, dtype=torch.float32)[None]
    jac_x, jac_u = torch.autograd.functional.jacobian(lambda a, b: dynamics(a, b)[0], (x, u))
    return jac_x[:, 0].double().numpy(), jac_u[:, 0].double().numpy()


HESSIAN_STEP = 1e-4  # central-difference step of cost_hessian, relative to max(1, |x*_j|)


def cost_hessian(cost: Callable[[Tensor], Tensor], x_star: np.ndarray) -> np.ndarray:
    """``Q = d^2 c / dx^2`` (n, n) of the cost at ``x*``, symmetrised: central differences of
    its gradient (first-order autograd, in float64; the package's cost has a hand-written
    backward that is not differentiated again)."""
    x0 = torch.as_tensor(x_star, dtype=torch.float64)

    def grad(v: Tensor) -> np.ndarray:
        v = v.clone().requires_grad_(True)
        (g,) = torch.autograd.grad(cost(v[None]).sum(), v)
        return g.numpy()

    n = len(x0)
    h = np.zeros((n, n))
    for j in range(n):
        step = HESSIAN_STEP * max(1.0, abs(float(x0[j])))
        e = torch.zeros(n, dtype=torch.float64)
        e[j] = step
        h[:, j] = (grad(x0 + e) - grad(x0 - e)) / (2.0 * step)
    return (h + h.T) / 2.0


def lqr_gain(a: np.ndarray, b: np.ndarray, q: np.ndarray, r: np.ndarray) -> np.ndarray | None:
    """``K = (R + B^T P B)^-1 B^T P A`` of the discrete algebraic Riccati equation, or None
    when it has no stabilising solution (the closed loop ``A - B K`` has a pole on or outside
    the unit circle, or the solver fails)."""
    from scipy.linalg import solve_discrete_are

    q = q + Q_FLOOR * max(float(np.max(np.abs(q))), 1.0) * np.eye(len(q))
    try:
        p = solve_discrete_are(a, b, q, r)
    except (ValueError, np.linalg.LinAlgError):
        return None
    k = np.linalg.solve(r + b.T @ p @ b, b.T @ p @ a)
    if not np.all(np.isfinite(k)) or np.max(np.abs(np.linalg.eigvals(a - b @ k))) >= 1.0:
        return None
    return k


def feature_gains(
    k: np.ndarray,
    layout: StateLayout,
    x_star: np.ndarray,
    scale: np.ndarray,
    u_half: np.ndarray,
) -> np.ndarray:
    """``G`` (F, A) of the policy's linear term equal to ``u = u* - K (x - x*)`` to first
    order (module glossary), for the feature order of ``layout`` (plain coordinates, then
    ``(sin, cos)`` of each angle)."""
    k = np.asarray(k, dtype=np.float64)
    rows = [k[:, i] for i in layout.plain_idx]
    for i in layout.angle_idx:
        psi = float(x_star[i])
        rows += [k[:, i] * math.cos(psi), -k[:, i] * math.sin(psi)]
    d = np.stack(rows)  # (F, A): dU/dx~ of -u
    return -d * np.asarray(scale, dtype=np.float64)[:, None] / np.asarray(u_half)[None, :]


def catch_gate(k: np.ndarray, layout: StateLayout, u_half: np.ndarray) -> np.ndarray:
    """The gate widths ``v`` (F,) of a catch around ``x*`` from the LQR gain ``K`` (A, n):
    ``v_j = GATE_REACH min_a u_half_a / |K_aj|`` (module glossary; infinite where no action
    feeds state ``j`` back), in the feature order of ``layout`` (an angle's ``sin, cos`` both
    get its width)."""
    k = np.abs(np.asarray(k, dtype=np.float64))
    half = np.asarray(u_half, dtype=np.float64).reshape(-1, 1)
    with np.errstate(divide="ignore"):
        v = GATE_REACH * np.min(half / k, axis=0)  # (n,)
    widths = [v[i] for i in layout.plain_idx]
    for i in layout.angle_idx:
        widths += [v[i], v[i]]
    return np.asarray(widths)


def regulator_lqr(
    dynamics: Callable[[Tensor, Tensor], Tensor],
    cost: Callable[[Tensor], Tensor],
    x_star: np.ndarray,
    u_mid: np.ndarray,
    u_half: np.ndarray,
) -> np.ndarray | None:
    """``K`` (A, n): the LQR of the model linearised at ``(x*, u_mid)`` with ``Q`` the cost's
    Hessian and ``R = 2 / u_half^2`` (module glossary); None when the linearised model has no
    stabilising LQR. :func:`feature_gains` turns it into the policy's initial ``G``,
    :func:`catch_gate` into a catch's gate."""
    a, b = model_jacobians(dynamics, x_star, u_mid)
    q = cost_hessian(cost, x_star)
    r = np.diag(2.0 / np.asarray(u_half, dtype=np.float64) ** 2)
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b)) and np.all(np.isfinite(q))):
        return None
    return lqr_gain(a, b, q, r)

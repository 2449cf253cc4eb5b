"""Likelihood-ratio intervals of continuous shape values from their profile log-evidence.

A shape value ``x`` of an effect (smoothing ``eps``, Stribeck velocity ``v_s``, dead-zone
width ``c``, cogging order ``n``, delay ``k`` in samples) enters its block non-linearly. Its
profile log-evidence is

.. math::

    \\Delta(x) = \\max_{\\sigma^2, \\lambda} \\log p(r \\mid \\text{current} + e(x))
    - \\log p(r \\mid \\text{current})

(:mod:`.search`: the noise and the block's prior variance re-optimised at every ``x``; a
delay re-optimises every hyperparameter). By Wilks' theorem ``2 (Delta(x_hat) - Delta(x))``
is ``chi^2_1`` distributed at the true ``x``, so the 95% likelihood-ratio interval is

.. math::

    \\{x : \\Delta(x) \\ge \\Delta(\\hat x) - \\tfrac12 \\chi^2_{1, 0.95}\\},
    \\qquad \\tfrac12 \\chi^2_{1, 0.95} = 1.92 \\text{ nats}.

:func:`likelihood_interval` finds its ends on ``u = log x``: steps out from ``u_hat``
(doubling from :data:`FIRST_STEP`) to the first point below the threshold, then Brent's
root-finder between it and the last point above. An end that reaches the search limit
without crossing is returned as *limited*: the data do not pin that side down. The interval
is the connected one around ``x_hat`` (a far side lobe above the threshold is not joined).

Cogging phase (:func:`phase_interval`). At order ``n`` the block's weights ``w = (a, b)`` of
``a sin(n q) + b cos(n q)`` have the Gaussian posterior ``N(w_hat(n), C(n))`` (exact at fixed
hyperparameters); the torque ``A sin(n q + phi)`` is ``w = A u(phi)``,
``u = (cos phi, sin phi)``, ``A >= 0``. The phase's profile over both the amplitude and the
order is

.. math::

    l(\\phi) = \\max_n \\Big[\\Delta(n) - \\tfrac12 \\min_{A \\ge 0}
    (A u - \\hat w)^\\top C^{-1} (A u - \\hat w)\\Big],

with ``min_A = w_hat^T P w_hat - max(0, u^T P w_hat)^2 / (u^T P u)``, ``P = C^{-1}``; its
interval is the connected arc around ``phi_hat`` where ``l >= l(phi_hat) - 1.92``, the orders
taken over the order's own interval (outside it ``Delta(n)`` alone is below the threshold).
Since ``phi`` is the phase at ``q = 0``, an uncertain order widens it by about
``|q_mean| dn``.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import brentq

FloatArray = NDArray[np.float64]

__all__ = ["CHI2_HALF_95", "likelihood_interval", "phase_interval"]

CHI2_HALF_95 = 1.920729410347062  # half the 95% quantile of chi^2 with 1 dof [nats]
FIRST_STEP = 0.005  # first step out from the optimum on log x (0.5%)
INTERVAL_XTOL = 1e-3  # tolerance of an interval end on log x (0.1%)
PHASE_POINTS = 1441  # phase grid over one turn (0.25 degree)


def likelihood_interval(
    f: Callable[[float], float],
    u_hat: float,
    f_hat: float,
    u_lo: float,
    u_hi: float,
    drop: float = CHI2_HALF_95,
) -> tuple[float, float, bool]:
    """Ends of ``{u : f(u) >= f_hat - drop}`` around ``u_hat`` within ``[u_lo, u_hi]``.

    Args:
        f: the profile (non-finite values count as below the threshold).
        u_hat: the maximiser (``f(u_hat) = f_hat``).

    Returns:
        ``(lo, hi, limited)``; ``limited`` when an end is a search limit, not a crossing.
    """
    level = f_hat - drop

    def g(u: float) -> float:
        v = f(u)
        return v - level if math.isfinite(v) else -1e6

    ends, limited = [], False
    for direction, limit in ((-1.0, u_lo), (1.0, u_hi)):
        if direction * (limit - u_hat) <= 0:
            ends.append(u_hat)
            limited = True
            continue
        inside, step = u_hat, FIRST_STEP
        while True:
            u = u_hat + direction * step
            if direction * (u - limit) >= 0:
                u = limit
            if g(u) < 0:
                a, b = sorted((inside, u))
                ends.append(brentq(g, a, b, xtol=INTERVAL_XTOL))
                break
            if u == limit:
                ends.append(limit)
                limited = True
                break
            inside, step = u, 2.0 * step
    return ends[0], ends[1], limited


def phase_interval(
    deltas: FloatArray, means: FloatArray, covs: FloatArray, drop: float = CHI2_HALF_95
) -> tuple[float, float, float, bool]:
    """Profile interval of the cogging phase (module docstring).

    Args:
        deltas: ``(G,)`` profile log-evidence ``Delta(n_g)`` on a grid of orders.
        means: ``(G, 2)`` posterior means ``(a, b)``.
        covs: ``(G, 2, 2)`` posterior covariances.

    Returns:
        ``(phi_hat, lo, hi, limited)`` [rad]: ``phi_hat`` in ``(-pi, pi]`` at the best order,
        ``lo <= phi_hat <= hi`` (not wrapped), ``limited`` when the arc is the whole turn.
    """
    deltas = np.asarray(deltas, dtype=np.float64)
    ok = np.isfinite(deltas)
    deltas, means, covs = deltas[ok], np.asarray(means)[ok], np.asarray(covs)[ok]
    g = int(np.argmax(deltas))
    phi_hat = math.atan2(means[g, 1], means[g, 0])
    offsets = np.linspace(-math.pi, math.pi, PHASE_POINTS)
    phi = phi_hat + offsets
    u = np.stack([np.cos(phi), np.sin(phi)], axis=1)  # (M, 2)
    prec = np.linalg.inv(covs)  # (G, 2, 2)
    pw = np.einsum("gij,gj->gi", prec, means)  # P w_hat
    wpw = np.einsum("gi,gi->g", means, pw)
    upw = u @ pw.T  # (M, G)
    upu = np.einsum("mi,gij,mj->mg", u, prec, u)
    quad = wpw[None, :] - np.maximum(upw, 0.0) ** 2 / upu
    prof = np.max(deltas[None, :] - 0.5 * quad, axis=1)  # (M,)
    level = prof[PHASE_POINTS // 2] - drop
    inside = prof >= level
    mid = PHASE_POINTS // 2
    if inside.all():
        return phi_hat, phi_hat - math.pi, phi_hat + math.pi, True
    lo = mid
    while lo > 0 and inside[lo - 1]:
        lo -= 1
    hi = mid
    while hi < PHASE_POINTS - 1 and inside[hi + 1]:
        hi += 1
    gap = prof - level

    def crossing(a: int, b: int) -> float:  # a inside, b outside (or a at the grid's end)
        if b < 0 or b >= PHASE_POINTS:
            return float(phi[a])
        return float(phi[a] + (phi[b] - phi[a]) * gap[a] / (gap[a] - gap[b]))

    return phi_hat, crossing(lo, lo - 1), crossing(hi, hi + 1), False

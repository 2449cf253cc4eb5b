"""Effects with one weight vector for several joints: the evidence of a stacked block.

A rigid-body effect (a link's inertial parameters, a payload; :attr:`.Effect.shared`) adds
``Y_j w`` to the torque of every joint ``j`` it moves, with the *same* weights ``w``. The
joints' GPs are independent given ``w`` (residual ``r_j ~ N(0, K_j)``, :class:`JointGP`), so
with the prior ``w ~ N(0, V)`` the stacked residual has

.. math::

    \\log p(r) = \\sum_j \\log p(r_j \\mid K_j)
      + \\tfrac12 b^\\top (A + V^{-1})^{-1} b - \\tfrac12 \\log |1 + V^{1/2} A V^{1/2}|,

    A = \\sum_j Y_j^\\top K_j^{-1} Y_j,\\qquad b = \\sum_j Y_j^\\top K_j^{-1} r_j

(the matrix determinant lemma and Woodbury's identity), and the posterior
``w | r ~ N((A + V^{-1})^{-1} b, (A + V^{-1})^{-1})``. ``V`` is diagonal: per effect one
scale ``lambda_e`` times ``t^2 / rms_k^2`` for its columns ``k`` (``t``: rms of the stacked
residual, ``rms_k``: of column ``k`` over all rows and joints), so ``lambda_e`` is unitless.

:func:`score_shared` gives a candidate's gain ``Delta`` with ``lambda`` and every moved
joint's noise ``sigma_j^2`` re-optimised (as a one-joint candidate re-optimises its joint's
noise, so the two kinds compete on equal terms). :func:`fit_shared` gives the posterior of
the shared weights of a model's rigid-body effects for fixed ``K_j``; the model alternates it
with the joints' own fits (:meth:`.DiagnosisModel.fit`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize

from mcpilco.models.gp.linear_gp import LOG_LAMBDA_BOUNDS, JointGP

FloatArray = NDArray[np.float64]

__all__ = ["SharedFit", "fit_shared", "score_shared", "shared_gain"]

SCORE_FTOL = 1e-10
"""Relative tolerance of the joint optimisation in :func:`score_shared` (``1e-10`` of a gain
of thousands of nats is well below 0.01 nats)."""
NOISE_SHIFT_BOUNDS = (-10.0, 2.0)
"""Bounds of the change of a joint's ``log sigma^2`` while a shared candidate is scored."""


@dataclass
class SharedFit:
    """Posterior ``N(mean, cov)`` of stacked shared weights, their prior scales
    ``log_lambda`` (one per effect) and the evidence gain over the joints' own models."""

    mean: FloatArray
    cov: FloatArray
    log_lambda: FloatArray
    gain: float


def _terms(gp: JointGP, theta: FloatArray, cols: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``(Y^T K^-1 Y, Y^T K^-1 r)`` of one joint in original units."""
    s2 = gp.scale**2
    kinv = gp.solve(theta, np.concatenate([cols, gp.r[:, None] * gp.scale], axis=1)) / s2
    return cols.T @ kinv[:, :-1], cols.T @ kinv[:, -1]


def shared_gain(
    A: FloatArray, b: FloatArray, prior_var: FloatArray
) -> tuple[float, FloatArray, FloatArray]:
    """``(gain, mean, cov)`` of the stacked block for ``A, b`` and prior variances
    ``prior_var (P,)`` (module docstring); ``gain = -inf`` when the system is singular."""
    sv = np.sqrt(prior_var)
    M = np.eye(sv.size) + sv[:, None] * A * sv[None, :]
    try:
        L = np.linalg.cholesky(0.5 * (M + M.T))
    except np.linalg.LinAlgError:
        return -math.inf, np.zeros_like(b), np.zeros_like(A)
    c = np.linalg.solve(L, sv * b)
    gain = 0.5 * float(c @ c) - float(np.sum(np.log(np.diag(L))))
    Linv = np.linalg.inv(L)
    minv = Linv.T @ Linv
    cov = sv[:, None] * minv * sv[None, :]
    return gain, sv * (minv @ (sv * b)), cov


def _prior(log_lambda: FloatArray, sizes: Sequence[int], col_var: FloatArray) -> FloatArray:
    return np.repeat(np.exp(log_lambda), sizes) * col_var


def _col_var(cols: Sequence[FloatArray], targets: Sequence[FloatArray]) -> FloatArray:
    """``t^2 / rms_k^2`` per stacked column (module docstring)."""
    stacked = np.concatenate(cols, axis=0)
    rms2 = np.mean(stacked**2, axis=0)
    t2 = float(np.mean(np.concatenate(targets) ** 2)) or 1.0
    return t2 / np.where(rms2 > 0, rms2, 1.0)


def fit_shared(
    gps: Sequence[JointGP],
    thetas: Sequence[FloatArray],
    cols: Sequence[FloatArray],
    sizes: Sequence[int],
    log_lambda0: FloatArray | None = None,
) -> SharedFit:
    """Posterior of the shared weights for fixed joint models: ``lambda`` by type-II ML.

    Args:
        gps, thetas: each moved joint's GP (its target without the shared part) and
            hyperparameters.
        cols: each joint's stacked shared columns ``(N, P)``.
        sizes: columns per effect (one ``lambda`` each).
        log_lambda0: starting values.
    """
    A = np.zeros((cols[0].shape[1],) * 2)
    b = np.zeros(cols[0].shape[1])
    for gp, th, c in zip(gps, thetas, cols, strict=True):
        a_j, b_j = _terms(gp, th, c)
        A += a_j
        b += b_j
    col_var = _col_var(cols, [gp.r * gp.scale for gp in gps])
    x0 = np.zeros(len(sizes)) if log_lambda0 is None else np.asarray(log_lambda0, float)

    def neg(x: FloatArray) -> float:
        g = shared_gain(A, b, _prior(x, sizes, col_var))[0]
        return -g if math.isfinite(g) else 1e300

    best = None
    for start in (x0, np.full(len(sizes), -6.0)):
        res = minimize(neg, start, method="L-BFGS-B", bounds=[LOG_LAMBDA_BOUNDS] * len(sizes))
        if best is None or res.fun < best.fun:
            best = res
    gain, mean, cov = shared_gain(A, b, _prior(best.x, sizes, col_var))
    return SharedFit(mean, cov, np.asarray(best.x, float), gain)


def score_shared(
    gps: Sequence[JointGP],
    thetas: Sequence[FloatArray],
    evidences: Sequence[float],
    cols: Sequence[FloatArray],
) -> tuple[float, SharedFit]:
    """Gain ``Delta`` of one shared candidate over the joints' own models, with its
    ``lambda`` and every moved joint's noise re-optimised (module docstring).

    Returns:
        ``(Delta, fit)``: ``fit`` at the optimum (its ``gain`` the block's part alone).
    """
    heads = [int(gp.has_kernel) for gp in gps]
    col_var = _col_var(cols, [gp.r * gp.scale for gp in gps])
    sizes = [cols[0].shape[1]]
    base = float(sum(evidences))

    def total(x: FloatArray) -> tuple[float, FloatArray, FloatArray]:
        A = np.zeros((sizes[0], sizes[0]))
        b = np.zeros(sizes[0])
        ev = 0.0
        for j, (gp, th, c) in enumerate(zip(gps, thetas, cols, strict=True)):
            t = np.array(th, dtype=np.float64)
            t[heads[j]] += x[1 + j]
            ev += gp.log_evidence(t)
            a_j, b_j = _terms(gp, t, c)
            A += a_j
            b += b_j
        g, mean, cov = shared_gain(A, b, _prior(x[:1], sizes, col_var))
        return ev + g - base, mean, cov

    def neg(x: FloatArray) -> float:
        v = total(x)[0]
        return -v if math.isfinite(v) else 1e300

    # start: the best lambda with every noise held (A, b computed once), then all together
    fixed = fit_shared(gps, thetas, cols, sizes)
    x0 = np.zeros(1 + len(gps))
    x0[0] = fixed.log_lambda[0]
    bounds = [LOG_LAMBDA_BOUNDS] + [NOISE_SHIFT_BOUNDS] * len(gps)
    best = minimize(neg, x0, method="L-BFGS-B", bounds=bounds, options={"ftol": SCORE_FTOL})
    delta, mean, cov = total(best.x)
    return delta, SharedFit(mean, cov, best.x[:1].copy(), delta)

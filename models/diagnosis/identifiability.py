"""Can the data pin an effect's parameters down? Otherwise say so instead of giving a number.

An effect's parameters are functions ``theta_k = g_k(w_b)`` of its block's weights ``w_b``
(:meth:`.Effect.estimates`; mostly ``theta_k = w_{b,k}``). One output joint's GP gives the
posterior ``w | r ~ N(m, C)`` of all its block weights (the start function marginalised,
:mod:`mcpilco.models.gp.linear_gp`) and the data's information ``H = Phi^T (alpha K_0 +
sigma^2 I)^-1 Phi`` on them (the log-likelihood's curvature; ``C^-1 = H + Lambda^-1``). With
``a = d theta_k / d w`` (central differences of :meth:`.Effect.estimates`), a parameter is *not
identifiable from these data* when

1. the likelihood is flat along it: ``a`` has a component in the null space of ``H`` (in the
   correlation scale ``H_ij / sqrt(H_ii H_jj)``, eigenvalues below :data:`FLAT_EIGENVALUE` of
   the largest; a weight whose column the data never excite has ``H_ii = 0``);
2. its 95% posterior interval ``Z95 sqrt(a^T C a)`` is wider than ``|theta_k|``;
3. the data alone bound it only to ``Z95 sqrt(a^T H^-1 a) >= |theta_k|``: the reported number
   then comes from the prior ``w_b ~ N(0, lambda_b I)``, whose variance type-II maximum
   likelihood shrinks towards 0 for an effect the data do not support;
4. its posterior correlation with another weight of the joint's model (another effect's, or
   another of the same effect's that it does not read), ``(C a)_i / sqrt(a^T C a C_ii)``, has
   ``|rho| >= IDENTIFIABLE_CORRELATION``: the data fix only a combination of the two (for a
   pair, ``|rho| = 0.95`` inflates the variance tenfold, the usual collinearity limit).

The reasons are given in words (``ParamEstimate.unidentified``), e.g. ``"posterior correlation
-0.998 with offset:2 tau_0: the data fix only their combination"``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from mcpilco.models.diagnosis.effects import Effect, FeatureContext, ParamEstimate
from mcpilco.models.gp.linear_gp import JointGP
from mcpilco.models.stats import Z95

FloatArray = NDArray[np.float64]

__all__ = ["IDENTIFIABLE_CORRELATION", "judge_estimates", "posterior_correlation", "weight_names"]

IDENTIFIABLE_CORRELATION = 0.95
"""Posterior ``|correlation|`` with another weight from which a parameter is not identifiable."""
FLAT_EIGENVALUE = 1e-9
"""Eigenvalue of the correlation-scaled information, relative to the largest, taken as flat."""
DEAD_INFORMATION = 1e-12
"""A weight whose information is below this fraction of the largest is not excited at all."""


def weight_names(effects: Sequence[Effect], sizes: Sequence[int]) -> list[str]:
    """Names of one joint's block weights: ``"<effect label> <parameter>"`` where the block has
    one weight per parameter, else ``"<effect label> w<k>"``."""
    if len(effects) != len(sizes):
        raise ValueError(f"{len(effects)} effects for {len(sizes)} blocks")
    out = []
    for e, p in zip(effects, sizes, strict=True):
        if len(e.params) == p:
            out += [f"{e.variant_label} {q.name}" for q in e.params]
        else:
            out += [f"{e.variant_label} w{k + 1}" for k in range(p)]
    return out


def _gradients(
    effect: Effect,
    mean: FloatArray,
    cov: FloatArray,
    ctx: FeatureContext,
    output: int,
    n_params: int,
) -> FloatArray:
    """``(n_params, p)`` derivatives of the reported parameters by the block's weights."""
    p = mean.size
    grad = np.zeros((n_params, p))
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    for i in range(p):
        h = 1e-6 * max(abs(float(mean[i])), float(sd[i]), 1e-12)
        up, down = mean.copy(), mean.copy()
        up[i] += h
        down[i] -= h
        a = effect.estimates(up, cov, ctx, output)
        b = effect.estimates(down, cov, ctx, output)
        for k in range(min(n_params, len(a), len(b))):
            grad[k, i] = (a[k].value - b[k].value) / (2.0 * h)
    return grad


def _likelihood_variance(info: FloatArray, a: FloatArray) -> tuple[float, str, int | None]:
    """``(a^T H^-1 a, why, partner)``: ``inf`` when ``a`` reaches a direction the likelihood is
    flat along, ``why`` ``"dead"`` (a weight the data never excite) or ``"flat"`` (a
    combination of weights they cannot separate; ``partner``: the weight outside ``a``'s
    support that the flat direction moves most, if any); otherwise ``partner`` is the weight
    whose likelihood correlation (in ``H^-1``) with the parameter reaches
    :data:`IDENTIFIABLE_CORRELATION`, if any."""
    d = np.sqrt(np.clip(np.diag(info), 0.0, None))
    dead = d <= DEAD_INFORMATION * max(float(d.max(initial=0.0)), 1e-300)
    if np.any(dead & (a != 0)):
        return math.inf, "dead", None
    alive = np.flatnonzero(~dead)
    if not alive.size:
        return 0.0, "", None
    an = a[alive] / d[alive]
    hn = info[np.ix_(alive, alive)] / d[alive][:, None] / d[alive][None, :]
    w, V = np.linalg.eigh(0.5 * (hn + hn.T))
    proj = V.T @ an
    flat = w <= FLAT_EIGENVALUE * max(float(w.max()), 1e-300)
    reach = flat & (np.abs(proj) > 1e-3 * float(np.linalg.norm(an)))
    if np.any(reach):
        v = V[:, int(np.argmax(np.where(reach, np.abs(proj), -1.0)))]
        outside = np.where(a[alive] == 0, np.abs(v), 0.0)
        k = int(np.argmax(outside))
        return math.inf, "flat", int(alive[k]) if outside[k] > 1e-3 else None
    # the weight the likelihood ties it to most: correlation in H^-1 on the non-flat space
    inv = (V[:, ~flat] / w[~flat]) @ V[:, ~flat].T
    var = float(an @ inv @ an)
    cross = inv @ an
    diag = np.clip(np.diag(inv), 0.0, None)
    rho = np.where((a[alive] == 0) & (diag > 0), cross / np.sqrt(var * diag + 1e-300), 0.0)
    k = int(np.argmax(np.abs(rho)))
    partner = int(alive[k]) if abs(rho[k]) >= IDENTIFIABLE_CORRELATION else None
    return var, "", partner


def judge_estimates(
    effect: Effect,
    estimates: Sequence[ParamEstimate],
    gp: JointGP,
    theta: FloatArray,
    block: int,
    names: Sequence[str],
    ctx: FeatureContext,
    output: int,
) -> list[ParamEstimate]:
    """``estimates`` of ``effect`` (block ``block`` of ``gp`` at hyperparameters ``theta``,
    output joint ``output``, 0-based) with ``unidentified`` set where the data cannot pin a
    parameter down (module docstring); ``names``: every weight's name
    (:func:`weight_names`)."""
    mean, cov = gp.weights(theta)
    if len(names) != mean.size:
        raise ValueError(f"names has {len(names)} entries for {mean.size} weights")
    sl = gp.block_slices()[block]
    info = gp.information(theta)
    grads = _gradients(effect, mean[sl], cov[sl, sl], ctx, output, len(estimates))
    out = []
    for est, g in zip(estimates, grads, strict=True):
        a = np.zeros(mean.size)
        a[sl] = g
        if not np.any(a):
            out.append(est)
            continue
        reasons = []
        value = abs(est.value)
        var_l, why, partner = _likelihood_variance(info, a)
        if why == "dead":
            reasons.append("the likelihood is flat along it: these data do not excite it")
        elif why == "flat":
            reasons.append(
                "the likelihood is flat along it"
                + (
                    f": these data cannot separate it from {names[partner]}"
                    if partner is not None
                    else ": these data fix only a combination of it with other weights"
                )
            )
        elif est.ci95 >= value:
            reasons.append(
                f"its 95% interval ±{est.ci95:.3g} is wider than its value {est.value:.3g}"
            )
        elif Z95 * math.sqrt(var_l) >= value:
            reasons.append(
                f"the data alone bound it only to ±{Z95 * math.sqrt(var_l):.3g}, wider than "
                f"its value {est.value:.3g}, which comes from the prior"
                + (f"; the likelihood ties it to {names[partner]}" if partner is not None else "")
            )
        var_post = float(a @ cov @ a)
        others = np.flatnonzero(a == 0)
        if var_post > 0 and others.size:
            diag = np.clip(np.diag(cov)[others], 0.0, None)
            with np.errstate(divide="ignore", invalid="ignore"):
                rho = np.where(diag > 0, (cov[others] @ a) / np.sqrt(var_post * diag), 0.0)
            i = int(np.argmax(np.abs(rho)))
            if abs(rho[i]) >= IDENTIFIABLE_CORRELATION:
                reasons.append(
                    f"posterior correlation {rho[i]:+.3f} with {names[others[i]]}: the data fix "
                    "only their combination"
                )
        out.append(dataclasses.replace(est, unidentified="; ".join(reasons)))
    return out


def posterior_correlation(gp: JointGP, theta: FloatArray) -> FloatArray:
    """``(P, P)`` posterior correlation of one joint's block weights (``0`` off the diagonal
    of a weight with no posterior variance)."""
    _, cov = gp.weights(theta)
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = np.where(np.outer(sd, sd) > 0, cov / np.outer(sd, sd), 0.0)
    np.fill_diagonal(corr, 1.0)
    return corr

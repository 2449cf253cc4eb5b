"""Greedy subset-of-data selection by posterior variance (pivoted Cholesky).

With :math:`S` the points chosen so far, the next point is

.. math::
    i^\\star = \\arg\\max_{i \\notin S} \\sum_b \\frac{v_b(x_i \\mid S)}{k_b(x_i, x_i)},\\qquad
    v_b(x \\mid S) = k_b(x, x) - k_b(x, X_S) (K_{b,SS} + \\sigma_b^2 I)^{-1} k_b(X_S, x),

(summed over the independent GPs :math:`b` of a batched kernel, each normalised by its prior
variance). The factor :math:`V = L^{-1} K_{S,X}` grows by one row per pick,

.. math::
    v_{new}(x) = \\frac{k(x_{i^\\star}, x) - V_{:, i^\\star}^T V_{:, x}}
                      {\\sqrt{v(x_{i^\\star} \\mid S) + \\sigma^2}},\\qquad
    v(x \\mid S \\cup \\{i^\\star\\}) = v(x \\mid S) - v_{new}(x)^2,

so k picks cost :math:`O(N k^2)` time and :math:`O(N k)` memory. With :math:`\\sigma^2 = 0` this is
the pivoted Cholesky factorisation of :math:`K`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import gpytorch
import numpy as np
import torch
from torch import Tensor

from mcpilco.models.gp.dense import dense_covar, dense_diag

if TYPE_CHECKING:
    from mcpilco.models.gp.regressor import GPRegressor

__all__ = ["greedy_subset"]


@torch.no_grad()
def greedy_subset(
    X: np.ndarray | Tensor,
    kernel_or_gp: gpytorch.kernels.Kernel | GPRegressor,
    k: int,
    *,
    noise_variance: float | Tensor | None = None,
    return_variance: bool = False,
) -> Tensor | tuple[Tensor, Tensor]:
    """Pick ``k`` rows of ``X`` greedily, each time the one of largest posterior variance.

    Args:
        X: ``(N, d)`` candidate inputs (original units when a GPRegressor is given: they are
            standardised with its constants).
        kernel_or_gp: a kernel (batch shape ``[]`` or ``[m]``), or a fitted
            :class:`~mcpilco.models.gp.GPRegressor` (its kernel and noise are used).
        k: number of points to select, ``1 <= k <= N``.
        noise_variance: observation noise :math:`\\sigma^2` (scalar or ``(m,)``); None means 0
            for a kernel and the fitted (standardised) noise for a GPRegressor.
        return_variance: also return the posterior variance at every row after the k picks.

    Returns:
        ``indices`` (int64, ``(k,)``, in selection order, no duplicates), and with
        ``return_variance`` the variances ``(*batch, N)``.
    """
    if isinstance(kernel_or_gp, gpytorch.kernels.Kernel):
        kernel = kernel_or_gp
        X = torch.as_tensor(X, dtype=torch.float64)
        if X.dim() != 2:
            raise ValueError(f"X must be 2-D (N, d), got shape {tuple(X.shape)}")
        if noise_variance is None:
            noise_variance = 0.0
    elif hasattr(kernel_or_gp, "model_"):  # a GPRegressor (regressor.py imports this module)
        gp = kernel_or_gp
        gp._check_fitted()
        X = gp._standardize_x(gp._as_inputs(X))
        kernel = gp.model_.covar_module
        if noise_variance is None:
            noise_variance = gp.model_.likelihood.noise.detach().squeeze(-1)
    else:
        raise TypeError(
            "kernel_or_gp must be a gpytorch Kernel or a fitted GPRegressor, got "
            f"{type(kernel_or_gp).__name__}"
        )
    n = X.shape[0]
    if not 1 <= k <= n:
        raise ValueError(f"k must be between 1 and N={n} (rows of X), got {k}")
    params = list(kernel.parameters())
    if params:
        X = X.to(params[0].dtype)

    batch = kernel.batch_shape
    Xb = X.expand(*batch, n, X.shape[-1])
    prior = dense_diag(kernel, Xb).reshape(-1, n)  # (B, N)
    nb = prior.shape[0]
    noise = torch.as_tensor(noise_variance, dtype=X.dtype).reshape(-1).expand(nb)
    var = prior.clone()
    inv_prior = 1.0 / prior.clamp_min(torch.finfo(X.dtype).tiny)
    V = X.new_zeros(nb, k, n)
    chosen = torch.zeros(n, dtype=torch.bool)
    indices = torch.empty(k, dtype=torch.long)
    tiny = 1e-12
    for j in range(k):
        score = (var * inv_prior).sum(0)
        score[chosen] = -torch.inf
        i = int(score.argmax())
        indices[j] = i
        chosen[i] = True
        col = dense_covar(kernel, Xb, Xb[..., i : i + 1, :]).reshape(nb, n)
        if j > 0:
            col = col - torch.einsum("bjn,bj->bn", V[:, :j], V[:, :j, i])
        denom2 = var[:, i] + noise
        ok = denom2 > tiny * prior[:, i]
        row = torch.where(ok[:, None], col / denom2.clamp_min(tiny).sqrt()[:, None], 0.0)
        V[:, j] = row
        var = (var - row.pow(2)).clamp_min(0.0)
    if return_variance:
        return indices, var.reshape(*batch, n)
    return indices

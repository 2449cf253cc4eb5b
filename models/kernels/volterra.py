"""Volterra-series kernels of order r (thesis section 6.3-6.4) built from this package.

- ``"pk"`` (eq. 6.18): :math:`\\sum_{i=1}^r (\\mathbf u^T \\Sigma^{(i)} \\mathbf u')^i + \\rho_0`
- ``"ipk"`` (eq. 6.23): :math:`(1 + \\mathbf u^T \\Sigma \\mathbf u')^r` (offset fixed to 1)
- ``"mpk"`` (eq. 6.25): :math:`\\sum_{i=1}^r \\rho_i k^{(i)}_{mpk} + \\rho_0`, homogeneous MPK
- ``"sed_mpk"`` (eq. 6.30): :math:`\\sum_{i=1}^r \\rho_i k^{(i)}_{sed} + \\rho_0`
- ``"sed_mpk_tied"`` (eq. 6.30 with 6.35): the same with all :math:`\\alpha_p = \\alpha`,
  :math:`\\beta_p = \\beta` in every block, :math:`\\sum_{i=1}^r \\rho_i
  (\\mathbf u^T \\Sigma(\\alpha, \\beta) \\mathbf u')^i + \\rho_0`
  (:class:`~mcpilco.models.kernels.TiedSEDMPKernel`)

Inputs are the lagged vectors :math:`\\mathbf u_k = [u_k, u_{k-1}, \\dots, u_{k-m}]` (most
recent first), i.e. ``memory + 1`` columns. Every degree :math:`i` has its own
hyperparameters, except in ``"sed_mpk_tied"`` (one :math:`\\alpha, \\beta` for all).
:math:`\\rho_i` is a ``ScaleKernel`` outputscale, :math:`\\rho_0` a ``ConstantKernel``.
The IPK is the thesis' (6.23): the offset is fixed to 1 and not trained, so it has no free
overall scale (its expansion already contains the constant, so no :math:`\\rho_0` is added);
the input and output scaling done by :class:`~mcpilco.models.volterra.VolterraGP` therefore
sets its prior.
"""

from __future__ import annotations

import torch
from gpytorch.kernels import AdditiveKernel, ConstantKernel, Kernel, ScaleKernel

from mcpilco.models.kernels._base import NO_BATCH, check_positive_int
from mcpilco.models.kernels.mpk import MPKernel
from mcpilco.models.kernels.polynomial import PolynomialKernel
from mcpilco.models.kernels.sed_mpk import SEDMPKernel, TiedSEDMPKernel

__all__ = ["VOLTERRA_KINDS", "volterra_kernel"]

VOLTERRA_KINDS = ("pk", "ipk", "mpk", "sed_mpk", "sed_mpk_tied")


def volterra_kernel(
    kind: str,
    order: int,
    memory: int,
    batch_shape: torch.Size = NO_BATCH,
    active_dims: tuple[int, ...] | None = None,
) -> Kernel:
    """Kernel for a Volterra series of order ``order`` and memory ``memory`` (see module doc).

    Args:
        kind: one of ``"pk"``, ``"ipk"``, ``"mpk"``, ``"sed_mpk"``, ``"sed_mpk_tied"``.
        order: :math:`r \\ge 1`.
        memory: :math:`m \\ge 0`; the kernel takes ``memory + 1`` input columns.
        batch_shape: batch of independent kernels (one per output).
        active_dims: the ``memory + 1`` input columns holding the lagged inputs (set on every
            term of the sum).

    Returns:
        a ``gpytorch.kernels.Kernel`` (an ``AdditiveKernel`` except for ``"ipk"`` and
        ``"sed_mpk_tied"``, a :class:`~mcpilco.models.kernels.TiedSEDMPKernel`).
    """
    r = check_positive_int(order, "order")
    if isinstance(memory, bool) or not isinstance(memory, int) or memory < 0:
        raise ValueError(f"memory must be an int >= 0, got {memory!r}")
    d = memory + 1
    bs = torch.Size(batch_shape)
    ad = active_dims
    if kind == "ipk":
        return PolynomialKernel(
            r, d, homogeneous=False, batch_shape=bs, active_dims=ad, fixed_sigma2=1.0
        )
    if kind == "sed_mpk_tied":
        return TiedSEDMPKernel(r, memory, batch_shape=bs, active_dims=ad)
    # ScaleKernel calls its base kernel's forward directly, so active_dims go on the terms
    if kind == "pk":
        terms: list[Kernel] = [
            PolynomialKernel(i, d, homogeneous=True, batch_shape=bs, active_dims=ad)
            for i in range(1, r + 1)
        ]
    elif kind == "mpk":
        terms = [
            ScaleKernel(
                MPKernel(i, d, homogeneous=True, batch_shape=bs), batch_shape=bs, active_dims=ad
            )
            for i in range(1, r + 1)
        ]
    elif kind == "sed_mpk":
        terms = [
            ScaleKernel(SEDMPKernel(i, memory, batch_shape=bs), batch_shape=bs, active_dims=ad)
            for i in range(1, r + 1)
        ]
    else:
        raise ValueError(f"unknown Volterra kernel kind {kind!r}; use one of {VOLTERRA_KINDS}")
    return AdditiveKernel(*terms, ConstantKernel(batch_shape=bs, active_dims=ad))

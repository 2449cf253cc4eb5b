"""Homogeneous (PK) and inhomogeneous (IPK) polynomial kernels with ARD weights."""

from __future__ import annotations

import torch
from gpytorch.constraints import Interval, Positive
from torch import Tensor

from mcpilco.models.kernels._base import (
    NO_BATCH,
    DenseKernel,
    check_positive_int,
    weighted_inner,
)

__all__ = ["PolynomialKernel"]


class PolynomialKernel(DenseKernel):
    r"""Polynomial kernel of degree :math:`p` with a diagonal (ARD) weight matrix.

    Homogeneous (PK, thesis eq. 6.17a):

    .. math::

        k^{(p)}_{pk}(\mathbf x, \mathbf x') = \left(\mathbf x^T \Sigma\, \mathbf x'\right)^p,

    inhomogeneous (IPK, thesis eq. 3.9 / 6.23):

    .. math::

        k^{(p)}_{ipk}(\mathbf x, \mathbf x') = \left(\sigma^2 + \mathbf x^T \Sigma\,
        \mathbf x'\right)^p,

    with :math:`\Sigma = \operatorname{diag}(\sigma_1, \dots, \sigma_d) \ge 0` and
    :math:`\sigma^2 \ge 0`. The PK spans the monomials of degree exactly :math:`p`, the IPK all
    monomials of degree :math:`\le p` (with weights tied by the binomial expansion, which is
    what the MPK relaxes). The thesis' IPK (6.23) fixes :math:`\sigma^2 = 1`
    (``fixed_sigma2=1.0``); then the kernel has no free overall scale and the offset sets the
    prior variance of the constant term (1 on standardised outputs).

    Args:
        degree: :math:`p \ge 1`.
        ard_num_dims: input dimension :math:`d`.
        homogeneous: True for PK (no :math:`\sigma^2`), False for IPK.
        batch_shape, active_dims: as for every GPyTorch kernel.
        sigma2_constraint, Sigma_constraint: default ``Positive()``.
        fixed_sigma2: IPK only: hold :math:`\sigma^2` at this value (a buffer, not trained);
            ``None`` (default) trains it.

    Attributes:
        raw_sigma2: ``(*batch_shape, 1)``, only when ``homogeneous=False`` and
            ``fixed_sigma2`` is None (else the buffer ``fixed_sigma2``).
        raw_Sigma_diag: ``(*batch_shape, d)``.
        sigma2: the offset (zeros for the PK), ``Sigma_diag``: the weights.
    """

    def __init__(
        self,
        degree: int,
        ard_num_dims: int,
        homogeneous: bool,
        batch_shape: torch.Size = NO_BATCH,
        active_dims: tuple[int, ...] | None = None,
        sigma2_constraint: Interval | None = None,
        Sigma_constraint: Interval | None = None,
        fixed_sigma2: float | None = None,
    ) -> None:
        d = check_positive_int(ard_num_dims, "ard_num_dims")
        self.degree = check_positive_int(degree, "degree")
        if not isinstance(homogeneous, bool):
            raise TypeError(f"homogeneous must be a bool, got {type(homogeneous).__name__}")
        if fixed_sigma2 is not None:
            if homogeneous:
                raise ValueError("fixed_sigma2 needs homogeneous=False (the PK has no offset)")
            if not (isinstance(fixed_sigma2, int | float) and fixed_sigma2 >= 0):
                raise ValueError(f"fixed_sigma2 must be a float >= 0, got {fixed_sigma2!r}")
        super().__init__(ard_num_dims=d, batch_shape=batch_shape, active_dims=active_dims)
        self.homogeneous = homogeneous
        self.sigma2_is_fixed = fixed_sigma2 is not None
        self.register_parameter(
            "raw_Sigma_diag", torch.nn.Parameter(torch.zeros(*self.batch_shape, d))
        )
        self.register_constraint("raw_Sigma_diag", Sigma_constraint or Positive())
        if self.sigma2_is_fixed:
            self.register_buffer(
                "fixed_sigma2", torch.full((*self.batch_shape, 1), float(fixed_sigma2))
            )
        elif not homogeneous:
            self.register_parameter(
                "raw_sigma2", torch.nn.Parameter(torch.zeros(*self.batch_shape, 1))
            )
            self.register_constraint("raw_sigma2", sigma2_constraint or Positive())
            self.sigma2 = 1.0
        self.Sigma_diag = 1.0 / d

    @property
    def sigma2(self) -> Tensor:
        """Offset :math:`\\sigma^2`, ``(*batch_shape, 1)`` (zeros for the homogeneous PK)."""
        if self.homogeneous:
            return torch.zeros_like(self.raw_Sigma_diag[..., :1])
        if self.sigma2_is_fixed:
            return self.fixed_sigma2
        return self._get("sigma2")

    @sigma2.setter
    def sigma2(self, value: Tensor | float) -> None:
        if self.homogeneous:
            raise AttributeError("the homogeneous PK has no sigma2; use homogeneous=False (IPK)")
        if self.sigma2_is_fixed:
            raise AttributeError("sigma2 is fixed (fixed_sigma2); build the kernel without it")
        self._set("sigma2", value)

    @property
    def Sigma_diag(self) -> Tensor:
        """Diagonal of :math:`\\Sigma`, shape ``(*batch_shape, d)``."""
        return self._get("Sigma_diag")

    @Sigma_diag.setter
    def Sigma_diag(self, value: Tensor | float) -> None:
        self._set("Sigma_diag", value)

    def forward(
        self, x1: Tensor, x2: Tensor, diag: bool = False, last_dim_is_batch: bool = False, **params
    ) -> Tensor:
        self._check_inputs(x1, x2, last_dim_is_batch, self.ard_num_dims)
        base = weighted_inner(x1, x2, self.Sigma_diag.to(x1.dtype), diag)
        if not self.homogeneous:
            sigma2 = self.sigma2.to(x1.dtype)
            base = base + (sigma2 if diag else sigma2.unsqueeze(-1))
        return base if self.degree == 1 else base.pow(self.degree)

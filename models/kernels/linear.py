"""Linear kernel with offset and ARD weights (the building block of PK, IPK, MPK and GIP)."""

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

__all__ = ["LinearKernel"]


class LinearKernel(DenseKernel):
    r"""Linear kernel with an offset and a diagonal (ARD) weight matrix.

    .. math::

        k(\mathbf x, \mathbf x') = \sigma^2 + \mathbf x^T \Sigma\, \mathbf x',
        \qquad \Sigma = \operatorname{diag}(\sigma_1, \dots, \sigma_d),

    with :math:`\sigma^2 \ge 0` and :math:`\sigma_j \ge 0` (thesis eq. 3.10 with :math:`p = 1`).
    Its RKHS is the space of affine functions of :math:`\mathbf x`.

    Args:
        ard_num_dims: input dimension :math:`d` (one weight per input column).
        batch_shape: batch of independent kernels, e.g. ``torch.Size([m])`` for ``m`` outputs.
        active_dims: columns of the input the kernel acts on.
        sigma2_constraint: constraint on :math:`\sigma^2` (default: ``Positive()``).
        Sigma_constraint: constraint on the diagonal of :math:`\Sigma` (default: ``Positive()``).

    Attributes:
        raw_sigma2: ``(*batch_shape, 1)``; ``sigma2`` is the constrained value.
        raw_Sigma_diag: ``(*batch_shape, d)``; ``Sigma_diag`` is the constrained value.

    Example:
        >>> k = LinearKernel(ard_num_dims=3)
        >>> K = k(torch.randn(5, 3)).to_dense()  # (5, 5)
    """

    def __init__(
        self,
        ard_num_dims: int,
        batch_shape: torch.Size = NO_BATCH,
        active_dims: tuple[int, ...] | None = None,
        sigma2_constraint: Interval | None = None,
        Sigma_constraint: Interval | None = None,
    ) -> None:
        d = check_positive_int(ard_num_dims, "ard_num_dims")
        super().__init__(ard_num_dims=d, batch_shape=batch_shape, active_dims=active_dims)
        self.register_parameter("raw_sigma2", torch.nn.Parameter(torch.zeros(*self.batch_shape, 1)))
        self.register_parameter(
            "raw_Sigma_diag", torch.nn.Parameter(torch.zeros(*self.batch_shape, d))
        )
        self.register_constraint("raw_sigma2", sigma2_constraint or Positive())
        self.register_constraint("raw_Sigma_diag", Sigma_constraint or Positive())
        self.sigma2 = 1.0
        self.Sigma_diag = 1.0

    @property
    def sigma2(self) -> Tensor:
        """Offset :math:`\\sigma^2`, shape ``(*batch_shape, 1)``."""
        return self._get("sigma2")

    @sigma2.setter
    def sigma2(self, value: Tensor | float) -> None:
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
        sigma2 = self.sigma2.to(x1.dtype)
        inner = weighted_inner(x1, x2, self.Sigma_diag.to(x1.dtype), diag)
        return inner + (sigma2 if diag else sigma2.unsqueeze(-1))

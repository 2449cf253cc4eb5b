"""Kernels on precomputed per-joint feature rows: the parametric prior (PP) kernel (eq. 3.6).

The model-based GPs see an input row ``[q, qd, qdd, phi_1, ..., phi_n]`` (``3n + n p``
columns; ``phi_i`` the feature row of joint ``i`` from
:class:`~mcpilco.models.inverse_dynamics.rigid_body.RigidBodyFeatures`). The GP of joint
``b`` (batch element ``b`` of a ``batch_shape=[n]`` kernel) must use ``phi_b`` only:
:class:`RowLinearKernel` does this with a fixed block mask on an ARD linear kernel.
"""

from __future__ import annotations

import torch
from gpytorch.constraints import Interval, Positive
from torch import Tensor

from mcpilco.models.kernels import (
    NO_BATCH,
    DenseKernel,
    check_positive_int,
    weighted_inner,
)

__all__ = ["RowLinearKernel"]


class RowLinearKernel(DenseKernel):
    r"""Linear kernel of output ``b`` on its own feature row (thesis eq. 3.6, PP kernel).

    .. math::

        k_b(\mathbf x, \mathbf x') = \boldsymbol\phi_b(\mathbf x)^T\, \Sigma_b\,
        \boldsymbol\phi_b(\mathbf x'), \qquad \Sigma_b = \operatorname{diag}(\sigma_{b,1},
        \dots, \sigma_{b,p}) \ge 0,

    i.e. the prior ``w_b ~ N(0, Sigma_b)`` on the parameters of the linear model
    ``tau_b = phi_b(x)^T w_b`` (zero prior mean, distinct diagonal entries, as in the thesis).
    The input holds the ``n_rows`` rows side by side, ``[phi_1, ..., phi_n]`` (``n_rows * p``
    columns, use ``active_dims`` to pick them out of a wider input); batch element ``b`` reads
    columns ``b p .. (b + 1) p - 1``. The Gram matrix is one matmul with weights that are zero
    outside row ``b``.

    Args:
        n_rows: number of rows ``n`` (= outputs); ``batch_shape`` must be ``[n_rows]``.
        row_dim: features per row ``p``.
        batch_shape: ``torch.Size([n_rows])``.
        active_dims: the ``n_rows * row_dim`` columns of the rows in a wider input.
        Sigma_constraint: constraint of the diagonal of :math:`\Sigma_b` (default Positive).

    Attributes:
        raw_Sigma_diag: ``(n_rows, row_dim)``; ``Sigma_diag`` the constrained value.
    """

    def __init__(
        self,
        n_rows: int,
        row_dim: int,
        batch_shape: torch.Size = NO_BATCH,
        active_dims: tuple[int, ...] | None = None,
        Sigma_constraint: Interval | None = None,
    ) -> None:
        n = check_positive_int(n_rows, "n_rows")
        p = check_positive_int(row_dim, "row_dim")
        if tuple(batch_shape) != (n,):
            raise ValueError(
                f"RowLinearKernel needs batch_shape=torch.Size([{n}]) (one GP per row/joint), "
                f"got {tuple(batch_shape)}"
            )
        super().__init__(ard_num_dims=n * p, batch_shape=batch_shape, active_dims=active_dims)
        self.n_rows, self.row_dim = n, p
        self.register_parameter("raw_Sigma_diag", torch.nn.Parameter(torch.zeros(n, p)))
        self.register_constraint("raw_Sigma_diag", Sigma_constraint or Positive())
        self.register_buffer("row_mask", torch.eye(n).repeat_interleave(p, dim=1))  # (n, n p)
        self.Sigma_diag = 1.0

    @property
    def Sigma_diag(self) -> Tensor:
        """``(n_rows, row_dim)`` prior variances of the parameters of each row."""
        return self._get("Sigma_diag")

    @Sigma_diag.setter
    def Sigma_diag(self, value: Tensor | float) -> None:
        self._set("Sigma_diag", value)

    def full_weights(self) -> Tensor:
        """``(n_rows, n_rows * row_dim)``: ``Sigma_b`` placed on row ``b``'s columns."""
        return self.Sigma_diag.repeat(1, self.n_rows) * self.row_mask.to(self.Sigma_diag)

    def forward(
        self, x1: Tensor, x2: Tensor, diag: bool = False, last_dim_is_batch: bool = False, **params
    ) -> Tensor:
        self._check_inputs(x1, x2, last_dim_is_batch, self.ard_num_dims)
        return weighted_inner(x1, x2, self.full_weights().to(x1.dtype), diag)

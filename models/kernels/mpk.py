"""Multiplicative polynomial kernel (MPK) with the hierarchical parametrisation of eq. (6.28)."""

from __future__ import annotations

import torch
from gpytorch.constraints import Interval, Positive
from torch import Tensor

from mcpilco.models.kernels._base import (
    NO_BATCH,
    DenseKernel,
    as_parameter_value,
    check_positive_int,
    increments_from_levels,
    levels_from_increments,
)

__all__ = ["MPKernel", "product_over_factors"]


def product_over_factors(factors: Tensor, dim: int) -> Tensor:
    """Product of the slices of ``factors`` along ``dim`` (a few factors; explicit multiplies).

    Explicit multiplications instead of ``torch.prod`` keep the backward pass a chain of
    elementwise products (``torch.prod`` has a slow, zero-aware backward).
    """
    first, *rest = factors.unbind(dim)  # unbind: one stack in backward, not one per slice
    out = first
    for f in rest:
        out = out * f
    return out


class MPKernel(DenseKernel):
    r"""Multiplicative polynomial kernel of degree :math:`p` (thesis eq. 3.10 and 6.24).

    .. math::

        k^{(p)}_{mpk}(\mathbf x, \mathbf x') = \prod_{s=1}^{p}
        \left(\sigma_s^2 + \mathbf x^T \Sigma_s\, \mathbf x'\right),
        \qquad \Sigma_s = \operatorname{diag}(\boldsymbol\sigma_s),

    with the hierarchical parametrisation of eq. (6.28) (backward iteration), applied to both
    the diagonal weights and the offsets:

    .. math::

        \Sigma_p = A_p,\quad \Sigma_s = \Sigma_{s+1} + A_s, \qquad
        \sigma_p^2 = b_p,\quad \sigma_s^2 = \sigma_{s+1}^2 + b_s, \qquad s = p-1, \dots, 1,

    where :math:`A_s \ge 0` (diagonal) and :math:`b_s \ge 0` are the free hyperparameters, so
    :math:`\Sigma_1 \ge \Sigma_2 \ge \dots \ge \Sigma_p` elementwise (likewise the offsets).
    This removes the permutation symmetry of the factors; increasing :math:`A_s[j]` promotes
    all monomials in which :math:`x_j` has degree :math:`\ge s`. The inhomogeneous kernel spans
    exactly the monomials of degree :math:`\le p`. With ``homogeneous=True`` the offsets are
    dropped (:math:`\sigma_s^2 = 0`, eq. 6.24a) and the kernel spans the monomials of degree
    exactly :math:`p` (the Volterra building block :math:`k^{(i)}_{mpk}`).

    Args:
        degree: :math:`p \ge 1`.
        ard_num_dims: input dimension :math:`d`.
        homogeneous: drop the offsets :math:`\sigma_s^2` (default False, as in chapter 3).
        batch_shape, active_dims: as for every GPyTorch kernel.
        increment_constraint: constraint on :math:`A_s` and :math:`b_s` (default ``Positive()``).

    Attributes:
        raw_Sigma_increment: ``(*batch_shape, p, d)``, the :math:`A_s` before the constraint.
        raw_sigma2_increment: ``(*batch_shape, p)``, the :math:`b_s` (absent if homogeneous).
        Sigma_increment, sigma2_increment: the constrained :math:`A_s`, :math:`b_s`.
        Sigma_diag: ``(*batch_shape, p, d)`` effective diagonals :math:`\boldsymbol\sigma_s`
            (non-increasing in :math:`s`); settable (must be non-increasing).
        sigma2: ``(*batch_shape, p)`` effective offsets :math:`\sigma^2_s` (zeros if
            homogeneous); settable.

    Example:
        >>> k = MPKernel(degree=2, ard_num_dims=6, batch_shape=torch.Size([2]))
        >>> K = k(torch.randn(400, 6), torch.randn(300, 6)).to_dense()  # (2, 400, 300)
    """

    def __init__(
        self,
        degree: int,
        ard_num_dims: int,
        homogeneous: bool = False,
        batch_shape: torch.Size = NO_BATCH,
        active_dims: tuple[int, ...] | None = None,
        increment_constraint: Interval | None = None,
    ) -> None:
        d = check_positive_int(ard_num_dims, "ard_num_dims")
        p = check_positive_int(degree, "degree")
        if not isinstance(homogeneous, bool):
            raise TypeError(f"homogeneous must be a bool, got {type(homogeneous).__name__}")
        super().__init__(ard_num_dims=d, batch_shape=batch_shape, active_dims=active_dims)
        self.degree = p
        self.homogeneous = homogeneous
        self.register_parameter(
            "raw_Sigma_increment", torch.nn.Parameter(torch.zeros(*self.batch_shape, p, d))
        )
        self.register_constraint("raw_Sigma_increment", increment_constraint or Positive())
        self.Sigma_increment = 1.0 / (p * d)
        if not homogeneous:
            self.register_parameter(
                "raw_sigma2_increment", torch.nn.Parameter(torch.zeros(*self.batch_shape, p))
            )
            self.register_constraint("raw_sigma2_increment", increment_constraint or Positive())
            self.sigma2_increment = 1.0 / p

    # --- free hyperparameters (increments) -------------------------------------------------
    @property
    def Sigma_increment(self) -> Tensor:
        """:math:`A_s` (diagonals), shape ``(*batch_shape, p, d)``."""
        return self._get("Sigma_increment")

    @Sigma_increment.setter
    def Sigma_increment(self, value: Tensor | float) -> None:
        self._set("Sigma_increment", value)

    @property
    def sigma2_increment(self) -> Tensor:
        """:math:`b_s`, shape ``(*batch_shape, p)`` (zeros if homogeneous)."""
        if self.homogeneous:
            return torch.zeros_like(self.raw_Sigma_increment[..., 0])
        return self._get("sigma2_increment")

    @sigma2_increment.setter
    def sigma2_increment(self, value: Tensor | float) -> None:
        if self.homogeneous:
            raise AttributeError("a homogeneous MPK has no offsets; use homogeneous=False")
        self._set("sigma2_increment", value)

    # --- effective values --------------------------------------------------------------------
    @property
    def Sigma_diag(self) -> Tensor:
        """Effective :math:`\\boldsymbol\\sigma_s`, ``(*batch_shape, p, d)``, non-increasing."""
        return levels_from_increments(self.Sigma_increment, dim=-2, reverse=True)

    @Sigma_diag.setter
    def Sigma_diag(self, value: Tensor | float) -> None:
        raw = self.raw_Sigma_increment
        value = as_parameter_value(value, raw, "Sigma_diag")
        self.Sigma_increment = increments_from_levels(value, -2, reverse=True, name="Sigma_diag")

    @property
    def sigma2(self) -> Tensor:
        """Effective offsets :math:`\\sigma^2_s`, ``(*batch_shape, p)``, non-increasing."""
        return levels_from_increments(self.sigma2_increment, dim=-1, reverse=True)

    @sigma2.setter
    def sigma2(self, value: Tensor | float) -> None:
        if self.homogeneous:
            raise AttributeError("a homogeneous MPK has no offsets; use homogeneous=False")
        raw = self.raw_sigma2_increment
        value = as_parameter_value(value, raw, "sigma2")
        self.sigma2_increment = increments_from_levels(value, -1, reverse=True, name="sigma2")

    def factors(self, x1: Tensor, x2: Tensor, diag: bool = False) -> Tensor:
        r"""The :math:`p` linear factors, ``(..., p, n, m)`` (or ``(..., p, n)`` if diag).

        The offsets ride along in the matmul as an extra column:
        :math:`\sigma_s^2 + \mathbf x^T \Sigma_s \mathbf x' =
        [\Sigma_s \mathbf x;\ \sigma_s^2]^T [\mathbf x';\ 1]`, which saves a broadcast add
        (and its reduction in the backward pass) over the ``(p, n, m)`` tensor.
        """
        Sigma = self.Sigma_diag.to(x1.dtype)  # (*b, p, d)
        a = x1.unsqueeze(-3) * Sigma.unsqueeze(-2)  # (*b, p, n, d)
        if diag:
            out = (a * x2.unsqueeze(-3)).sum(-1)  # (*b, p, n)
            return out if self.homogeneous else out + self.sigma2.to(x1.dtype).unsqueeze(-1)
        if self.homogeneous:
            return a @ x2.unsqueeze(-3).mT  # (*b, p, n, m)
        sigma2 = self.sigma2.to(x1.dtype)[..., None, None].expand(*a.shape[:-1], 1)
        a = torch.cat([a, sigma2], dim=-1)  # (*b, p, n, d + 1)
        b = torch.cat([x2, x2.new_ones(*x2.shape[:-1], 1)], dim=-1)  # (..., m, d + 1)
        return a @ b.unsqueeze(-3).mT  # (*b, p, n, m)

    def forward(
        self, x1: Tensor, x2: Tensor, diag: bool = False, last_dim_is_batch: bool = False, **params
    ) -> Tensor:
        self._check_inputs(x1, x2, last_dim_is_batch, self.ard_num_dims)
        return product_over_factors(self.factors(x1, x2, diag), dim=-2 if diag else -3)

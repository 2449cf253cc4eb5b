"""Smooth exponentially decaying MPK (SED-MPK, thesis section 6.4)."""

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
from mcpilco.models.kernels.mpk import product_over_factors

__all__ = ["SEDMPKernel", "TiedSEDMPKernel", "sed_matrix"]


def sed_matrix(alpha: Tensor, beta: Tensor, memory: int) -> Tensor:
    r"""The SED regularisation matrices of eq. (6.29b).

    .. math::

        \Sigma(i, j) = e^{-\alpha |i - j|}\, e^{-\beta (i + j)}, \qquad i, j = 0, \dots, m,

    (0-based lags; the thesis writes :math:`|i-1+j-1|` with 1-based indices). Positive
    semidefinite for :math:`\alpha, \beta \ge 0`: the Hadamard product of the exponential
    (Ornstein-Uhlenbeck) covariance on a grid and the rank-one matrix
    :math:`\mathbf d \mathbf d^T` with :math:`d_i = e^{-\beta i}`.

    Args:
        alpha, beta: tensors of the same shape ``S`` (any).
        memory: :math:`m`; the matrices are :math:`(m+1) \times (m+1)`.

    Returns:
        ``(*S, m+1, m+1)``.
    """
    idx = torch.arange(memory + 1, dtype=alpha.dtype, device=alpha.device)
    dist = (idx.unsqueeze(-1) - idx).abs()
    lag_sum = idx.unsqueeze(-1) + idx
    a = alpha.unsqueeze(-1).unsqueeze(-1)
    b = beta.unsqueeze(-1).unsqueeze(-1)
    return torch.exp(-a * dist - b * lag_sum)


class SEDMPKernel(DenseKernel):
    r"""SED-MPK building block of degree :math:`p` on lagged inputs (thesis eq. 6.29).

    .. math::

        k^{(p)}_{sed}(\mathbf u_t, \mathbf u_j) = \prod_{s=1}^{p} \mathbf u_t^T \Sigma_s\,
        \mathbf u_j, \qquad
        \Sigma_s(i, j) = e^{-\alpha_s |i - j|}\, e^{-\beta_s (i + j)},

    where :math:`\mathbf u_t = [u_t, u_{t-1}, \dots, u_{t-m}]` (most recent input first: column
    :math:`i` holds lag :math:`i`, so the decay :math:`e^{-\beta i}` shrinks older lags). The
    :math:`\Sigma_s` are full :math:`(m+1) \times (m+1)` matrices; the factors are computed as
    ``(u1 @ Sigma_s) @ u2.mT``. The kernel spans the monomials of degree exactly :math:`p` in
    the lagged inputs. The Volterra model of order :math:`r` (eq. 6.30) is
    :math:`\sum_{i=1}^r \rho_i k^{(i)}_{sed} + \rho_0`; see
    :func:`mcpilco.models.kernels.volterra_kernel`.

    Hierarchical parametrisation (forward iteration), with free increments
    :math:`a^{\alpha}_s, a^{\beta}_s \ge 0`:

    .. math::

        \alpha_1 = a^{\alpha}_1,\quad \alpha_s = \alpha_{s-1} + a^{\alpha}_s, \qquad
        \beta_1 = a^{\beta}_1,\quad \beta_s = \beta_{s-1} + a^{\beta}_s, \qquad s = 2..p.

    Direction: the entries of :math:`\Sigma_s` decrease with :math:`\alpha_s, \beta_s`, so
    non-decreasing :math:`\alpha_s, \beta_s` make the matrices entrywise non-increasing in
    :math:`s`, :math:`\Sigma_1 \ge \Sigma_2 \ge \dots \ge \Sigma_p` -- the same ordering as the
    MPK's :math:`\Sigma_s = \Sigma_{s+1} + A_s` (eq. 6.28). It removes the permutation symmetry
    of the factors, and reads the same way: the first factor has the longest, smoothest memory,
    and every further factor (each extra degree of a monomial) can only shorten it, so high-
    degree interactions are confined to recent lags (fading memory).

    Args:
        degree: :math:`p \ge 1`.
        memory: :math:`m \ge 0`; inputs have :math:`m + 1` columns.
        batch_shape, active_dims: as for every GPyTorch kernel.
        increment_constraint: constraint on the increments (default ``Positive()``).

    Attributes:
        raw_alpha_increment, raw_beta_increment: ``(*batch_shape, p)``.
        alpha_increment, beta_increment: constrained increments.
        alpha, beta: ``(*batch_shape, p)`` effective values, non-decreasing in :math:`s`;
            settable (must be non-decreasing and >= 0).
        Sigma: ``(*batch_shape, p, m+1, m+1)``, the matrices :math:`\Sigma_s`.
    """

    def __init__(
        self,
        degree: int,
        memory: int,
        batch_shape: torch.Size = NO_BATCH,
        active_dims: tuple[int, ...] | None = None,
        increment_constraint: Interval | None = None,
    ) -> None:
        p = check_positive_int(degree, "degree")
        if isinstance(memory, bool) or not isinstance(memory, int) or memory < 0:
            raise ValueError(f"memory must be an int >= 0 (number of past lags), got {memory!r}")
        super().__init__(ard_num_dims=memory + 1, batch_shape=batch_shape, active_dims=active_dims)
        self.degree = p
        self.memory = memory
        for name in ("raw_alpha_increment", "raw_beta_increment"):
            self.register_parameter(name, torch.nn.Parameter(torch.zeros(*self.batch_shape, p)))
            self.register_constraint(name, increment_constraint or Positive())
        # alpha_s = 0.1 s, beta_s = 0.05 s: correlation 0.9 between adjacent lags, lag weights
        # e^{-0.1 i} for the first factor.
        self.alpha_increment = 0.1
        self.beta_increment = 0.05

    @property
    def alpha_increment(self) -> Tensor:
        """:math:`a^{\\alpha}_s`, ``(*batch_shape, p)``."""
        return self._get("alpha_increment")

    @alpha_increment.setter
    def alpha_increment(self, value: Tensor | float) -> None:
        self._set("alpha_increment", value)

    @property
    def beta_increment(self) -> Tensor:
        """:math:`a^{\\beta}_s`, ``(*batch_shape, p)``."""
        return self._get("beta_increment")

    @beta_increment.setter
    def beta_increment(self, value: Tensor | float) -> None:
        self._set("beta_increment", value)

    @property
    def alpha(self) -> Tensor:
        """Effective :math:`\\alpha_s`, ``(*batch_shape, p)``, non-decreasing in :math:`s`."""
        return levels_from_increments(self.alpha_increment, dim=-1, reverse=False)

    @alpha.setter
    def alpha(self, value: Tensor | float) -> None:
        value = as_parameter_value(value, self.raw_alpha_increment, "alpha")
        self.alpha_increment = increments_from_levels(value, -1, reverse=False, name="alpha")

    @property
    def beta(self) -> Tensor:
        """Effective :math:`\\beta_s`, ``(*batch_shape, p)``, non-decreasing in :math:`s`."""
        return levels_from_increments(self.beta_increment, dim=-1, reverse=False)

    @beta.setter
    def beta(self, value: Tensor | float) -> None:
        value = as_parameter_value(value, self.raw_beta_increment, "beta")
        self.beta_increment = increments_from_levels(value, -1, reverse=False, name="beta")

    @property
    def Sigma(self) -> Tensor:
        """:math:`\\Sigma_s` of eq. (6.29b), ``(*batch_shape, p, m+1, m+1)``."""
        return sed_matrix(self.alpha, self.beta, self.memory)

    def forward(
        self, x1: Tensor, x2: Tensor, diag: bool = False, last_dim_is_batch: bool = False, **params
    ) -> Tensor:
        self._check_inputs(x1, x2, last_dim_is_batch, self.memory + 1)
        Sigma = self.Sigma.to(x1.dtype)  # (*b, p, m+1, m+1)
        a = x1.unsqueeze(-3) @ Sigma  # (*b, p, n, m+1)
        if diag:
            factors = (a * x2.unsqueeze(-3)).sum(-1)  # (*b, p, n)
            return product_over_factors(factors, dim=-2)
        factors = a @ x2.unsqueeze(-3).mT  # (*b, p, n, n')
        return product_over_factors(factors, dim=-3)


class TiedSEDMPKernel(DenseKernel):
    r"""SED-MPK of order :math:`r` with all :math:`\alpha_p = \alpha`, :math:`\beta_p = \beta`.

    The special case of thesis eq. (6.35) used in the thesis' experiment 2: every factor of
    every block of the Volterra kernel (6.30) shares the same SED matrix
    :math:`\Sigma = \Sigma(\alpha, \beta)` of eq. (6.29b), so

    .. math::

        K^{(r)}_{sed}(\mathbf u_t, \mathbf u_j) = \sum_{i=1}^{r} \rho_i
        \left(\mathbf u_t^T \Sigma\, \mathbf u_j\right)^i + \rho_0, \qquad
        \Sigma(i, j) = e^{-\alpha |i - j|}\, e^{-\beta (i + j)},

    and the similarity of two Volterra coefficients of order :math:`i` is
    :math:`P(\boldsymbol\tau, \boldsymbol\tau') = e^{-\alpha\|\boldsymbol\tau -
    \boldsymbol\tau'\|_1} e^{-\beta\|\boldsymbol\tau + \boldsymbol\tau'\|_1}` (eq. 6.35) for
    every order. It equals :func:`~mcpilco.models.kernels.volterra_kernel` ``"sed_mpk"`` with
    all its :math:`\alpha_p, \beta_p` set equal (every increment but the first zero), but has
    only :math:`r + 3` hyperparameters (:math:`\alpha, \beta, \rho_0, \dots, \rho_r`) instead
    of :math:`r(r+1) + r + 1`. The base :math:`\mathbf u_t^T \Sigma \mathbf u_j` is computed
    once and raised to the powers :math:`1..r`.

    Args:
        order: :math:`r \ge 1`.
        memory: :math:`m \ge 0`; inputs have :math:`m + 1` columns (lag :math:`i` in column
            :math:`i`, most recent first).
        batch_shape, active_dims: as for every GPyTorch kernel.
        alpha_constraint, beta_constraint, rho_constraint: default ``Positive()`` (the
            :math:`\rho` constraint applies to :math:`\rho_1..\rho_r` and :math:`\rho_0`).

    Attributes:
        raw_alpha, raw_beta: ``(*batch_shape, 1)``.
        raw_rho: ``(*batch_shape, r)``, the :math:`\rho_1..\rho_r` before the constraint.
        raw_rho0: ``(*batch_shape, 1)``.
        alpha, beta, rho, rho0: the constrained values (settable).
        Sigma: ``(*batch_shape, m+1, m+1)``, the matrix :math:`\Sigma(\alpha, \beta)`.

    Initial values: :math:`\alpha = 0.1`, :math:`\beta = 0.05` (as :class:`SEDMPKernel`),
    :math:`\rho_0 = 1/(r+1)` and :math:`\rho_i = 1 / ((r+1)\,\operatorname{tr}(\Sigma)^i)`, so
    that for unit-variance inputs every order contributes about the same prior variance
    :math:`\rho_i\, E[(\mathbf u^T\Sigma\mathbf u)^i] \approx 1/(r+1)` (standardised outputs).
    """

    def __init__(
        self,
        order: int,
        memory: int,
        batch_shape: torch.Size = NO_BATCH,
        active_dims: tuple[int, ...] | None = None,
        alpha_constraint: Interval | None = None,
        beta_constraint: Interval | None = None,
        rho_constraint: Interval | None = None,
    ) -> None:
        r = check_positive_int(order, "order")
        if isinstance(memory, bool) or not isinstance(memory, int) or memory < 0:
            raise ValueError(f"memory must be an int >= 0 (number of past lags), got {memory!r}")
        super().__init__(ard_num_dims=memory + 1, batch_shape=batch_shape, active_dims=active_dims)
        self.order = r
        self.memory = memory
        shapes = {"alpha": 1, "beta": 1, "rho": r, "rho0": 1}
        constraints = {
            "alpha": alpha_constraint,
            "beta": beta_constraint,
            "rho": rho_constraint,
            "rho0": rho_constraint,
        }
        for name, size in shapes.items():
            raw = torch.nn.Parameter(torch.zeros(*self.batch_shape, size))
            self.register_parameter(f"raw_{name}", raw)
            self.register_constraint(f"raw_{name}", constraints[name] or Positive())
        self.alpha = 0.1
        self.beta = 0.05
        lags = torch.arange(memory + 1, dtype=torch.float64)
        trace = float(torch.exp(-2 * 0.05 * lags).sum())  # tr(Sigma(0.1, 0.05))
        powers = torch.arange(1, r + 1, dtype=self.raw_rho.dtype)
        self.rho = 1.0 / ((r + 1) * trace**powers)
        self.rho0 = 1.0 / (r + 1)

    @property
    def alpha(self) -> Tensor:
        """:math:`\\alpha`, ``(*batch_shape, 1)``."""
        return self._get("alpha")

    @alpha.setter
    def alpha(self, value: Tensor | float) -> None:
        self._set("alpha", value)

    @property
    def beta(self) -> Tensor:
        """:math:`\\beta`, ``(*batch_shape, 1)``."""
        return self._get("beta")

    @beta.setter
    def beta(self, value: Tensor | float) -> None:
        self._set("beta", value)

    @property
    def rho(self) -> Tensor:
        """:math:`\\rho_1..\\rho_r`, ``(*batch_shape, r)``."""
        return self._get("rho")

    @rho.setter
    def rho(self, value: Tensor | float) -> None:
        self._set("rho", value)

    @property
    def rho0(self) -> Tensor:
        """:math:`\\rho_0`, ``(*batch_shape, 1)``."""
        return self._get("rho0")

    @rho0.setter
    def rho0(self, value: Tensor | float) -> None:
        self._set("rho0", value)

    @property
    def Sigma(self) -> Tensor:
        """:math:`\\Sigma(\\alpha, \\beta)` of eq. (6.29b), ``(*batch_shape, m+1, m+1)``."""
        return sed_matrix(self.alpha[..., 0], self.beta[..., 0], self.memory)

    def forward(
        self, x1: Tensor, x2: Tensor, diag: bool = False, last_dim_is_batch: bool = False, **params
    ) -> Tensor:
        self._check_inputs(x1, x2, last_dim_is_batch, self.memory + 1)
        Sigma = self.Sigma.to(x1.dtype)  # (*b, m+1, m+1)
        a = x1 @ Sigma  # (*b, n, m+1)
        base = (a * x2).sum(-1) if diag else a @ x2.mT  # (*b, n) or (*b, n, n')
        expand = (lambda c: c.unsqueeze(-1)) if diag else (lambda c: c[..., None, None])
        rho = self.rho.to(x1.dtype)
        # Horner: rho_0 + b (rho_1 + b (rho_2 + ... + b rho_r))
        out = expand(rho[..., -1])
        for i in range(self.order - 2, -1, -1):
            out = expand(rho[..., i]) + base * out
        return expand(self.rho0.to(x1.dtype)[..., 0]) + base * out

"""Cached GP posterior for repeated calls (particle rollouts).

Glossary (thesis ch. 5, eq. for the GP posterior; standardised units, one GP per output b):

* :math:`\\tilde X` ``(N, d)``: standardised training inputs,
  :math:`\\tilde x = (x - \\mu_x) / s_x`.
* :math:`K_b = k_b(\\tilde X, \\tilde X) + \\sigma_{n,b}^2 I = L_b L_b^T` (Cholesky).
* :math:`\\alpha_b = K_b^{-1} \\tilde y_b`, precomputed.
* mean :math:`\\tilde m_b(x) = k_b(x, \\tilde X)\\, \\alpha_b`.
* variance :math:`\\tilde v_b(x) = k_b(x, x) - \\lVert L_b^{-1} k_b(\\tilde X, x) \\rVert^2`, with
  :math:`L_b^{-1}` precomputed and kept as column panels without its zero upper half
  (:class:`~mcpilco.models.gp.linalg.LowerTriangularBlocks`): the product costs about
  :math:`N^2 n` flops per output instead of :math:`2 N^2 n` for a dense matmul (and instead of
  the two triangular solves of :math:`N^2 n` each that ``cholesky_solve`` does).
* original units: :math:`m_b = s_{y,b} \\tilde m_b + \\mu_{y,b}`,
  :math:`v_b = s_{y,b}^2 \\tilde v_b`.

The cross-covariance is evaluated as :math:`k_b(\\tilde X, x)` of shape ``(m, N, n)`` (training
points along rows), the layout of the right-hand side of :math:`L_b^{-1} k_b(\\tilde X, x)`.
Everything in the call path is a dense torch op, so the predictor is differentiable
w.r.t. the test inputs and works under ``torch.compile``.
"""

from __future__ import annotations

import copy

import gpytorch
import torch
from torch import Tensor, nn

from mcpilco.models.gp.dense import dense_covar, dense_diag
from mcpilco.models.gp.linalg import LowerTriangularBlocks, jittered_cholesky

__all__ = ["CachedPredictor"]


class CachedPredictor(nn.Module):
    """Dense, differentiable GP posterior mean and latent variance in original units.

    Built by :meth:`mcpilco.models.gp.GPRegressor.cached_predictor` (or :meth:`from_data`);
    holds a frozen copy of the kernel and the precomputed :math:`\\alpha`, :math:`L^{-1}` (as
    :attr:`linv`, column panels) and standardisation constants as buffers, all cast once to
    ``dtype``.

    Call: ``mean, var = pred(x)`` with ``x`` of shape ``(..., d)``; returns ``(..., m)`` each.
    ``var`` is the latent variance (no noise); add :attr:`noise_variance` for the predictive
    variance of an observation. Input of another dtype is cast to the predictor's dtype.

    Attributes:
        validate: when True (default) each call checks that ``x`` and the outputs are finite;
            set it to False in hot loops (the last-dim shape check always runs).
        noise_variance: ``(m,)`` noise variance in original units.
    """

    x_mean: Tensor
    x_scale: Tensor
    y_mean: Tensor
    y_scale: Tensor
    train_x: Tensor
    alpha: Tensor
    noise_variance: Tensor

    def __init__(
        self,
        kernel: gpytorch.kernels.Kernel,
        train_x: Tensor,
        alpha: Tensor,
        linv: LowerTriangularBlocks | None,
        x_mean: Tensor,
        x_scale: Tensor,
        y_mean: Tensor,
        y_scale: Tensor,
        noise_variance: Tensor,
        *,
        validate: bool = True,
    ) -> None:
        """Low-level constructor; prefer :meth:`from_data`.

        Args:
            kernel: frozen dense-evaluable kernel (batch shape ``[m]`` or ``[]``).
            train_x: ``(N, d)`` standardised training inputs.
            alpha: ``(m, 1, N)`` = :math:`\\alpha_b^T`.
            linv: :math:`L_b^{-1}` (``(m, N, N)`` as column panels), or None for a mean-only
                predictor (the call then returns ``(mean, None)``).
            x_mean, x_scale: ``(d,)`` input standardisation.
            y_mean, y_scale: ``(m,)`` output standardisation.
            noise_variance: ``(m,)`` in original units.
            validate: check finiteness of inputs and outputs on every call.
        """
        super().__init__()
        self.kernel = kernel
        self.register_buffer("train_x", train_x)
        self.register_buffer("alpha", alpha)
        self.linv = linv
        self.register_buffer("x_mean", x_mean)
        self.register_buffer("x_scale", x_scale)
        self.register_buffer("y_mean", y_mean)
        self.register_buffer("y_scale", y_scale)
        self.register_buffer("noise_variance", noise_variance)
        self.validate = validate
        self.with_variance = linv is not None
        self.input_dim = int(train_x.shape[-1])
        self.output_dim = int(alpha.shape[0])
        self.num_train = int(train_x.shape[0])

    @classmethod
    @torch.no_grad()
    def from_data(
        cls,
        kernel: gpytorch.kernels.Kernel,
        train_x: Tensor,
        train_y: Tensor,
        noise: Tensor,
        *,
        x_mean: Tensor,
        x_scale: Tensor,
        y_mean: Tensor,
        y_scale: Tensor,
        dtype: torch.dtype = torch.float32,
        validate: bool = True,
        with_variance: bool = True,
    ) -> CachedPredictor:
        """Precompute :math:`\\alpha` and :math:`L^{-1}` in float64, then cast once to ``dtype``.

        Args:
            kernel: fitted kernel with batch shape ``[m]`` (or ``[]``); it is deep-copied and
                frozen (no gradients w.r.t. hyperparameters).
            train_x: ``(N, d)`` standardised training inputs.
            train_y: ``(m, N)`` standardised training targets.
            noise: ``(m,)`` noise variance in standardised units.
            x_mean, x_scale, y_mean, y_scale: standardisation constants.
            dtype: dtype of the buffers and of the call (float32 or float64).
            validate: see the class docstring.
            with_variance: when False only :math:`\\alpha` is kept (no :math:`L^{-1}`, an
                :math:`O(N^3)` solve and :math:`O(N^2)` memory less) and the call returns
                ``(mean, None)``; for large-N mean predictions such as the Volterra benchmark.
        """
        if dtype not in (torch.float32, torch.float64):
            raise TypeError(f"dtype must be torch.float32 or torch.float64, got {dtype}")
        f64 = torch.float64
        k64 = copy.deepcopy(kernel).to(f64)
        X = train_x.to(f64)
        m, n = train_y.shape
        Xb = X.expand(m, n, X.shape[-1])
        K = dense_covar(k64, Xb, Xb)
        K = K.expand(m, n, n) + torch.diag_embed(noise.to(f64).reshape(m, 1).expand(m, n))
        L, _ = jittered_cholesky(K)
        alpha = torch.cholesky_solve(train_y.to(f64).unsqueeze(-1), L)  # (m, N, 1)
        linv = None
        if with_variance:
            eye = torch.eye(n, dtype=f64).expand(m, n, n)
            Linv = torch.linalg.solve_triangular(L, eye, upper=False).tril()
            linv = LowerTriangularBlocks(Linv.to(dtype))
        frozen = k64.to(dtype)
        for p in frozen.parameters():
            p.requires_grad_(False)
        return cls(
            frozen,
            X.to(dtype).contiguous(),
            alpha.transpose(-1, -2).to(dtype).contiguous(),
            linv,
            x_mean.to(dtype),
            x_scale.to(dtype),
            y_mean.to(dtype),
            y_scale.to(dtype),
            (noise.to(f64) * y_scale.to(f64) ** 2).to(dtype),
            validate=validate,
        )

    @property
    def dtype(self) -> torch.dtype:
        """Dtype of the buffers and of the outputs."""
        return self.alpha.dtype

    def forward(self, x: Tensor) -> tuple[Tensor, Tensor | None]:
        """Posterior mean and latent variance at ``x``.

        Args:
            x: ``(..., d)`` test inputs in original units.

        Returns:
            ``(mean, var)``, each ``(..., m)``, in original units and the predictor's dtype;
            ``var`` is None for a mean-only predictor (``with_variance=False``).
        """
        if x.shape[-1] != self.input_dim:
            raise ValueError(
                f"x must have shape (..., {self.input_dim}) (the training input dimension), "
                f"got {tuple(x.shape)}"
            )
        if self.validate and not bool(torch.isfinite(x).all()):
            raise ValueError("x holds NaN or inf; the GP posterior is undefined there")
        lead = x.shape[:-1]
        m, d = self.output_dim, self.input_dim
        xs = (x.to(self.dtype).reshape(-1, d) - self.x_mean) / self.x_scale
        n = xs.shape[0]
        x_test = xs.expand(m, n, d)
        x_train = self.train_x.expand(m, self.num_train, d)
        k_cross = dense_covar(self.kernel, x_train, x_test).expand(m, self.num_train, n)
        mean = (self.alpha @ k_cross)[:, 0].T * self.y_scale + self.y_mean  # (n, m)
        mean = mean.reshape(*lead, m)
        if self.linv is None:
            if self.validate and not bool(torch.isfinite(mean).all()):
                raise ValueError("the GP posterior mean produced NaN or inf; check the inputs")
            return mean, None
        prior = dense_diag(self.kernel, x_test).expand(m, n)
        var_s = (prior - self.linv.sq_col_norms(k_cross)).clamp_min(0.0)
        var = (var_s.T * self.y_scale.pow(2)).reshape(*lead, m)
        if self.validate and not bool(torch.isfinite(mean).all() & torch.isfinite(var).all()):
            raise ValueError(
                "the GP posterior produced NaN or inf (inputs far outside the training range "
                "in float32?); use dtype=torch.float64 or check the inputs"
            )
        return mean, var

    def extra_repr(self) -> str:
        return (
            f"input_dim={self.input_dim}, output_dim={self.output_dim}, "
            f"num_train={self.num_train}, dtype={self.dtype}, validate={self.validate}"
        )

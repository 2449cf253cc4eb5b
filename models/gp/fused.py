"""A fused GP posterior for particle rollouts: RBF (+ MPK) with all hyperparameters baked in.

The GP core's :class:`~mcpilco.models.gp.CachedPredictor` evaluates the kernel tree at each
call (constraint transforms, one op per kernel node). In the rollout hot loop (60 steps,
forward and backward, per optimisation step) those small ops dominate. This module reads the
fitted hyperparameters once and evaluates the same posterior with a few large ops.

Glossary (standardised inputs ``x^ = (x - mu_x) / s_x``; one GP per output ``b = 1..m``)
---------------------------------------------------------------------------------------
``k_b(x^, x^') = lambda_b^2 exp(-1/2 ||(x^ - x^')/l_b||^2) + prod_{s=1}^{p} (sigma_bs^2 +
x^^T Sigma_bs x^')``
    RBF (thesis eq. 5.2) plus MPK of degree ``p`` (eq. 5.10); the MPK part is optional.
``exp(-1/2 ||(x^ - X_j)/l||^2) = exp(x^^T (X_j / l^2) - 1/2 ||X_j/l||^2 - 1/2 ||x^/l||^2)``
    matmul form: the products ``(X_j / l^2)^T x^`` of all outputs, and the MPK factors
    ``X_j^T Sigma_bs x^``, come out of ONE matrix product ``W x^^T`` with
    ``W = [X/l_1^2 ; ... ; X Sigma_11 ; ...]`` (rows: parts, outputs, training points), so
    the cross-covariance ``k_b(X, x^)`` comes out as ``(m, N, k)``: training points on rows.
``m_b = alpha_b^T k_b(X, x^)``
    posterior mean (standardised).
``v_b = k_b(x^, x^) - ||L_b^{-1} k_b(X, x^)||^2``
    latent variance; ``L_b^{-1}`` is shared with the cached predictor as column panels without its
    zero half (:class:`~mcpilco.models.gp.linalg.LowerTriangularBlocks`, about ``N^2 k`` flops
    per output instead of ``2 N^2 k``); outputs in original units (``s_y m + mu_y``,
    ``s_y^2 v``).
"""

from __future__ import annotations

import gpytorch
import torch
from torch import Tensor, nn

from mcpilco.models.gp.linalg import LowerTriangularBlocks

INV_L2_MAX = 1e12
"""Largest ``1 / l^2`` kept (standardised inputs): a shorter lengthscale is a delta kernel."""


def _split_kernel(kernel) -> tuple[object, object | None] | None:
    """``(ScaleKernel(RBF), MPKernel | None)`` if ``kernel`` has that structure, else None."""
    from mcpilco.models.kernels import MPKernel

    def is_scaled_rbf(k) -> bool:
        return (
            isinstance(k, gpytorch.kernels.ScaleKernel)
            and type(k.base_kernel) is gpytorch.kernels.RBFKernel
            and k.active_dims is None
            and k.base_kernel.active_dims is None
        )

    if is_scaled_rbf(kernel):
        return kernel, None
    if isinstance(kernel, gpytorch.kernels.AdditiveKernel) and len(kernel.kernels) == 2:
        a, b = kernel.kernels
        if is_scaled_rbf(a) and isinstance(b, MPKernel) and b.active_dims is None:
            return a, b
    return None


class FusedRBFMPKPredictor(nn.Module):
    """Posterior mean and latent variance of ``m`` GPs with kernel RBF (+ MPK), fused.

    Build it with :meth:`from_cached`; the call has the interface of ``CachedPredictor``:
    ``mean, var = pred(x)`` with ``x (..., d)`` -> ``(..., m)`` each, original units.
    All linear forms of the kernel come from one product ``W x^^T``; its parts are taken with
    ``unbind`` (whose backward is one ``stack``, where slicing would fill full-size zero
    tensors per slice).
    """

    def __init__(
        self,
        W: Tensor,
        rbf_offset: Tensor,
        mp_sigma2: Tensor | None,
        diag_W: Tensor,
        outputscale: Tensor,
        alpha: Tensor,
        linv: LowerTriangularBlocks,
        x_mean: Tensor,
        x_scale: Tensor,
        y_mean: Tensor,
        y_scale: Tensor,
        noise_variance: Tensor,
    ) -> None:
        super().__init__()
        self.m, self.n = rbf_offset.shape[:2]
        self.input_dim = int(W.shape[1])
        self.p = W.shape[0] // (self.m * self.n) - 1
        self.register_buffer("W", W)  # ((1 + p) m N, d): [X/l_b^2 ; X Sigma_b1 ; ...]
        self.register_buffer("rbf_offset", rbf_offset)  # (m, N, 1): log lambda^2 - ||X/l||^2/2
        self.register_buffer("mp_sigma2", mp_sigma2)  # (p, m, 1, 1)
        self.register_buffer("diag_W", diag_W)  # ((1 + p) m, d): [1/l_b^2 ; Sigma_bs]
        self.register_buffer("outputscale", outputscale)  # (m, 1, 1)
        self.register_buffer("alpha", alpha)  # (m, 1, N): alpha_b^T
        self.linv = linv  # L_b^{-1} (m, N, N) as column panels, shared with the cached predictor
        self.register_buffer("x_mean", x_mean)
        self.register_buffer("x_scale", x_scale)
        self.register_buffer("y_mean", y_mean)
        self.register_buffer("y_scale", y_scale)
        self.register_buffer("noise_variance", noise_variance)

    @classmethod
    @torch.no_grad()
    def from_cached(cls, pred: nn.Module) -> FusedRBFMPKPredictor | None:
        """Fuse a ``CachedPredictor`` whose kernel is ``ScaleKernel(RBF) [+ MPKernel]`` (no
        ``active_dims``); returns None for any other kernel, or for a mean-only predictor (use
        ``pred`` as is then). The panels of :math:`L^{-1}` are shared, not copied."""
        parts = _split_kernel(pred.kernel)
        if parts is None or pred.linv is None:
            return None
        rbf, mpk = parts
        f64 = torch.float64
        dtype = pred.alpha.dtype
        X = pred.train_x.to(f64)  # (N, d) standardised
        n, d = X.shape
        m = pred.alpha.shape[0]
        inv_l2 = rbf.base_kernel.lengthscale.to(f64).reshape(-1, d).expand(m, -1) ** -2  # (m, d)
        os_ = rbf.outputscale.to(f64).reshape(-1).expand(m)
        # degenerate fits: an RBF switched off (lambda^2 underflows to 0; its lengthscales then
        # drift anywhere, even to 0) contributes exactly 0, and a lengthscale -> 0 is a delta
        # kernel; keep every buffer finite so that 0 * inf never makes a NaN
        inv_l2 = torch.where(os_[:, None] > 0, inv_l2.clamp(max=INV_L2_MAX), 0.0)
        blocks = [X[None] * inv_l2[:, None, :]]  # (m, N, d) per part
        offset = os_.log()[:, None] - 0.5 * (X[None] ** 2 * inv_l2[:, None, :]).sum(-1)
        diag = [inv_l2]  # (m, d) per part
        sigma2 = None
        if mpk is not None:
            p = mpk.degree
            Sig = mpk.Sigma_diag.to(f64).reshape(-1, p, d).expand(m, -1, -1)  # (m, p, d)
            s2 = mpk.sigma2.to(f64).reshape(-1, p).expand(m, -1)  # (m, p)
            blocks += [X[None] * Sig[:, s, None, :] for s in range(p)]
            diag += [Sig[:, s, :] for s in range(p)]
            sigma2 = s2.T.reshape(p, m, 1, 1)
        W = torch.stack(blocks).reshape(-1, d)  # ((1 + p) m N, d), order [part][b][j]
        cast = lambda t: None if t is None else t.to(dtype).contiguous()
        return cls(
            W=cast(W),
            rbf_offset=cast(offset[..., None]),
            mp_sigma2=cast(sigma2),
            diag_W=cast(torch.stack(diag).reshape(-1, d)),
            outputscale=cast(os_.reshape(m, 1, 1)),
            alpha=pred.alpha,
            linv=pred.linv,
            x_mean=pred.x_mean,
            x_scale=pred.x_scale,
            y_mean=pred.y_mean,
            y_scale=pred.y_scale,
            noise_variance=pred.noise_variance,
        )

    def forward(self, x: Tensor) -> tuple[Tensor, Tensor]:
        lead = x.shape[:-1]
        m, n, p = self.m, self.n, self.p
        xs = ((x - self.x_mean) / self.x_scale).reshape(-1, self.input_dim)  # (k, d)
        k = xs.shape[0]
        xt = xs.T  # (d, k)
        G = (self.W @ xt).view(1 + p, m, n, k).unbind(0)  # linear forms, each (m, N, k)
        D = (self.diag_W @ (xt * xt)).view(1 + p, m, 1, k).unbind(0)  # ||x/l||^2, x Sigma x
        K = torch.exp(G[0] + self.rbf_offset - 0.5 * D[0])  # (m, N, k)
        prior = self.outputscale  # (m, 1, 1)
        if p:
            prod = G[1] + self.mp_sigma2[0]
            prod_d = D[1] + self.mp_sigma2[0]
            for s in range(1, p):
                prod = prod * (G[s + 1] + self.mp_sigma2[s])
                prod_d = prod_d * (D[s + 1] + self.mp_sigma2[s])
            K = K + prod
            prior = prior + prod_d  # (m, 1, k)
        mean = (self.alpha @ K)[:, 0].T  # (k, m)
        var = (prior[:, 0] - self.linv.sq_col_norms(K)).clamp_min(0.0).T  # (k, m)
        mean = mean * self.y_scale + self.y_mean
        var = var * self.y_scale.pow(2)
        return mean.reshape(*lead, m), var.reshape(*lead, m)

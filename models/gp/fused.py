"""A fused GP posterior for particle rollouts: RBF (+ MPK) with all hyperparameters baked in.

The GP core's :class:`~mcpilco.models.gp.CachedPredictor` evaluates the kernel tree at each
call (constraint transforms, one op per kernel node). In the rollout hot loop (60 steps,
forward and backward, per optimisation step) those small ops, and the autograd nodes they
record, dominate. This module reads the fitted hyperparameters once, evaluates the same
posterior with a few large ops, and differentiates it with a hand-written backward (one
autograd node per call).

Glossary (standardised inputs ``x^ = (x - mu_x) / s_x``; one GP per output ``b = 1..m``;
``k`` test points)
---------------------------------------------------------------------------------------
``k_b(x^, x^') = lambda_b^2 exp(-1/2 ||(x^ - x^')/l_b||^2) + prod_{s=1}^{p} (sigma_bs^2 +
x^^T Sigma_bs x^')``
    RBF (thesis eq. 5.2) plus MPK of degree ``p <= 2`` (eq. 5.10); the MPK part is optional.
``r_b(X_j, x^) = exp(E_bj),  E_bj = (X_j/l_b^2)^T x^ + (log lambda_b^2 - 1/2 ||X_j/l_b||^2)
- 1/2 ||x^/l_b||^2``
    RBF part in matmul form: ``E_b = W_b [x^; 1; -1/2 ||x^/l_b||^2]`` with the constant
    ``W_b = [X/l_b^2, log lambda_b^2 - 1/2 ||X/l_b||^2, 1]`` (N, d + 2): one batched
    product, then one ``exp``; training points on rows, ``(m, N, k)``.
``z = [1, x^]``, ``a_bs(X_j) = [sigma_bs^2, X_j o Sigma_bs]``
    each MPK factor is linear in ``z``: ``sigma_bs^2 + X_j^T Sigma_bs x^ = a_bs(X_j)^T z``, so
    the MPK part is a polynomial of degree ``p`` in ``x^``:
    ``prod_s a_bs^T z = Phi_b(X_j)^T psi(x^)`` with the monomials ``psi`` of ``z``
    (``p = 1``: ``psi = z``; ``p = 2``: ``psi = (z_a z_c)_{a <= c}``, ``Phi_{ac} = a_1a a_2c +
    a_1c a_2a`` for ``a < c`` and ``a_1a a_2a`` for ``a = c``).
``V_b = L_b^{-1} k_b(X, x^) = L_b^{-1} r_b + (L_b^{-1} Phi_b) psi``
    ``L_b^{-1} Phi_b`` (N, F) is computed once per GP fit. With ``R_b = [psi; r_b]``
    (F + N, k), row block ``i`` (rows ``s_i..e_i`` of ``L^{-1}``, about
    :data:`~mcpilco.models.gp.linalg.TRI_PANEL_WIDTH` each) is one product,
    ``V_b[s_i:e_i] = [L_b^{-1} Phi_b, L_b^{-1}]_{[s_i:e_i, :F + e_i]} R_b[:F + e_i]``: the
    zeros right of the diagonal are skipped (about ``N^2 k`` flops per output instead of
    ``2 N^2 k``) and every block writes its own rows (nothing accumulated or copied).
``m_b = alpha_b^T r_b + (alpha_b^T Phi_b) psi = [alpha_b^T Phi_b, alpha_b^T] R_b``
    posterior mean (standardised).
``v_b = max(k_b(x^, x^) - ||V_b||^2, 0)``,  ``k_b(x^, x^) = lambda_b^2 + prod_s (sigma_bs^2 +
x^^T Sigma_bs x^)``
    latent variance; outputs in original units (``s_y m + mu_y``, ``s_y^2 v``).
backward (``g_m``, ``g_v``: gradients of the standardised mean and variance, ``g_v`` zero
where the clamp is active)
    ``dV_b = -2 g_v V_b``; ``dR_b = [L_b^{-1} Phi_b, L_b^{-1}]^T dV_b + [alpha_b^T Phi_b,
    alpha_b^T]^T g_m^T``, by blocks of rows of ``R_b`` with ``g_m`` as one more row of ``dV``:
    ``dpsi_b = [(L_b^{-1} Phi_b)^T, (alpha_b^T Phi_b)^T] [dV_b; g_m^T]`` and ``dr_b[s_i:e_i] =
    [L_b^{-T}_{[s_i:e_i, s_i:]}, alpha_b[s_i:e_i]] [dV_b[s_i:]; g_m^T]``;
    ``dE_b = r_b o dr_b``; ``dx^ += sum_b (X/l_b^2)^T dE_b - (1^T dE_b) (x^ o 1/l_b^2)``;
    ``dpsi = sum_b dpsi_b``, chained through ``psi(z)``; ``dk_b(x^, x^)/dx^ = sum_s
    prod_{s' != s}(sigma_bs'^2 + x^^T Sigma_bs' x^) 2 Sigma_bs x^``.
"""

from __future__ import annotations

from typing import NamedTuple

import gpytorch
import torch
from torch import Tensor, nn

from mcpilco.models.gp.linalg import LowerTriangularBlocks, panel_product
from mcpilco.models.numerics import exp_floor_

INV_L2_MAX = 1e12
"""Largest ``1 / l^2`` kept (standardised inputs): a shorter lengthscale is a delta kernel."""

MAX_MPK_DEGREE = 2
"""Largest MPK degree the fused predictor handles (its monomial features grow as ``d^p``)."""


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


class RowBlocks(NamedTuple):
    """The constant factors of the posterior's products with :math:`L^{-1}`, cut into blocks
    of rows so that each product writes its own rows (module glossary; ``F`` MPK features,
    0 without MPK; row blocks ``s_i..e_i``).

    Attributes:
        features: ``F``.
        alpha: ``[alpha^T Phi, alpha^T]`` ``(m, 1, F + N)``: ``m = alpha R``.
        forward: ``([L^{-1} Phi, L^{-1}]_{[s_i:e_i, :F + e_i]}, F + e_i)`` per block:
            ``V[s_i:e_i] = B_i R[:F + e_i]``.
        backward: ``(B_j, t_j)`` per block of rows of ``dR = cat_j B_j [dV; g_m^T][t_j:]``:
            ``([(L^{-1} Phi)^T, (alpha^T Phi)^T], 0)`` for ``psi`` (if ``F > 0``), then
            ``([L^{-T}_{[s_i:e_i, s_i:]}, alpha[s_i:e_i]], s_i)``.
    """

    features: int
    alpha: Tensor
    forward: list[tuple[Tensor, int]]
    backward: list[tuple[Tensor, int]]

    @classmethod
    def build(
        cls,
        linv: LowerTriangularBlocks,
        alpha: Tensor,
        linv_phi: Tensor | None,
        alpha_phi: Tensor | None,
        m: int,
    ) -> RowBlocks:
        """From :math:`L^{-1}` (its blocks cut at its panels), ``alpha (m, 1, N)`` and, with
        MPK, ``L^{-1} Phi (m, N, F)`` and ``alpha^T Phi (m, F)``."""
        bounds = linv.bounds
        linv = linv.dense().expand(m, -1, -1)  # (m, N, N)
        lt, a = linv.transpose(1, 2), alpha.transpose(1, 2)  # (m, N, N), (m, N, 1)
        if linv_phi is None:
            f, alpha_aug, left = 0, alpha, linv
            backward = []
        else:
            f = linv_phi.shape[-1]
            alpha_aug = torch.cat([alpha_phi.unsqueeze(1), alpha], dim=2)
            left = torch.cat([linv_phi, linv], dim=2)  # (m, N, F + N)
            psi_rows = torch.cat([linv_phi.transpose(1, 2), alpha_phi.unsqueeze(2)], dim=2)
            backward = [(psi_rows.contiguous(), 0)]
        forward = [(left[:, s:e, : f + e].contiguous(), f + e) for s, e in bounds]
        backward += [(torch.cat([lt[:, s:e, s:], a[:, s:e]], dim=2), s) for s, e in bounds]
        return cls(f, alpha_aug.contiguous(), forward, backward)


class FusedPosteriorSaved(NamedTuple):
    """What :func:`fused_posterior_backward` needs (module glossary; ``k`` test points):
    ``x^ (k, d)``, ``z = [1, x^]`` (None without MPK), ``R = [psi; r]`` (m, F + N, k), ``V``
    (m, N, k), ``1[v >= 0]`` (m, k) and the MPK factors ``sigma_bs^2 + x^^T Sigma_bs x^``
    (p, m, k) (None without MPK)."""

    xs: Tensor
    z: Tensor | None
    R: Tensor
    V: Tensor
    active: Tensor
    fac: Tensor | None


def fused_posterior_forward(
    x: Tensor, pred: FusedRBFMPKPredictor
) -> tuple[tuple[Tensor, Tensor], FusedPosteriorSaved]:
    """``(mean, var)`` (..., m) of ``pred`` at ``x (..., d)`` (original units, ``x``'s dtype)
    and what the backward needs: the fused posterior's step protocol, with
    :func:`fused_posterior_backward` (module glossary)."""
    m, d = pred.m, pred.input_dim
    lead = x.shape[:-1]
    xs = ((x.to(pred.W_aug.dtype) - pred.x_mean) / pred.x_scale).reshape(-1, d)  # (k, d)
    k = xs.shape[0]
    opts = {"dtype": xs.dtype, "device": xs.device}
    sq = xs * xs
    # [x^ ; 1 ; -||x^/l_b||^2 / 2] per output b (built by cat, which torch.compile traces)
    xaug = torch.cat(
        [
            xs.T.expand(m, d, k),
            torch.ones(m, 1, k, **opts),
            torch.mm(pred.inv_l2, sq.T).mul_(-0.5).unsqueeze(1),
        ],
        dim=1,
    )
    blocks = pred.row_blocks
    F = blocks.features
    r = exp_floor_(torch.bmm(pred.W_aug, xaug))  # (m, N, k)
    prior = pred.outputscale.expand(m, k)
    z = fac = None
    if pred.p:
        z = torch.cat([torch.ones(1, k, **opts), xs.T], dim=0)
        psi = z if pred.p == 1 else z[pred.idx_a] * z[pred.idx_c]  # (F, k), row gathers
        R = torch.cat([psi.expand(m, F, k), r], dim=1)  # (m, F + N, k)
        fac = torch.matmul(pred.mp_sigma_diag, sq.T) + pred.mp_sigma2  # (p, m, k)
        prior = prior + fac.prod(0)
    else:
        R = r
    mean = torch.bmm(blocks.alpha, R).view(m, k)  # (m, k)
    # V = L^{-1} k(X, x^), row block by row block (module glossary)
    V = torch.cat([torch.bmm(B, R[:, :c]) for B, c in blocks.forward], dim=1)
    v = prior - torch.linalg.vecdot(V, V, dim=1)  # (m, k)
    active = v >= 0  # clamp_min passes the gradient where v >= 0
    v = v.clamp_min(0.0)
    saved = FusedPosteriorSaved(xs, z, R, V, active, fac)
    mean_out = (mean.T * pred.y_scale + pred.y_mean).reshape(*lead, m)
    var_out = (v.T * pred.y_scale.pow(2)).reshape(*lead, m)
    return (mean_out.to(x.dtype), var_out.to(x.dtype)), saved


def fused_posterior_backward(
    saved: FusedPosteriorSaved, g_mean: Tensor, g_var: Tensor, pred: FusedRBFMPKPredictor
) -> Tensor:
    """``dJ/dx`` (..., d) from ``g_mean``, ``g_var`` (..., m) (module glossary, backward); in
    the gradients' dtype (that of the forward's ``x``)."""
    xs, z, R, V, active, fac = saved
    m, d = pred.m, pred.input_dim
    blocks = pred.row_blocks
    F = blocks.features
    k = xs.shape[0]
    dt = xs.dtype
    gm = (g_mean.to(dt).reshape(k, m) * pred.y_scale).T  # (m, k), standardised
    gv = (g_var.to(dt).reshape(k, m) * pred.y_scale.pow(2)).T.contiguous() * active
    # [dV; g_m^T] (m, N + 1, k), dV = -2 g_v V
    dVg = torch.cat([V * (-2.0 * gv).unsqueeze(1), gm.unsqueeze(1)], dim=1)
    dR = torch.cat([torch.bmm(B, dVg[:, s:]) for B, s in blocks.backward], dim=1)
    dE = dR[:, F:] * R[:, F:]  # dr o r
    dx = torch.bmm(pred.W_t, dE)  # (m, d + 1, k): [(X/l^2)^T dE ; 1^T dE]
    dxs = dx[:, :d].sum(0).T - xs * (dx[:, d].T @ pred.inv_l2)  # (k, d)
    if pred.p:
        dpsi = dR[:, :F].sum(0)  # (F, k)
        if pred.p == 1:
            dz = dpsi
        else:  # psi_f = z_a(f) z_c(f): dz = S_a (dpsi o z_c) + S_c (dpsi o z_a)
            dz = pred.psi_select @ torch.cat([dpsi * z[pred.idx_c], dpsi * z[pred.idx_a]])
        dxs = dxs + dz[1:].T
        # prior: d/dx^ prod_s f_s = sum_s prod_{s' != s} f_s' 2 Sigma_s x^
        others = torch.ones_like(fac) if pred.p == 1 else fac.flip(0)  # p <= 2
        w = gv * others  # (p, m, k)
        dxs = dxs + 2.0 * xs * (w.view(-1, k).T @ pred.mp_sigma_diag.view(-1, d))
    return (dxs / pred.x_scale).reshape(*g_mean.shape[:-1], d).to(g_mean.dtype)


class _FusedPosterior(torch.autograd.Function):
    """:func:`fused_posterior_forward` and :func:`fused_posterior_backward` as one autograd
    node. Differentiable once, w.r.t. ``x`` only."""

    @staticmethod
    def forward(ctx, x: Tensor, pred: FusedRBFMPKPredictor) -> tuple[Tensor, Tensor]:  # noqa: D102
        out, saved = fused_posterior_forward(x, pred)
        ctx.pred = pred
        ctx.save_for_backward(*saved)
        return out

    @staticmethod
    def backward(ctx, g_mean: Tensor, g_var: Tensor) -> tuple[Tensor, None]:  # noqa: D102
        saved = FusedPosteriorSaved(*ctx.saved_tensors)
        return fused_posterior_backward(saved, g_mean, g_var, ctx.pred), None


class FusedRBFMPKPredictor(nn.Module):
    """Posterior mean and latent variance of ``m`` GPs with kernel RBF (+ MPK), fused.

    Build it with :meth:`from_cached`; the call has the interface of ``CachedPredictor``:
    ``mean, var = pred(x)`` with ``x (..., d)`` -> ``(..., m)`` each, original units, in the
    input's dtype (computed in the predictor's). One autograd node per call (analytic
    backward w.r.t. ``x``; see the module glossary).
    """

    def __init__(
        self,
        W_aug: Tensor,
        inv_l2: Tensor,
        outputscale: Tensor,
        alpha: Tensor,
        linv: LowerTriangularBlocks,
        x_mean: Tensor,
        x_scale: Tensor,
        y_mean: Tensor,
        y_scale: Tensor,
        noise_variance: Tensor,
        mp_sigma_diag: Tensor | None = None,
        mp_sigma2: Tensor | None = None,
        linv_phi: Tensor | None = None,
        alpha_phi: Tensor | None = None,
    ) -> None:
        super().__init__()
        self.m, self.n = W_aug.shape[:2]
        self.input_dim = int(W_aug.shape[2]) - 2
        d = self.input_dim
        self.p = 0 if mp_sigma_diag is None else int(mp_sigma_diag.shape[0])
        if self.p > MAX_MPK_DEGREE:
            raise ValueError(f"MPK degree {self.p} > {MAX_MPK_DEGREE} is not supported")
        self.register_buffer("W_aug", W_aug)  # (m, N, d + 2)
        w_t = torch.cat([W_aug[:, :, :d], torch.ones_like(W_aug[:, :, :1])], dim=2)
        self.register_buffer("W_t", w_t.transpose(1, 2).contiguous())  # (m, d + 1, N)
        self.register_buffer("inv_l2", inv_l2)  # (m, d)
        self.register_buffer("outputscale", outputscale)  # (m, 1)
        self.register_buffer("alpha", alpha)  # (m, 1, N)
        self.linv = linv  # L_b^{-1} as column panels, shared with the cached predictor
        self._blocks: RowBlocks | None = None
        self._blocks_key: tuple | None = None
        self.register_buffer("x_mean", x_mean)
        self.register_buffer("x_scale", x_scale)
        self.register_buffer("y_mean", y_mean)
        self.register_buffer("y_scale", y_scale)
        self.register_buffer("noise_variance", noise_variance)
        self.register_buffer("mp_sigma_diag", mp_sigma_diag)  # (p, m, d)
        self.register_buffer("mp_sigma2", mp_sigma2)  # (p, m, 1)
        self.register_buffer("linv_phi", linv_phi)  # (m, N, F)
        self.register_buffer("alpha_phi", alpha_phi)  # (m, F)
        ia, ic = torch.triu_indices(d + 1, d + 1)
        self.register_buffer("idx_a", ia)
        self.register_buffer("idx_c", ic)
        # one-hot (d + 1, 2F): [S_a | S_c], S_a[a, f] = 1 if a(f) = a
        select = torch.zeros(d + 1, 2 * ia.numel(), dtype=W_aug.dtype, device=W_aug.device)
        select[torch.cat([ia, ic]), torch.arange(2 * ia.numel())] = 1.0
        self.register_buffer("psi_select", select)

    @classmethod
    @torch.no_grad()
    def from_cached(cls, pred: nn.Module) -> FusedRBFMPKPredictor | None:
        """Fuse a ``CachedPredictor`` whose kernel is ``ScaleKernel(RBF) [+ MPKernel]`` (no
        ``active_dims``, MPK degree <= 2); returns None for any other kernel, or for a
        mean-only predictor (use ``pred`` as is then). The panels of :math:`L^{-1}` are
        shared, not copied; :math:`L^{-1} \\Phi` is formed from them in float64."""
        parts = _split_kernel(pred.kernel)
        if parts is None or pred.linv is None:
            return None
        rbf, mpk = parts
        if mpk is not None and mpk.degree > MAX_MPK_DEGREE:
            return None
        f64 = torch.float64
        dtype = pred.alpha.dtype
        X = pred.train_x.to(f64)  # (N, d) standardised
        n, d = X.shape
        m = pred.alpha.shape[0]
        inv_l2 = rbf.base_kernel.lengthscale.to(f64).reshape(-1, d).expand(m, -1) ** -2  # (m, d)
        os_ = rbf.outputscale.to(f64).reshape(-1).expand(m)
        # degenerate fits: an RBF switched off (lambda^2 underflows to 0; its lengthscales then
        # drift anywhere, even to 0) contributes exactly 0 (offset -inf, exp -> 0), and a
        # lengthscale -> 0 is a delta kernel; the gradient path never reads the offset
        inv_l2 = torch.where(os_[:, None] > 0, inv_l2.clamp(max=INV_L2_MAX), 0.0)
        Xl = X[None] * inv_l2[:, None, :]  # (m, N, d)
        offset = os_.log()[:, None] - 0.5 * (X[None] * Xl).sum(-1)  # (m, N)
        W_aug = torch.cat([Xl, offset[..., None], torch.ones(m, n, 1, dtype=f64)], dim=2)
        extra = {}
        if mpk is not None:
            p = mpk.degree
            Sig = mpk.Sigma_diag.to(f64).reshape(-1, p, d).expand(m, -1, -1)  # (m, p, d)
            s2 = mpk.sigma2.to(f64).reshape(-1, p).expand(m, -1)  # (m, p)
            a = torch.cat([s2[:, :, None, None].expand(m, p, n, 1), X * Sig[:, :, None, :]], -1)
            if p == 1:
                Phi = a[:, 0]  # (m, N, d + 1)
            else:
                ia, ic = torch.triu_indices(d + 1, d + 1)
                a1, a2 = a[:, 0], a[:, 1]
                Phi = a1[..., ia] * a2[..., ic] + torch.where(
                    ia == ic, 0.0, a1[..., ic] * a2[..., ia]
                )  # (m, N, F)
            linv64 = [P.to(f64) for P in pred.linv.panels]
            extra = {
                "mp_sigma_diag": Sig.transpose(0, 1),
                "mp_sigma2": s2.T[..., None],
                "linv_phi": panel_product(linv64, Phi),
                "alpha_phi": (pred.alpha.to(f64) @ Phi)[:, 0],
            }
        cast = lambda t: t.to(dtype).contiguous()  # noqa: E731
        return cls(
            W_aug=cast(W_aug),
            inv_l2=cast(inv_l2),
            outputscale=cast(os_[:, None]),
            alpha=pred.alpha,
            linv=pred.linv,
            x_mean=pred.x_mean,
            x_scale=pred.x_scale,
            y_mean=pred.y_mean,
            y_scale=pred.y_scale,
            noise_variance=pred.noise_variance,
            **{key: cast(val) for key, val in extra.items()},
        )

    @property
    def row_blocks(self) -> RowBlocks:
        """The blocks of the products with :math:`L^{-1}` (module glossary), batch ``m``, for
        the hot path; cut at the panels of :math:`L^{-1}` and rebuilt when those change (e.g.
        after ``.to()``)."""
        key = (self.linv.panels[0], self.alpha, self.linv_phi)
        old = self._blocks_key
        if old is None or any(a is not b for a, b in zip(key, old, strict=True)):
            self._blocks_key = key
            self._blocks = RowBlocks.build(
                self.linv, self.alpha, self.linv_phi, self.alpha_phi, self.m
            )
        return self._blocks

    @property
    def dtype(self) -> torch.dtype:
        """Dtype of the buffers (and of the computation)."""
        return self.W_aug.dtype

    def forward(self, x: Tensor) -> tuple[Tensor, Tensor]:
        if x.shape[-1] != self.input_dim:
            raise ValueError(f"x must have shape (..., {self.input_dim}), got {tuple(x.shape)}")
        self.row_blocks  # noqa: B018 (build the block cache here, not inside the Function)
        return _FusedPosterior.apply(x, self)

    def extra_repr(self) -> str:
        return f"m={self.m}, N={self.n}, d={self.input_dim}, mpk_degree={self.p}"

"""Cholesky factorisation with jitter escalation, and triangular products without the zero half."""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import torch
from torch import Tensor, nn

__all__ = [
    "CHOLESKY_FIX_HINT",
    "JITTER_MAX",
    "JITTER_START",
    "TRI_PANEL_WIDTH",
    "LowerTriangularBlocks",
    "jittered_cholesky",
    "panel_product",
]

JITTER_START = 1e-8
"""First relative jitter tried (times the mean diagonal of the matrix)."""
JITTER_MAX = 1e-3
"""Largest relative jitter tried before giving up."""

CHOLESKY_FIX_HINT = (
    "check the training inputs for duplicate (or near-duplicate) rows, raise noise_min "
    "(a floor on the noise variance), and keep standardize_x / standardize_y on"
)


def jittered_cholesky(
    A: Tensor,
    *,
    jitter_start: float = JITTER_START,
    jitter_max: float = JITTER_MAX,
    what: str = "K + sigma_n^2 I",
) -> tuple[Tensor, float]:
    """Lower Cholesky factor :math:`L L^T = A + \\epsilon\\,\\bar a\\, I` of a (batched) PSD matrix.

    Tries :math:`\\epsilon = 0` first, then :math:`\\epsilon` = ``jitter_start``, x10, ... up to
    ``jitter_max``, where :math:`\\bar a` is the mean diagonal of each matrix (relative jitter).
    Each escalation warns with the jitter used.

    Args:
        A: ``(..., N, N)`` symmetric matrix.
        jitter_start: first relative jitter.
        jitter_max: largest relative jitter.
        what: name of the matrix in messages.

    Returns:
        ``(L, epsilon)`` with the relative jitter that was needed (0.0 if none).

    Raises:
        ValueError: A holds non-finite values, or is not positive definite even with
            ``jitter_max``; the message suggests the fix.
    """
    L, info = torch.linalg.cholesky_ex(A)
    if not bool(info.any()):
        return L, 0.0
    if not bool(torch.isfinite(A).all()):
        raise ValueError(
            f"{what} holds NaN or inf (the kernel hyperparameters diverged?); {CHOLESKY_FIX_HINT}"
        )
    scale = A.diagonal(dim1=-2, dim2=-1).mean(-1).clamp_min(torch.finfo(A.dtype).tiny)
    eye = torch.eye(A.shape[-1], dtype=A.dtype, device=A.device)
    eps = jitter_start
    while eps <= jitter_max * (1 + 1e-9):
        L, info = torch.linalg.cholesky_ex(A + (eps * scale)[..., None, None] * eye)
        if not bool(info.any()):
            warnings.warn(
                f"Cholesky of {what} (N={A.shape[-1]}) failed; succeeded after adding a "
                f"relative jitter of {eps:.1e} (x mean diagonal) to the diagonal. "
                f"To avoid this: {CHOLESKY_FIX_HINT}.",
                RuntimeWarning,
                stacklevel=2,
            )
            return L, eps
        eps *= 10.0
    raise ValueError(
        f"Cholesky of {what} (N={A.shape[-1]}) failed even with a relative jitter of "
        f"{jitter_max:.0e}: the matrix is singular. To fix: {CHOLESKY_FIX_HINT}."
    )


TRI_PANEL_WIDTH = 64
"""Columns per panel of :class:`LowerTriangularBlocks` (narrow panels skip more zeros, wide
ones make larger matmuls)."""


def panel_product(panels: Sequence[Tensor], B: Tensor) -> Tensor:
    """:math:`M B = \\sum_i [0; P_i] B_{[i]}`, accumulated in place (no autograd graph)."""
    starts = [P.shape[-1] for P in panels]
    starts = [sum(starts[:i]) for i in range(len(panels))]
    n = panels[0].shape[-2]
    batch = torch.broadcast_shapes(panels[0].shape[:-2], B.shape[:-2])
    B3 = B.expand(*batch, *B.shape[-2:]).reshape(-1, *B.shape[-2:])
    out = None
    for P, s in zip(panels, starts, strict=True):
        P3 = P.expand(*batch, *P.shape[-2:]).reshape(-1, *P.shape[-2:])
        rhs = B3[:, s : s + P.shape[-1]]
        if out is None:  # the first panel covers all rows
            out = torch.bmm(P3, rhs)
        else:
            out[:, s:].baddbmm_(P3, rhs)
    return out.reshape(*batch, n, B.shape[-1])


class _TriangularMatmul(torch.autograd.Function):
    """:math:`V = M B` for a constant lower-triangular :math:`M` given as column panels.

    Backward: :math:`\\partial B = M^T \\partial V`, whose row chunk :math:`i` is
    :math:`P_i^T\\, \\partial V_{[s_i{:}]}` (one matmul per chunk, written once); built from
    differentiable ops, so higher-order gradients w.r.t. ``B`` work too. No gradient flows to
    :math:`M`.
    """

    @staticmethod
    def forward(ctx, B: Tensor, *panels: Tensor) -> Tensor:
        ctx.save_for_backward(*panels)
        ctx.batch_b = B.shape[:-2]
        return panel_product(panels, B)

    @staticmethod
    def backward(ctx, grad: Tensor) -> tuple[Tensor | None, ...]:
        panels = ctx.saved_tensors
        n = panels[0].shape[-2]
        chunks = [P.transpose(-1, -2) @ grad[..., n - P.shape[-2] :, :] for P in panels]
        gB = torch.cat(chunks, dim=-2)
        if gB.shape[:-2] != ctx.batch_b:  # B was broadcast over the batch of M
            gB = gB.sum_to_size(*ctx.batch_b, *gB.shape[-2:])
        return (gB, *([None] * len(panels)))


class LowerTriangularBlocks(nn.Module):
    """A constant lower-triangular matrix :math:`M` (``(..., N, N)``) without its zero half.

    :math:`M` is split into column panels :math:`i = 1..J` of about :data:`TRI_PANEL_WIDTH`
    columns :math:`s_i{:}e_i`; panel :math:`P_i = M_{[s_i{:}N,\\, s_i{:}e_i]}` keeps only the
    rows from the diagonal down (above them the panel is zero):

    .. math::
        M B = \\sum_{i=1}^{J} \\begin{bmatrix} 0 \\\\ P_i \\end{bmatrix} B_{[s_i{:}e_i]},

    accumulated in place into one output, so a product with ``B (..., N, n)`` costs
    :math:`\\sum_i 2 (N - s_i)(e_i - s_i)\\, n \\approx (1 + 1/J) N^2 n` flops against
    :math:`2 N^2 n` for the dense matmul. The product is differentiable w.r.t. ``B`` (custom
    backward :math:`M^T \\partial V`, by row chunks, without the full-size zero fills that
    slicing would cost). For the GP variance :math:`M = L^{-1}` and :math:`B = k(X, x)`.

    Args:
        M: ``(..., N, N)`` lower-triangular matrix (exact zeros above the diagonal); stored
            detached (no gradient w.r.t. ``M``).
        panel_width: columns per panel (about ``N / panel_width`` panels of equal width).

    Raises:
        ValueError: ``M`` is not square, or has a non-zero entry above the diagonal.
    """

    def __init__(self, M: Tensor, panel_width: int = TRI_PANEL_WIDTH) -> None:
        super().__init__()
        if M.dim() < 2 or M.shape[-1] != M.shape[-2]:
            raise ValueError(f"M must have shape (..., N, N), got {tuple(M.shape)}")
        if panel_width < 1:
            raise ValueError(f"panel_width must be >= 1, got {panel_width}")
        if bool(torch.triu(M, diagonal=1).any()):
            raise ValueError(
                "M must be lower triangular: it has non-zero entries above the diagonal"
            )
        n = M.shape[-1]
        num = max(1, round(n / panel_width))
        ends = [round(n * (i + 1) / num) for i in range(num)]
        starts = [0, *ends[:-1]]
        self.num_panels = num
        self.size = n
        self.bounds = list(zip(starts, ends, strict=True))  # (s_i, e_i) of each panel
        M = M.detach()
        for i, (s0, s1) in enumerate(zip(starts, ends, strict=True)):
            self.register_buffer(f"panel{i}", M[..., s0:, s0:s1].contiguous())

    @property
    def panels(self) -> tuple[Tensor, ...]:
        """The column panels :math:`P_i`, each ``(..., N - s_i, e_i - s_i)``."""
        return tuple(getattr(self, f"panel{i}") for i in range(self.num_panels))

    def dense(self) -> Tensor:
        """:math:`M` itself, ``(..., N, N)``, with its zeros."""
        P0 = self.panels[0]
        M = P0.new_zeros(*P0.shape[:-2], self.size, self.size)
        for P, (s0, s1) in zip(self.panels, self.bounds, strict=True):
            M[..., s0:, s0:s1] = P
        return M

    def multiply_adds(self, n: int) -> int:
        r"""Multiply-adds of :meth:`matmul` with ``B (N, n)`` per batch element:
        :math:`\sum_i (N - s_i)(e_i - s_i)\, n` (the panels' entries times ``n``)."""
        return sum(P.shape[-2] * P.shape[-1] for P in self.panels) * int(n)

    def _check(self, B: Tensor) -> None:
        if B.dim() < 2 or B.shape[-2] != self.size:
            raise ValueError(f"B must have shape (..., {self.size}, n), got {tuple(B.shape)}")

    def matmul(self, B: Tensor) -> Tensor:
        """:math:`M B`, shape ``(..., N, n)`` (batch dims broadcast)."""
        self._check(B)
        return _TriangularMatmul.apply(B, *self.panels)

    def sq_col_norms(self, B: Tensor) -> Tensor:
        """Squared column norms :math:`\\lVert M b_c \\rVert^2`, shape ``(..., n)``."""
        V = self.matmul(B)
        return torch.linalg.vecdot(V, V, dim=-2)

    def extra_repr(self) -> str:
        return f"size={self.size}, num_panels={self.num_panels}"

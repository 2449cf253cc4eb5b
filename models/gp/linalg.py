"""Cholesky factorisation with jitter escalation and an actionable error."""

from __future__ import annotations

import warnings

import torch
from torch import Tensor

__all__ = ["CHOLESKY_FIX_HINT", "JITTER_START", "JITTER_MAX", "jittered_cholesky"]

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

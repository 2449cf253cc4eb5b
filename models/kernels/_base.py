"""Shared plumbing for the dense polynomial-family kernels.

Every kernel in this package evaluates its Gram matrix with plain torch ops in "matmul form":
a weighted inner product :math:`\\mathbf x^T \\Sigma \\mathbf x'` between all pairs of rows is
``(x1 * w) @ x2.mT`` (diagonal :math:`\\Sigma`) or ``(x1 @ Sigma) @ x2.mT`` (full
:math:`\\Sigma`), so no ``(n, m, d)`` tensor of pairwise differences is ever materialised.

Hyperparameters are cast to the dtype of the inputs inside ``forward``, so a float64 kernel
evaluated on float32 inputs returns float32 (useful for float32 cached predictors) and vice
versa; gradients flow through the cast.
"""

from __future__ import annotations

import torch
from gpytorch.kernels import Kernel
from torch import Tensor

__all__ = [
    "NO_BATCH",
    "DenseKernel",
    "as_parameter_value",
    "check_positive_int",
    "levels_from_increments",
    "increments_from_levels",
    "weighted_inner",
]

#: default ``batch_shape`` of every kernel here (a module constant so defaults are not calls)
NO_BATCH = torch.Size([])


def check_positive_int(value: object, name: str) -> int:
    """Return ``value`` as an ``int`` after checking it is an integer >= 1.

    Raises:
        TypeError: if ``value`` is not an integer (bool is rejected too).
        ValueError: if ``value`` < 1.
    """
    if isinstance(value, bool) or not isinstance(value, int):
        raise TypeError(f"{name} must be an int >= 1, got {type(value).__name__} {value!r}")
    if value < 1:
        raise ValueError(f"{name} must be >= 1, got {value}")
    return value


def as_parameter_value(value: Tensor | float, like: Tensor, name: str) -> Tensor:
    """``value`` as a tensor with the dtype, device and shape of ``like`` (broadcast).

    Raises:
        ValueError: if ``value`` does not broadcast to ``like.shape`` or is not finite.
    """
    value = torch.as_tensor(value, dtype=like.dtype, device=like.device)
    try:
        value = value.expand_as(like)
    except RuntimeError:
        raise ValueError(
            f"{name} must broadcast to shape {tuple(like.shape)}, got {tuple(value.shape)}"
        ) from None
    if not bool(torch.isfinite(value).all()):
        raise ValueError(f"{name} must be finite, got {value.detach().cpu().tolist()}")
    return value


def levels_from_increments(increments: Tensor, dim: int, reverse: bool) -> Tensor:
    """Hierarchical levels from non-negative increments along ``dim``.

    ``reverse=True`` is the backward iteration of thesis eq. (6.28):
    :math:`\\sigma_p = a_p,\\ \\sigma_s = \\sigma_{s+1} + a_s`, i.e. a reversed cumulative sum,
    so the levels are non-increasing in :math:`s`. ``reverse=False`` is the forward iteration
    :math:`\\alpha_1 = a_1,\\ \\alpha_s = \\alpha_{s-1} + a_s` (non-decreasing in :math:`s`).
    """
    if reverse:
        return increments.flip(dim).cumsum(dim).flip(dim)
    return increments.cumsum(dim)


def increments_from_levels(levels: Tensor, dim: int, reverse: bool, name: str) -> Tensor:
    """Inverse of :func:`levels_from_increments`; raises ValueError on a wrong ordering."""
    n = levels.size(dim)
    if reverse:
        nxt = torch.cat(
            [levels.narrow(dim, 1, n - 1), torch.zeros_like(levels.narrow(dim, 0, 1))], dim
        )
        inc = levels - nxt
        order = "non-increasing in the degree index s (and >= 0)"
    else:
        prev = torch.cat(
            [torch.zeros_like(levels.narrow(dim, 0, 1)), levels.narrow(dim, 0, n - 1)], dim
        )
        inc = levels - prev
        order = "non-decreasing in the degree index s (and >= 0)"
    if bool((inc < 0).any()):
        raise ValueError(
            f"{name} must be {order} to fit the hierarchical parametrisation; "
            f"got {levels.detach().cpu().tolist()}. Sort the values along the degree axis."
        )
    # zero increments are allowed; they map to a tiny positive value so that the softplus
    # inverse of the Positive() constraint stays finite.
    return inc.clamp_min(1e-12)


def weighted_inner(x1: Tensor, x2: Tensor, weights: Tensor, diag: bool) -> Tensor:
    """:math:`\\mathbf x_1^T \\operatorname{diag}(w) \\mathbf x_2` for all pairs (or the diagonal).

    Args:
        x1: ``(..., n, d)``.
        x2: ``(..., m, d)``.
        weights: ``(..., d)`` broadcastable against the batch of ``x1``; extra leading dims of
            the weights (e.g. one per factor) broadcast as batch dims.
        diag: if True return ``(..., n)`` with ``n == m``; else ``(..., n, m)``.
    """
    w = weights.unsqueeze(-2)
    if diag:
        return (x1 * w * x2).sum(-1)
    return (x1 * w) @ x2.mT


class DenseKernel(Kernel):
    """Base class: input validation common to the kernels of this package."""

    has_lengthscale = False

    def _get(self, name: str) -> Tensor:
        """The constrained value of the parameter ``raw_<name>``."""
        return getattr(self, f"raw_{name}_constraint").transform(getattr(self, f"raw_{name}"))

    def _set(self, name: str, value: Tensor | float) -> None:
        """Set ``raw_<name>`` so that its constrained value is ``value`` (validated)."""
        raw = getattr(self, f"raw_{name}")
        value = as_parameter_value(value, raw, name)
        constraint = getattr(self, f"raw_{name}_constraint")
        self.initialize(**{f"raw_{name}": constraint.inverse_transform(value)})

    def _check_inputs(self, x1: Tensor, x2: Tensor, last_dim_is_batch: bool, dim: int) -> None:
        if last_dim_is_batch:
            raise NotImplementedError(
                f"{type(self).__name__} does not support last_dim_is_batch=True (deprecated in "
                "GPyTorch); build one kernel per dimension with active_dims instead."
            )
        for name, x in (("x1", x1), ("x2", x2)):
            if x.size(-1) != dim:
                raise ValueError(
                    f"{type(self).__name__} expects inputs with last dimension {dim}, got {name} "
                    f"of shape {tuple(x.shape)}; pass active_dims to select the columns."
                )

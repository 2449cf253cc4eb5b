"""Boundary checks for GP data: shapes, finiteness, constant targets, named columns."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from torch import Tensor

__all__ = [
    "MAX_ABS_VALUE",
    "as_tensor_2d",
    "column_name",
    "check_finite_columns",
    "check_magnitude_columns",
    "check_targets_vary",
]

MAX_ABS_VALUE = 1e150
"""Largest magnitude accepted in GP data: sums of 1e8 squares of it stay below float64's
maximum (1.8e308), so means, spreads and kernel distances stay finite."""


def column_name(names: Sequence[str] | None, array: str, j: int) -> str:
    """``names[j]`` when names are given, else ``"X[:, j]"``-style."""
    if names is not None:
        return f"{names[j]!r} ({array}[:, {j}])"
    return f"{array}[:, {j}]"


def as_tensor_2d(
    value: np.ndarray | Tensor,
    array: str,
    *,
    allow_1d: bool = False,
    dtype: torch.dtype = torch.float64,
) -> tuple[Tensor, bool]:
    """Convert numpy / torch input to a 2-D tensor of ``dtype``.

    Args:
        value: array-like input.
        array: its name in messages (``"X"`` or ``"Y"``).
        allow_1d: accept a 1-D array and treat it as one column.
        dtype: target dtype.

    Returns:
        ``(tensor, was_1d)``.

    Raises:
        TypeError: not numeric.
        ValueError: wrong number of dimensions or no rows.
    """
    if isinstance(value, Tensor):
        t = value.detach()
    else:
        try:
            t = torch.as_tensor(np.asarray(value, dtype=np.float64))
        except (TypeError, ValueError) as err:
            raise TypeError(
                f"{array} must be a numeric array or tensor, got {type(value)}"
            ) from err
    if not (
        t.is_floating_point() or t.dtype in (torch.int32, torch.int64, torch.int16, torch.uint8)
    ):
        raise TypeError(f"{array} must hold real numbers, got dtype {t.dtype}")
    was_1d = t.dim() == 1
    if was_1d and allow_1d:
        t = t.unsqueeze(-1)
    if t.dim() != 2:
        allowed = "1-D (N,) or 2-D (N, m)" if allow_1d else "2-D (N, d)"
        raise ValueError(
            f"{array} must be {allowed}, got shape {tuple(t.shape)}; "
            f"reshape it, e.g. {array}.reshape(N, -1)"
        )
    if t.shape[0] == 0:
        raise ValueError(f"{array} is empty (shape {tuple(t.shape)}); pass at least one row")
    if t.shape[1] == 0:
        raise ValueError(f"{array} has no columns (shape {tuple(t.shape)})")
    return t.to(dtype), was_1d


def check_finite_columns(t: Tensor, array: str, names: Sequence[str] | None) -> None:
    """Raise ValueError naming the first column that holds NaN or inf."""
    bad = ~torch.isfinite(t)
    if bool(bad.any()):
        j = int(bad.any(0).nonzero()[0, 0])
        rows = bad[:, j].nonzero()[:, 0]
        raise ValueError(
            f"{column_name(names, array, j)} holds {len(rows)} non-finite value(s) (NaN or inf), "
            f"first at row {int(rows[0])}; drop or impute those rows before fitting"
        )


def check_targets_vary(y: Tensor, names: Sequence[str] | None) -> None:
    """Raise ValueError naming a target column that is constant (zero spread)."""
    spread = y.max(0).values - y.min(0).values
    for j in range(y.shape[1]):
        if not spread[j] > 0:
            raise ValueError(
                f"{column_name(names, 'Y', j)} is constant ({float(y[0, j]):g} in all "
                f"{y.shape[0]} rows): a GP cannot learn from it; drop this output or collect "
                "data where it varies"
            )


def check_magnitude_columns(t: Tensor, array: str, names: Sequence[str] | None) -> None:
    """Raise ValueError naming the column and row of the first value beyond
    :data:`MAX_ABS_VALUE` (its square would overflow float64 in the standardisation)."""
    big = t.abs() > MAX_ABS_VALUE
    if bool(big.any()):
        j = int(big.any(0).nonzero()[0, 0])
        i = int(big[:, j].nonzero()[0, 0])
        raise ValueError(
            f"{column_name(names, array, j)} holds {float(t[i, j]):.3g} at row {i}, beyond "
            f"+-{MAX_ABS_VALUE:g} (its square overflows float64): check the units of that "
            "column or drop the row before fitting"
        )

"""Boundary checks shared by the inverse-dynamics estimators: inputs ``(q, qd, qdd)``, targets.

Input convention (every estimator of :mod:`mcpilco.models.inverse_dynamics`)
-------------------------------------------------------------------------
``X``
    either a :class:`~mcpilco.models.robot_data.Trajectories` (its ``q``, ``qd``, ``qdd``) or
    an array ``(N, 3n)`` whose columns are ``[q_1..q_n, qd_1..qd_n, qdd_1..qdd_n]`` (the
    schema's column order).
``y``
    joint torques ``(N, n)`` (or any per-joint output such as motor currents); with a
    robot log (``Trajectories``) and ``y=None`` the log's ``tau`` group (or ``i`` when
    ``tau`` is absent) is used.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from mcpilco.models.robot_data import Trajectories

FloatArray = NDArray[np.float64]

__all__ = ["JointStates", "as_joint_states", "as_targets", "input_names", "stack_states"]


class JointStates:
    """Validated joint positions, velocities and accelerations, each ``(N, n)`` float64."""

    __slots__ = ("q", "qd", "qdd")

    def __init__(self, q: FloatArray, qd: FloatArray, qdd: FloatArray) -> None:
        self.q, self.qd, self.qdd = q, qd, qdd

    @property
    def n_joints(self) -> int:
        return int(self.q.shape[1])

    @property
    def n_samples(self) -> int:
        return int(self.q.shape[0])

    def stacked(self) -> FloatArray:
        """``(N, 3n)`` array ``[q, qd, qdd]``."""
        return np.concatenate([self.q, self.qd, self.qdd], axis=1)


def input_names(n_joints: int) -> list[str]:
    """``["q1", ..., "qn", "qd1", ..., "qddn"]`` (the columns of an ``(N, 3n)`` input)."""
    return [f"{g}{j}" for g in ("q", "qd", "qdd") for j in range(1, n_joints + 1)]


def _as_float_array(value: Any, name: str) -> FloatArray:
    if hasattr(value, "detach"):  # torch tensor
        value = value.detach().cpu().numpy()
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise TypeError(f"{name} must be a numeric array, got {type(value).__name__}") from err
    return arr


def as_joint_states(X: Any, n_joints: int | None = None) -> JointStates:
    """Validate ``X`` (a robot log, ``Trajectories``, or an ``(N, 3n)`` array) into
    :class:`JointStates`.

    Args:
        X: inputs (see the module docstring).
        n_joints: expected ``n``; ``None`` infers it (``3n`` columns).

    Raises:
        TypeError: non-numeric input.
        ValueError: wrong number of dimensions, a column count that is not ``3n``, a joint
            count different from ``n_joints``, no rows, or a NaN/inf (the column is named).
    """
    if isinstance(X, Trajectories):
        q, qd, qdd = (np.asarray(a, dtype=np.float64) for a in (X.q, X.qd, X.qdd))
        n = q.shape[1]
        if n_joints is not None and n != n_joints:
            raise ValueError(
                f"the dataset has {n} joints (q1..q{n}) but the estimator expects {n_joints}"
            )
        states = JointStates(q, qd, qdd)
    else:
        arr = _as_float_array(X, "X")
        if arr.ndim != 2:
            raise ValueError(
                f"X must be 2-D (N, 3n) with columns [q, qd, qdd], got shape {arr.shape}"
            )
        if n_joints is None:
            if arr.shape[1] % 3 != 0 or arr.shape[1] == 0:
                raise ValueError(
                    f"X must have 3n columns [q1..qn, qd1..qdn, qdd1..qddn], got {arr.shape[1]} "
                    "columns (not a multiple of 3)"
                )
            n = arr.shape[1] // 3
        else:
            n = n_joints
            if arr.shape[1] != 3 * n:
                raise ValueError(
                    f"X must have shape (N, {3 * n}) = [q, qd, qdd] for {n} joints, got {arr.shape}"
                )
        states = JointStates(arr[:, :n], arr[:, n : 2 * n], arr[:, 2 * n :])
    if states.n_samples == 0:
        raise ValueError("X has no rows; give at least one sample")
    bad = ~np.isfinite(states.stacked())
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise ValueError(
            f"X row {row} has a NaN/inf in column {input_names(states.n_joints)[col]!r}; "
            "drop or fill that row"
        )
    return states


def as_targets(y: Any, X: Any, n_rows: int, n_joints: int) -> FloatArray:
    """Validate the targets: ``(N, n)`` float64 matching ``N`` rows of ``X`` and ``n`` joints.

    With ``y=None`` and a robot log ``X`` (``Trajectories``) the log's ``tau`` (else ``i``)
    is used.
    A 1-D ``y`` is accepted for ``n = 1``.
    """
    if y is None:
        if not isinstance(X, Trajectories):
            raise ValueError(
                "y is None: give the joint torques y (N, n) or a robot log X (Trajectories)"
            )
        y = X.tau if X.tau is not None else X.i
        if y is None:
            raise ValueError("the dataset has neither 'tau' nor 'i' columns to fit")
    arr = _as_float_array(y, "y")
    if arr.ndim == 1 and n_joints == 1:
        arr = arr[:, None]
    if arr.ndim != 2:
        raise ValueError(f"y must be 2-D (N, n) joint torques, got shape {arr.shape}")
    if arr.shape != (n_rows, n_joints):
        raise ValueError(
            f"y must have shape ({n_rows}, {n_joints}) (one row per X row, one column per "
            f"joint), got {arr.shape}"
        )
    bad = ~np.isfinite(arr)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise ValueError(f"y row {row} has a NaN/inf in column tau{col + 1}; drop that row")
    return arr


def stack_states(q: Any, qd: Any, qdd: Any) -> FloatArray:
    """``(N, 3n)`` input array from separate ``q``, ``qd``, ``qdd`` arrays ``(N, n)``."""
    parts = [_as_float_array(a, name) for a, name in ((q, "q"), (qd, "qd"), (qdd, "qdd"))]
    if not (parts[0].shape == parts[1].shape == parts[2].shape) or parts[0].ndim != 2:
        raise ValueError(
            "q, qd, qdd must be 2-D arrays of the same shape (N, n), got "
            f"{[p.shape for p in parts]}"
        )
    return np.concatenate(parts, axis=1)

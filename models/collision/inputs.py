"""Inputs of the current estimators of collision detection and the quasi-static gate.

Glossary (thesis chapter 4)
---------------------------
``x = [q, qd, qdd]``
    joint positions, velocities, accelerations (the inverse-dynamics input, ``3n`` columns).
``x_bar = [q, qd, qdd, e_q, ed_q, i_c]`` (eq. 4.8)
    the augmented input of the FC estimator: ``x`` plus the position and velocity errors of
    the low-level controller (reference minus measured) and the controller's current command
    ``i_c`` (``6n`` columns, schema groups ``q, qd, qdd, e_q, e_qd, i_cmd``).
``a_i(x) = 1 if |qd_i| < sigma_v else 0`` (eq. 4.9)
    the quasi-static gate of joint ``i``: the non-parametric friction component of joint ``i``
    acts only while that joint is (nearly) at rest. ``sigma_v`` [rad/s] is the velocity below
    which the kinetic-friction model ``F_k sign(qd_i) + F_v qd_i`` (eq. 4.5) stops holding
    (thesis value ``1e-2`` rad/s, chosen by cross-validation).

Accepted input forms (every public function here): a
:class:`~mcpilco.models.robot_data.Trajectories` (the documented file format), a mapping of
arrays keyed by group (``{"q": (N, n), "qd": ..., "i_cmd": ...}``), or one ``(N, 6n)`` array
with the columns of ``x_bar`` in order (``(N, 3n)`` when only ``x`` is needed).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mcpilco.models.inverse_dynamics import JointStates
from mcpilco.models.robot_data import Trajectories

FloatArray = NDArray[np.float64]

__all__ = [
    "CONTROLLER_GROUPS",
    "STATE_GROUPS",
    "CollisionInputs",
    "as_collision_inputs",
    "quasi_static_gate",
]

STATE_GROUPS: tuple[str, ...] = ("q", "qd", "qdd")
"""Groups of ``x`` (inverse-dynamics input)."""

CONTROLLER_GROUPS: tuple[str, ...] = ("e_q", "e_qd", "i_cmd")
"""Groups that ``x_bar`` adds to ``x``: position error, velocity error, current command."""


class CollisionInputs(JointStates):
    """Validated ``x`` (``q, qd, qdd``) and, when given, ``e_q, e_qd, i_cmd``; each ``(N, n)``.

    A :class:`~mcpilco.models.inverse_dynamics.JointStates`, so the inverse-dynamics feature
    maps (rigid-body regressor, friction columns) read it directly.
    """

    __slots__ = ("e_q", "e_qd", "i_cmd")

    def __init__(
        self,
        q: FloatArray,
        qd: FloatArray,
        qdd: FloatArray,
        e_q: FloatArray | None = None,
        e_qd: FloatArray | None = None,
        i_cmd: FloatArray | None = None,
    ) -> None:
        super().__init__(q, qd, qdd)
        self.e_q, self.e_qd, self.i_cmd = e_q, e_qd, i_cmd

    @property
    def has_controller(self) -> bool:
        """True when ``e_q``, ``e_qd`` and ``i_cmd`` are all present."""
        return self.e_q is not None and self.e_qd is not None and self.i_cmd is not None

    def augmented(self) -> FloatArray:
        """``(N, 6n)`` array ``x_bar = [q, qd, qdd, e_q, e_qd, i_cmd]`` (eq. 4.8).

        Raises:
            ValueError: when a controller group is missing (it names the group).
        """
        missing = [g for g in CONTROLLER_GROUPS if getattr(self, g) is None]
        if missing:
            n = self.n_joints
            raise ValueError(
                f"x_bar needs the controller columns {', '.join(f'{g}1..{g}{n}' for g in missing)}"
                " (thesis eq. 4.8); log them or use the PP/SP estimators"
            )
        return np.concatenate([self.q, self.qd, self.qdd, self.e_q, self.e_qd, self.i_cmd], axis=1)

    def rows(self, index: Any) -> CollisionInputs:
        """The rows ``index`` (slice, index array or boolean mask) as new inputs."""
        parts = [
            None if a is None else a[index]
            for a in (self.q, self.qd, self.qdd, self.e_q, self.e_qd, self.i_cmd)
        ]
        return CollisionInputs(*parts)


def _array(value: Any, name: str) -> FloatArray:
    if hasattr(value, "detach"):  # torch tensor
        value = value.detach().cpu().numpy()
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise TypeError(f"{name} must be a numeric array, got {type(value).__name__}") from err


def as_collision_inputs(
    X: Any, n_joints: int | None = None, require_controller: bool = False
) -> CollisionInputs:
    """Validate ``X`` into :class:`CollisionInputs` (see the module docstring for the forms).

    Args:
        X: a robot log (``Trajectories``), a mapping of group arrays, a ``CollisionInputs``,
            or an array ``(N, 3n)`` (``x``) / ``(N, 6n)`` (``x_bar``).
        n_joints: expected ``n``; ``None`` infers it.
        require_controller: raise unless ``e_q``, ``e_qd`` and ``i_cmd`` are present.

    Raises:
        TypeError: non-numeric values or an unsupported type.
        ValueError: a missing group (named with its columns), a shape that is not ``(N, n)``,
            a joint count other than ``n_joints``, no rows, or a NaN/inf (row and column named).
    """
    groups: dict[str, FloatArray | None]
    if isinstance(X, CollisionInputs):
        groups = {g: getattr(X, g) for g in (*STATE_GROUPS, *CONTROLLER_GROUPS)}
    elif isinstance(X, Trajectories) or isinstance(X, Mapping):
        get = (lambda g: getattr(X, g)) if isinstance(X, Trajectories) else X.get
        groups = {}
        for g in (*STATE_GROUPS, *CONTROLLER_GROUPS):
            value = get(g)
            groups[g] = None if value is None else _array(value, g)
    else:
        arr = _array(X, "X")
        if arr.ndim != 2:
            raise ValueError(
                f"X must be 2-D (N, 3n) = [q, qd, qdd] or (N, 6n) = [q, qd, qdd, e_q, e_qd, "
                f"i_cmd], got shape {arr.shape}"
            )
        cols = arr.shape[1]
        if n_joints is not None:
            n = n_joints
            if cols not in (3 * n, 6 * n):
                raise ValueError(
                    f"X must have {3 * n} columns [q, qd, qdd] or {6 * n} columns "
                    f"[q, qd, qdd, e_q, e_qd, i_cmd] for {n} joints, got {cols}"
                )
        else:
            per = 6 if require_controller else 3
            if cols == 0 or cols % per:
                raise ValueError(
                    f"X must have {per}n columns, got {cols}; give n_joints to read a "
                    "(N, 3n) or (N, 6n) array unambiguously"
                )
            n = cols // per
        names = (*STATE_GROUPS, *CONTROLLER_GROUPS)[: cols // n]
        groups = {g: None for g in (*STATE_GROUPS, *CONTROLLER_GROUPS)}
        for k, g in enumerate(names):
            groups[g] = arr[:, k * n : (k + 1) * n]
    for g in STATE_GROUPS:
        if groups[g] is None:
            raise ValueError(f"missing group '{g}' (columns {g}1..{g}n): x needs q, qd, qdd")
    q = groups["q"]
    if q.ndim != 2:
        raise ValueError(f"'q' must be 2-D (N, n), got shape {q.shape}")
    n_rows, n = q.shape
    if n_joints is not None and n != n_joints:
        raise ValueError(f"the data have {n} joints (q1..q{n}) but {n_joints} are expected")
    if n_rows == 0:
        raise ValueError("no rows; give at least one sample")
    if require_controller:
        missing = [g for g in CONTROLLER_GROUPS if groups[g] is None]
        if missing:
            raise ValueError(
                "missing controller column group(s) "
                + ", ".join(f"'{g}' ({g}1..{g}{n})" for g in missing)
                + ": the FC estimator's input x_bar (thesis eq. 4.8) needs e_q, e_qd, i_cmd"
            )
    for g, arr in groups.items():
        if arr is None:
            continue
        if arr.shape != (n_rows, n):
            raise ValueError(f"'{g}' must have shape {(n_rows, n)} like 'q', got {arr.shape}")
        bad = ~np.isfinite(arr)
        if bad.any():
            row, col = np.argwhere(bad)[0]
            raise ValueError(f"row {row} has a NaN/inf in column '{g}{col + 1}'; drop or fill it")
    return CollisionInputs(**groups)


def quasi_static_gate(qd: Any, sigma_v: float) -> FloatArray:
    """``a_i = 1`` where ``|qd_i| < sigma_v``, else ``0`` (thesis eq. 4.9), elementwise.

    Args:
        qd: joint velocities ``(N, n)`` (any shape) [rad/s or m/s].
        sigma_v: velocity threshold ``> 0``.

    Returns:
        float64 array of 0/1 of the shape of ``qd``.
    """
    if not (isinstance(sigma_v, int | float) and np.isfinite(sigma_v) and sigma_v > 0):
        raise ValueError(f"sigma_v must be a finite velocity > 0 [rad/s], got {sigma_v!r}")
    arr = _array(qd, "qd")
    if not np.all(np.isfinite(arr)):
        raise ValueError("qd has NaN/inf values; the gate needs finite velocities")
    return (np.abs(arr) < sigma_v).astype(np.float64)

"""The one interface of the inverse-dynamics estimators: ``fit(X, y)`` / ``predict(X)``.

``predict`` returns ``(mean, var)``, two numpy float64 arrays ``(N, n)`` in the units of
``y``; ``var`` is the *latent* variance of the estimate (no measurement noise added), or
``None`` for estimators without one (the neural network). Inputs follow
:mod:`mcpilco.models.inverse_dynamics.inputs` (a robot log (``Trajectories``) or ``(N, 3n)`` arrays
``[q, qd, qdd]``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mcpilco.models.inverse_dynamics.inputs import JointStates, as_joint_states, as_targets

FloatArray = NDArray[np.float64]

__all__ = ["InverseDynamicsEstimator", "nmse", "gmse"]


class InverseDynamicsEstimator(ABC):
    """Base class: validation at the boundary, then ``_fit`` / ``_predict`` on joint states.

    Args:
        n_joints: number of joints ``n``; ``None`` infers it from the first ``fit``.

    Attributes:
        name: short label used by the benchmark (``"GIP"``, ``"RBF"``, ...).
        n_joints_: joints of the fitted data.
    """

    name = "estimator"

    def __init__(self, n_joints: int | None = None) -> None:
        if n_joints is not None and (isinstance(n_joints, bool) or n_joints < 1):
            raise ValueError(f"n_joints must be a positive int or None, got {n_joints}")
        self.n_joints = n_joints
        self.n_joints_: int | None = None

    def fit(self, X: Any, y: Any = None) -> InverseDynamicsEstimator:
        """Fit on inputs ``X`` (dataset or ``(N, 3n)``) and torques ``y`` ``(N, n)``.

        Raises:
            ValueError: shape mismatches (``X`` not ``3n`` columns, ``y`` not ``(N, n)``),
                NaN/inf values; the message names the shape or column.
        """
        states = as_joint_states(X, self.n_joints)
        targets = as_targets(y, X, states.n_samples, states.n_joints)
        self.n_joints_ = states.n_joints
        self._fit(states, targets)
        return self

    def predict(self, X: Any) -> tuple[FloatArray, FloatArray | None]:
        """``(mean, var)`` at ``X``: each ``(N, n)`` float64 (``var`` may be ``None``)."""
        if self.n_joints_ is None:
            raise RuntimeError(f"{type(self).__name__} is not fitted; call fit(X, y) first")
        states = as_joint_states(X, self.n_joints_)
        mean, var = self._predict(states)
        return np.asarray(mean, dtype=np.float64), (
            None if var is None else np.asarray(var, dtype=np.float64)
        )

    @abstractmethod
    def _fit(self, states: JointStates, y: FloatArray) -> None: ...

    @abstractmethod
    def _predict(self, states: JointStates) -> tuple[FloatArray, FloatArray | None]: ...

    def __repr__(self) -> str:
        fitted = "unfitted" if self.n_joints_ is None else f"n={self.n_joints_}"
        return f"{type(self).__name__}({fitted})"


def nmse(y_true: Any, y_pred: Any) -> FloatArray:
    """Normalised mean squared error per joint, ``MSE(tau_i, y_i) / Var(tau_i)`` (thesis 3.4.1).

    Args:
        y_true, y_pred: ``(N, n)`` arrays.

    Returns:
        ``(n,)``.
    """
    y_true = np.asarray(y_true, dtype=np.float64)
    y_pred = np.asarray(y_pred, dtype=np.float64)
    if y_true.shape != y_pred.shape:
        raise ValueError(f"shapes differ: y_true {y_true.shape}, y_pred {y_pred.shape}")
    var = y_true.var(axis=0)
    if np.any(var <= 0):
        raise ValueError("nMSE is undefined for a constant output column (zero variance)")
    return ((y_true - y_pred) ** 2).mean(axis=0) / var


def gmse(y_true: Any, y_pred: Any) -> float:
    """Global mean squared error: the sum over joints of ``MSE(tau_i, y_i)`` (thesis 3.4.1)."""
    y_true = np.asarray(y_true, dtype=np.float64)
    y_pred = np.asarray(y_pred, dtype=np.float64)
    if y_true.shape != y_pred.shape:
        raise ValueError(f"shapes differ: y_true {y_true.shape}, y_pred {y_pred.shape}")
    return float(((y_true - y_pred) ** 2).mean(axis=0).sum())

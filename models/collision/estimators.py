"""GP estimators of the motor currents for collision detection: PP, SP and FC (thesis 4.4-4.5).

Glossary (thesis chapter 4; one independent GP per joint ``i``, targets the motor currents)
-----------------------------------------------------------------------------------------
``M_eq(q) qdd + C(q, qd) qd + g(q) - tau_eps - tau_e + B_eq qd = K_eq i`` (eq. 4.4)
    the arm plus its motors: ``M_eq = M + K_r^2 J_m``, ``K_eq = K_tau K_r``; ``tau_e`` is the
    external (collision) torque, ``tau_eps`` the friction.
``phi_i(x) = [phi_d_i(x), sign(qd_i), qd_i]`` (eq. 4.6)
    the nominal rigid-body regressor row of joint ``i`` (with the rotor-inertia column
    ``qdd_i``) plus the kinetic-friction features, Coulomb ``F_k sign(qd_i)`` and viscous
    ``F_v qd_i`` (blocks ``rigid, armature, coulomb, viscous`` of
    :class:`~mcpilco.models.inverse_dynamics.RigidBodyFeatures`); ``sign(qd_i)`` is evaluated
    as ``tanh(qd_i / 1e-4)`` (:data:`COULOMB_VELOCITY`: 0 on a stuck joint).
PP (eq. 4.7)
    ``k_i(x, x') = phi_i(x)^T Sigma_i phi_i(x')``: a Bayesian linear model of the currents.
SP (eq. 3.7 with the PP part of eq. 4.7)
    PP ``+ k_RBF(x, x')`` on ``x = [q, qd, qdd]``.
FC (eqs. 4.8-4.10, "SP with non-parametric friction compensation")
    ``k_i(x, x') = phi_i(x)^T Sigma_i phi_i(x') + a_i(x) k_RBF(x_bar, x_bar') a_i(x')`` with the
    gate ``a_i(x) = 1{|qd_i| < sigma_v}`` and ``x_bar = [q, qd, qdd, e_q, ed_q, i_c]``: the RBF
    component acts only while joint ``i`` is quasi-static, where the controller's errors and
    command carry the history that stiction leaves in the current (thesis Fig. 4.1).
``i_hat``
    posterior mean of the GP of the currents, trained on collision-free data; the monitoring
    signal is ``s = i - i_hat`` (:mod:`mcpilco.models.collision.detector`).

All three take :class:`~mcpilco.models.collision.inputs.CollisionInputs` (or a
``Trajectories`` / arrays, see that module) and currents ``i`` ``(N, n)`` [A]; ``predict``
returns ``(mean, var)`` ``(N, n)`` with ``var`` the latent variance (noise variance in
``noise_variance_``). Hyperparameters by marginal likelihood on ``hyper_points`` random rows,
then the GP is conditioned on all rows (:class:`~mcpilco.models.inverse_dynamics.
GPInverseDynamics`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import gpytorch
import numpy as np
import torch
from numpy.typing import NDArray
from torch import Tensor

from mcpilco.models.collision.inputs import (
    CollisionInputs,
    as_collision_inputs,
    quasi_static_gate,
)
from mcpilco.models.gp import dense_covar
from mcpilco.models.inverse_dynamics import (
    PPEstimator,
    RowLinearKernel,
    SPEstimator,
    as_targets,
    load_pinocchio_model,
    rbf_kernel,
)
from mcpilco.models.robot_data import Trajectories
from mcpilco.models.robot_files import read_robot_file
from mcpilco.models.torch_files import load_torch_bytes, load_torch_file

FloatArray = NDArray[np.float64]

__all__ = [
    "COULOMB_VELOCITY",
    "ESTIMATORS",
    "FRICTION_BLOCKS",
    "SIGMA_V",
    "CurrentEstimator",
    "FCCurrentEstimator",
    "GatedKernel",
    "PPCurrentEstimator",
    "SPCurrentEstimator",
    "load_estimator",
    "make_estimator",
    "rmse_split",
    "select_sigma_v",
]

FRICTION_BLOCKS: tuple[str, ...] = ("rigid", "armature", "viscous", "coulomb")
"""Feature blocks of ``phi_i`` (eq. 4.6): regressor, rotor inertia, ``qd_i``, ``sign(qd_i)``."""

SIGMA_V = 1e-2
"""Default quasi-static velocity threshold ``sigma_v`` [rad/s] (the thesis's CV value)."""

COULOMB_VELOCITY = 1e-4
"""[rad/s] The Coulomb feature's ``sign(qd_i)`` is ``tanh(qd_i / 1e-4)``: 0 on a stuck joint, whose
simulated creep would otherwise leak the stiction torque's direction. ``0`` = exact sign."""

_FORMAT = "mcpilco.collision.CurrentEstimator/1"


class GatedKernel(gpytorch.kernels.Kernel):
    r"""A kernel switched on and off per output by a 0/1 gate column (thesis eq. 4.10).

    .. math::

        k_b(\mathbf x, \mathbf x') = a_b(\mathbf x)\, k_{base,b}(\mathbf x, \mathbf x')\,
        a_b(\mathbf x'),

    the "vertical rescaling" of ``k_base`` by ``a_b``: a GP ``f`` with kernel ``k_base`` times
    ``a_b(x)``. Batch element ``b`` (the GP of joint ``b``) reads its gate from input column
    ``gate_dims[b]``, which holds ``a_b(x)`` (:func:`~mcpilco.models.collision.inputs.
    quasi_static_gate`); ``base_kernel`` picks its own columns with its ``active_dims``.

    Args:
        base_kernel: kernel with batch shape ``[n]`` (e.g. ``ScaleKernel(RBFKernel)``).
        gate_dims: the ``n`` gate columns, one per output.
        batch_shape: ``torch.Size([n])``.
    """

    def __init__(
        self,
        base_kernel: gpytorch.kernels.Kernel,
        gate_dims: Sequence[int],
        batch_shape: torch.Size,
    ) -> None:
        gate_dims = [int(d) for d in gate_dims]
        n = len(gate_dims)
        if tuple(batch_shape) != (n,):
            raise ValueError(
                f"GatedKernel needs batch_shape=torch.Size([{n}]) (one gate column per output), "
                f"got {tuple(batch_shape)}"
            )
        super().__init__(batch_shape=batch_shape)
        self.base_kernel = base_kernel
        self.register_buffer("gate_index", torch.tensor(gate_dims, dtype=torch.long))
        self.register_buffer("gate_mask", torch.eye(n).unsqueeze(-2))  # (n, 1, n)

    def gates(self, x: Tensor) -> Tensor:
        """``(..., n, N)``: ``a_b`` of every row for every output ``b``."""
        g = x.index_select(-1, self.gate_index.to(x.device))  # (..., N, n)
        if g.dim() >= 3 and g.shape[-3] == g.shape[-1]:  # batched like the kernel
            return (g * self.gate_mask.to(g)).sum(-1)
        return g.movedim(-1, -2)

    def forward(
        self, x1: Tensor, x2: Tensor, diag: bool = False, last_dim_is_batch: bool = False, **params
    ) -> Tensor:
        if last_dim_is_batch:
            raise NotImplementedError("GatedKernel does not support last_dim_is_batch=True")
        k = dense_covar(self.base_kernel, x1, x2, diag=diag)
        g1, g2 = self.gates(x1), self.gates(x2)
        if diag:
            return k * g1 * g2
        return k * g1.unsqueeze(-1) * g2.unsqueeze(-2)


def _model_text(model: Any) -> str | None:
    """MJCF/URDF text of ``model`` when it is text or a path (kept for :meth:`save`)."""
    if isinstance(model, str) and "<" in model:
        return model
    try:
        path = Path(model)
        if path.exists():
            return read_robot_file(path)  # includes expanded, confined to its folder
    except (TypeError, OSError):
        pass
    return None


def _current_targets(y: Any, X: Any, n_rows: int, n_joints: int) -> FloatArray:
    """Motor currents ``(N, n)``: ``y``, or the ``i`` group of a robot log ``X``
    (``Trajectories``)."""
    if y is None:
        if isinstance(X, Trajectories):
            if X.i is None:
                raise ValueError(
                    f"the dataset has no motor-current columns i1..i{n_joints}; the collision "
                    "estimators model the currents"
                )
            y = X.i
        elif isinstance(X, Mapping) and X.get("i") is not None:
            y = X["i"]
        else:
            raise ValueError("give the motor currents y (N, n) [A] or a dataset with i1..in")
    return as_targets(y, None, n_rows, n_joints)


class CurrentEstimator:
    """Mixin: fit / predict on :class:`CollisionInputs`, currents as targets, save / load.

    ``fit(X, y=None)`` accepts a robot log (``Trajectories``; targets: its ``i`` columns), a
    mapping of group arrays or an ``(N, 3n)`` / ``(N, 6n)`` array with currents ``y``
    ``(N, n)`` [A].
    The rows the GP is conditioned on are kept (``train_inputs_``, ``train_targets_``) so
    that :meth:`save` writes a small file (inputs and hyperparameters, not the Gram matrix).
    """

    requires_controller = False
    name = "current"

    def _init_source(self, model: Any) -> None:
        self.model_text = _model_text(model)

    def fit(self, X: Any, y: Any = None) -> CurrentEstimator:
        """Fit on collision-free inputs ``X`` and currents ``y`` (see the class docstring).

        Raises:
            ValueError: a missing column group (named), NaN/inf, mismatched shapes.
        """
        inputs = as_collision_inputs(X, self.n_joints, self.requires_controller)
        targets = _current_targets(y, X, inputs.n_samples, inputs.n_joints)
        self.n_joints_ = inputs.n_joints
        self._fit(inputs, targets)
        self.train_inputs_, self.train_targets_ = inputs, targets
        return self

    def predict(self, X: Any, return_var: bool = True) -> tuple[FloatArray, FloatArray | None]:
        """``(i_hat, var)``: posterior mean and latent variance ``(N, n)`` at ``X``.

        ``return_var=False`` skips the variance (``None``), which dominates the cost for
        large conditioning sets.
        """
        if getattr(self, "n_joints_", None) is None:
            raise RuntimeError(f"{type(self).__name__} is not fitted; call fit(X, y) first")
        inputs = as_collision_inputs(X, self.n_joints_, self.requires_controller)
        if return_var:
            mean, var = self._predict(inputs)
            return np.asarray(mean, dtype=np.float64), np.asarray(var, dtype=np.float64)
        Z = self.gp_inputs(inputs)
        chunks = [
            self.gp_.predict_mean(Z[k : k + self.predict_chunk]).numpy()
            for k in range(0, Z.shape[0], self.predict_chunk)
        ]
        return np.concatenate(chunks).astype(np.float64), None

    def config(self) -> dict[str, Any]:
        """Constructor arguments (JSON-serialisable) that :func:`load_estimator` replays."""
        return dict(
            blocks=list(self.features.blocks),
            coulomb_velocity=self.features.coulomb_velocity,
            noise_init=self.noise_init,
            noise_min=self.noise_min,
            predict_chunk=self.predict_chunk,
        )

    def save(self, path: Any) -> None:
        """Write the estimator (nominal model text, config, conditioned rows, hyperparameters).

        Raises:
            RuntimeError: not fitted.
            ValueError: the nominal model was given as a ``pinocchio.Model`` (no text to save);
                build the estimator from MJCF/URDF text or a file path instead.
        """
        if getattr(self, "gp_", None) is None:
            raise RuntimeError("fit the estimator before saving it")
        if self.model_text is None:
            raise ValueError(
                "cannot save an estimator built from a pinocchio.Model; pass the MJCF/URDF "
                "text or path as `model`"
            )
        x = self.train_inputs_
        arrays = {
            g: torch.as_tensor(getattr(x, g))
            for g in ("q", "qd", "qdd", "e_q", "e_qd", "i_cmd")
            if getattr(x, g) is not None
        }
        payload = {
            "format": _FORMAT,
            "name": self.name,
            "model_text": self.model_text,
            "config": self.config(),
            "inputs": arrays,
            "targets": torch.as_tensor(self.train_targets_),
            "state_dict": self.gp_.model_.state_dict(),
        }
        torch.save(payload, path)


class PPCurrentEstimator(CurrentEstimator, PPEstimator):
    """PP: linear kernel on ``phi_i`` with the kinetic-friction features (thesis eq. 4.7).

    Args:
        model: NOMINAL robot: MJCF/URDF text or path (``pinocchio.Model`` works but cannot be
            saved).
        blocks: feature blocks (default :data:`FRICTION_BLOCKS`).
        coulomb_velocity: smoothing of ``sign(qd_i)`` (:data:`COULOMB_VELOCITY`; 0 = exact).
        **kwargs: GP options of :class:`~mcpilco.models.inverse_dynamics.GPInverseDynamics`
            (``hyper_points``, ``adam_iters``, ``lbfgs_iters``, ``seed``, ...).
    """

    name = "PP"

    def __init__(
        self,
        model: Any,
        blocks: Sequence[str] = FRICTION_BLOCKS,
        coulomb_velocity: float = COULOMB_VELOCITY,
        **kwargs: Any,
    ) -> None:
        self._init_source(model)
        super().__init__(load_pinocchio_model(model), blocks, coulomb_velocity, **kwargs)


class SPCurrentEstimator(CurrentEstimator, SPEstimator):
    """SP: PP (eq. 4.7) plus an RBF kernel on ``x = [q, qd, qdd]`` (eq. 3.7).

    Args: as :class:`PPCurrentEstimator`, plus ``rbf_outputscale_init`` (standardised units).
    """

    name = "SP"

    def __init__(
        self,
        model: Any,
        blocks: Sequence[str] = FRICTION_BLOCKS,
        coulomb_velocity: float = COULOMB_VELOCITY,
        rbf_outputscale_init: float = 0.1,
        **kwargs: Any,
    ) -> None:
        self._init_source(model)
        super().__init__(
            load_pinocchio_model(model), blocks, coulomb_velocity, rbf_outputscale_init, **kwargs
        )

    def config(self) -> dict[str, Any]:
        return {**super().config(), "rbf_outputscale_init": self.rbf_outputscale_init}


class FCCurrentEstimator(CurrentEstimator, PPEstimator):
    """FC: PP plus a quasi-static-gated RBF on ``x_bar`` (thesis eqs. 4.8-4.10).

    GP input row: ``[x_bar (6n), phi_1 .. phi_n (n p), a_1 .. a_n (n)]``; ``x_bar`` and
    ``phi`` standardised here (mean / std over the training rows), the gates stay 0/1.
    Kernel of joint ``b``: ``RowLinearKernel`` on ``phi_b`` plus
    ``GatedKernel(ScaleKernel(RBF-ARD on x_bar))`` gated by ``a_b``.

    Initial RBF lengthscales (the ARD marginal likelihood over ``6n`` dimensions has many
    local optima, so the start matters): in the GP of joint ``b``, joint ``b``'s own columns
    (``q_b, qd_b, qdd_b, e_q_b, ed_q_b, i_c_b``) start at :attr:`OWN_LENGTHSCALE` times their
    spread over the rows where joint ``b`` is quasi-static relative to their spread over all
    rows (the gated RBF sees only those rows, and ``e_q`` at rest spreads ~100x less than in
    motion); the other joints' columns start at :attr:`OTHER_LENGTHSCALE`.

    Args:
        model, blocks, coulomb_velocity: as :class:`PPCurrentEstimator`.
        sigma_v: quasi-static threshold [rad/s] of the gate (thesis ``1e-2``;
            :func:`select_sigma_v` picks it by cross-validation).
        rbf_outputscale_init: initial RBF output scale (standardised units).
        rbf_lengthscale_init: one initial lengthscale for every column instead of the
            structured start above (``None``).
        **kwargs: GP options (``standardize_x`` is fixed: this class standardises itself).

    Fitted: ``x_mean_``, ``x_scale_`` (standardisation of ``[x_bar, phi]``),
    ``lengthscale_init_`` ``(n, 6n)``.
    """

    name = "FC"
    requires_controller = True
    OWN_LENGTHSCALE = 1.0
    """Initial lengthscale of a joint's own columns, in units of their quasi-static spread."""
    OTHER_LENGTHSCALE = 3.0
    """Initial lengthscale of the other joints' columns (standardised units)."""

    def __init__(
        self,
        model: Any,
        blocks: Sequence[str] = FRICTION_BLOCKS,
        coulomb_velocity: float = COULOMB_VELOCITY,
        sigma_v: float = SIGMA_V,
        rbf_outputscale_init: float = 0.1,
        rbf_lengthscale_init: float | None = None,
        **kwargs: Any,
    ) -> None:
        if kwargs.pop("standardize_x", False):
            raise ValueError("FCCurrentEstimator standardises its own inputs; drop standardize_x")
        quasi_static_gate(np.zeros(1), sigma_v)  # validates sigma_v
        self.sigma_v = float(sigma_v)
        self.rbf_outputscale_init = float(rbf_outputscale_init)
        self.rbf_lengthscale_init = rbf_lengthscale_init
        self._init_source(model)
        super().__init__(
            load_pinocchio_model(model), blocks, coulomb_velocity, standardize_x=False, **kwargs
        )

    def config(self) -> dict[str, Any]:
        return {
            **super().config(),
            "sigma_v": self.sigma_v,
            "rbf_outputscale_init": self.rbf_outputscale_init,
            "rbf_lengthscale_init": self.rbf_lengthscale_init,
        }

    def _raw(self, states: CollisionInputs) -> FloatArray:
        return np.concatenate([states.augmented(), self.features.flat_features(states)], axis=1)

    def _fit(self, states: CollisionInputs, y: FloatArray) -> None:
        raw = self._raw(states)
        n = states.n_joints
        std = raw.std(axis=0)
        self.x_mean_ = raw.mean(axis=0)
        self.x_scale_ = np.where(std > 0, std, 1.0)
        # initial RBF lengthscales of joint i's GP: its own x_bar columns (e_q_i, i_c_i, ...)
        # at their spread over the rows where joint i is quasi-static (the only rows its gated
        # RBF sees; e_q at rest spreads ~100x less than in motion), the other joints' columns
        # at OTHER_LENGTHSCALE (standardised units)
        gate = quasi_static_gate(states.qd, self.sigma_v).astype(bool)
        ls = np.full((n, 6 * n), self.OTHER_LENGTHSCALE)
        for i in range(n):
            cols = np.arange(i, 6 * n, n)
            rows = raw[gate[:, i]][:, cols]
            ratio = rows.std(axis=0) / self.x_scale_[cols] if rows.shape[0] >= 2 else 1.0
            ls[i, cols] = np.clip(ratio, 1e-3, 1.0) * self.OWN_LENGTHSCALE
        self.lengthscale_init_ = ls
        super()._fit(states, y)

    def gp_inputs(self, states: CollisionInputs) -> FloatArray:
        raw = (self._raw(states) - self.x_mean_) / self.x_scale_
        return np.concatenate([raw, quasi_static_gate(states.qd, self.sigma_v)], axis=1)

    def kernel(self, batch_shape: torch.Size, n_joints: int) -> gpytorch.kernels.Kernel:
        aug = 6 * n_joints
        p = self.features.n_features
        pp_dims = tuple(range(aug, aug + n_joints * p))
        gate_dims = range(aug + n_joints * p, aug + n_joints * p + n_joints)
        pp = RowLinearKernel(n_joints, p, batch_shape=batch_shape, active_dims=pp_dims)
        rbf = rbf_kernel(aug, batch_shape, active_dims=range(aug))
        rbf.outputscale = self.rbf_outputscale_init
        ls = self.rbf_lengthscale_init
        if ls is None:
            ls = torch.as_tensor(self.lengthscale_init_).reshape(n_joints, 1, aug)
        rbf.base_kernel.lengthscale = ls
        return pp + GatedKernel(rbf, gate_dims, batch_shape)


ESTIMATORS: dict[str, type[CurrentEstimator]] = {
    "PP": PPCurrentEstimator,
    "SP": SPCurrentEstimator,
    "FC": FCCurrentEstimator,
}
"""The three estimators of the thesis's comparison (section 4.6), by name."""


def make_estimator(name: str, model: Any, **kwargs: Any) -> CurrentEstimator:
    """``"PP"``, ``"SP"`` or ``"FC"`` (:data:`ESTIMATORS`) on the nominal ``model``."""
    if name not in ESTIMATORS:
        raise ValueError(f"estimator must be one of {sorted(ESTIMATORS)}, got {name!r}")
    return ESTIMATORS[name](model, **kwargs)


def load_estimator(source: Any) -> CurrentEstimator:
    """Rebuild an estimator written by :meth:`CurrentEstimator.save` (a path, file object or
    bytes): the GP is conditioned again on the saved rows at the saved hyperparameters."""
    remedy = "save the estimator again (CurrentEstimator.save)"
    if isinstance(source, bytes | bytearray):
        what, data = "current-estimator data", bytes(source)
    elif isinstance(source, str | Path):
        what, data = f"current-estimator file {source}", None
    else:
        what, data = "current-estimator data", source.read()
    if data is None:
        payload = load_torch_file(source, "current-estimator file", remedy)
    else:
        payload = load_torch_bytes(data, what, remedy)
    problem = _estimator_problem(payload)
    if problem is not None:
        raise ValueError(f"{what} does not match its format: {problem}; {remedy}")
    name = payload["name"]
    try:
        est = make_estimator(
            name, payload["model_text"], adam_iters=0, lbfgs_iters=0, **payload["config"]
        )
        inputs = CollisionInputs(**{g: v.numpy() for g, v in payload["inputs"].items()})
        est.fit(inputs, payload["targets"].numpy())
        est.gp_.model_.load_state_dict(payload["state_dict"])
    except (RuntimeError, TypeError, KeyError, IndexError) as err:
        first = " ".join(str(err).split())[:160]
        raise ValueError(
            f"{what}: the saved {name} estimator cannot be rebuilt ({first})"
        ) from None
    est.gp_.model_.eval()
    return est


MAX_SAVED_ROWS = 1_000_000  # most conditioning rows an estimator file may hold
_INPUT_GROUPS = ("q", "qd", "qdd", "e_q", "e_qd", "i_cmd")  # input groups of a saved estimator
_CONFIG_KEYS = {
    "blocks",
    "coulomb_velocity",
    "noise_init",
    "noise_min",
    "predict_chunk",
    "rbf_outputscale_init",
    "rbf_lengthscale_init",
    "sigma_v",
}  # constructor arguments a saved estimator may replay (CurrentEstimator.config)


def _estimator_problem(payload: Any) -> str | None:
    """What in a loaded estimator payload does not match the format of
    :meth:`CurrentEstimator.save` (None: nothing): the format tag, a known estimator name,
    the model text, the constructor config's keys, equally long finite 2-D input and target
    tensors of at most :data:`MAX_SAVED_ROWS` rows, a state dict of tensors."""
    if not isinstance(payload, dict) or payload.get("format") != _FORMAT:
        return "not a collision current-estimator file (written by CurrentEstimator.save)"
    if payload.get("name") not in ESTIMATORS:
        return f"estimator name is not one of {sorted(ESTIMATORS)}"
    if not isinstance(payload.get("model_text"), str) or "<" not in payload["model_text"]:
        return "no nominal robot description text"
    config = payload.get("config")
    if not isinstance(config, dict) or not set(config) <= _CONFIG_KEYS:
        return f"config is not a mapping of {sorted(_CONFIG_KEYS)}"
    inputs, targets = payload.get("inputs"), payload.get("targets")
    if not isinstance(inputs, dict) or not inputs or not set(inputs) <= set(_INPUT_GROUPS):
        return f"inputs are not a mapping of {_INPUT_GROUPS}"
    arrays = [*inputs.values(), targets]
    if not all(isinstance(a, Tensor) and a.ndim == 2 and a.is_floating_point() for a in arrays):
        return "inputs and targets are not 2-D float tensors"
    if len({a.shape for a in arrays}) != 1 or not 1 <= len(targets) <= MAX_SAVED_ROWS:
        return f"inputs and targets are not of one shape with 1..{MAX_SAVED_ROWS} rows"
    if not all(bool(torch.isfinite(a).all()) for a in arrays):
        return "inputs or targets hold NaN or inf"
    state = payload.get("state_dict")
    if not isinstance(state, dict) or not all(isinstance(v, Tensor) for v in state.values()):
        return "state_dict is not a mapping of tensors"
    return None


def rmse_split(i: Any, i_hat: Any, qd: Any, sigma_v: float = SIGMA_V) -> dict[str, FloatArray]:
    """RMSE of ``i_hat`` per joint on quasi-static (``|qd_j| < sigma_v``) and dynamic samples.

    ``RMSE_j = sqrt(mean_k (i_j(t_k) - i_hat_j(t_k))^2)`` over the samples of each regime
    (thesis section 4.6, Fig. 4.2); the regime is judged per joint.

    Returns:
        ``{"quasi_static": (n,), "dynamic": (n,), "all": (n,), "n_quasi_static": (n,),
        "n_dynamic": (n,)}`` (NaN where a regime has no samples).
    """
    i, i_hat, qd = (np.asarray(a, dtype=np.float64) for a in (i, i_hat, qd))
    if not (i.shape == i_hat.shape == qd.shape) or i.ndim != 2:
        raise ValueError(
            f"i, i_hat and qd must be (N, n) arrays of one shape, got {i.shape}, {i_hat.shape}, "
            f"{qd.shape}"
        )
    gate = quasi_static_gate(qd, sigma_v).astype(bool)
    sq = (i - i_hat) ** 2

    def masked(mask: NDArray[np.bool_]) -> FloatArray:
        count = mask.sum(0)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(count > 0, np.sqrt((sq * mask).sum(0) / np.maximum(count, 1)), np.nan)

    return {
        "quasi_static": masked(gate),
        "dynamic": masked(~gate),
        "all": np.sqrt(sq.mean(0)),
        "n_quasi_static": gate.sum(0).astype(np.float64),
        "n_dynamic": (~gate).sum(0).astype(np.float64),
    }


def select_sigma_v(
    factory: Callable[[float], CurrentEstimator],
    train: Any,
    train_i: Any,
    validation: Any,
    validation_i: Any,
    candidates: Sequence[float] = (3e-3, 1e-2, 3e-2, 1e-1),
    progress: bool = False,
) -> tuple[float, dict[float, float]]:
    """Pick ``sigma_v`` by hold-out cross-validation (thesis 4.4.2: ``sigma_v`` "can be
    identified by cross-validation, measuring the out of sample performance").

    For every candidate an estimator ``factory(sigma_v)`` is fitted on ``train`` and scored by
    the validation error summed over joints, ``sum_j mean_k (i_j - i_hat_j)^2`` [A^2].

    Returns:
        ``(best sigma_v, {sigma_v: score})``.
    """
    if not candidates:
        raise ValueError("give at least one sigma_v candidate")
    val_y = np.asarray(validation_i, dtype=np.float64)
    scores: dict[float, float] = {}
    iterator: Any = candidates
    if progress:
        from tqdm.auto import tqdm

        iterator = tqdm(candidates, desc="sigma_v CV", leave=False)
    for sv in iterator:
        est = factory(float(sv)).fit(train, train_i)
        mean, _ = est.predict(validation)
        scores[float(sv)] = float(((val_y - mean) ** 2).mean(0).sum())
    best = min(scores, key=scores.get)
    return best, scores

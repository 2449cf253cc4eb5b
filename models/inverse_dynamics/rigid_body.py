"""Rigid-body regressor features (pinocchio) and the Fisherian estimator (FE) (thesis eq. 3.2).

Glossary (thesis section 3.2)
-----------------------------
``tau = M(q) qdd + C(q, qd) qd + g(q) = Phi(q, qd, qdd) w``
    rigid-body inverse dynamics, linear in the dynamic parameters ``w`` (eq. 3.2); ``Phi``
    is the joint-torque regressor, ``(n, 10 n_b)``: pinocchio's
    ``computeJointTorqueRegressor`` with the parameters of each body ordered
    ``[m, m c_x, m c_y, m c_z, I_xx, I_xy, I_yy, I_xz, I_yz, I_zz]`` (inertia about the joint
    frame origin). ``Phi`` is built from the NOMINAL kinematics of the model given here; a real
    robot whose kinematics differ gives *model bias*.
``phi_i(x)``
    row ``i`` of the feature matrix: the regressor row of joint ``i`` plus optional
    joint-local columns, one *block* each (:data:`FEATURE_BLOCKS`):

    ========== ===================================  ==================================
    block      column of row ``i`` (per joint)      parameter
    ========== ===================================  ==================================
    rigid      ``Phi_i(q, qd, qdd)`` (``10 n_b``)     inertial parameters ``w``
    armature   ``qdd_i`` (column ``i``; 0 in others)  reflected rotor inertia ``K_r^2 J_m``
    viscous    ``qd_i``                               viscous friction ``F_v``
    coulomb    ``sign(qd_i)``                         Coulomb friction ``F_c``
    ========== ===================================  ==================================

    Joint-local blocks contribute ``n`` columns each, non-zero only in row ``i`` (so one
    parameter per joint): ``features(...)`` returns ``(N, n, p)`` with
    ``p = 10 n_b + n * len(local blocks)``.
FE
    ``w_hat = argmin ||tau - Phi w||^2`` over the stacked rows (minimum-norm least squares:
    only the identifiable combinations, the base parameters, are determined);
    prediction ``Phi(x) w_hat``; its variance ``sigma^2 phi (Phi^T Phi)^+ phi^T`` with
    ``sigma^2`` the residual variance of each joint.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mcpilco.models.inverse_dynamics.base import InverseDynamicsEstimator
from mcpilco.models.inverse_dynamics.inputs import JointStates
from mcpilco.models.robot_files import read_robot_file, refuse_includes

FloatArray = NDArray[np.float64]

__all__ = [
    "FEATURE_BLOCKS",
    "LOCAL_BLOCKS",
    "FisherianEstimator",
    "RigidBodyFeatures",
    "load_pinocchio_model",
    "pseudo_inertia",
]

FEATURE_BLOCKS: tuple[str, ...] = ("rigid", "armature", "viscous", "coulomb")
"""Feature blocks of :class:`RigidBodyFeatures`, in column order."""

LOCAL_BLOCKS: tuple[str, ...] = ("armature", "viscous", "coulomb")
"""Joint-local blocks (one column per joint, non-zero only in that joint's row)."""


def _import_pinocchio() -> Any:
    try:
        import pinocchio
    except ImportError as err:  # pragma: no cover - pin is a dependency
        raise ImportError(
            "the model-based estimators need pinocchio: pip install pin (PyPI name)"
        ) from err
    return pinocchio


def load_pinocchio_model(source: Any) -> Any:
    """A ``pinocchio.Model`` from a model, an MJCF/URDF file path, or MJCF/URDF text.

    Args:
        source: a ``pinocchio.Model`` (returned as is); a path to ``.xml`` (MJCF) or
            ``.urdf`` file; or the text of an MJCF (``<mujoco ...>``) or URDF
            (``<robot ...>``) document.

    Raises:
        TypeError: an unsupported type.
        ValueError: text that is neither MJCF nor URDF, or a missing file.
    """
    pin = _import_pinocchio()
    if isinstance(source, pin.Model):
        return source
    if isinstance(source, Path) or (
        isinstance(source, str) and "<" not in source and len(source) < 4096
    ):
        path = Path(source)
        if not path.exists():
            raise ValueError(f"no robot description at {path}; give an MJCF/URDF path or text")
        text = read_robot_file(path)  # includes expanded, confined to the model's folder
        expanded = text != path.read_text()
        try:
            if "<robot" in text:
                return pin.buildModelFromUrdf(str(path))
            if "<mujoco" in text and not expanded:
                return with_mujoco_inertias(pin.buildModelFromMJCF(str(path)), path=path)
        except RuntimeError as err:
            raise ValueError(f"pinocchio cannot build the robot in {path}: {err}") from err
        if "<mujoco" not in text:
            raise ValueError(f"{path} is neither MJCF (<mujoco>) nor URDF (<robot>)")
        source = text  # the includes expanded: built from the text
    if isinstance(source, str):
        refuse_includes(source, "the robot description text")
        if "<robot" in source:
            try:
                return pin.buildModelFromXML(source)
            except RuntimeError as err:
                raise ValueError(f"pinocchio cannot build the URDF robot: {err}") from err
        if "<mujoco" in source:
            # pinocchio's MJCF importer reads files only
            fd, name = tempfile.mkstemp(suffix=".xml")
            try:
                with os.fdopen(fd, "w") as fh:
                    fh.write(source)
                return with_mujoco_inertias(pin.buildModelFromMJCF(name), text=source)
            except RuntimeError as err:  # named after the text, not the temporary file
                msg = " ".join(str(err).replace(name, "<MJCF text>").split())
                raise ValueError(f"pinocchio cannot build the MJCF robot: {msg}") from err
            finally:
                os.unlink(name)
        raise ValueError("robot description text must be MJCF (<mujoco>) or URDF (<robot>)")
    raise TypeError(
        f"give a pinocchio.Model, an MJCF/URDF path or text, got {type(source).__name__}"
    )


MUJOCO_MATCH_RTOL = 1e-6
"""Relative agreement with ``mj_inverse`` that an MJCF model read by pinocchio must reach."""


def with_mujoco_inertias(model: Any, path: Path | None = None, text: str | None = None) -> Any:
    """``model`` (read from an MJCF by pinocchio) with every link's inertia as MuJoCo compiles
    it, where the two disagree.

    Pinocchio's MJCF importer does not apply every rule of the format (a ``<default>``
    class's geom ``mass``, for one, is read as the density's mass), while MuJoCo defines
    what the file means. When each MuJoCo body but the world carries exactly one joint, in
    the order of pinocchio's joints, link ``i`` gets MuJoCo's mass, centre of mass and
    inertia of joint ``i``'s body (expressed in the joint frame, the body frame shifted by
    the joint's ``pos``). The result is kept only if its inverse dynamics then equal MuJoCo's
    ``mj_inverse`` (passive forces and constraints switched off) within
    :data:`MUJOCO_MATCH_RTOL` on random states; otherwise ``model`` is returned as read."""
    import mujoco

    pin = _import_pinocchio()
    try:
        mj = (
            mujoco.MjModel.from_xml_path(str(path))
            if path is not None
            else mujoco.MjModel.from_xml_string(text)
        )
    except (ValueError, TypeError):
        return model
    hinge_slide = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
    if (
        mj.njnt != model.njoints - 1
        or mj.nbody != mj.njnt + 1
        or any(int(t) not in hinge_slide for t in mj.jnt_type)
        or any(int(n) != 1 for n in mj.body_jntnum[1:])
    ):
        return model
    aligned = model.copy()
    for i in range(1, model.njoints):
        j = i - 1
        b = int(mj.jnt_bodyid[j])
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, mj.body_iquat[b])
        rot = rot.reshape(3, 3)
        inertia_c = rot @ np.diag(mj.body_inertia[b]) @ rot.T
        com = np.asarray(mj.body_ipos[b]) - np.asarray(mj.jnt_pos[j])
        aligned.inertias[i] = pin.Inertia(float(mj.body_mass[b]), com, inertia_c)
    data = mujoco.MjData(mj)
    mj.dof_damping[:] = 0.0
    mj.jnt_stiffness[:] = 0.0
    mj.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)
    rng = np.random.default_rng(0)
    err_aligned, err_read, scale = 0.0, 0.0, 1e-9
    for _ in range(5):
        q, qd, qdd = (rng.uniform(-1.0, 1.0, mj.nv) for _ in range(3))
        data.qpos[:], data.qvel[:], data.qacc[:] = q, qd, qdd
        mujoco.mj_inverse(mj, data)
        ref = np.array(data.qfrc_inverse)
        scale = max(scale, float(np.abs(ref).max()))
        for m, name in ((aligned, "a"), (model, "r")):
            tau = pin.rnea(m, m.createData(), q, qd, qdd)
            e = float(np.abs(tau - ref).max())
            if name == "a":
                err_aligned = max(err_aligned, e)
            else:
                err_read = max(err_read, e)
    if err_aligned <= MUJOCO_MATCH_RTOL * scale and err_aligned < err_read:
        return aligned
    return model


def pseudo_inertia(phi: FloatArray) -> FloatArray:
    """The ``4 x 4`` pseudo-inertia matrix of one body's parameters ``phi`` (pinocchio's
    order ``[m, h_x, h_y, h_z, I_xx, I_xy, I_yy, I_xz, I_yz, I_zz]``, ``h = m c``, ``I``
    about the frame origin):

    .. math::

        J = \\begin{bmatrix} \\Sigma & h \\\\ h^\\top & m \\end{bmatrix},\\qquad
        \\Sigma = \\int r r^\\top dm = \\tfrac12 \\operatorname{tr}(I) 1_3 - I .

    ``phi`` belongs to a physical body (positive mass, an inertia about the centre of mass
    that is positive definite and obeys the triangle inequalities) exactly when ``J`` is
    positive definite (Wensing, Kim & Slotine 2017).

    Raises:
        ValueError: ``phi`` is not 10 values.
    """
    phi = np.asarray(phi, dtype=np.float64)
    if phi.shape != (10,):
        raise ValueError(f"phi must hold the 10 inertial parameters of one body, got {phi.shape}")
    m, h = phi[0], phi[1:4]
    ixx, ixy, iyy, ixz, iyz, izz = phi[4:]
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    out = np.empty((4, 4))
    out[:3, :3] = 0.5 * np.trace(inertia) * np.eye(3) - inertia
    out[:3, 3] = out[3, :3] = h
    out[3, 3] = m
    return out


class RigidBodyFeatures:
    """Per-joint feature rows ``phi_i(q, qd, qdd)`` of the nominal rigid-body model.

    Args:
        model: the NOMINAL robot: ``pinocchio.Model``, MJCF/URDF path or text (see
            :func:`load_pinocchio_model`). Its ``nv`` must equal the number of joints.
        blocks: subset of :data:`FEATURE_BLOCKS` (kept in that order), e.g.
            ``("rigid", "armature")`` or, for collision detection with friction,
            ``("rigid", "armature", "viscous", "coulomb")``.
        coulomb_velocity: ``sign(qd)`` is smoothed to ``tanh(qd / coulomb_velocity)`` when
            > 0 (0 = exact sign).

    Attributes:
        n_joints: ``n``.
        n_features: ``p`` (columns per row).
        feature_names: names of the ``p`` columns.
    """

    def __init__(
        self,
        model: Any,
        blocks: Sequence[str] = ("rigid", "armature"),
        coulomb_velocity: float = 0.0,
    ) -> None:
        pin = _import_pinocchio()
        blocks = tuple(blocks)
        unknown = [b for b in blocks if b not in FEATURE_BLOCKS]
        if unknown or not blocks:
            raise ValueError(f"blocks must be a non-empty subset of {FEATURE_BLOCKS}, got {blocks}")
        if coulomb_velocity < 0:
            raise ValueError(f"coulomb_velocity must be >= 0, got {coulomb_velocity}")
        self.model = load_pinocchio_model(model)
        if self.model.nq != self.model.nv:
            raise ValueError(
                f"only models with nq == nv are supported (revolute/prismatic joints), got "
                f"nq={self.model.nq}, nv={self.model.nv}"
            )
        self.data = self.model.createData()
        self.blocks = tuple(b for b in FEATURE_BLOCKS if b in blocks)
        self.coulomb_velocity = float(coulomb_velocity)
        self.n_joints = int(self.model.nv)
        self.n_bodies = int(self.model.njoints) - 1
        self._pin = pin
        names: list[str] = []
        if "rigid" in self.blocks:
            params = ("m", "mcx", "mcy", "mcz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")
            for b in range(1, self.n_bodies + 1):
                names += [f"{p}_{self.model.names[b]}" for p in params]
        for block in self.blocks:
            if block in LOCAL_BLOCKS:
                names += [f"{block}_{j}" for j in range(1, self.n_joints + 1)]
        self.feature_names = names
        self.n_features = len(names)

    def rigid_regressor(self, states: JointStates) -> FloatArray:
        """``(N, n, 10 n_b)`` joint-torque regressor ``Phi`` at every sample."""
        n = self.n_joints
        out = np.empty((states.n_samples, n, 10 * self.n_bodies))
        reg = self._pin.computeJointTorqueRegressor
        for k in range(states.n_samples):
            out[k] = reg(self.model, self.data, states.q[k], states.qd[k], states.qdd[k])
        return out

    def features(self, states: JointStates) -> FloatArray:
        """``(N, n, p)`` feature rows ``phi_i`` (module docstring)."""
        if states.n_joints != self.n_joints:
            raise ValueError(
                f"the rigid-body model has {self.n_joints} joints but the data {states.n_joints}"
            )
        parts = []
        if "rigid" in self.blocks:
            parts.append(self.rigid_regressor(states))
        eye = np.eye(self.n_joints)
        local = {
            "armature": states.qdd,
            "viscous": states.qd,
            "coulomb": (
                np.tanh(states.qd / self.coulomb_velocity)
                if self.coulomb_velocity > 0
                else np.sign(states.qd)
            ),
        }
        for block in self.blocks:
            if block in LOCAL_BLOCKS:
                # row i holds value_i in column i: (N, n, n) = value[:, :, None] * I
                parts.append(local[block][:, :, None] * eye)
        return np.concatenate(parts, axis=2)

    def flat_features(self, states: JointStates) -> FloatArray:
        """``(N, n p)``: the rows ``phi_1, ..., phi_n`` side by side (GP input layout)."""
        f = self.features(states)
        return f.reshape(f.shape[0], -1)

    def true_parameters(self) -> FloatArray:
        """``(p,)`` parameters of the model itself: inertial parameters of every body, its
        ``armature``, zeros for friction (pinocchio's model holds no friction values)."""
        parts = []
        if "rigid" in self.blocks:
            parts.append(
                np.concatenate(
                    [
                        self.model.inertias[b].toDynamicParameters()
                        for b in range(1, self.n_bodies + 1)
                    ]
                )
            )
        for block in self.blocks:
            if block == "armature":
                parts.append(np.asarray(self.model.armature, dtype=np.float64).copy())
            elif block in LOCAL_BLOCKS:
                parts.append(np.zeros(self.n_joints))
        return np.concatenate(parts)


class FisherianEstimator(InverseDynamicsEstimator):
    """Fisherian estimator (FE): least squares on the nominal regressor (thesis eq. 3.2).

    Args:
        model: nominal robot (``pinocchio.Model`` or MJCF/URDF path/text).
        blocks: feature blocks (:data:`FEATURE_BLOCKS`); add ``"viscous", "coulomb"`` for
            friction.
        rcond: relative cut-off of small singular values in the least squares
            (``numpy.linalg.lstsq``); ``None`` = machine precision x max(N n, p).
        coulomb_velocity: smoothing of ``sign(qd)`` (:class:`RigidBodyFeatures`).

    Fitted attributes: ``parameters_`` ``(p,)``, ``parameter_cov_`` ``(n, p, p)`` (one
    ``sigma_i^2 (Phi^T Phi)^+`` per joint, ``sigma_i^2`` the residual variance of joint
    ``i``), ``residual_variance_`` ``(n,)``, ``gram_pinv_`` ``(p, p)``, ``rank_`` (rank of
    the stacked regressor).

    ``predict`` returns ``(mean, var)`` with ``var`` the variance of ``phi_i w_hat`` (the
    parameter uncertainty; no noise added).
    """

    name = "FE"

    def __init__(
        self,
        model: Any,
        blocks: Sequence[str] = ("rigid", "armature"),
        rcond: float | None = None,
        coulomb_velocity: float = 0.0,
    ) -> None:
        self.features = RigidBodyFeatures(model, blocks, coulomb_velocity)
        self.rcond = rcond
        super().__init__(n_joints=self.features.n_joints)

    def _fit(self, states: JointStates, y: FloatArray) -> None:
        phi = self.features.features(states)  # (N, n, p)
        n_rows, n, p = phi.shape
        a = phi.reshape(n_rows * n, p)
        w, _, rank, _ = np.linalg.lstsq(a, y.reshape(-1), rcond=self.rcond)
        self.parameters_ = w
        self.rank_ = int(rank)
        resid = y - phi @ w
        dof = max(n_rows - rank / n, 1.0)
        self.residual_variance_ = (resid**2).sum(0) / dof
        self.gram_pinv_ = np.linalg.pinv(a.T @ a, rcond=1e-12, hermitian=True)

    @property
    def parameter_cov_(self) -> FloatArray:
        """``(n, p, p)``: ``sigma_i^2 (Phi^T Phi)^+`` for every joint ``i``."""
        return self.residual_variance_[:, None, None] * self.gram_pinv_

    def _predict(self, states: JointStates) -> tuple[FloatArray, FloatArray]:
        phi = self.features.features(states)
        mean = phi @ self.parameters_
        quad = ((phi @ self.gram_pinv_) * phi).sum(-1)  # phi G phi^T per row, via BLAS
        var = np.maximum(quad, 0.0) * self.residual_variance_
        return mean, var

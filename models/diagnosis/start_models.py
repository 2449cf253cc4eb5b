"""Start models of the diagnosis loop: nominal rigid-body physics, or a learned GIP/RBF GP.

=========  ====================================================  ==========================
kind       prior mean ``m_j`` / start kernel ``K_0``              torque ``tau_hat``
=========  ====================================================  ==========================
nominal    ``m = RNEA(q, qd, qdd)`` of the MJCF/URDF (pinocchio;  ``m``
           armature included), ``K_0 = 0``
gip        ``m_j`` = the GP's constant mean, ``K_0`` = the GIP   the GIP posterior mean
           kernel (thesis eq. 3.11) fitted by marginal            (version 0)
           likelihood on the training rows
           (:class:`~mcpilco.models.inverse_dynamics.GIPEstimator`)
rbf        as ``gip`` with an ARD RBF kernel on ``[q, qd, qdd]``  the RBF posterior mean
           (:class:`~mcpilco.models.inverse_dynamics.RBFEstimator`)
=========  ====================================================  ==========================

Both can give the joint-torque regressor of every body (pinocchio's
``computeJointTorqueRegressor``) and the nominal body data for the inertial candidates (every
link's inertia, the payload at the flange) when a robot file is known.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from mcpilco.models.diagnosis.effects import RigidBody
from mcpilco.models.inverse_dynamics import (
    MAX_RIGID_FEATURES,
    ChainEstimator,
    GIPEstimator,
    GPInverseDynamics,
    JointStates,
    LagrangianEstimator,
    NystromGIPEstimator,
    RBFEstimator,
    lagrangian_parameters,
    load_pinocchio_model,
)
from mcpilco.models.robot_files import read_robot_file, refuse_includes

FloatArray = NDArray[np.float64]

__all__ = [
    "LEARNED_STARTS",
    "GIPStart",
    "LearnedStart",
    "NominalStart",
    "RBFStart",
    "StartModel",
    "read_robot_text",
]


def read_robot_text(source: str | Path, include_root: str | Path | None = None) -> str:
    """The MJCF/URDF text of a path (its includes expanded and confined to its folder, or to
    ``include_root``: :func:`mcpilco.models.robot_files.read_robot_file`) or the text itself
    (which may include no file), kept so that a saved model is whole."""
    if isinstance(source, Path) or ("<" not in str(source) and len(str(source)) < 4096):
        path = Path(source)
        if not path.exists():
            raise ValueError(f"no robot description at {path}; give an MJCF (.xml) or URDF file")
        if not path.is_file():
            raise ValueError(f"robot description {path} is not a file; give an MJCF or URDF file")
        text = read_robot_file(path, include_root)
        check_robot_text(text, str(path))
        return text
    check_robot_text(str(source), "the robot description text")
    refuse_includes(str(source), "the robot description text")
    return str(source)


def check_robot_text(text: str, source: str) -> None:
    """Raise ValueError naming ``source`` when ``text`` is empty, not well-formed XML, or
    neither MJCF (``<mujoco>``) nor URDF (``<robot>``)."""
    import xml.etree.ElementTree as ET

    if not text.strip():
        raise ValueError(f"{source} is empty; give an MJCF (.xml) or URDF robot description")
    try:
        root = ET.fromstring(text)
    except ET.ParseError as err:
        raise ValueError(f"{source} is not well-formed XML ({err}); fix or replace it") from err
    if root.tag not in ("mujoco", "robot"):
        raise ValueError(
            f"{source} is neither MJCF (<mujoco>) nor URDF (<robot>): its root is <{root.tag}>"
        )


ALL_ROWS_HYPER_POINTS = 600
"""Rows of the exact hyperparameter fit of a GIP start fitted on every row
(:class:`GIPStart` with ``inducing``)."""
RIGID_BODY_EFFECTS = ("armature", "inertia", "payload")
"""Effect keys whose torques ``GIPStart(span="rigid")`` and ``span="chain"`` span
(rigid-body torques)."""
SPANS = ("auto", "rigid", "chain", "gip")
"""The fits of :class:`GIPStart` (its ``span``)."""
RIGID_SPANS = ("rigid", "chain")
"""Spans of rigid-body torques only: the start's torque is its prior mean, no ``K_0``."""
HYPER_POINTS = 200
"""Training rows on which a learned start fits its kernel's hyperparameters (of the 600 it
is conditioned on by default; :class:`LearnedStart`)."""
MEMO_SIZE = 8
"""State arrays whose RNEA / regressor / learned torque a start model keeps (least recently
used dropped): the loop evaluates the same training and held-out states for every version."""


def _states_key(tag: str, arrays: tuple[FloatArray, ...]) -> tuple:
    """Content key of state arrays (shape and a BLAKE2 digest of the bytes)."""
    h = hashlib.blake2b(digest_size=16)
    for a in arrays:
        a = np.ascontiguousarray(a, dtype=np.float64)
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return tag, h.digest()


def _memo(
    cache: OrderedDict, tag: str, arrays: tuple[FloatArray, ...], compute: Callable[[], Any]
) -> Any:
    """``compute()`` of the states ``arrays``, kept in ``cache`` by content (a copy out, so
    that a caller's change never reaches the cache)."""
    key = _states_key(tag, arrays)
    if key in cache:
        cache.move_to_end(key)
    else:
        cache[key] = compute()
        if len(cache) > MEMO_SIZE:
            cache.popitem(last=False)
    return cache[key].copy()


def _joint_types(model: Any) -> str:
    """``"RRPR"`` from a pinocchio model's joints (revolute R, prismatic P)."""
    out = []
    for j in range(1, model.njoints):
        name = model.joints[j].shortname()
        core = name.replace("JointModel", "")
        if core.startswith(("R", "Revolute")):
            out.append("R")
        elif core.startswith(("P", "Prismatic")):
            out.append("P")
        else:
            raise ValueError(f"joint {j} is a {name}; only revolute and prismatic are supported")
    return "".join(out)


FLANGE_NAMES = ("flange", "ee", "tool0", "attachment_site")
"""Frame names taken as the flange, first match on the last body (else its last site, else
the body's own frame)."""


class _Robot:
    """Pinocchio model of a robot file: RNEA, the joint-torque regressor, the body data."""

    def __init__(self, text: str) -> None:
        import pinocchio

        self._pin = pinocchio
        self.text = text
        self.model = load_pinocchio_model(text)
        if self.model.nq != self.model.nv:
            raise ValueError("only revolute/prismatic joints (nq == nv) are supported")
        self.data = self.model.createData()
        self.n_joints = int(self.model.nv)
        self.joint_types = _joint_types(self.model)
        self._memo: OrderedDict = OrderedDict()

    def check(self, n_joints: int) -> None:
        if n_joints != self.n_joints:
            raise ValueError(
                f"joint count mismatch: the data has {n_joints} joints but the model file has "
                f"{self.n_joints} (nv={self.n_joints})"
            )

    def rnea(self, q: FloatArray, qd: FloatArray, qdd: FloatArray) -> FloatArray:
        """``(N, n)`` inverse dynamics, row by row (kept for repeated states, :func:`_memo`)."""

        def compute() -> FloatArray:
            out = np.empty((q.shape[0], self.n_joints))
            for k in range(q.shape[0]):
                out[k] = self._pin.rnea(self.model, self.data, q[k], qd[k], qdd[k])
            return out

        return _memo(self._memo, "rnea", (q, qd, qdd), compute)

    def regressor(self, q: FloatArray, qd: FloatArray, qdd: FloatArray) -> FloatArray:
        """``(N, n, 10 n_b)``: the joint-torque regressor of every body
        (:meth:`~mcpilco.models.inverse_dynamics.RigidBodyFeatures.rigid_regressor`)."""
        from mcpilco.models.inverse_dynamics import RigidBodyFeatures

        if not hasattr(self, "_features"):
            self._features = RigidBodyFeatures(self.model, blocks=("rigid",))
        return _memo(
            self._memo,
            "regressor",
            (q, qd, qdd),
            lambda: self._features.rigid_regressor(JointStates(q, qd, qdd)),
        )

    def rigid_body(self) -> RigidBody:
        """Every body's nominal inertial parameters and the flange pose in the last body
        (the frame named as in :data:`FLANGE_NAMES`, else the last body's last site, else
        the body frame itself)."""
        model = self.model
        last = model.njoints - 1
        params = np.stack(
            [model.inertias[b].toDynamicParameters() for b in range(1, model.njoints)]
        )
        frames = [
            f
            for f in model.frames
            if f.parentJoint == last and f.type == self._pin.FrameType.OP_FRAME
        ]
        named = [f for name in FLANGE_NAMES for f in frames if f.name == name]
        pose = (named or frames[-1:] or [None])[0]
        if pose is None:
            return RigidBody(params, np.zeros(3), np.eye(3))
        return RigidBody(
            params, np.array(pose.placement.translation), np.array(pose.placement.rotation)
        )


def rigid_span_fits(joint_types: str, strict: bool = False) -> bool:
    """Whether the chain's Lagrangian (:func:`~mcpilco.models.inverse_dynamics.
    lagrangian_parameters`) has at most :data:`~mcpilco.models.inverse_dynamics.
    MAX_RIGID_FEATURES` parameters; ``strict``: raise ValueError naming the size instead of
    returning False."""
    size = len(lagrangian_parameters(joint_types))
    if size <= MAX_RIGID_FEATURES:
        return True
    if strict:
        raise ValueError(
            f"the Lagrangian of joint types {joint_types!r} has {size} parameters (at most "
            f"{MAX_RIGID_FEATURES}); use span='chain'"
        )
    return False


class StartModel:
    """Interface: ``fit``, ``prior_mean``, ``torque``, optional kernel ``K_0``."""

    kind = "start"
    torque_is_prior_mean: bool = False  # tau_hat = m (physics); a learned start's differ
    all_rows: bool = False  # fit() reads every training row, not the kernel's subset
    output: str = "tau"  # what fit() is given: "tau" torques or "i" motor currents
    joint_types: str = ""
    n_joints: int = 0
    robot: _Robot | None = None

    def fit(self, q: FloatArray, qd: FloatArray, qdd: FloatArray, y: FloatArray) -> None:
        """Fit on training rows (nothing to do for a physics model)."""

    def prior_mean(self, q: FloatArray, qd: FloatArray, qdd: FloatArray) -> FloatArray:
        raise NotImplementedError

    def torque(self, q: FloatArray, qd: FloatArray, qdd: FloatArray) -> FloatArray:
        """``tau_hat (N, n)``: the start model's own prediction."""
        raise NotImplementedError

    @property
    def has_kernel(self) -> bool:
        return False

    def kernel(self, a: tuple[FloatArray, ...], b: tuple[FloatArray, ...]) -> FloatArray:
        """``(n, Na, Nb)`` start kernel between the states ``a = (q, qd, qdd)`` and ``b``."""
        raise NotImplementedError

    def kernel_diag(self, a: tuple[FloatArray, ...]) -> FloatArray:
        raise NotImplementedError

    def noise_variance(self) -> FloatArray | None:
        return None

    def spans(self, effect: Any) -> bool:
        """Whether the start kernel ``K_0`` already spans every torque of ``effect`` (then the
        effect cannot be missing, only under-learned). Default: no kernel, nothing spanned."""
        return False

    def spec(self) -> dict[str, Any]:
        raise NotImplementedError

    def describe(self) -> str:
        raise NotImplementedError


class NominalStart(StartModel):
    """Nominal rigid-body physics from an MJCF or URDF file (path or text).

    Raises:
        ValueError: a missing file, a non-MJCF/URDF text, unsupported joints.
    """

    kind = "nominal"
    torque_is_prior_mean = True

    def __init__(self, robot: str | Path, name: str | None = None) -> None:
        self.name = name or (str(robot) if len(str(robot)) < 200 else "<text>")
        self.robot = _Robot(read_robot_text(robot))
        self.n_joints = self.robot.n_joints
        self.joint_types = self.robot.joint_types

    def prior_mean(self, q: FloatArray, qd: FloatArray, qdd: FloatArray) -> FloatArray:
        return self.robot.rnea(q, qd, qdd)

    def torque(self, q: FloatArray, qd: FloatArray, qdd: FloatArray) -> FloatArray:
        return self.robot.rnea(q, qd, qdd)

    def spec(self) -> dict[str, Any]:
        return {"kind": self.kind, "robot_text": self.robot.text, "name": self.name}

    def describe(self) -> str:
        return f"nominal rigid-body model ({self.name}, joints {self.joint_types})"


class LearnedStart(StartModel):
    """A GP start model fitted by marginal likelihood on the training rows (base class).

    Subclasses choose the estimator (its feature map and kernel ``K_0``):
    :class:`GIPStart` (thesis eq. 3.8/3.11) or :class:`RBFStart` (ARD RBF on ``[q, qd, qdd]``).
    ``m_j`` is the GP's constant mean and ``tau_hat`` its posterior mean.

    Convergence (why it matters here)
        Candidates are scored by the evidence they add to this start (significance at 5 nats,
        :mod:`~mcpilco.models.diagnosis.search`). A start whose hyperparameters stopped short
        of the optimum leaves structure its kernel spans (armature: ``qdd`` times a constant)
        for a candidate block to claim: an apparent gain of several nats with no missing
        effect. So after ``adam_iters`` + ``lbfgs_iters`` the fit continues in rounds of
        ``lbfgs_iters`` L-BFGS iterations while a round raises
        :math:`\\sum_j \\log p(y_j)` by more than ``converge_nats`` (default 0.5, a tenth of the
        significance threshold), at most ``max_rounds`` rounds (then a warning).

    Args:
        joint_types: e.g. ``"RRPR"`` (one letter per joint).
        robot: optional MJCF/URDF (path or text) for the inertial candidates (links, payload).
        adam_iters, lbfgs_iters: optimisation of the start kernel's hyperparameters.
        converge_nats: stop the extra L-BFGS rounds when one gains less than this (nats).
        max_rounds: most extra rounds (0: the fixed budget only).
        hyper_points: the kernel's hyperparameters are fitted (and backfitted) on a random
            subset of this many training rows (seeded), then the GP is conditioned on all of
            them (``None``: on all rows). Each marginal-likelihood step costs ``O(N^2 F)``
            for the kernel's ``F`` factors and ``O(N^3)`` for its Cholesky factor, so 200 of
            600 rows make the fit about ten times cheaper; the diagnosis GP re-optimises the
            kernel's scale and the noise on every training row (:class:`.DiagnosisModel`).
    """

    def __init__(
        self,
        joint_types: str,
        robot: str | Path | None = None,
        adam_iters: int = 100,
        lbfgs_iters: int = 30,
        converge_nats: float = 0.5,
        max_rounds: int = 10,
        hyper_points: int | None = HYPER_POINTS,
    ) -> None:
        if hyper_points is not None and hyper_points < 2:
            raise ValueError(f"hyper_points must be >= 2 or None, got {hyper_points}")
        if converge_nats <= 0 or max_rounds < 0 or lbfgs_iters < 0 or adam_iters < 0:
            raise ValueError(
                "need converge_nats > 0 and max_rounds, adam_iters, lbfgs_iters >= 0; got "
                f"{converge_nats}, {max_rounds}, {adam_iters}, {lbfgs_iters}"
            )
        self.joint_types = joint_types
        self.n_joints = len(joint_types)
        self.adam_iters = adam_iters
        self.lbfgs_iters = lbfgs_iters
        self.converge_nats = converge_nats
        self.max_rounds = max_rounds
        self.hyper_points = hyper_points
        self.rounds_: int = 0
        self.robot = None if robot is None else _Robot(read_robot_text(robot))
        if self.robot is not None and self.robot.joint_types != joint_types:
            raise ValueError(
                f"joint types {joint_types!r} differ from the robot file's "
                f"{self.robot.joint_types!r}"
            )
        self.estimator_: GPInverseDynamics | None = None
        self._memo: OrderedDict = OrderedDict()

    def make_estimator(self) -> GPInverseDynamics:
        """The unfitted GP estimator whose kernel is ``K_0``."""
        raise NotImplementedError

    def fit(self, q: FloatArray, qd: FloatArray, qdd: FloatArray, y: FloatArray) -> None:
        est = self.make_estimator()
        est.fit(np.concatenate([q, qd, qdd], axis=1), y)
        self.estimator_ = est
        self._converge(q, qd, qdd, y)
        self._memo = OrderedDict()  # torques of the previous fit

    def _hyper_data(
        self, q: FloatArray, qd: FloatArray, qdd: FloatArray, y: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """``(X, y, X_h, y_h)``: the GP inputs of all rows and of the hyperparameter rows."""
        X = self.estimator_.gp_inputs(JointStates(q, qd, qdd))
        rows = getattr(self.estimator_, "hyper_rows_", None)
        if rows is None:
            return X, y, X, y
        return X, y, X[rows], y[rows]

    def _converge(self, q: FloatArray, qd: FloatArray, qdd: FloatArray, y: FloatArray) -> None:
        """Extra L-BFGS rounds (warm start) on the hyperparameter rows until one gains
        ``< converge_nats`` in :math:`\\sum_j \\log p(y_j)`, then conditioned on all rows;
        sets ``rounds_`` (see the class docstring)."""
        import warnings

        gp = self._gp()
        self.rounds_ = 0
        if self.max_rounds == 0 or self.lbfgs_iters == 0:
            return
        X, y, Xh, yh = self._hyper_data(q, qd, qdd, y)
        subset = Xh is not X
        try:
            if subset:
                gp.fit(Xh, yh, adam_iters=0, lbfgs_iters=0)
            lml = float(gp.log_marginal_likelihood().sum())
            for _ in range(self.max_rounds):
                gp.fit(Xh, yh, adam_iters=0, lbfgs_iters=self.lbfgs_iters)
                self.rounds_ += 1
                new = float(gp.log_marginal_likelihood().sum())
                gain, lml = new - lml, new
                if gain < self.converge_nats:
                    return
        finally:
            if subset:  # conditioned on every row at the fitted hyperparameters
                gp.fit(X, y, adam_iters=0, lbfgs_iters=0)
        warnings.warn(
            f"the {self.kind} start model still gained {gain:.2f} nats in its last L-BFGS round "
            f"after {self.max_rounds} rounds (converge_nats={self.converge_nats}); candidate "
            "evidences may be inflated by under-fitting: raise max_rounds or lbfgs_iters",
            RuntimeWarning,
            stacklevel=3,
        )

    def refit(self, q: FloatArray, qd: FloatArray, qdd: FloatArray, y: FloatArray) -> LearnedStart:
        """A copy whose kernel hyperparameters are re-optimised on ``y`` (warm start from the
        current ones, the full ``adam_iters`` + ``lbfgs_iters`` budget): backfitting after
        effects were added, so that the learned start stops absorbing them (a shorter budget
        can stop before the start model has let go of them)."""
        import copy

        new = copy.copy(self)  # the robot (pinocchio) is shared; the estimator is copied
        new.estimator_ = copy.deepcopy(self.estimator_)
        new._memo = OrderedDict()
        X, y, Xh, yh = new._hyper_data(q, qd, qdd, y)
        new.estimator_.gp_.fit(Xh, yh, adam_iters=self.adam_iters, lbfgs_iters=self.lbfgs_iters)
        if Xh is not X:
            new.estimator_.gp_.fit(X, y, adam_iters=0, lbfgs_iters=0)
        new._converge(q, qd, qdd, y)
        return new

    def _gp(self) -> Any:
        if self.estimator_ is None:
            raise RuntimeError(f"the {self.kind} start model is not fitted")
        return self.estimator_.gp_

    def prior_mean(self, q: FloatArray, qd: FloatArray, qdd: FloatArray) -> FloatArray:
        mean = self._gp().y_mean_.numpy()
        return np.broadcast_to(mean, q.shape).copy()

    def torque(self, q: FloatArray, qd: FloatArray, qdd: FloatArray) -> FloatArray:
        def compute() -> FloatArray:  # the posterior mean only (no variance products)
            X = self.estimator_.gp_inputs(JointStates(q, qd, qdd))
            return self._gp().predict_mean(X).numpy()

        return _memo(self._memo, "torque", (q, qd, qdd), compute)

    @property
    def has_kernel(self) -> bool:
        return True

    def _x(self, a: tuple[FloatArray, ...]) -> torch.Tensor:
        gp = self._gp()
        x = torch.as_tensor(self.estimator_.gp_inputs(JointStates(*a)), dtype=torch.float64)
        return gp._standardize_x(x)

    @torch.no_grad()
    def kernel(self, a: tuple[FloatArray, ...], b: tuple[FloatArray, ...]) -> FloatArray:
        from mcpilco.models.gp import dense_covar

        gp = self._gp()
        m = self.n_joints
        xa, xb = self._x(a), self._x(b)
        k = dense_covar(gp.model_.covar_module, xa.expand(m, *xa.shape), xb.expand(m, *xb.shape))
        return (k * (gp.y_scale_**2)[:, None, None]).numpy()

    @torch.no_grad()
    def kernel_diag(self, a: tuple[FloatArray, ...]) -> FloatArray:
        from mcpilco.models.gp import dense_diag

        gp = self._gp()
        m = self.n_joints
        xa = self._x(a)
        k = dense_diag(gp.model_.covar_module, xa.expand(m, *xa.shape))
        return (k.expand(m, xa.shape[0]) * (gp.y_scale_**2)[:, None]).numpy()

    def noise_variance(self) -> FloatArray:
        return self._gp().noise_variance.numpy()

    def spec(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "joint_types": self.joint_types,
            "robot_text": None if self.robot is None else self.robot.text,
            "adam_iters": self.adam_iters,
            "lbfgs_iters": self.lbfgs_iters,
            "converge_nats": self.converge_nats,
            "max_rounds": self.max_rounds,
            "hyper_points": self.hyper_points,
        }


class GIPStart(LearnedStart):
    """A GIP GP (thesis eq. 3.8/3.11): ``K_0`` = the GIP kernel of the joint types
    (:class:`~mcpilco.models.inverse_dynamics.GIPEstimator`); see :class:`LearnedStart`.

    Four fits, by ``span`` and ``inducing``:

    ``span="rigid"``
        The rigid-body terms of the serial chain's Lagrangian
        ``1/2 qd^T M(q) qd - V(q)`` (:func:`~mcpilco.models.inverse_dynamics.
        lagrangian_parameters`: the monomials of ``M`` and ``V`` these joint types allow,
        a subspace of the GIP span with one parameter vector for every joint), by Bayesian
        linear regression on **every** training row
        (:class:`~mcpilco.models.inverse_dynamics.LagrangianEstimator`). Its posterior mean
        is the start's torque and prior mean, as a nominal model's RNEA is (no ``K_0``), so
        that effects outside rigid-body dynamics (viscous and dry friction, offsets,
        springs, cogging, delays) stay in the residual for the search, as on a nominal
        start; rigid-body effects (armature, payload, link inertia) it holds, as
        :meth:`spans` says. Backfitting refits the regression on ``y`` minus the effects.
        The default where the chain has at most
        :data:`~mcpilco.models.inverse_dynamics.MAX_RIGID_FEATURES` parameters (up to 5
        joints: 84 for ``RRR``, 2,013 for ``RRRRR``; 9,947 for 6 and 49,374 for 7 revolute
        joints).
    ``span="chain"``
        The same torques (every rigid-body torque of a serial chain of these joint types)
        with the chain's kinematics fitted too: ``10 n`` inertial parameters by Bayesian
        linear regression on every row with an armature per joint, the DH numbers and the
        gravity direction by a search from a grid of right-angle twists and random starts
        (:class:`~mcpilco.models.inverse_dynamics.ChainEstimator`). Not convex, but
        ``77`` parameters for 7 joints instead of 49,374: the default (``"auto"``) where
        the Lagrangian is too large. Used as ``span="rigid"`` is (torque = prior mean, no
        ``K_0``, rigid-body effects spanned, backfitting keeps the kinematics).

        On motor-current logs (``output == "i"``, set by
        :class:`~mcpilco.models.diagnosis.DiagnosisModel`) one parameter vector for every
        joint cannot follow ``i_a = tau_a / k_a`` with per-joint constants: ``"rigid"``
        fits a free output scale per joint (``output_scales``), ``"chain"`` a parameter
        vector per joint (``per_joint``).
    ``span="gip"`` with ``inducing``
        Every row: :class:`~mcpilco.models.inverse_dynamics.NystromGIPEstimator` fits the
        GIP kernel's hyperparameters exactly on ``hyper_points`` random rows, then a
        Bayesian linear regression over ``inducing`` Nystroem features of that kernel on
        all rows (``O(N M^2)``). Its posterior mean is the prior mean ``m_j``; ``K_0``
        (same kernel) models what the mean leaves on the diagnosis GP's rows.
    ``span="gip"`` without ``inducing``
        The exact GP on the diagnosis GP's ``max_points`` rows.

    Args:
        span: ``"rigid"``, ``"chain"``, ``"gip"`` or ``"auto"`` (default: with
            ``inducing`` ``"gip"``, else ``"rigid"`` where its size allows, else
            ``"chain"``).
        inducing: Nystroem rows ``M`` of ``span="gip"`` (``None``: the exact GP).
        hyper_points: with ``inducing``, rows of the exact hyperparameter fit (default
            :data:`ALL_ROWS_HYPER_POINTS`); otherwise as in :class:`LearnedStart`.
        **kwargs: as in :class:`LearnedStart`.
    """

    kind = "gip"

    def __init__(
        self,
        joint_types: str,
        robot: str | Path | None = None,
        *,
        span: str = "auto",
        inducing: int | None = None,
        hyper_points: int | None = HYPER_POINTS,
        **kwargs: Any,
    ) -> None:
        if span not in SPANS:
            raise ValueError(f"span must be one of {SPANS}, got {span!r}")
        if inducing is not None and inducing < 1:
            raise ValueError(f"inducing must be >= 1 or None, got {inducing}")
        if span in RIGID_SPANS and inducing is not None:
            raise ValueError(f"inducing is a setting of span='gip', not of span={span!r}")
        if span == "auto":
            if inducing is not None:
                span = "gip"
            else:
                span = "rigid" if rigid_span_fits(joint_types) else "chain"
        if inducing is not None and hyper_points == HYPER_POINTS:
            hyper_points = ALL_ROWS_HYPER_POINTS
        super().__init__(joint_types, robot, hyper_points=hyper_points, **kwargs)
        if span == "rigid":
            rigid_span_fits(self.joint_types, strict=True)
        self.span = span
        self.inducing = inducing
        self.all_rows = span in RIGID_SPANS or inducing is not None
        self.torque_is_prior_mean = span in RIGID_SPANS

    @property
    def has_kernel(self) -> bool:
        """No ``K_0`` with ``span="rigid"`` or ``"chain"`` (its mean is the whole start, as
        RNEA is)."""
        return self.span not in RIGID_SPANS

    def make_estimator(self) -> GPInverseDynamics | LagrangianEstimator:
        currents = self.output == "i"  # each joint i = tau / k_t: its own output scale
        if self.span == "rigid":
            return LagrangianEstimator(self.joint_types, output_scales=currents)
        if self.span == "chain":
            return ChainEstimator(self.joint_types, per_joint=currents)
        opt = dict(adam_iters=self.adam_iters, lbfgs_iters=self.lbfgs_iters)
        if self.inducing is not None:
            return NystromGIPEstimator(
                self.joint_types, inducing=self.inducing, hyper_points=self.hyper_points, **opt
            )
        return GIPEstimator(self.joint_types, hyper_points=self.hyper_points, **opt)

    def fit(self, q: FloatArray, qd: FloatArray, qdd: FloatArray, y: FloatArray) -> None:
        if not self.all_rows:
            return super().fit(q, qd, qdd, y)
        est = self.make_estimator()
        est.fit(np.concatenate([q, qd, qdd], axis=1), y)
        self.estimator_ = est
        self.rounds_ = 0
        self._memo = OrderedDict()

    def refit(self, q: FloatArray, qd: FloatArray, qdd: FloatArray, y: FloatArray) -> GIPStart:
        """Every-row start: a copy whose regression is refitted on ``y`` (the output minus
        the fitted effects) at the same kernel hyperparameters; else
        :meth:`LearnedStart.refit`."""
        if not self.all_rows:
            return super().refit(q, qd, qdd, y)
        import copy

        new = copy.copy(self)
        new.estimator_ = copy.deepcopy(self.estimator_)
        new.estimator_.refit_targets(np.concatenate([q, qd, qdd], axis=1), y)
        new._memo = OrderedDict()
        return new

    def prior_mean(self, q: FloatArray, qd: FloatArray, qdd: FloatArray) -> FloatArray:
        if not self.all_rows:
            return super().prior_mean(q, qd, qdd)
        return self.torque(q, qd, qdd)

    def torque(self, q: FloatArray, qd: FloatArray, qdd: FloatArray) -> FloatArray:
        if not self.all_rows:
            return super().torque(q, qd, qdd)
        if self.estimator_ is None:
            raise RuntimeError(f"the {self.kind} start model is not fitted")
        return _memo(
            self._memo,
            "torque",
            (q, qd, qdd),
            lambda: self.estimator_.predict_mean(np.concatenate([q, qd, qdd], axis=1)),
        )

    def noise_variance(self) -> FloatArray:
        if not self.all_rows:
            return super().noise_variance()
        return self.estimator_.noise_variance_

    def spec(self) -> dict[str, Any]:
        return {**super().spec(), "span": self.span, "inducing": self.inducing}

    def spans(self, effect: Any) -> bool:
        """Whether the start's function space holds every torque of ``effect``: with
        ``span="gip"`` :meth:`Effect.in_gip_span` (offset, armature, payload, prismatic
        spring, cogging of order <= 2); with ``span="rigid"`` or ``"chain"`` the
        rigid-body effects (:data:`RIGID_BODY_EFFECTS`: armature, link inertia, payload),
        which a Lagrangian of these joints already holds."""
        if self.span in RIGID_SPANS:
            return effect.key in RIGID_BODY_EFFECTS
        return bool(effect.in_gip_span(self.joint_types))

    def describe(self) -> str:
        if self.span == "rigid":
            return f"learned rigid-body GIP span (joints {self.joint_types}, every row)"
        if self.span == "chain":
            return f"learned rigid-body chain (joints {self.joint_types}, every row)"
        return f"learned GIP GP (joints {self.joint_types})"


class RBFStart(LearnedStart):
    """A black-box GP: ``K_0`` = ARD RBF on the standardised ``[q, qd, qdd]``
    (:class:`~mcpilco.models.inverse_dynamics.RBFEstimator`); see :class:`LearnedStart`.
    The joint types only set the joint count and the effect features (``R``: angles)."""

    kind = "rbf"

    def make_estimator(self) -> GPInverseDynamics:
        return RBFEstimator(
            self.n_joints,
            adam_iters=self.adam_iters,
            lbfgs_iters=self.lbfgs_iters,
            hyper_points=self.hyper_points,
        )

    def describe(self) -> str:
        return f"learned RBF GP ({self.n_joints} joints)"


LEARNED_STARTS: dict[str, type[LearnedStart]] = {"gip": GIPStart, "rbf": RBFStart}

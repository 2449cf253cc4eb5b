"""The effects a diagnosis found, written back into the nominal MJCF: a corrected robot file.

A diagnosis model's torque is ``tau = tau_start(q, qd, qdd) + sum_e phi_e^T w_e`` (the start
model plus the added effect blocks, :mod:`.effects`). For a nominal start
(:class:`~.start_models.NominalStart`) ``tau_start`` is pinocchio's RNEA of the robot file,
which holds the rigid bodies and the joint ``armature`` but not the file's passive joint
forces (``damping``, ``frictionloss``, ``stiffness``). :func:`write_corrected_mjcf` edits the
file with :class:`mujoco.MjSpec` so that MuJoCo's own physics carries each effect, as a joint
torque the actuators must supply (MuJoCo's passive forces act against the motion):

============  ============================================  ===================================
effect        MJCF                                          value written
============  ============================================  ===================================
viscous       ``joint/@damping``                            ``F_v`` (replaces the file's value)
coulomb       ``joint/@frictionloss``                       ``F_c`` (replaces the file's value)
stribeck      ``joint/@frictionloss``                       ``F_c``; the static excess
                                                            ``F_s - F_c`` goes to the side file
spring        ``joint/@stiffness``, ``joint/@springref``    ``k``, ``q_0 = q_ref - c / k``
armature      ``joint/@armature``                           file value ``+ I_a``
payload       a body ``payload`` on the last link           ``m``, centre of mass ``c = mc / m``,
                                                            inertia about ``c`` (module text)
inertia       the link's ``inertial`` (mass, ipos,          the link's parameters plus the
              principal inertia)                            fitted change
============  ============================================  ===================================

A change of a link's 10 inertial parameters is written by :func:`write_link_inertial`: the
link's compiled parameters plus the change, as explicit ``mass``, ``ipos`` and principal
``inertia``/``iquat``.

The writer is the table :data:`WRITERS` (effect key -> function); an effect type without an
entry (cogging, dead-zone, torque offset, delay, ...) has no MuJoCo element and is listed in
the side record instead, with its parameters and 95 % intervals
(:class:`CorrectedFile`.``not_expressed``). A value on the unphysical side (negative
damping, friction, stiffness, armature or mass) is not written either; it is listed with the
reason.

Payload
    The payload's weights ``[m, m d, I_p]`` (one vector for all joints) are mapped to the
    change of the last body's 10 inertial parameters ``pi = [m, m c, I_o]`` (pinocchio's
    order, inertia about the joint frame) by :meth:`~.effects.Payload.change`. A block with
    one posterior per output joint (an effect with ``all_joints`` that is not shared) is
    fused by its information,
    ``Sigma^-1 = sum_j Sigma_j^-1``, ``mu = Sigma sum_j Sigma_j^-1 mu_j`` (each ``Sigma_j``
    includes the same weak prior: a slight over-regularisation, negligible when the block is
    significant). The body gets ``m``, ``c = m c / m`` and
    ``I_c = I_o - m (|c|^2 1 - c c^T)`` when ``I_c`` is physically consistent (principal
    moments ``>= 0`` obeying the triangle inequality); otherwise a solid sphere of radius
    :data:`PAYLOAD_FALLBACK_RADIUS` about ``c`` (the fitted tensor goes to the side record).
    The joint frame is the body frame shifted by the joint's ``pos`` (pinocchio's MJCF
    import).

Files the start model read differently: a joint whose file value of ``damping``,
``frictionloss`` or ``stiffness`` is not zero but for which no effect was found keeps it,
with a note (the diagnosis compared the data with a model without it).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from numpy.typing import NDArray

from mcpilco.models.diagnosis.effects import (
    INERTIAL_PARAMS,
    MODEL_ONLY_EFFECTS,
    Effect,
    ParamEstimate,
    Payload,
)
from mcpilco.models.diagnosis.model import DiagnosisModel
from mcpilco.models.diagnosis.start_models import NominalStart
from mcpilco.models.stats import Z95

FloatArray = NDArray[np.float64]

__all__ = [
    "WRITERS",
    "Change",
    "CorrectedFile",
    "FoundEffect",
    "found_effects",
    "joint_handles",
    "joint_label",
    "write_corrected_mjcf",
    "write_link_inertial",
]

PAYLOAD_FALLBACK_RADIUS = 0.03  # m: solid sphere used when the fitted inertia is inconsistent
PAYLOAD_BODY = "payload"  # name of the body the payload is written as
PASSIVE_ATTRIBUTES = ("damping", "frictionloss", "stiffness")  # file values RNEA does not hold


@dataclass(frozen=True)
class FoundEffect:
    """An effect of a fitted model with its parameter estimates (95 % intervals).

    ``inertial`` / ``inertial_cov``: for the payload, the fused change of the last body's 10
    inertial parameters (:data:`~.effects.INERTIAL_PARAMS`) and its covariance.
    """

    effect: Effect
    estimates: tuple[ParamEstimate, ...]
    inertial: FloatArray | None = None
    inertial_cov: FloatArray | None = None

    def value(self, name: str) -> ParamEstimate:
        for p in self.estimates:
            if p.name == name:
                return p
        raise KeyError(f"{self.effect.label} has no parameter {name!r}")

    def to_dict(self) -> dict[str, Any]:
        return {
            "effect": self.effect.variant_label,
            "title": self.effect.title,
            "spec": self.effect.spec(),
            "parameters": [asdict(p) for p in self.estimates],
        }


@dataclass(frozen=True)
class Change:
    """One MJCF attribute written: ``element`` (e.g. ``joint j2``), ``attribute``, the file's
    value ``before`` and the value ``after``, from the effect ``effect`` (``source``: the
    estimate in words)."""

    element: str
    attribute: str
    before: float | list[float] | None
    after: float | list[float]
    effect: str
    source: str
    ci95: float | None = None


@dataclass
class CorrectedFile:
    """The corrected MJCF and the side record of what was and was not written.

    Attributes:
        xml: the corrected MJCF text.
        changes: every attribute written (:class:`Change`).
        not_expressed: effects (or parts of them) MuJoCo cannot express, with parameters and
            95 % intervals and the reason.
        notes: remarks on the file (values the start model did not read, inertia projected).
    """

    xml: str
    changes: list[Change] = field(default_factory=list)
    not_expressed: list[dict[str, Any]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    effects: list[FoundEffect] = field(default_factory=list)

    def side_record(self) -> dict[str, Any]:
        """JSON-serialisable record (the side file)."""
        return {
            "format": "mcpilco-corrected-robot/1",
            "effects": [e.to_dict() for e in self.effects],
            "written": [asdict(c) for c in self.changes],
            "not_expressed": self.not_expressed,
            "notes": self.notes,
        }

    def write(self, xml_path: str | Path, side_path: str | Path) -> tuple[Path, Path]:
        """Write the MJCF and the side record (JSON); returns both paths."""
        xml_path, side_path = Path(xml_path), Path(side_path)
        xml_path.parent.mkdir(parents=True, exist_ok=True)
        xml_path.write_text(self.xml)
        side_path.write_text(json.dumps(self.side_record(), indent=1, default=float))
        return xml_path, side_path

    def lines(self) -> list[str]:
        """The record in words, one line per item."""
        out = [
            f"   {c.element} {c.attribute}: {_short(c.before)} -> {_short(c.after)} "
            f"({c.effect}: {c.source})"
            for c in self.changes
        ]
        out += [f"   not in the MJCF: {e['effect']}: {e['reason']}" for e in self.not_expressed]
        out += [f"   note: {n}" for n in self.notes]
        return out


def _short(x: Any) -> str:
    if x is None:
        return "-"
    if isinstance(x, (list, tuple, np.ndarray)):
        return "[" + ", ".join(f"{float(v):.4g}" for v in x) + "]"
    return f"{float(x):.4g}"


# ----------------------------------------------------------------------------- estimates


def block_posterior(
    model: DiagnosisModel, effect: Effect, output: int
) -> tuple[FloatArray, FloatArray] | None:
    """Posterior mean and covariance of ``effect``'s block weights on ``output`` (0-based),
    or ``None`` when the effect has no block there."""
    effs = model.block_effects(output)
    k = next((i for i, e in enumerate(effs) if e.same_slot(effect)), None)
    if k is None:
        return None
    sl = model.gps_[output].block_slices()[k]
    mean, cov = model.gps_[output].weights(model.theta_[output])
    return mean[sl], cov[sl, sl]


def shared_posterior(model: DiagnosisModel, effect: Effect) -> tuple[FloatArray, FloatArray]:
    """Posterior mean and covariance of a shared (rigid-body) effect's weights."""
    shared = model.shared_effects
    k = shared.index(effect)
    sizes = model._shared_sizes()
    sl = slice(sum(sizes[:k]), sum(sizes[: k + 1]))
    return model.shared_.mean[sl], model.shared_.cov[sl, sl]


def model_estimates(model: DiagnosisModel, effect: Effect) -> list[ParamEstimate]:
    """A shared effect's estimates as the model reports them (:meth:`DiagnosisModel.parameters`)."""
    mean, cov = shared_posterior(model, effect)
    return effect.estimates(mean, cov, model.ctx_, 0)


def _fuse(posteriors: Sequence[tuple[FloatArray, FloatArray]]) -> tuple[FloatArray, FloatArray]:
    """Information fusion of Gaussian posteriors of one vector (module docstring)."""
    info = sum(np.linalg.pinv(c, hermitian=True) for _, c in posteriors)
    vec = sum(np.linalg.pinv(c, hermitian=True) @ m for m, c in posteriors)
    cov = np.linalg.pinv(info, hermitian=True)
    return cov @ vec, cov


def found_effects(model: DiagnosisModel) -> list[FoundEffect]:
    """Every effect of fitted ``model`` with its estimates (the payload: fused over joints)."""
    model._check_fitted()
    out = []
    for e in model.effects:
        if e.key in MODEL_ONLY_EFFECTS:  # a unit conversion (torque scale), not physics
            continue
        if e.is_shift:
            ests = e.estimates(
                np.zeros(1), np.zeros((1, 1)), model.ctx_, e.outputs(model.n_joints)[0]
            )
            out.append(FoundEffect(e, tuple(ests)))
            continue
        if e in model.shared_effects:  # one weight vector for all joints (a body's inertia)
            mean, cov = shared_posterior(model, e)
            ests = tuple(model_estimates(model, e))
            change = e.change(mean, model.ctx_) if isinstance(e, Payload) else e.change(mean)
            out.append(FoundEffect(e, ests, change))
            continue
        posts = [
            (j, p)
            for j in e.outputs(model.n_joints)
            if (p := block_posterior(model, e, j)) is not None
        ]
        if not posts:
            continue
        if e.all_joints:
            mean, cov = _fuse([p for _, p in posts])
            sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
            ests = tuple(
                ParamEstimate(
                    name,
                    float(mean[k]),
                    float(Z95 * sd[k]),
                    _payload_unit(name),
                    bool(name == "m" and mean[k] < -Z95 * sd[k]),
                )
                for k, name in enumerate(INERTIAL_PARAMS)
            )
            out.append(FoundEffect(e, ests, mean, cov))
        else:
            j, (mean, cov) = posts[0]
            out.append(FoundEffect(e, tuple(e.estimates(mean, cov, model.ctx_, j))))
    return out


def _payload_unit(name: str) -> str:
    return {"m": "kg"}.get(name, "kg·m" if name.startswith("mc") else "kg·m²")


# ----------------------------------------------------------------------------- the file


def joint_handles(spec: mujoco.MjSpec) -> list[mujoco.MjsJoint]:
    """The hinge and slide joints of ``spec`` in tree order (the diagnosis joints 1..n)."""
    kinds = (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE)
    return [j for j in spec.joints if j.type in kinds]


def joint_label(spec: mujoco.MjSpec, k: int) -> str:
    """``joint <name>`` of the ``k``-th (0-based) hinge/slide joint, ``joint #<k+1>`` when it
    has no name (the ``element`` of a :class:`Change`)."""
    jnt = joint_handles(spec)[k]
    return f"joint {jnt.name}" if jnt.name else f"joint #{k + 1}"


@dataclass
class _Target:
    """What a writer edits: the spec and its joints (diagnosis order)."""

    spec: mujoco.MjSpec
    joints: list[mujoco.MjsJoint]

    def joint(self, effect: Effect) -> tuple[mujoco.MjsJoint, str]:
        k = effect.joint - 1
        return self.joints[k], joint_label(self.spec, k)


WriteResult = tuple[list[Change], str | None]
"""Changes written and, when part of the effect stays out of the file, why."""


class NotWritten(Exception):
    """An effect (or value) that cannot be written; the message says why."""


def _positive(found: FoundEffect, name: str) -> ParamEstimate:
    p = found.value(name)
    if not p.value > 0:
        raise NotWritten(
            f"{name} = {p.value:.3g} {p.unit} is not > 0: not a physical value for MuJoCo"
        )
    return p


def _set_joint_scalar(
    target: _Target,
    found: FoundEffect,
    attribute: str,
    value: float,
    source: str,
    ci95: float | None = None,
) -> Change:
    jnt, where = target.joint(found.effect)
    current = getattr(jnt, attribute)
    if isinstance(current, np.ndarray):  # damping / stiffness are arrays in MjSpec
        before = float(current[0])
        current = current.copy()
        current[0] = value
        setattr(jnt, attribute, current)
    else:
        before = float(current)
        setattr(jnt, attribute, value)
    return Change(where, attribute, before, float(value), found.effect.variant_label, source, ci95)


def write_viscous(target: _Target, found: FoundEffect) -> WriteResult:
    """``damping = F_v``."""
    p = _positive(found, "F_v")
    return [_set_joint_scalar(target, found, "damping", p.value, p.text(), p.ci95)], None


def write_coulomb(target: _Target, found: FoundEffect) -> WriteResult:
    """``frictionloss = F_c`` (MuJoCo's dry friction: ``F_c`` against the motion)."""
    p = _positive(found, "F_c")
    return [_set_joint_scalar(target, found, "frictionloss", p.value, p.text(), p.ci95)], None


def write_stribeck(target: _Target, found: FoundEffect) -> WriteResult:
    """``frictionloss = F_c``; the static excess ``F_s - F_c`` has no MuJoCo element."""
    p = _positive(found, "F_c")
    change = _set_joint_scalar(target, found, "frictionloss", p.value, p.text(), p.ci95)
    return [change], "the static excess F_s - F_c (Stribeck) has no MuJoCo joint attribute"


def write_spring(target: _Target, found: FoundEffect) -> WriteResult:
    """``stiffness = k``, ``springref = q_ref - c / k``."""
    k = _positive(found, "k")
    c = found.value("c")
    q_ref = found.effect.q_ref
    if q_ref is None:
        raise NotWritten("the spring's reference position was never calibrated on data")
    q0 = q_ref - c.value / k.value
    changes = [
        _set_joint_scalar(target, found, "stiffness", k.value, k.text(), k.ci95),
        _set_joint_scalar(
            target, found, "springref", q0, f"q_0 = q_ref - c/k = {q0:.4g} ({c.text()})"
        ),
    ]
    return changes, None


def write_armature(target: _Target, found: FoundEffect) -> WriteResult:
    """``armature += I_a`` (the nominal start's RNEA holds the file's armature)."""
    p = _positive(found, "I_a")
    jnt, _ = target.joint(found.effect)
    value = float(jnt.armature) + p.value
    return [_set_joint_scalar(target, found, "armature", value, p.text(), p.ci95)], None


def _consistent(inertia: FloatArray) -> bool:
    """Principal moments ``>= 0`` and obeying the triangle inequality."""
    ev = np.linalg.eigvalsh(0.5 * (inertia + inertia.T))
    tol = 1e-12 * max(1.0, float(np.abs(ev).max()))
    return bool(ev.min() >= -tol and (ev.sum() - 2 * ev).min() >= -tol)


def _split_inertial(pi: FloatArray) -> tuple[float, FloatArray, FloatArray]:
    """``(m, c, I_c)`` of 10 inertial parameters ``[m, m c, I_o]`` (pinocchio's order,
    inertia ``I_o`` about the frame's origin): ``I_c = I_o - m (|c|^2 1 - c c^T)``."""
    m = float(pi[0])
    c = np.asarray(pi[1:4], dtype=np.float64) / m
    ixx, ixy, iyy, ixz, iyz, izz = pi[4:10]
    i_o = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    return m, c, i_o - m * (float(c @ c) * np.eye(3) - np.outer(c, c))


def _full(i_c: FloatArray) -> list[float]:
    """MJCF ``fullinertia`` order: ``Ixx, Iyy, Izz, Ixy, Ixz, Iyz``."""
    return [float(v) for v in (i_c[0, 0], i_c[1, 1], i_c[2, 2], i_c[0, 1], i_c[0, 2], i_c[1, 2])]


def _principal(i_c: FloatArray) -> tuple[list[float], list[float]]:
    """``(iquat, diaginertia)`` of an inertia tensor: its principal axes (a right-handed
    rotation as a quaternion) and moments."""
    moments, axes = np.linalg.eigh(0.5 * (i_c + i_c.T))
    if np.linalg.det(axes) < 0:
        axes[:, 0] = -axes[:, 0]
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(axes).ravel())
    return quat.tolist(), moments.tolist()


def _joint_frame_parameters(model: mujoco.MjModel, body: int, offset: FloatArray) -> FloatArray:
    """The compiled body's 10 inertial parameters about the joint frame (the body frame
    shifted by ``offset``, the joint's ``pos``), in pinocchio's order."""
    m = float(model.body_mass[body])
    c = np.asarray(model.body_ipos[body]) - offset
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, np.asarray(model.body_iquat[body], dtype=np.float64))
    rot = rot.reshape(3, 3)
    i_o = rot @ np.diag(model.body_inertia[body]) @ rot.T
    i_o = i_o + m * (float(c @ c) * np.eye(3) - np.outer(c, c))
    return np.array([m, *(m * c), i_o[0, 0], i_o[0, 1], i_o[1, 1], i_o[0, 2], i_o[1, 2], i_o[2, 2]])


def write_payload(target: _Target, found: FoundEffect) -> WriteResult:
    """A body ``payload`` on the last joint's body: mass, centre of mass and inertia from the
    fused 10 inertial parameters (module docstring)."""
    if found.inertial is None:
        raise NotWritten("no inertial parameters were fitted")
    _positive(found, "m")
    m, c, i_c = _split_inertial(np.asarray(found.inertial, dtype=np.float64))
    note = None
    if not _consistent(i_c):
        i_c = 0.4 * m * PAYLOAD_FALLBACK_RADIUS**2 * np.eye(3)
        note = (
            "the fitted inertia tensor about the centre of mass is not physically consistent; "
            f"a solid sphere of radius {PAYLOAD_FALLBACK_RADIUS} m is written instead"
        )
    last = target.joints[-1]
    parent = last.parent
    pos = (np.asarray(last.pos, dtype=np.float64) + c).tolist()
    if target.spec.body(PAYLOAD_BODY) is not None:
        raise NotWritten(f"the file already has a body named {PAYLOAD_BODY!r}")
    body = parent.add_body(name=PAYLOAD_BODY, pos=pos)
    body.explicitinertial = True
    body.mass = m
    body.ipos = [0.0, 0.0, 0.0]
    body.iquat = [1.0, 0.0, 0.0, 0.0]
    body.fullinertia = _full(i_c)
    where = f"body {PAYLOAD_BODY} (on {parent.name or 'the last link'})"
    label = found.effect.variant_label
    mtext = found.value("m").text()
    changes = [
        Change(where, "mass", None, m, label, mtext, found.value("m").ci95),
        Change(where, "pos", None, pos, label, "centre of mass c = (m c) / m in the link frame"),
        Change(where, "fullinertia", None, _full(i_c), label, "inertia about c"),
    ]
    return changes, note


def write_link_inertial(target: _Target, found: FoundEffect) -> WriteResult:
    """Change of the 10 inertial parameters of joint ``found.effect.joint``'s body
    (``found.inertial``: ``[dm, d(m c), dI_o]`` about the joint frame, pinocchio's order):
    the body's compiled parameters plus the change, written back as explicit ``mass``,
    ``ipos`` and ``fullinertia``. A result with ``m <= 0`` or an inertia that is not
    physically consistent is not written. For a per-link inertial candidate: register it
    as ``WRITERS[key] = write_link_inertial``."""
    if found.inertial is None:
        raise NotWritten("no inertial parameters were fitted")
    k = found.effect.joint - 1
    jnt = target.joints[k]
    body = jnt.parent
    model = target.spec.compile()
    bid = int(model.jnt_bodyid[_joint_id(model, k)])
    offset = np.asarray(jnt.pos, dtype=np.float64)
    before = _joint_frame_parameters(model, bid, offset)
    after = before + np.asarray(found.inertial, dtype=np.float64)
    if not after[0] > 0:
        raise NotWritten(f"the link's mass would be {after[0]:.3g} kg")
    m, c, i_c = _split_inertial(after)
    if not _consistent(i_c):
        raise NotWritten("the link's inertia tensor would not be physically consistent")
    body.explicitinertial = True
    body.mass = m
    body.ipos = (c + offset).tolist()
    body.iquat, body.inertia = _principal(i_c)  # the file may give diaginertia
    where = f"body {body.name or '#' + str(bid)}"
    label = found.effect.variant_label
    src = "link parameters + the fitted change"
    changes = [
        Change(where, "mass", float(before[0]), m, label, src),
        Change(where, "ipos", None, body.ipos.tolist(), label, src),
        Change(where, "inertia (about ipos)", None, _full(i_c), label, src),
    ]
    return changes, None


def _joint_id(model: mujoco.MjModel, k: int) -> int:
    """Id of the ``k``-th (0-based) hinge/slide joint of a compiled model."""
    kinds = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
    return [j for j in range(model.njnt) if int(model.jnt_type[j]) in kinds][k]


Writer = Callable[[_Target, FoundEffect], WriteResult]
WRITERS: dict[str, Writer] = {
    "viscous": write_viscous,
    "coulomb": write_coulomb,
    "stribeck": write_stribeck,
    "spring": write_spring,
    "armature": write_armature,
    "payload": write_payload,
    "inertia": write_link_inertial,
}
"""Effect key -> the function that writes it into the MJCF (keys without one: side file)."""


def write_corrected_mjcf(
    model: DiagnosisModel, effects: Sequence[FoundEffect] | None = None
) -> CorrectedFile:
    """The nominal MJCF of ``model`` with its effects written in (module docstring).

    Args:
        model: a fitted diagnosis model whose start is a :class:`NominalStart` of an MJCF.
        effects: the effects to write (default: :func:`found_effects` of ``model``).

    Returns:
        the corrected file and its side record.

    Raises:
        ValueError: a start model that is not a nominal MJCF, a model fitted on currents, or
            a file whose hinge and slide joints do not match the model's joints.
    """
    start = model.start
    if not isinstance(start, NominalStart):
        raise ValueError(
            f"a corrected robot file needs a nominal MJCF start model, got {start.describe()}"
        )
    if model.train_ is not None and model.train_.output != "tau":
        raise ValueError(
            "the model was fitted on motor currents: its effects are in A, not in the joint "
            "torque units an MJCF needs"
        )
    text = start.robot.text
    if "<mujoco" not in text:
        raise ValueError(
            f"the start model's robot file ({start.name}) is not MJCF (<mujoco>); "
            "a corrected file is written for MJCF only"
        )
    spec = mujoco.MjSpec.from_string(text)
    joints = joint_handles(spec)
    if len(joints) != model.n_joints:
        raise ValueError(
            f"the MJCF has {len(joints)} hinge/slide joints but the model has {model.n_joints}"
        )
    target = _Target(spec, joints)
    found = found_effects(model) if effects is None else list(effects)
    result = CorrectedFile(xml="", effects=found)
    touched: set[tuple[int, str]] = set()
    for f in found:
        writer = WRITERS.get(f.effect.key)
        entry = {
            "effect": f.effect.variant_label,
            "title": f.effect.title,
            "parameters": [asdict(p) for p in f.estimates],
        }
        if writer is None:
            result.not_expressed.append({**entry, "reason": "MuJoCo has no element for it"})
            continue
        try:
            changes, partial = writer(target, f)
        except NotWritten as err:
            result.not_expressed.append({**entry, "reason": str(err)})
            continue
        result.changes += changes
        if partial:
            result.not_expressed.append({**entry, "reason": partial})
        if f.effect.joint is not None:
            touched |= {(f.effect.joint - 1, c.attribute) for c in changes}
    for k, jnt in enumerate(joints):
        for attr in PASSIVE_ATTRIBUTES:
            value = getattr(jnt, attr)
            value = float(value[0]) if isinstance(value, np.ndarray) else float(value)
            if value != 0.0 and (k, attr) not in touched:
                result.notes.append(
                    f"{joint_label(spec, k)}: {attr} = {value:.4g} in the file is kept; the "
                    "diagnosis compared the data with a start model without it (pinocchio's "
                    "RNEA: rigid bodies and armature)"
                )
    spec.compile()  # raises on an invalid result
    result.xml = spec.to_xml()
    return result

"""Serial robot arms as MuJoCo models, built from a table of Denavit-Hartenberg parameters.

One :class:`ArmSpec` (a DH table, joint types, link inertial parameters, joint friction, rotor
inertia and gear ratio) becomes a ``mujoco.MjSpec`` with :func:`build_arm_spec`, a compiled
``mujoco.MjModel`` with :func:`build_arm_model`, or MJCF text with :func:`arm_to_xml`. No
robot is written as hand-pasted XML; :mod:`mcpilco.envs.arms` holds the tables.

Glossary (standard DH convention, thesis section 2.2 / Siciliano et al. 2009)
----------------------------------------------------------------------------
``A_i(q_i) = Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``
    transform from frame ``{i-1}`` to frame ``{i}``; for a revolute joint (``R``)
    ``theta_i = theta0_i + q_i`` and ``d_i`` is constant, for a prismatic joint (``P``)
    ``d_i = d0_i + q_i`` and ``theta_i`` is constant. ``{0}`` is the base frame.
``T_0n(q) = A_1(q_1) ... A_n(q_n)``
    forward kinematics; the site ``ee`` of the model sits at ``{n}`` (the flange).
link ``i``
    the rigid body moved by joint ``i``; its inertial parameters (mass ``m_i``, centre of
    mass ``c_i``, inertia ``I_i`` about the centre of mass) are given in DH frame ``{i}``.
``tau_i``
    generalised force of joint ``i``: torque [N m] for ``R`` joints, force [N] for ``P``.

How the DH chain maps onto MuJoCo bodies
----------------------------------------
Body ``link{i}`` has the frame ``B_i = {i-1} Rz(theta_i) Tz(d_i)`` (the frame ``{i-1}``
moved by joint ``i``), so every joint axis is the body's z axis through its origin (a plain
``RevoluteZ``/``PrismaticZ`` joint for pinocchio's MJCF importer). The next body sits at
``Tx(a_i) Rx(alpha_i) Rz(theta0_{i+1}) Tz(d0_{i+1})`` in ``B_i``, and the site ``link{i}``
marks DH frame ``{i} = B_i Tx(a_i) Rx(alpha_i)``. Inertial parameters given in ``{i}`` are
rotated/translated into ``B_i``.

Joint friction, rotor inertia, gear
-----------------------------------
* viscous friction ``F_v q_dot`` -> MuJoCo joint ``damping = F_v`` (integrated implicitly by
  the ``implicitfast`` integrator).
* static friction ``F_s`` -> MuJoCo joint ``frictionloss = F_s``. ``frictionloss`` is a
  dry-friction *constraint*: at zero velocity it holds the joint still against any other
  generalised force up to ``F_s`` (stiction), and while sliding it opposes motion with a
  force of magnitude ``F_s`` (soft constraint, so very slow creep below ``F_s`` is possible;
  ``solref``/``solimp`` of the friction constraints are made stiffer here, see
  ``FRICTION_SOLIMP``). A Coulomb
  level ``F_c < F_s`` (Stribeck effect) is not a MuJoCo joint attribute: the arm envs add
  the sliding correction ``(F_s - F_c) (1 - exp(-(q_dot/v_s)^2)) sign(q_dot)`` themselves.
* rotor inertia ``J_m`` and gear ratio ``K_r`` -> ``armature = J_m K_r^2`` (reflected
  rotor inertia, the ``K_r^2 J_m`` of thesis eq. 4.4).
* actuators ``m{i}`` are torque motors with ``gear = 1``: ``ctrl_i`` is the joint-side
  torque ``tau_i`` (the env converts to motor currents with ``K_tau K_r``).

Timestep and integrator
-----------------------
The default physics timestep is ``0.002`` s (500 Hz, the rate of a UR controller's inner
loop) with the ``implicitfast`` integrator; the arm envs sample every 8 ms, i.e. 4 physics
substeps per sample.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
from numpy.typing import ArrayLike, NDArray

FRICTION_SOLREF: tuple[float, float] = (0.002, 1.0)
"""``solref`` of the dry-friction constraints (time constant 2 ms, critically damped)."""

FRICTION_SOLIMP: tuple[float, float, float, float, float] = (0.9999, 0.9999, 0.001, 0.5, 2.0)
"""``solimp`` of the dry-friction constraints: impedance 0.9999 (MuJoCo: 0.9-0.95), nearly hard
stiction (the regulariser ``R = (1 - d)/d A`` sets the creep of a held joint)."""

JOINT_TYPES = ("R", "P")


@dataclass(frozen=True)
class DHJoint:
    """One row of a standard DH table plus the joint's actuation and friction data.

    Attributes:
        a: link length ``a_i`` [m] (along ``x_i``).
        alpha: link twist ``alpha_i`` [rad] (about ``x_i``).
        d: link offset ``d_i`` [m] (along ``z_{i-1}``); for a ``P`` joint the offset ``d0_i``
            added to ``q_i``.
        theta: joint angle offset ``theta0_i`` [rad] (about ``z_{i-1}``); for an ``R`` joint
            added to ``q_i``, for a ``P`` joint the constant ``theta_i``.
        type: ``"R"`` (revolute) or ``"P"`` (prismatic).
        range: joint limits ``(q_min, q_max)`` [rad or m], ``None`` for unlimited.
        viscous: viscous friction ``F_v`` [N m s/rad or N s/m] -> MuJoCo ``damping``.
        static_friction: stiction level ``F_s`` [N m or N] -> MuJoCo ``frictionloss``.
        coulomb: kinetic (Coulomb) friction ``F_c <= F_s`` [N m or N]; applied by the envs.
        stribeck_velocity: Stribeck velocity ``v_s`` [rad/s or m/s] of the ``F_s -> F_c`` decay.
        rotor_inertia: rotor inertia ``J_m`` [kg m^2] (motor side).
        gear: gear reduction ratio ``K_r`` (motor angle = ``K_r`` x joint angle).
        torque_constant: motor torque constant ``K_tau`` [N m/A] (motor side).
        torque_limit: largest joint-side torque ``|tau_i|`` [N m or N]; ``None`` = no limit.
        velocity_limit: largest joint speed [rad/s or m/s] (used by trajectory generators).
    """

    a: float
    alpha: float
    d: float
    theta: float = 0.0
    type: str = "R"
    range: tuple[float, float] | None = None
    viscous: float = 0.0
    static_friction: float = 0.0
    coulomb: float = 0.0
    stribeck_velocity: float = 0.02
    rotor_inertia: float = 0.0
    gear: float = 1.0
    torque_constant: float = 1.0
    torque_limit: float | None = None
    velocity_limit: float = 1.0

    def __post_init__(self) -> None:
        if self.type not in JOINT_TYPES:
            raise ValueError(f"joint type must be 'R' or 'P', got {self.type!r}")
        if self.range is not None and not self.range[0] < self.range[1]:
            raise ValueError(f"joint range must be (low, high) with low < high, got {self.range}")
        for name in ("viscous", "static_friction", "coulomb", "rotor_inertia"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.coulomb > self.static_friction and self.static_friction > 0:
            raise ValueError(
                f"coulomb friction ({self.coulomb}) must not exceed static_friction "
                f"({self.static_friction}); set static_friction >= coulomb"
            )
        if self.gear <= 0 or self.torque_constant <= 0 or self.stribeck_velocity <= 0:
            raise ValueError("gear, torque_constant and stribeck_velocity must be > 0")

    @property
    def armature(self) -> float:
        """Reflected rotor inertia ``J_m K_r^2`` [kg m^2] (MuJoCo ``armature``)."""
        return self.rotor_inertia * self.gear**2

    @property
    def current_gain(self) -> float:
        """``K_eq = K_tau K_r`` [N m/A]: joint torque per motor ampere (thesis eq. 4.4)."""
        return self.torque_constant * self.gear


@dataclass(frozen=True)
class LinkInertia:
    """Inertial parameters of link ``i`` in its DH frame ``{i}``.

    Attributes:
        mass: ``m_i`` [kg], > 0.
        com: centre of mass ``c_i`` in ``{i}`` [m].
        inertia: inertia about the centre of mass, axes of ``{i}``, as
            ``(Ixx, Iyy, Izz, Ixy, Ixz, Iyz)`` [kg m^2] (MuJoCo ``fullinertia`` order).
    """

    mass: float
    com: tuple[float, float, float] = (0.0, 0.0, 0.0)
    inertia: tuple[float, float, float, float, float, float] = (1e-3, 1e-3, 1e-3, 0, 0, 0)

    def __post_init__(self) -> None:
        if not self.mass > 0:
            raise ValueError(f"link mass must be > 0 (MuJoCo needs it), got {self.mass}")
        if len(self.com) != 3 or len(self.inertia) != 6:
            raise ValueError("com needs 3 entries and inertia 6 (Ixx, Iyy, Izz, Ixy, Ixz, Iyz)")
        eig = np.linalg.eigvalsh(inertia_matrix(self.inertia))
        if eig.min() <= 0 or eig.sum() < 2 * eig.max() - 1e-12:
            raise ValueError(f"inertia {self.inertia} is not positive definite / triangle-valid")


@dataclass(frozen=True)
class ArmSpec:
    """A serial arm: DH rows, one :class:`LinkInertia` per link, and drawing data.

    Attributes:
        name: model name.
        joints: the DH rows, base to tip.
        links: inertial parameters, one per joint.
        base_pos: position of DH frame ``{0}`` in the world [m].
        base_quat: orientation of ``{0}`` in the world (w, x, y, z).
        radius: capsule radius of the drawn links [m].
        description: where the numbers come from.
    """

    name: str
    joints: tuple[DHJoint, ...]
    links: tuple[LinkInertia, ...]
    base_pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    base_quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    radius: float = 0.04
    description: str = ""

    def __post_init__(self) -> None:
        if len(self.joints) == 0:
            raise ValueError("an arm needs at least one joint")
        if len(self.joints) != len(self.links):
            raise ValueError(
                f"got {len(self.joints)} DH rows but {len(self.links)} links; give one "
                "LinkInertia per joint"
            )

    @property
    def n_joints(self) -> int:
        """Number of joints ``n``."""
        return len(self.joints)

    @property
    def joint_types(self) -> str:
        """Joint-type string, e.g. ``"RRPR"`` (the GIP kernel's argument)."""
        return "".join(j.type for j in self.joints)

    def joint_array(self, attribute: str) -> NDArray[np.float64]:
        """Per-joint values of a :class:`DHJoint` attribute, shape ``(n,)`` (``None`` -> inf)."""
        vals = [getattr(j, attribute) for j in self.joints]
        return np.array([np.inf if v is None else v for v in vals], dtype=np.float64)

    @property
    def joint_ranges(self) -> NDArray[np.float64]:
        """``(n, 2)`` joint limits (``+-inf`` where unlimited)."""
        return np.array(
            [(-np.inf, np.inf) if j.range is None else j.range for j in self.joints],
            dtype=np.float64,
        )

    def replace_joints(self, **changes: float) -> ArmSpec:
        """A copy with the same change on every joint, e.g. ``replace_joints(viscous=0)``."""
        joints = tuple(dataclasses.replace(j, **changes) for j in self.joints)
        return dataclasses.replace(self, joints=joints)

    def without_friction(self) -> ArmSpec:
        """A copy with viscous, static and Coulomb friction set to zero."""
        return self.replace_joints(viscous=0.0, static_friction=0.0, coulomb=0.0)

    def rigid(self) -> ArmSpec:
        """A copy without friction and without rotor inertia (pure rigid-body dynamics)."""
        return self.without_friction().replace_joints(rotor_inertia=0.0)


# ----------------------------------------------------------------------------- geometry


def inertia_matrix(inertia: Sequence[float]) -> NDArray[np.float64]:
    """3x3 inertia matrix from ``(Ixx, Iyy, Izz, Ixy, Ixz, Iyz)``."""
    ixx, iyy, izz, ixy, ixz, iyz = (float(v) for v in inertia)
    return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])


def rot_x(angle: float) -> NDArray[np.float64]:
    """Rotation matrix ``Rx(angle)``."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_z(angle: float) -> NDArray[np.float64]:
    """Rotation matrix ``Rz(angle)``."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _quat(rot: NDArray[np.float64]) -> list[float]:
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(rot).ravel())
    return q.tolist()


def solid_cylinder_inertia(
    mass: float, radius: float, length: float, axis: str = "x"
) -> tuple[float, float, float, float, float, float]:
    """Inertia of a solid cylinder about its centre: ``m r^2 / 2`` about its axis and
    ``m (3 r^2 + L^2) / 12`` about the two others; ``axis`` is ``"x"``, ``"y"`` or ``"z"``."""
    along = 0.5 * mass * radius**2
    across = mass * (3 * radius**2 + length**2) / 12.0
    diag = {
        "x": (along, across, across),
        "y": (across, along, across),
        "z": (across, across, along),
    }
    return (*diag[axis], 0.0, 0.0, 0.0)


# ----------------------------------------------------------------------------- builder


def build_arm_spec(
    arm: ArmSpec,
    *,
    timestep: float = 0.002,
    integrator: str = "implicitfast",
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81),
    friction: bool = True,
    armature: bool = True,
    torque_limits: bool = True,
    floor: bool = False,
) -> mujoco.MjSpec:
    """Build the MJCF of ``arm`` as a ``mujoco.MjSpec`` (see the module docstring for the map).

    Named elements: bodies ``link1..n``, joints ``j1..jn`` (hinge for ``R``, slide for
    ``P``, axis z of the body), torque actuators ``m1..mn`` (``gear = 1``: ``ctrl`` is the
    joint torque; ``ctrlrange = +-torque_limit`` when ``torque_limits``), sites ``base``,
    ``link1..n`` (DH frames ``{i}``) and ``ee`` (= ``{n}``), capsule geoms ``link{i}_z``
    (along ``z_{i-1}``) and ``link{i}_x`` (along ``x_i``) with collisions disabled.

    Args:
        arm: the arm.
        timestep: physics timestep [s].
        integrator: ``"implicitfast"``, ``"implicit"``, ``"RK4"`` or ``"Euler"``.
        gravity: world gravity [m/s^2].
        friction: write ``damping = F_v`` and ``frictionloss = F_s``; ``False`` -> zeros.
        armature: write ``armature = J_m K_r^2``; ``False`` -> zero.
        torque_limits: limit the actuators' ``ctrl`` to ``+-torque_limit``.
        floor: add a ground plane (drawing only, no contacts with the arm).

    Returns:
        the spec; ``spec.compile()`` gives the ``MjModel`` and ``spec.to_xml()`` the MJCF.
    """
    integrators = {
        "euler": mujoco.mjtIntegrator.mjINT_EULER,
        "rk4": mujoco.mjtIntegrator.mjINT_RK4,
        "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT,
        "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
    }
    if integrator.lower() not in integrators:
        raise ValueError(f"integrator must be one of {sorted(integrators)}, got {integrator!r}")
    if not timestep > 0:
        raise ValueError(f"timestep must be > 0, got {timestep}")

    spec = mujoco.MjSpec()
    spec.modelname = arm.name
    spec.option.timestep = timestep
    spec.option.integrator = integrators[integrator.lower()]
    spec.option.gravity = list(gravity)
    spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE
    spec.compiler.autolimits = True
    spec.compiler.degree = False  # angles (joint ranges) in radians

    world = spec.worldbody
    if floor:
        world.add_geom(
            name="floor",
            type=mujoco.mjtGeom.mjGEOM_PLANE,
            size=[2.0, 2.0, 0.05],
            rgba=[0.8, 0.8, 0.8, 1.0],
            contype=0,
            conaffinity=0,
        )
        world.add_light(name="light", pos=[0.0, 0.0, 3.0], dir=[0.0, 0.0, -1.0])
    world.add_site(
        name="base", pos=list(arm.base_pos), quat=list(arm.base_quat), size=[0.01, 0.01, 0.01]
    )

    # (pos, rot): pose of frame {i-1} in the parent body; B_i = {i-1} Rz(theta0_i) Tz(d0_i)
    parent = world
    pos = np.asarray(arm.base_pos, dtype=np.float64)
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, np.asarray(arm.base_quat, dtype=np.float64))
    rot = rot.reshape(3, 3)
    for i, (joint, link) in enumerate(zip(arm.joints, arm.links, strict=True), start=1):
        rot_b = rot @ rot_z(joint.theta)
        pos_b = pos + rot @ np.array([0.0, 0.0, joint.d])
        body = parent.add_body(name=f"link{i}", pos=pos_b.tolist(), quat=_quat(rot_b))
        _add_inertial(body, joint, link)
        _add_joint(body, i, joint, friction=friction, armature=armature)
        _add_geoms(body, i, joint, arm.radius)
        # DH frame {i} in B_i: Tx(a) Rx(alpha)
        rot_i = rot_x(joint.alpha)
        pos_i = np.array([joint.a, 0.0, 0.0])
        body.add_site(
            name=f"link{i}", pos=pos_i.tolist(), quat=_quat(rot_i), size=[0.01, 0.01, 0.01]
        )
        if i == arm.n_joints:
            body.add_site(name="ee", pos=pos_i.tolist(), quat=_quat(rot_i), size=[0.015] * 3)
            break
        # frame {i} is the parent frame of the next body's Rz(theta0) Tz(d0)
        pos, rot = pos_i, rot_i
        parent = body

    for i, joint in enumerate(arm.joints, start=1):
        act = spec.add_actuator(name=f"m{i}", target=f"j{i}")
        act.trntype = mujoco.mjtTrn.mjTRN_JOINT
        act.set_to_motor()
        act.gear = [1.0, 0, 0, 0, 0, 0]
        if torque_limits and joint.torque_limit is not None:
            act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
            act.ctrlrange = [-joint.torque_limit, joint.torque_limit]
        else:
            act.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
    return spec


def _add_inertial(body: mujoco.MjsBody, joint: DHJoint, link: LinkInertia) -> None:
    """Inertial parameters of ``{i}`` expressed in ``B_i`` (``{i} = B_i Tx(a) Rx(alpha)``)."""
    r = rot_x(joint.alpha)
    com_b = np.array([joint.a, 0.0, 0.0]) + r @ np.asarray(link.com, dtype=np.float64)
    inertia_b = r @ inertia_matrix(link.inertia) @ r.T
    body.explicitinertial = True
    body.mass = float(link.mass)
    body.ipos = com_b.tolist()
    body.iquat = [1.0, 0.0, 0.0, 0.0]
    body.fullinertia = [
        inertia_b[0, 0],
        inertia_b[1, 1],
        inertia_b[2, 2],
        inertia_b[0, 1],
        inertia_b[0, 2],
        inertia_b[1, 2],
    ]


def _add_joint(
    body: mujoco.MjsBody, i: int, joint: DHJoint, *, friction: bool, armature: bool
) -> None:
    kind = mujoco.mjtJoint.mjJNT_HINGE if joint.type == "R" else mujoco.mjtJoint.mjJNT_SLIDE
    jnt = body.add_joint(name=f"j{i}", type=kind, axis=[0.0, 0.0, 1.0], pos=[0.0, 0.0, 0.0])
    if joint.range is not None:
        jnt.limited = mujoco.mjtLimited.mjLIMITED_TRUE
        jnt.range = list(joint.range)
    else:
        jnt.limited = mujoco.mjtLimited.mjLIMITED_FALSE
    jnt.damping = [joint.viscous if friction else 0.0, 0.0, 0.0]  # (linear, poly terms)
    jnt.frictionloss = joint.static_friction if friction else 0.0
    jnt.solref_friction = list(FRICTION_SOLREF)
    jnt.solimp_friction = list(FRICTION_SOLIMP)
    jnt.armature = joint.armature if armature else 0.0


def _add_geoms(body: mujoco.MjsBody, i: int, joint: DHJoint, radius: float) -> None:
    """Capsules along ``z_{i-1}`` (from ``{i-1}`` to ``B_i``) and along ``x_i`` (length a)."""
    rgba = [0.25, 0.45, 0.85, 1.0] if i % 2 else [0.85, 0.55, 0.2, 1.0]
    common = dict(contype=0, conaffinity=0, group=1, rgba=rgba, mass=0.0)
    # a P joint's rod runs up to 0.3 m behind B_i; an R joint's from {i-1} (d behind B_i)
    z_len = (
        joint.d
        if joint.type == "R"
        else max(0.3, abs(joint.d) + (joint.range[1] if joint.range else 0.0))
    )
    if abs(z_len) > 1e-9:
        body.add_geom(
            name=f"link{i}_z",
            type=mujoco.mjtGeom.mjGEOM_CAPSULE,
            fromto=[0.0, 0.0, -z_len, 0.0, 0.0, 0.0],
            size=[radius, 0, 0],
            **common,
        )
    if abs(joint.a) > 1e-9:
        body.add_geom(
            name=f"link{i}_x",
            type=mujoco.mjtGeom.mjGEOM_CAPSULE,
            fromto=[0.0, 0.0, 0.0, joint.a, 0.0, 0.0],
            size=[0.8 * radius, 0, 0],
            **common,
        )
    body.add_geom(
        name=f"joint{i}",
        type=mujoco.mjtGeom.mjGEOM_SPHERE if joint.type == "R" else mujoco.mjtGeom.mjGEOM_BOX,
        size=[1.2 * radius, 1.2 * radius, 1.2 * radius],
        **common,
    )


def build_arm_model(arm: ArmSpec, **kwargs: object) -> mujoco.MjModel:
    """Compile :func:`build_arm_spec` (same keyword arguments) into a ``mujoco.MjModel``."""
    return build_arm_spec(arm, **kwargs).compile()


def arm_to_xml(arm: ArmSpec, **kwargs: object) -> str:
    """MJCF text of :func:`build_arm_spec` (same keyword arguments); loadable by MuJoCo and by
    pinocchio's ``buildModelFromMJCF``."""
    spec = build_arm_spec(arm, **kwargs)
    spec.compile()
    return spec.to_xml()


def dh_forward_kinematics(arm: ArmSpec, q: ArrayLike) -> NDArray[np.float64]:
    """``T_0n(q)`` in the world frame, 4x4 (base pose times the product of ``A_i(q_i)``).

    A numpy helper for task-space code (IK, reference generation); the MuJoCo site ``ee``
    gives the same pose.
    """
    q = np.asarray(q, dtype=np.float64)
    if q.shape != (arm.n_joints,):
        raise ValueError(f"q must have shape ({arm.n_joints},), got {q.shape}")
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, np.asarray(arm.base_quat, dtype=np.float64))
    t = np.eye(4)
    t[:3, :3] = rot.reshape(3, 3)
    t[:3, 3] = arm.base_pos
    for joint, qi in zip(arm.joints, q, strict=True):
        theta = joint.theta + (qi if joint.type == "R" else 0.0)
        d = joint.d + (qi if joint.type == "P" else 0.0)
        a = np.eye(4)
        a[:3, :3] = rot_z(theta) @ rot_x(joint.alpha)
        a[:3, 3] = [joint.a * math.cos(theta), joint.a * math.sin(theta), d]
        t = t @ a
    return t

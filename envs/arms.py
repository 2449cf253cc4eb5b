"""Robot tables for :mod:`mcpilco.envs.arm_builder`: UR10, an AdeptOne-like SCARA, the Franka
Emika Panda, the KUKA LBR iiwa 14, random arms.

Every function returns an :class:`~mcpilco.envs.arm_builder.ArmSpec` (pure data; nothing is
compiled here). Units: m, rad, kg, kg m^2, N m (N for prismatic joints), A.

Sources and assumptions
-----------------------
UR10
    DH table, link masses and centres of mass: Universal Robots' public "DH parameters for
    calculations of kinematics and dynamics" page (UR10 column), written from that public
    data: ``d1 = 0.1273, a2 = -0.612, a3 = -0.5723, d4 = 0.163941, d5 = 0.1157,
    d6 = 0.0922`` m, ``alpha = [pi/2, 0, 0, pi/2, -pi/2, 0]``, masses ``7.1, 12.7, 4.27, 2.0,
    2.0, 0.365`` kg; centres of mass in the DH frames ``{i}``. UR does not publish inertia
    tensors: they are solid-cylinder approximations (radii/lengths below). Drive data are
    plausible values, not datasheet numbers: harmonic-drive gear ``K_r = 101``; motor
    torque constants ``K_tau = 0.13`` N m/A (joints 1-3) and ``0.09`` N m/A (wrists), so
    ``K_tau K_r`` is about 13.1 and 9.1 N m/A; rotor inertias ``J_m = 7e-5, 7e-5, 3e-5, 1e-5,
    1e-5, 1e-5`` kg m^2 (armature ``J_m K_r^2`` = 0.71, 0.71, 0.31, 0.10, 0.10, 0.10);
    torque limits 330, 330, 150, 56, 56, 56 N m (UR joint sizes 4, 4, 3, 2, 2, 2); speed
    limits 120 deg/s (joints 1-2) and 180 deg/s; joint range +-2 pi. Friction (joint side):
    viscous ``F_v = 8, 8, 5, 1.5, 1.5, 1.5`` N m s/rad, Coulomb ``F_c = 7, 7, 4.5, 1.5, 1.5,
    1.5`` N m and stiction ``F_s = 1.3 F_c`` with Stribeck velocity 0.01 rad/s (the
    thesis's quasi-static threshold ``sigma_v = 1e-2`` rad/s, section 4.4.2).
SCARA (AdeptOne-like, joints R R P R, thesis section 3.4.1)
    The thesis gives no numbers; the kinematics follow the AdeptOne's public data as used in
    Spong, Hutchinson & Vidyasagar's SCARA example: inner arm ``a1 = 0.425`` m, outer arm
    ``a2 = 0.375`` m, column height ``d1 = 0.877`` m, ``alpha2 = pi`` (the quill points
    down), quill stroke 0.195 m, flange offset ``d4 = 0.06`` m. Masses (15, 8, 2, 1 kg),
    centres of mass (middle of each arm, quill centre above the tip) and cylinder inertias
    are assumptions. Joints 1-2 are direct drive (``K_r = 1``) as on the AdeptOne, the quill
    is a ball screw (``K_r = 2 pi / 0.02`` rad/m), joint 4 has ``K_r = 20``.
Franka Emika Panda (7 revolute joints)
    Bodies, frames, joint ranges and inertials transcribed from MuJoCo Menagerie's
    ``franka_emika_panda/panda.xml`` (google-deepmind/mujoco_menagerie, commit
    ``1b428b08bb26ca6024e7b21e8ff21a59f847eb87``, Apache-2.0 licence); its inertials are from
    Gaz, Cognetti, Oliva, Robuffo Giordano & De Luca, "Dynamic identification of the Franka
    Emika Panda robot with retrieval of feasible parameters using penalty-based
    optimization", IEEE RA-L 2019. No meshes. Menagerie's body frames are the modified-DH
    frames of Franka's documentation, ``B_{i+1} = B_i Tx(a_i) Rx(alpha_i) Rz(q_{i+1})
    Tz(d_{i+1})``, which is the builder's body-to-body transform: the DH rows below
    reproduce Menagerie's bodies ``link1..link6`` exactly; ``link7``'s body sits at the flange
    (Menagerie's ``link8``, 0.107 m along joint 7's axis), which moves the frame along the
    axis only. The gripper is rigid: the hand (0.73 kg) and both fingers (0.015 kg each,
    closed, at their body origins) are lumped into link 7 (mass, centre of mass and inertia
    combined by the parallel-axis theorem); the base ``link0`` is fixed to the world and
    carries no joint, so it is left out. Menagerie's joint ``armature = 0.1`` and ``damping =
    1`` (simulation settings, not identified values) are kept as ``rotor_inertia`` (gear 1)
    and ``viscous``; ``arm.rigid()`` drops them. Torque limits 87 N m (joints 1-4) and 12 N m
    (5-7) are Menagerie's actuator force ranges; speed limits 2.175 rad/s (joints 1-4) and
    2.61 rad/s (5-7) are Franka's datasheet values (not in the Menagerie file); torque
    constants are not published (1 N m/A, gear 1).
KUKA LBR iiwa 14 R820 (7 revolute joints)
    Bodies, frames, joint ranges and inertials transcribed from MuJoCo Menagerie's
    ``kuka_iiwa_14/iiwa14.xml`` (google-deepmind/mujoco_menagerie, commit
    ``28ffb48b5c1d409a37fbfbb01c023c12e61cdefd``, BSD 3-Clause licence, Copyright 2012-2022
    Robot Locomotion Group @ CSAIL: the Drake model). No meshes. Menagerie's body ``M_{i+1}
    = M_i Rz(q_i) T(p_{i+1}) R_{i+1}`` puts each joint axis on the body's z axis; every
    ``p_{i+1}`` lies along joint ``i``'s or joint ``i+1``'s axis and every ``R_{i+1}`` is
    ``Rx(alpha) Rz(theta0)``, so the builder's body ``B_i = M_i Tz(s_i)`` (the same
    orientation, shifted along its own axis by ``s = 0.2025, 0, 0.2155, 0, 0.2155, 0,
    0.045`` m) follows the standard DH rows ``d = 0.36, 0, 0.42, 0, 0.4, 0, 0.126`` m, ``a =
    0``, ``alpha = -pi/2, -pi/2, pi/2, -pi/2, pi/2, -pi/2, 0``, ``theta0 = 0, pi, pi, 0, pi,
    0, pi`` (Menagerie's ``q = 0`` is the table's ``q = 0``); ``link7``'s body sits at the
    flange (Menagerie's ``attachment_site``, 0.045 m along joint 7's axis). The base body is
    fixed to the world and left out. Menagerie's joints have no armature, damping or
    friction, so the table has none either. Torque limits 320, 320, 176, 176, 110, 40, 40
    N m and speed limits 85, 85, 100, 75, 130, 135, 135 deg/s are the values KUKA publishes
    for the LBR iiwa 14 R820 (not in the Menagerie file), written here without the datasheet
    at hand: check them against it before relying on them (they bound the simulated actuators'
    torques and the generated trajectories' speeds). Torque constants are not published
    (1 N m/A, gear 1).
Random arms
    :func:`random_arm` draws joint types, DH parameters, masses and centres of mass from
    documented uniform ranges (seeded), for Monte Carlo studies.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from mcpilco.envs.arm_builder import (
    ArmSpec,
    DHJoint,
    LinkInertia,
    inertia_matrix,
    rot_x,
    rot_z,
    solid_cylinder_inertia,
)

TWO_PI = 2.0 * math.pi


def ur10() -> ArmSpec:
    """The Universal Robots UR10 (6 revolute joints); see the module docstring for sources."""
    a = (0.0, -0.612, -0.5723, 0.0, 0.0, 0.0)
    d = (0.1273, 0.0, 0.0, 0.163941, 0.1157, 0.0922)
    alpha = (math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0)
    mass = (7.1, 12.7, 4.27, 2.0, 2.0, 0.365)
    com = (
        (0.021, 0.0, 0.027),
        (0.38, 0.0, 0.158),
        (0.24, 0.0, 0.068),
        (0.0, 0.007, 0.018),
        (0.0, 0.007, 0.018),
        (0.0, 0.0, -0.026),
    )
    # solid cylinders: (radius, length, axis in {i}); link 1 is the vertical column (y_1)
    shapes = (
        (0.075, 0.18, "y"),
        (0.075, 0.612, "x"),
        (0.06, 0.5723, "x"),
        (0.05, 0.12, "z"),
        (0.05, 0.12, "z"),
        (0.045, 0.05, "z"),
    )
    torque_constant = (0.13, 0.13, 0.13, 0.09, 0.09, 0.09)
    rotor_inertia = (7e-5, 7e-5, 3e-5, 1e-5, 1e-5, 1e-5)
    torque_limit = (330.0, 330.0, 150.0, 56.0, 56.0, 56.0)
    velocity_limit = (math.radians(120),) * 2 + (math.radians(180),) * 4
    viscous = (8.0, 8.0, 5.0, 1.5, 1.5, 1.5)
    coulomb = (7.0, 7.0, 4.5, 1.5, 1.5, 1.5)
    joints = tuple(
        DHJoint(
            a=a[i],
            alpha=alpha[i],
            d=d[i],
            theta=0.0,
            type="R",
            range=(-TWO_PI, TWO_PI),
            viscous=viscous[i],
            coulomb=coulomb[i],
            static_friction=1.3 * coulomb[i],
            stribeck_velocity=0.01,
            rotor_inertia=rotor_inertia[i],
            gear=101.0,
            torque_constant=torque_constant[i],
            torque_limit=torque_limit[i],
            velocity_limit=velocity_limit[i],
        )
        for i in range(6)
    )
    links = tuple(
        LinkInertia(mass=mass[i], com=com[i], inertia=solid_cylinder_inertia(mass[i], *shapes[i]))
        for i in range(6)
    )
    return ArmSpec(
        name="ur10",
        joints=joints,
        links=links,
        radius=0.06,
        description="UR10: public UR DH/mass/CoM data; cylinder inertias; plausible drives",
    )


def scara() -> ArmSpec:
    """An AdeptOne-like SCARA, joints ``RRPR`` (thesis section 3.4.1); see the module docstring."""
    lead = 0.02  # ball-screw lead of the quill [m/rev]
    joints = (
        DHJoint(
            a=0.425, alpha=0.0, d=0.877, type="R", range=(-2.618, 2.618),
            viscous=5.0, coulomb=4.0, static_friction=5.2, rotor_inertia=0.03, gear=1.0,
            torque_constant=3.0, torque_limit=250.0, velocity_limit=3.0,
        ),
        DHJoint(
            a=0.375, alpha=math.pi, d=0.0, type="R", range=(-2.574, 2.574),
            viscous=3.0, coulomb=2.5, static_friction=3.25, rotor_inertia=0.01, gear=1.0,
            torque_constant=1.5, torque_limit=120.0, velocity_limit=3.0,
        ),
        DHJoint(
            a=0.0, alpha=0.0, d=0.0, type="P", range=(0.0, 0.195),
            viscous=50.0, coulomb=10.0, static_friction=13.0, stribeck_velocity=0.005,
            rotor_inertia=1e-5, gear=TWO_PI / lead, torque_constant=0.1, torque_limit=400.0,
            velocity_limit=0.5,
        ),
        DHJoint(
            a=0.0, alpha=0.0, d=0.06, type="R", range=(-4.71, 4.71),
            viscous=0.5, coulomb=0.4, static_friction=0.52, rotor_inertia=2e-5, gear=20.0,
            torque_constant=0.1, torque_limit=20.0, velocity_limit=6.0,
        ),
    )  # fmt: skip
    links = (
        LinkInertia(15.0, (-0.2125, 0.0, 0.0), solid_cylinder_inertia(15.0, 0.08, 0.425, "x")),
        LinkInertia(8.0, (-0.19, 0.0, 0.0), solid_cylinder_inertia(8.0, 0.06, 0.375, "x")),
        LinkInertia(2.0, (0.0, 0.0, -0.15), solid_cylinder_inertia(2.0, 0.02, 0.3, "z")),
        LinkInertia(1.0, (0.0, 0.0, -0.02), solid_cylinder_inertia(1.0, 0.04, 0.06, "z")),
    )
    return ArmSpec(
        name="scara",
        joints=joints,
        links=links,
        radius=0.05,
        description="AdeptOne-like SCARA (RRPR): public kinematics, assumed inertias",
    )


def lump_inertials(
    parts: list[tuple[float, NDArray[np.float64], NDArray[np.float64]]],
) -> tuple[float, NDArray[np.float64], NDArray[np.float64]]:
    """One rigid body from ``parts`` ``(m_k, c_k, I_k)`` given in one frame (``I_k`` 3x3 about
    ``c_k``): ``m = sum m_k``, ``c = sum m_k c_k / m`` and, by the parallel-axis theorem,
    ``I = sum I_k + m_k (|r_k|^2 E - r_k r_k^T)`` with ``r_k = c_k - c``."""
    mass = sum(m for m, _, _ in parts)
    com = sum(m * np.asarray(c, dtype=np.float64) for m, c, _ in parts) / mass
    inertia = np.zeros((3, 3))
    for m, c, i_k in parts:
        r = np.asarray(c, dtype=np.float64) - com
        inertia += i_k + m * (float(r @ r) * np.eye(3) - np.outer(r, r))
    return mass, com, inertia


def _in_dh_frame(
    mass: float, com: NDArray[np.float64], inertia: NDArray[np.float64], a: float, alpha: float
) -> LinkInertia:
    """A link given in its body frame ``B_i`` re-expressed in DH frame ``{i} = B_i Tx(a)
    Rx(alpha)`` (the frame :class:`~mcpilco.envs.arm_builder.LinkInertia` is given in)."""
    r = rot_x(alpha)
    c = r.T @ (np.asarray(com, dtype=np.float64) - np.array([a, 0.0, 0.0]))
    i = r.T @ inertia @ r
    full = (i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2])
    return LinkInertia(float(mass), tuple(c.tolist()), tuple(float(v) for v in full))


# Menagerie panda.xml inertials, each in its body's frame: (mass, pos, fullinertia)
PANDA_INERTIALS: tuple[tuple[float, tuple[float, ...], tuple[float, ...]], ...] = (
    (4.970684, (0.003875, 0.002081, -0.04762),
     (0.70337, 0.70661, 0.0091170, -0.00013900, 0.0067720, 0.019169)),
    (0.646926, (-0.003141, -0.02872, 0.003495),
     (0.0079620, 2.8110e-2, 2.5995e-2, -3.925e-3, 1.0254e-2, 7.04e-4)),
    (3.228604, (2.7518e-2, 3.9252e-2, -6.6502e-2),
     (3.7242e-2, 3.6155e-2, 1.083e-2, -4.761e-3, -1.1396e-2, -1.2805e-2)),
    (3.587895, (-5.317e-2, 1.04419e-1, 2.7454e-2),
     (2.5853e-2, 1.9552e-2, 2.8323e-2, 7.796e-3, -1.332e-3, 8.641e-3)),
    (1.225946, (-1.1953e-2, 4.1065e-2, -3.8437e-2),
     (3.5549e-2, 2.9474e-2, 8.627e-3, -2.117e-3, -4.037e-3, 2.29e-4)),
    (1.666555, (6.0149e-2, -1.4117e-2, -1.0517e-2),
     (1.964e-3, 4.354e-3, 5.433e-3, 1.09e-4, -1.158e-3, 3.41e-4)),
    (7.35522e-01, (1.0517e-2, -4.252e-3, 6.1597e-2),
     (1.2516e-2, 1.0027e-2, 4.815e-3, -4.28e-4, -1.196e-3, -7.41e-4)),
)  # fmt: skip
PANDA_HAND: tuple[float, tuple[float, ...], tuple[float, ...]] = (
    0.73,
    (-0.01, 0.0, 0.03),
    (0.001, 0.0025, 0.0017, 0.0, 0.0, 0.0),
)  # Menagerie hand inertial, hand frame
PANDA_FINGER: tuple[float, tuple[float, ...], tuple[float, ...]] = (
    0.015,
    (0.0, 0.0, 0.0584),
    (2.375e-6, 2.375e-6, 7.5e-7, 0.0, 0.0, 0.0),
)  # one finger (closed), hand frame
PANDA_FLANGE = 0.107  # Menagerie link8 (flange) along joint 7's axis [m]
PANDA_HAND_YAW = -math.pi / 4  # hand frame about the flange's z (quat 0.924 0 0 -0.383)


def panda() -> ArmSpec:
    """The Franka Emika Panda (7 revolute joints, rigid gripper) from MuJoCo Menagerie's
    ``panda.xml``; see the module docstring for the source, the licence and the frames."""
    # builder rows (d_i, a_i, alpha_i): Menagerie's modified-DH body transforms
    d = (0.333, 0.0, 0.316, 0.0, 0.384, 0.0, PANDA_FLANGE)
    a = (0.0, 0.0, 0.0825, -0.0825, 0.0, 0.088, 0.0)
    alpha = (-math.pi / 2, math.pi / 2, math.pi / 2, -math.pi / 2, math.pi / 2, math.pi / 2, 0.0)
    ranges = ((-2.8973, 2.8973), (-1.7628, 1.7628), (-2.8973, 2.8973), (-3.0718, -0.0698),
              (-2.8973, 2.8973), (-0.0175, 3.7525), (-2.8973, 2.8973))  # fmt: skip
    torque_limit = (87.0,) * 4 + (12.0,) * 3
    velocity_limit = (2.175,) * 4 + (2.61,) * 3
    joints = tuple(
        DHJoint(
            a=a[i],
            alpha=alpha[i],
            d=d[i],
            type="R",
            range=ranges[i],
            viscous=1.0,
            rotor_inertia=0.1,
            torque_limit=torque_limit[i],
            velocity_limit=velocity_limit[i],
        )
        for i in range(7)
    )
    links = []
    for i, (mass, pos, full) in enumerate(PANDA_INERTIALS):
        com, inertia = np.array(pos), inertia_matrix(full)
        if i == 6:  # link 7's body sits at the flange; the rigid hand and fingers join it
            flange = np.array([0.0, 0.0, PANDA_FLANGE])
            yaw = rot_z(PANDA_HAND_YAW)
            parts = [(mass, com - flange, inertia)] + [
                (m, yaw @ np.array(c), yaw @ inertia_matrix(f) @ yaw.T)
                for m, c, f in (PANDA_HAND, PANDA_FINGER, PANDA_FINGER)
            ]
            mass, com, inertia = lump_inertials(parts)
        links.append(_in_dh_frame(mass, com, inertia, a[i], alpha[i]))
    return ArmSpec(
        name="panda",
        joints=joints,
        links=tuple(links),
        radius=0.05,
        description="Franka Emika Panda: MuJoCo Menagerie panda.xml (Apache-2.0), rigid gripper",
    )


# Menagerie iiwa14.xml inertials, each in its body's frame M_i: (mass, pos, diaginertia)
IIWA14_INERTIALS: tuple[tuple[float, tuple[float, ...], tuple[float, ...]], ...] = (
    (5.76, (0.0, -0.03, 0.12), (0.0333, 0.033, 0.0123)),
    (6.35, (0.0003, 0.059, 0.042), (0.0305, 0.0304, 0.011)),
    (3.5, (0.0, 0.03, 0.13), (0.025, 0.0238, 0.0076)),
    (3.5, (0.0, 0.067, 0.034), (0.017, 0.0164, 0.006)),
    (3.5, (0.0001, 0.021, 0.076), (0.01, 0.0087, 0.00449)),
    (1.8, (0.0, 0.0006, 0.0004), (0.0049, 0.0047, 0.0036)),
    (1.2, (0.0, 0.0, 0.02), (0.001, 0.001, 0.001)),
)
IIWA14_SHIFT = (0.2025, 0.0, 0.2155, 0.0, 0.2155, 0.0, 0.045)  # s_i: B_i = M_i Tz(s_i) [m]


def iiwa14() -> ArmSpec:
    """The KUKA LBR iiwa 14 R820 (7 revolute joints) from MuJoCo Menagerie's ``iiwa14.xml``;
    see the module docstring for the source, the licence and the frames."""
    d = (0.36, 0.0, 0.42, 0.0, 0.4, 0.0, 0.126)
    alpha = (-math.pi / 2, -math.pi / 2, math.pi / 2, -math.pi / 2, math.pi / 2, -math.pi / 2, 0.0)
    theta = (0.0, math.pi, math.pi, 0.0, math.pi, 0.0, math.pi)
    ranges = ((-2.96706, 2.96706), (-2.0944, 2.0944), (-2.96706, 2.96706), (-2.0944, 2.0944),
              (-2.96706, 2.96706), (-2.0944, 2.0944), (-3.05433, 3.05433))  # fmt: skip
    torque_limit = (320.0, 320.0, 176.0, 176.0, 110.0, 40.0, 40.0)
    velocity_limit = tuple(math.radians(v) for v in (85, 85, 100, 75, 130, 135, 135))
    joints = tuple(
        DHJoint(
            a=0.0,
            alpha=alpha[i],
            d=d[i],
            theta=theta[i],
            type="R",
            range=ranges[i],
            torque_limit=torque_limit[i],
            velocity_limit=velocity_limit[i],
        )
        for i in range(7)
    )
    links = tuple(
        _in_dh_frame(
            mass,
            np.array(pos) - np.array([0.0, 0.0, IIWA14_SHIFT[i]]),
            np.diag(diag),
            0.0,
            alpha[i],
        )
        for i, (mass, pos, diag) in enumerate(IIWA14_INERTIALS)
    )
    return ArmSpec(
        name="iiwa14",
        joints=joints,
        links=links,
        radius=0.06,
        description="KUKA LBR iiwa 14: MuJoCo Menagerie iiwa14.xml (BSD-3-Clause)",
    )


RANDOM_ARM_RANGES: dict[str, tuple[float, float]] = dict(
    a=(-0.4, 0.4),  # link length [m]
    d=(0.0, 0.3),  # link offset [m] (offset d0 of prismatic joints too)
    alpha=(-math.pi, math.pi),  # link twist [rad]
    theta=(-math.pi, math.pi),  # joint angle offset [rad] (constant theta of P joints)
    mass=(0.5, 5.0),  # link mass [kg]
    radius=(0.02, 0.06),  # radius of the cylinder giving the inertia [m]
    prismatic_range=(0.0, 0.3),  # joint range of P joints [m]; R joints get +-pi
)
"""Uniform ranges of :func:`random_arm`."""


def random_arm(
    n_joints: int = 6,
    seed: int | None = 0,
    joint_types: str | None = None,
    p_prismatic: float = 0.25,
    friction: bool = False,
) -> ArmSpec:
    """A random serial arm for Monte Carlo studies (thesis section 2.6.1 style).

    Args:
        n_joints: number of joints ``n >= 1``.
        seed: seed of ``numpy.random.default_rng``; the same seed gives the same arm.
        joint_types: e.g. ``"RRPR"`` to fix the types; ``None`` draws each joint ``P`` with
            probability ``p_prismatic``.
        p_prismatic: probability of a prismatic joint when ``joint_types`` is ``None``.
        friction: give the joints small random friction (viscous U(0.05, 0.5), Coulomb
            U(0.05, 0.5), stiction 1.3 x Coulomb) instead of none.

    Returns:
        the arm; parameters drawn uniformly from :data:`RANDOM_ARM_RANGES`; every link's
        centre of mass is drawn on the segment from ``{i-1}`` to ``{i}`` and its inertia is
        a solid cylinder of the link's length.
    """
    if n_joints < 1:
        raise ValueError(f"n_joints must be >= 1, got {n_joints}")
    rng = np.random.default_rng(seed)
    if joint_types is None:
        joint_types = "".join("P" if rng.random() < p_prismatic else "R" for _ in range(n_joints))
    if len(joint_types) != n_joints or set(joint_types) - {"R", "P"}:
        raise ValueError(f"joint_types must be {n_joints} letters R/P, got {joint_types!r}")
    r = RANDOM_ARM_RANGES
    joints, links = [], []
    for kind in joint_types:
        a = float(rng.uniform(*r["a"]))
        d = float(rng.uniform(*r["d"]))
        alpha = float(rng.uniform(*r["alpha"]))
        theta = float(rng.uniform(*r["theta"]))
        mass = float(rng.uniform(*r["mass"]))
        radius = float(rng.uniform(*r["radius"]))
        fv, fc = rng.uniform(0.05, 0.5, size=2) if friction else (0.0, 0.0)
        joints.append(
            DHJoint(
                a=a,
                alpha=alpha,
                d=d,
                theta=theta,
                type=kind,
                range=r["prismatic_range"] if kind == "P" else (-math.pi, math.pi),
                viscous=float(fv),
                coulomb=float(fc),
                static_friction=1.3 * float(fc),
                rotor_inertia=0.0,
                gear=1.0,
                torque_constant=1.0,
                torque_limit=None,
                velocity_limit=1.0 if kind == "R" else 0.2,
            )
        )
        # {i-1} origin in {i}: p = -(Rx(alpha)^T [a, 0, 0] + Rx(alpha)^T Rz^T [0, 0, d])
        # the CoM is drawn on the straight segment from the joint to the frame {i} origin
        ca, sa = math.cos(alpha), math.sin(alpha)
        joint_in_i = -np.array([a, d * sa, d * ca])
        s = float(rng.uniform(0.2, 0.8))
        com = tuple((s * joint_in_i).tolist())
        length = max(float(np.linalg.norm(joint_in_i)), 0.05)
        links.append(LinkInertia(mass, com, solid_cylinder_inertia(mass, radius, length, "x")))
    return ArmSpec(
        name=f"random{n_joints}_{joint_types}_{seed}",
        joints=tuple(joints),
        links=tuple(links),
        radius=0.03,
        description=f"random arm, seed {seed}, ranges RANDOM_ARM_RANGES",
    )


ARMS = {"ur10": ur10, "scara": scara, "panda": panda, "iiwa14": iiwa14}
"""Named robot tables (factories)."""

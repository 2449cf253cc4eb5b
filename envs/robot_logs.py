"""Synthetic robot logs made the way a real robot's are: simulated, controlled, measured.

:func:`simulate_log` forward-simulates a serial arm (an
:class:`~mcpilco.envs.arm_builder.ArmSpec`, e.g. :func:`~mcpilco.envs.arms.ur10`,
:func:`~mcpilco.envs.arms.scara` or :func:`~mcpilco.envs.arms.random_arm`) in MuJoCo. Two
models are built from the same table with :func:`~mcpilco.envs.arm_builder.build_arm_spec`
(Euler integrator, which treats joint damping implicitly; timestep ``dt``):

* the **nominal** model: the table as given (what the user believes; the controller's
  model): rigid-body parameters, ``armature = J_m K_r^2``, ``damping = F_v`` and
  ``frictionloss = F_s`` (the Coulomb/Stribeck correction of the arm envs is not applied;
  use ``arm.rigid()`` for a friction-free nominal model);
* the **true** model: the nominal one plus the :class:`HiddenEffect` list, written as MuJoCo
  physics where MuJoCo has it, otherwise as an applied generalised force.

The log holds only what a robot controller records: time, measured joint positions and
measured joint torques, or motor currents (``torque_constants``). The ground truth (true
states, true accelerations, noise-free torques, the effects, the settings and the true model's
MJCF) comes back separately (:class:`LogTruth`).

Controller (inner loop at the physics rate, exact state)
--------------------------------------------------------
``tau_c = Kp e + Kd (qd_ref - qd) + Ki z + g_nom(q)``, ``e = q_ref - q``,
``tau = clip(tau_c, +-tau_max)``, ``z`` the integral of ``e`` (:func:`servo_gains`)

* ``g_nom(q)``: gravity torques of the *nominal* model (MuJoCo RNE at zero velocity and
  acceleration, ``qfrc_bias`` with ``qd = 0``), so every hidden effect shows up as a
  tracking error and in the torque the controller has to apply.
* gains per joint (:func:`servo_gains`) from the nominal inertia ``M_jj`` of
  ``M_nom(q_ref(0))``, the bandwidth ``w_c = 2 pi f_c`` (``f_c = bandwidth`` Hz, default 5) and
  the torque limit: ``Kp_j = M_jj w_c^2``, raised to ``tau_max_j / e_sat``
  (:data:`SATURATION_ERROR`: a stiff joint servo asks for its full torque at a small tracking
  error, so that a light wrist joint is not held still by a few N m of friction) and capped
  at ``m_j w_max^2`` (``m_j`` the joint's lightest ``M_jj`` at :data:`LIGHTEST_SAMPLES`
  points of the reference), ``w_max = min(4 w_c, 0.2 / dt)`` (:data:`MAX_SERVO_BANDWIDTH`: no
  stick-slip hunting faster than the log resolves; :data:`MAX_SERVO_STEP`: the loop stays
  well inside the stability limit of the explicit servo at the physics rate); ``w_j = sqrt(Kp_j /
  M_jj)`` the joint's closed-loop bandwidth, ``Kd_j = 2 M_jj w_j`` (critical damping) and
  ``Ki_j = INTEGRAL_SHARE w_j Kp_j`` (:data:`INTEGRAL_SHARE`): integral action, which breaks
  a joint loose that static friction holds against the proportional term.
* the coupled loop (:func:`coupled_servo_cap`): where joint axes line up, a joint's effective
  inertia ``1 / (M^-1)_jj`` falls far below ``M_jj``; the bandwidths of the joints in the
  worst mode are lowered until ``dt lambda_max(M(q)^-1 K_d) <= 1``
  (:data:`MAX_DAMPING_STEP`) at :data:`COUPLING_SAMPLES` points of the reference, so that
  the servo never chatters at the physics rate.
* ``z`` integrates ``e`` at the physics rate while ``tau_c`` is within the limit
  (conditional integration: no wind-up while the torque saturates); it starts at 0.
* ``tau_max``: the table's ``torque_limit`` (no limit when ``None``; no floor then).
* reference: :class:`~mcpilco.envs.arm_env.SumOfSinusoids` per joint (random amplitudes,
  frequencies and phases from the seed), centred in the joint range (revolute ranges cut to
  ``+-pi``) with ``sum |A| <= 0.3`` of the half range (and ``<= 1`` rad) and
  ``sum |A w| <= 0.5 v_max``; the arm starts on the reference (``q = q_ref(0)``,
  ``qd = qd_ref(0)``).

Hidden effects (``HiddenEffect(kind, joint, value, ref)``; ``joint`` counts from 1)
-----------------------------------------------------------------------------------
``damping`` (N m s/rad or N s/m)
    joint ``damping += value``: passive force ``-value qd_j`` (implicit in the integrator).
``frictionloss`` (N m or N)
    joint ``frictionloss += value``: MuJoCo's dry-friction constraint, ``value`` against the
    motion while sliding, up to ``value`` holding the joint at rest.
``armature`` (kg m^2 or kg)
    joint ``armature += value``: extra reflected inertia ``value qdd_j``.
``stiffness`` (N m/rad or N/m; ``ref`` in rad or m)
    joint ``stiffness = value``, ``springref = ref``: force ``-value (q_j - ref)``.
``mass`` (factor)
    body ``link{joint}``: mass and inertia times ``value`` (a heavier link; centre of mass
    unchanged).
``payload`` (kg; ``ref`` in m)
    a solid sphere of radius :data:`PAYLOAD_RADIUS` and mass ``value`` fixed to the last
    link at the flange site ``ee``, moved ``ref`` along the flange's z axis.
``position_friction`` (N m or N; ``ref`` in 1/rad or 1/m)
    applied ``-value (1 + 0.5 sin(ref q_j)) tanh(qd_j / FRICTION_VELOCITY)``: a dry friction
    whose level varies with position (no diagnosis candidate has this form).
``cogging`` (N m or N; ``ref`` in 1/rad or 1/m; ``phase`` in rad)
    applied ``value sin(ref q_j + phase)`` (the actuator then supplies the opposite torque:
    ``value sin(ref q_j + phase + pi)``).

The applied forces (``qfrc_applied``) are evaluated from the state at the start of every
physics step (explicit in time).

Measurement model (sample time ``T = substeps dt``; defaults ``dt = 1`` ms, ``T = 4`` ms)
---------------------------------------------------------------------------------------
* ``t_k = k T`` [s], one row every ``substeps`` physics steps.
* ``q_k = s round((q(t_k) + e_k) / s)``: an encoder with step ``s = 2 pi / counts_per_rev``
  rad (``1 / counts_per_metre`` m for prismatic joints) read with electrical noise
  ``e_k ~ N(0, (encoder_noise s)^2)`` (``encoder_noise`` in counts); ``q_k`` lies on the
  encoder grid ``s Z``. The quantisation alone has a standard deviation ``s / sqrt(12)``.
* ``tau_k = tau(t_k - d) + n_k``, ``n_k ~ N(0, tau_noise^2)`` [N m or N]: the actuator torque
  applied over the physics step that starts at ``t_k - d``, measured with noise. ``d``
  (``tau_delay``, per joint, default 0) is a measurement delay: the torque column lags the
  positions (a time-stamp offset between two buses); between physics steps ``tau`` is
  interpolated linearly, before the first step it is the first step's.
* or, with ``torque_constants`` ``k_t`` (one per joint, joint side: ``k_t = K_tau K_r``, the
  motor's torque constant times the gear ratio, negative for a motor mounted reversed), the
  motor currents ``i_k = tau(t_k - d) / k_t + m_k``, ``m_k ~ N(0, current_noise^2)`` [A]: what a
  drive that reports currents logs, in place of ``tau_k`` (the table's values are
  ``arm.joint_array("torque_constant") * arm.joint_array("gear")``).

Ground truth (:class:`LogTruth`) per sample: the exact ``q, qd`` and ``qdd`` (MuJoCo's
``qacc`` of the true model at that state and torque: the equation-of-motion acceleration),
the noise-free ``tau``, and the reference. Without hidden effects, delay and noise,
``tau_k`` equals the nominal model's inverse dynamics (``mj_inverse``) at
``(q, qd, qdd)(t_k)``; with effects, ``tau_k - ID_nom`` is the effects' torque.

Files (:func:`write_log`): columns ``t, q1..qn, tau1..taun``, or ``t, q1..qn, i1..in`` for a
current log (the schema of ``mcpilco.models.robot_data``; no ``qd``/``qdd``), CSV or Parquet by
suffix; the ground truth (with the torque constants in ``settings``) optionally in a separate
JSON file.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from mcpilco.envs.arm_builder import ArmSpec, build_arm_spec
from mcpilco.envs.arm_env import SumOfSinusoids

FloatArray = NDArray[np.float64]

__all__ = [
    "EFFECT_KINDS",
    "HiddenEffect",
    "LogTruth",
    "RobotLog",
    "build_models",
    "gravity_torque",
    "coupled_servo_cap",
    "servo_gains",
    "simulate_log",
    "write_log",
]

JOINT_KINDS = ("damping", "frictionloss", "armature", "stiffness")
"""Effects written as MuJoCo joint attributes."""
BODY_KINDS = ("mass", "payload")
"""Effects written as MuJoCo bodies."""
APPLIED_KINDS = ("position_friction", "cogging")
"""Effects MuJoCo lacks, applied as generalised forces."""
EFFECT_KINDS = JOINT_KINDS + BODY_KINDS + APPLIED_KINDS
"""Every kind of :class:`HiddenEffect`."""

PAYLOAD_RADIUS = 0.03
"""Radius [m] of the solid sphere that gives the payload's inertia."""
FRICTION_VELOCITY = 0.01
"""Velocity [rad/s or m/s] of the ``tanh`` that smooths the applied dry friction's sign."""
PHYSICS_TIMESTEP = 1e-3
"""Default physics timestep [s]."""
SUBSTEPS = 4
"""Default physics steps per logged sample (``T = 4`` ms)."""
SATURATION_ERROR = {"R": 0.1, "P": 0.01}
"""Tracking error [rad, m] at which a joint servo's position gain alone asks for the joint's
torque limit: the floor ``Kp_j >= tau_max_j / e_sat`` (:func:`servo_gains`)."""
MAX_SERVO_BANDWIDTH = 4.0
"""Largest closed-loop bandwidth of a joint over the design bandwidth ``w_c`` (20 Hz at 5 Hz):
the cap ``Kp_j <= M_jj (4 w_c)^2``. Faster loops on a light joint (the iiwa 14's first joint,
0.1 kg m^2 about its axis upright, at 28 Hz) hunt in stick-slip against dry friction at a
rate the log's samples do not resolve."""
MAX_SERVO_STEP = 0.2
"""Largest ``w_j dt`` of a joint's closed loop: the cap ``Kp_j <= M_jj (0.2 / dt)^2`` keeps the
explicit servo, evaluated once per physics step, far from its stability limit."""
LIGHTEST_SAMPLES = 50
"""Configurations along the reference at which :func:`simulate_log` reads each joint's
lightest inertia for the cap of :func:`servo_gains`."""
MAX_DAMPING_STEP = 1.0
"""Largest ``dt lambda_max(M(q)^-1 K_d)`` along the reference (:func:`coupled_servo_cap`): the
explicit damping term never reverses a velocity mode within one physics step (2 is the
stability limit, where the servo chatters at the physics rate)."""
COUPLING_SAMPLES = 500
"""Configurations along the reference at which :func:`simulate_log` checks the coupled loop
(:func:`coupled_servo_cap`): every 10 ms of a 5 s log, dense enough to catch the brief pass of
a 7-joint arm through a configuration where two joint axes line up."""
COUPLING_ITERATIONS = 50
"""Most rescaling rounds of :func:`coupled_servo_cap` before the uniform fallback."""
INTEGRAL_SHARE = 0.1
"""Integral gain over ``w_j Kp_j`` (:func:`servo_gains`): integral time ``10 / w_j``, slow
against the PD loop, which it leaves critically damped in all but the slowest pole."""
TRACKING_LIMIT = {"R": math.pi, "P": 1.0}
"""Largest tracking error |q - q_ref| [rad, m] of a joint under the controller before the
simulation counts as diverged (the arm out of control, e.g. an effect too stiff for ``dt``)."""


class SimulationDiverged(ValueError):
    """The simulated arm left the controller's reach (:data:`TRACKING_LIMIT`)."""


@dataclass(frozen=True)
class HiddenEffect:
    """One physical effect of the true robot that the nominal model lacks (module docstring).

    Attributes:
        kind: one of :data:`EFFECT_KINDS`.
        joint: joint number ``1..n``; for ``mass`` the link (body ``link{joint}``); ignored
            for ``payload`` (always at the flange).
        value: size of the effect (units per kind in the module docstring).
        ref: second parameter: ``springref`` of ``stiffness``, spatial frequency of
            ``position_friction``/``cogging``, offset of ``payload``.
        phase: phase of ``cogging`` at ``q_j = 0`` [rad].
    """

    kind: str
    joint: int
    value: float
    ref: float = 0.0
    phase: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in EFFECT_KINDS:
            raise ValueError(f"unknown effect kind {self.kind!r}; use one of {EFFECT_KINDS}")
        if self.joint < 1 and self.kind != "payload":
            raise ValueError(f"joint counts from 1, got {self.joint}")
        if self.kind in ("mass", "payload", "armature", "frictionloss") and self.value < 0:
            raise ValueError(f"{self.kind} needs value >= 0, got {self.value}")


@dataclass
class LogTruth:
    """What the log does not show: exact states, noise-free torques, effects and settings.

    Attributes:
        q, qd, qdd: exact ``(N, n)`` joint positions, velocities and equation-of-motion
            accelerations of the true model at the logged instants.
        tau: ``(N, n)`` torque applied at the logged instants (before the measurement delay
            and noise).
        q_ref, qd_ref: ``(N, n)`` the controller's reference.
        effects: the hidden effects.
        settings: controller gains, encoder steps, noise levels, timestep, sample time, and
            for a current log ``torque_constants`` (``k_t`` per joint) and ``current_noise``.
        true_xml: MJCF of the true model (the "corrected" model the diagnosis aims at).
        torque_constants: ``(n,)`` the ``k_t`` the currents were written with [N m/A or N/A]
            (``i = tau / k_t``), or ``None`` for a torque log.
    """

    q: FloatArray
    qd: FloatArray
    qdd: FloatArray
    tau: FloatArray
    q_ref: FloatArray
    qd_ref: FloatArray
    effects: tuple[HiddenEffect, ...]
    settings: dict[str, Any]
    true_xml: str
    torque_constants: FloatArray | None = None

    def to_json(self) -> dict[str, Any]:
        """Effects and settings as JSON-serialisable data (no arrays)."""
        return {
            "effects": [dataclasses.asdict(e) for e in self.effects],
            "settings": self.settings,
        }


@dataclass
class RobotLog:
    """A simulated log: ``table`` (columns ``t, q1..qn`` and ``tau1..taun`` or, for a current
    log, ``i1..in``) and its ``truth``."""

    table: pd.DataFrame
    truth: LogTruth

    @property
    def n_joints(self) -> int:
        return int(self.truth.q.shape[1])


# ----------------------------------------------------------------------------- models


def _true_spec(arm: ArmSpec, effects: Sequence[HiddenEffect], **build: Any) -> mujoco.MjSpec:
    """The nominal spec with the MuJoCo-expressible effects written in."""
    spec = build_arm_spec(arm, **build)
    n = arm.n_joints
    for e in effects:
        if e.kind != "payload" and e.joint > n:
            raise ValueError(f"{e.kind}: joint {e.joint} but the arm has {n} joints")
        if e.kind in JOINT_KINDS:
            jnt = spec.joint(f"j{e.joint}")
            if e.kind == "damping":
                jnt.damping[0] += e.value
            elif e.kind == "frictionloss":
                jnt.frictionloss += e.value
            elif e.kind == "armature":
                jnt.armature += e.value
            else:
                jnt.stiffness[0] = e.value
                jnt.springref = e.ref
        elif e.kind == "mass":
            body = spec.body(f"link{e.joint}")
            body.mass *= e.value
            body.fullinertia = (np.asarray(body.fullinertia) * e.value).tolist()
        elif e.kind == "payload":
            site = spec.site("ee")
            rot = np.zeros(9)
            mujoco.mju_quat2Mat(rot, np.asarray(site.quat, dtype=np.float64))
            pos = np.asarray(site.pos) + rot.reshape(3, 3) @ np.array([0.0, 0.0, e.ref])
            load = spec.body(f"link{n}").add_body(name="payload", pos=pos.tolist())
            load.explicitinertial = True
            load.mass = e.value
            load.ipos = [0.0, 0.0, 0.0]
            load.inertia = [0.4 * e.value * PAYLOAD_RADIUS**2] * 3
    return spec


def build_models(
    arm: ArmSpec, effects: Sequence[HiddenEffect] = (), timestep: float = PHYSICS_TIMESTEP
) -> tuple[mujoco.MjModel, mujoco.MjModel, str]:
    """``(nominal, true, true_xml)``: the compiled models of :func:`simulate_log` (Euler
    integrator with implicit damping, no actuator limits: the controller clips) and the
    true model's MJCF."""
    build = dict(timestep=timestep, integrator="Euler", torque_limits=False)
    nominal = build_arm_spec(arm, **build).compile()
    spec = _true_spec(arm, effects, **build)
    true = spec.compile()
    return nominal, true, spec.to_xml()


def _applied_force(effects: Sequence[HiddenEffect], q: FloatArray, qd: FloatArray) -> FloatArray:
    """``qfrc_applied`` of the effects MuJoCo lacks at state ``(q, qd)``."""
    out = np.zeros_like(q)
    for e in effects:
        j = e.joint - 1
        if e.kind == "position_friction":
            level = e.value * (1.0 + 0.5 * math.sin(e.ref * q[j]))
            out[j] -= level * math.tanh(qd[j] / FRICTION_VELOCITY)
        elif e.kind == "cogging":
            out[j] += e.value * math.sin(e.ref * q[j] + e.phase)
    return out


def gravity_torque(model: mujoco.MjModel, data: mujoco.MjData, q: FloatArray) -> FloatArray:
    """``g(q)``: RNE of ``model`` at zero velocity and acceleration (``data`` is scratch)."""
    data.qpos[:] = q
    data.qvel[:] = 0.0
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    out = np.zeros(model.nv)
    mujoco.mj_rne(model, data, 0, out)
    return out


def _reference(arm: ArmSpec, rng: np.random.Generator, duration: float) -> SumOfSinusoids:
    ranges = arm.joint_ranges.copy()
    for j, joint in enumerate(arm.joints):
        if joint.type == "R":
            ranges[j] = np.clip(ranges[j], -math.pi, math.pi)
    centre = ranges.mean(axis=1)
    amplitude = np.minimum(0.3 * 0.5 * (ranges[:, 1] - ranges[:, 0]), 1.0)
    max_speed = 0.5 * arm.joint_array("velocity_limit")
    return SumOfSinusoids.random(rng, centre, amplitude, max_speed, duration=duration)


def _per_joint(value: ArrayLike, n: int, name: str) -> FloatArray:
    try:
        arr = np.broadcast_to(np.asarray(value, dtype=np.float64), (n,)).copy()
    except ValueError as err:
        raise ValueError(f"{name} needs one value or {n} (one per joint), got {value!r}") from err
    if (arr < 0).any():
        raise ValueError(f"{name} must be >= 0, got {arr}")
    return arr


def _torque_constants(value: ArrayLike, n: int) -> FloatArray:
    """``k_t (n,)``: finite and nonzero, one value or one per joint."""
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim > 1 or arr.size not in (1, n):
        raise ValueError(
            f"torque_constants needs one value or {n} (one per joint), got {arr.size}: {value!r}"
        )
    arr = np.broadcast_to(arr.reshape(-1), (n,)).copy()
    bad = np.flatnonzero(~np.isfinite(arr) | (arr == 0))
    if bad.size:
        raise ValueError(
            f"torque_constants: joint {bad[0] + 1} has k_t = {arr[bad[0]]}; a torque constant "
            "must be finite and nonzero (negative for a motor mounted reversed)"
        )
    return arr


# ----------------------------------------------------------------------------- simulation
def servo_gains(
    inertia: ArrayLike,
    torque_limit: ArrayLike,
    joint_types: str,
    bandwidth: float = 5.0,
    timestep: float = PHYSICS_TIMESTEP,
    lightest: ArrayLike | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``(Kp, Kd, Ki)`` per joint of the generator's joint servo (module docstring).

    ``Kp_j = min(max(M_jj w_c^2, tau_max_j / e_sat), m_j w_max^2)`` with ``w_c = 2 pi
    bandwidth``, ``w_max = min(MAX_SERVO_BANDWIDTH w_c, MAX_SERVO_STEP / dt)`` and ``e_sat``
    :data:`SATURATION_ERROR` of the joint's type (no floor where ``tau_max`` is infinite);
    ``w_j = sqrt(Kp_j / M_jj)``; ``Kd_j = 2 M_jj w_j``; ``Ki_j = INTEGRAL_SHARE w_j Kp_j``;
    ``m_j``: the joint's lightest inertia along the motion (``M_jj`` when not given), so that
    the cap holds wherever the arm goes; the cap never takes ``Kp_j`` below ``M_jj w_c^2``.

    Args:
        inertia: ``M_jj`` (n,) [kg m^2 or kg], the nominal mass matrix's diagonal (> 0).
        torque_limit: ``tau_max`` (n,) [N m or N], ``inf`` where unlimited.
        joint_types: ``"R"``/``"P"`` per joint.
        bandwidth: ``f_c`` [Hz] on the joint's own inertia.
        timestep: the physics timestep ``dt`` [s] at which the servo runs.
        lightest: ``m_j`` (n,), each joint's smallest ``M_jj`` along the motion (> 0).
    """
    m = np.asarray(inertia, dtype=np.float64)
    low = m if lightest is None else np.minimum(np.asarray(lightest, dtype=np.float64), m)
    limit = np.asarray(torque_limit, dtype=np.float64)
    shapes = {m.shape, limit.shape, low.shape, (len(joint_types),)}
    if len(shapes) > 1 or not (low > 0).all():
        raise ValueError(
            f"inertia {m} must be > 0, one per joint like torque_limit {limit} and joint_types "
            f"{joint_types!r}"
        )
    if not (bandwidth > 0 and timestep > 0):
        raise ValueError(f"bandwidth and timestep must be > 0, got {bandwidth}, {timestep}")
    w_c = 2.0 * math.pi * bandwidth
    e_sat = np.array([SATURATION_ERROR[t] for t in joint_types])
    floor = np.where(np.isfinite(limit), limit / e_sat, 0.0)
    w_max = min(MAX_SERVO_BANDWIDTH * w_c, MAX_SERVO_STEP / timestep)
    kp = np.minimum(np.maximum(m * w_c**2, floor), np.maximum(low * w_max**2, m * w_c**2))
    w = np.sqrt(kp / m)
    return kp, 2.0 * m * w, INTEGRAL_SHARE * w * kp


def coupled_servo_cap(
    kp: ArrayLike,
    kd: ArrayLike,
    ki: ArrayLike,
    masses: ArrayLike,
    timestep: float = PHYSICS_TIMESTEP,
    limit: float = MAX_DAMPING_STEP,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Servo gains whose coupled loop stays within ``limit`` at every configuration.

    :func:`servo_gains` caps each joint on its own inertia ``M_jj``, but the explicit servo
    acts on the whole arm: one physics step maps the velocity through ``I - dt M(q)^-1 K_d``
    (``K_p`` adds ``dt^2 M^-1 K_p``, negligible at the capped gains), which reverses a mode
    when ``rho = dt lambda_max(M^-1 K_d) > 1`` and diverges (chatters at the physics rate,
    the torque bang-bang at its limit) beyond 2. Where two joint axes line up (a 7-joint
    arm's first and third joints with the second near 0) the first joint's effective inertia
    ``1 / (M^-1)_11`` falls far below ``M_11``, and ``rho`` past 2. The eigenvalues of
    ``M^-1 K_d`` are those of the symmetric ``A = K_d^(1/2) M^-1 K_d^(1/2)``; while the worst
    configuration's ``rho`` exceeds ``limit``, each joint's bandwidth is scaled by
    ``f_j = (limit / rho)^(u_j^2)`` (``u`` the unit eigenvector of that mode: the joints in
    the mode share the reduction in proportion to their share ``u_j^2`` of it, with
    ``prod_j f_j = limit / rho``), i.e. ``K_d`` by ``f_j``, ``K_p`` by ``f_j^2`` and ``K_i``
    by ``f_j^3`` (damping ratios kept). Gains that already satisfy the cap come back unchanged.

    Args:
        kp, kd, ki: the gains (n,) of :func:`servo_gains`.
        masses: ``M(q)`` (S, n, n) of the nominal model at configurations along the motion.
        timestep: the physics timestep ``dt`` [s].
        limit: the largest ``rho`` (:data:`MAX_DAMPING_STEP`).
    """
    kp, kd, ki = (np.array(x, dtype=np.float64) for x in (kp, kd, ki))
    m = np.asarray(masses, dtype=np.float64)
    if m.ndim != 3 or m.shape[1:] != (kd.size, kd.size) or not limit > 0:
        raise ValueError(
            f"masses must be (S, {kd.size}, {kd.size}) and limit > 0, got {m.shape}, {limit}"
        )
    inv = np.linalg.inv(m)

    def worst() -> tuple[float, FloatArray]:
        r = np.sqrt(kd)
        w, v = np.linalg.eigh(r[:, None] * inv * r[None, :])
        s = int(np.argmax(w[:, -1]))
        return float(timestep * w[s, -1]), v[s, :, -1]

    for _ in range(COUPLING_ITERATIONS):
        rho, u = worst()
        if rho <= limit:
            return kp, kd, ki
        f = (limit / rho) ** (u**2)
        kd, kp, ki = kd * f, kp * f**2, ki * f**3
    rho, _ = worst()
    if rho > limit:  # the rounds did not converge: scale every joint alike
        f = np.full_like(kd, limit / rho)
        kd, kp, ki = kd * f, kp * f**2, ki * f**3
    return kp, kd, ki


def simulate_log(
    arm: ArmSpec,
    effects: Sequence[HiddenEffect] = (),
    duration: float = 10.0,
    seed: int = 0,
    *,
    timestep: float = PHYSICS_TIMESTEP,
    substeps: int = SUBSTEPS,
    bandwidth: float = 5.0,
    counts_per_rev: float = 2**17,
    counts_per_metre: float = 1e6,
    encoder_noise: float = 0.3,
    tau_noise: ArrayLike = 0.05,
    tau_delay: ArrayLike = 0.0,
    reference: SumOfSinusoids | None = None,
    torque_constants: ArrayLike | None = None,
    current_noise: ArrayLike = 0.01,
) -> RobotLog:
    """Simulate ``duration`` s of the true arm tracking a reference; measure it (module
    docstring).

    Args:
        arm: the nominal arm table.
        effects: hidden effects of the true arm.
        duration: log length [s].
        seed: seeds the reference and the measurement noise; same seed, same log.
        timestep: physics timestep ``dt`` [s].
        substeps: physics steps per sample (``T = substeps dt``).
        bandwidth: controller bandwidth ``f_c`` [Hz] on each joint's nominal inertia
            (:func:`servo_gains`).
        counts_per_rev: encoder counts per revolution (revolute joints).
        counts_per_metre: encoder counts per metre (prismatic joints).
        encoder_noise: standard deviation of the encoder's reading noise [counts] before
            quantisation (0: quantisation only).
        tau_noise: standard deviation of the torque measurement noise [N m or N], one value
            or one per joint.
        tau_delay: measurement delay ``d`` of the torque columns [s] (>= 0), one value or one
            per joint.
        reference: the joint reference; default a random one from ``seed``.
        torque_constants: joint-side torque constants ``k_t`` [N m/A or N/A], one value or one
            per joint (finite, nonzero): the log then holds motor currents ``i = tau / k_t``
            plus noise (columns ``i1..in``) instead of torques, and ``tau_noise`` is unused.
        current_noise: standard deviation of the current measurement noise [A], one value or
            one per joint (current logs only).

    Returns:
        the log and its ground truth.

    Raises:
        SimulationDiverged: a joint's tracking error left :data:`TRACKING_LIMIT` (the effects
            are too stiff for ``timestep`` or beyond the controller).
    """
    if substeps < 1 or not timestep > 0 or not duration > 0:
        raise ValueError("need substeps >= 1, timestep > 0 and duration > 0")
    if not (counts_per_rev > 0 and counts_per_metre > 0 and encoder_noise >= 0):
        raise ValueError(
            f"encoder counts must be > 0 and encoder_noise >= 0, got counts_per_rev="
            f"{counts_per_rev}, counts_per_metre={counts_per_metre}, encoder_noise={encoder_noise}"
        )
    effects = tuple(effects)
    n = arm.n_joints
    k_t = None if torque_constants is None else _torque_constants(torque_constants, n)
    sigma_i = _per_joint(current_noise, n, "current_noise")
    sigma_tau = _per_joint(tau_noise, n, "tau_noise")
    rng = np.random.default_rng(seed)
    ref = reference if reference is not None else _reference(arm, rng, duration)
    nominal, true, true_xml = build_models(arm, effects, timestep)
    nom_data = mujoco.MjData(nominal)
    data = mujoco.MjData(true)

    q0, qd0, _ = ref(0.0)
    nom_data.qpos[:] = q0
    mujoco.mj_forward(nominal, nom_data)
    mass = np.zeros((n, n))
    mujoco.mj_fullM(nominal, nom_data, mass)

    def masses_along(samples: int) -> FloatArray:  # M_nom(q_ref(t)) at evenly spaced t
        out = np.zeros((samples, n, n))
        for i, t in enumerate(np.linspace(0.0, duration, samples)):
            nom_data.qpos[:] = ref(float(t))[0]
            mujoco.mj_forward(nominal, nom_data)
            mujoco.mj_fullM(nominal, nom_data, out[i])
        return out

    # each joint's smallest M_jj along the reference
    lightest = np.minimum(
        np.diag(mass), np.diagonal(masses_along(LIGHTEST_SAMPLES), 0, 1, 2).min(0)
    )
    limit = arm.joint_array("torque_limit")
    kp, kd, ki = servo_gains(
        np.diag(mass), limit, arm.joint_types, bandwidth, timestep, lightest=lightest
    )
    kp, kd, ki = coupled_servo_cap(kp, kd, ki, masses_along(COUPLING_SAMPLES), timestep)
    integral = np.zeros(n)  # z: the integral of the tracking error
    applied = any(e.kind in APPLIED_KINDS for e in effects)

    n_samples = int(math.floor(duration / (timestep * substeps))) + 1
    delay = _per_joint(tau_delay, n, "tau_delay")
    rec = {k: np.zeros((n_samples, n)) for k in ("q", "qd", "qdd", "tau", "q_ref", "qd_ref")}
    tau_steps = np.zeros((n_samples * substeps, n))  # the torque of every physics step
    data.qpos[:] = q0
    data.qvel[:] = qd0
    for k in range(n_samples):
        for s in range(substeps):
            t = (k * substeps + s) * timestep
            q, qd = data.qpos.copy(), data.qvel.copy()
            q_ref, qd_ref, _ = ref(t)
            e = q_ref - q
            tau_c = (
                kp * e + kd * (qd_ref - qd) + ki * integral + gravity_torque(nominal, nom_data, q)
            )
            tau = np.clip(tau_c, -limit, limit)
            integral += np.where(np.abs(tau_c) < limit, e * timestep, 0.0)
            data.ctrl[:] = tau
            if applied:
                data.qfrc_applied[:] = _applied_force(effects, q, qd)
            mujoco.mj_step(true, data)  # qacc: acceleration at the state before the step
            tau_steps[k * substeps + s] = tau
            if s == 0:
                rec["q"][k], rec["qd"][k], rec["qdd"][k] = q, qd, data.qacc
                rec["tau"][k], rec["q_ref"][k], rec["qd_ref"][k] = tau, q_ref, qd_ref

    limit_q = np.array([TRACKING_LIMIT[j.type] for j in arm.joints])
    err = np.abs(rec["q"] - rec["q_ref"])
    bad = ~np.isfinite(err) | (err > limit_q)
    unstable = data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number > 0  # MuJoCo reset the state
    if unstable and not bad.any():
        bad[np.unravel_index(np.argmax(np.abs(rec["qdd"])), bad.shape)] = True
    if bad.any():
        k, j = np.argwhere(bad)[0]
        raise SimulationDiverged(
            f"the simulated arm diverged: joint {j + 1} is {err[k, j]:.3g} from its reference at "
            f"t = {k * timestep * substeps:.3f} s (limit {limit_q[j]:g}"
            f"{'; MuJoCo found the acceleration unstable' if unstable else ''}); effects "
            f"{[(e.kind, e.joint, e.value) for e in effects]} are too stiff for the time step "
            f"{timestep:g} s or beyond the controller"
        )
    step = np.array(
        [
            2.0 * math.pi / counts_per_rev if j.type == "R" else 1.0 / counts_per_metre
            for j in arm.joints
        ]
    )
    reading = rec["q"] + rng.normal(0.0, 1.0, rec["q"].shape) * encoder_noise * step
    q_meas = np.round(reading / step) * step
    t = np.arange(n_samples) * (timestep * substeps)
    t_steps = np.arange(n_samples * substeps) * timestep
    logged = np.stack(
        [
            np.interp(t - delay[j], t_steps, tau_steps[:, j]) if delay[j] > 0 else rec["tau"][:, j]
            for j in range(n)
        ],
        axis=1,
    )
    white = rng.normal(0.0, 1.0, rec["tau"].shape)
    if k_t is None:
        out, y_meas = "tau", logged + white * sigma_tau
    else:
        out, y_meas = "i", logged / k_t + white * sigma_i
    cols: dict[str, FloatArray] = {"t": t}
    cols.update({f"q{j + 1}": q_meas[:, j] for j in range(n)})
    cols.update({f"{out}{j + 1}": y_meas[:, j] for j in range(n)})
    settings = {
        "arm": arm.name,
        "seed": seed,
        "timestep": timestep,
        "sample_time": timestep * substeps,
        "bandwidth": bandwidth,
        "kp": kp.tolist(),
        "kd": kd.tolist(),
        "ki": ki.tolist(),
        "encoder_step": step.tolist(),
        "encoder_noise": encoder_noise,
        "tau_delay": delay.tolist(),
    }
    if k_t is None:
        settings["tau_noise"] = sigma_tau.tolist()
    else:
        settings["torque_constants"] = k_t.tolist()
        settings["current_noise"] = sigma_i.tolist()
    truth = LogTruth(
        q=rec["q"],
        qd=rec["qd"],
        qdd=rec["qdd"],
        tau=rec["tau"],
        q_ref=rec["q_ref"],
        qd_ref=rec["qd_ref"],
        effects=effects,
        settings=settings,
        true_xml=true_xml,
        torque_constants=k_t,
    )
    return RobotLog(table=pd.DataFrame(cols), truth=truth)


def write_log(path: str | Path, log: RobotLog, truth_path: str | Path | None = None) -> Path:
    """Write ``log.table`` as CSV (``.csv``) or Parquet (``.parquet``/``.pq``); with
    ``truth_path`` also the effects and settings as JSON (kept apart from the log)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    suffix = path.suffix.lower()
    if suffix == ".csv":
        log.table.to_csv(path, index=False)
    elif suffix in (".parquet", ".pq"):
        log.table.to_parquet(path, index=False)
    else:
        raise ValueError(f"{path}: unknown file type {suffix!r}; use .csv or .parquet")
    if truth_path is not None:
        Path(truth_path).write_text(json.dumps(log.truth.to_json(), indent=1))
    return path

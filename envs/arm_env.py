"""Joint-trajectory tracking on torque-driven arms behind a black-box low-level controller.

``mcpilco/UR10-v0`` (:class:`UR10Env`) and ``mcpilco/SCARA-v0`` (:class:`SCARAEnv`) share
:class:`ArmTrackingEnv`. The arm is built from its DH table by
:mod:`mcpilco.envs.arm_builder` (tables in :mod:`mcpilco.envs.arms`).

Glossary (thesis sections 3.4.2 and 4.3)
----------------------------------------
``T = 8 ms``
    sampling time of the measurements and of the agent (the UR driver's 125 Hz).
``dt = 2 ms``
    physics timestep = period of the inner controller loop (500 Hz); 4 substeps per sample.
``tau_c = Kp (q_ref - q) + Kd (qd_ref - qd) + g(q) + u``
    the black-box controller (PD + gravity feed-forward ``g(q)`` from MuJoCo's RNE at zero
    velocity) plus the agent's torque correction ``u = action * action_scale``.
``tau_m = clip(tau_c, -tau_max, tau_max)``
    joint-side motor torque actually applied (``ctrl`` of the torque actuators ``m1..mn``).
``K_eq = K_tau K_r``
    torque-current ratio times gear (thesis eq. 4.4): ``i = tau_m / K_eq + noise`` is the
    measured motor current [A], ``i_c = tau_c / K_eq`` the controller's current command.
friction
    viscous ``F_v qd`` (joint damping), stiction ``F_s`` (MuJoCo ``frictionloss``, a dry
    friction constraint that holds the joint still below ``F_s``) and the Stribeck decay to
    the Coulomb level ``F_c`` while sliding (added here as
    ``qfrc_applied = (F_s - F_c)(1 - exp(-(qd/v_s)^2)) sign(qd)``); on by default.
``qdd``
    acceleration measured as on the real robot: causal backward difference of the measured
    velocity ``(qd_k - qd_{k-1}) / T``, optionally low-passed
    (``qdd_k = b * diff_k + (1 - b) * qdd_{k-1}`` with ``b = qdd_filter``; 1 = no filter).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces
from numpy.typing import ArrayLike, NDArray

from mcpilco.envs.arm_builder import ArmSpec, build_arm_model
from mcpilco.envs.arms import scara, ur10
from mcpilco.envs.display import MUJOCO_OFFSCREEN_MODES, check_render_mode, render_modes

FloatArray = NDArray[np.float64]


# ----------------------------------------------------------------------------- references


class JointTrajectory(Protocol):
    """A joint reference ``t -> (q_ref, qd_ref, qdd_ref)`` of duration ``duration`` [s]."""

    duration: float

    def __call__(self, t: float) -> tuple[FloatArray, FloatArray, FloatArray]: ...


@dataclass(frozen=True)
class SumOfSinusoids:
    """``q_ref_j(t) = c_j + sum_k A_jk sin(w_jk t + phi_jk)`` (thesis section 3.4.1).

    Attributes:
        centre: ``c``, shape ``(n,)``.
        amplitudes: ``A``, shape ``(n, K)``.
        omegas: ``w`` [rad/s], shape ``(n, K)``.
        phases: ``phi`` [rad], shape ``(n, K)``.
        duration: length [s] (the formula holds for any ``t``).
    """

    centre: FloatArray
    amplitudes: FloatArray
    omegas: FloatArray
    phases: FloatArray
    duration: float = math.inf

    def __call__(self, t: float | ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(q, qd, qdd)`` at time ``t`` (scalar -> ``(n,)``; array ``(T,)`` -> ``(T, n)``)."""
        t_arr = np.asarray(t, dtype=np.float64)
        arg = self.omegas * t_arr[..., None, None] + self.phases
        q = self.centre + np.sum(self.amplitudes * np.sin(arg), axis=-1)
        qd = np.sum(self.amplitudes * self.omegas * np.cos(arg), axis=-1)
        qdd = -np.sum(self.amplitudes * self.omegas**2 * np.sin(arg), axis=-1)
        return q, qd, qdd

    @classmethod
    def random(
        cls,
        rng: np.random.Generator,
        centre: ArrayLike,
        amplitude: ArrayLike,
        max_speed: ArrayLike,
        n_sinusoids: int = 5,
        omega_range: tuple[float, float] = (0.2, 2.0),
        duration: float = math.inf,
    ) -> SumOfSinusoids:
        """Random amplitudes and angular velocities (thesis: ``w`` in ``[-2, 2]`` rad/s).

        Raw amplitudes ``a ~ U(-1, 1)`` and ``w ~ U(omega_range)`` (a random sign), then each
        joint's amplitudes are scaled so that ``sum_k |A_jk| <= amplitude_j`` and
        ``sum_k |A_jk w_jk| <= max_speed_j`` (bounds on ``|q - c|`` and ``|qd|``).
        """
        centre = np.asarray(centre, dtype=np.float64)
        n = centre.shape[0]
        amplitude = np.broadcast_to(np.asarray(amplitude, dtype=np.float64), (n,))
        max_speed = np.broadcast_to(np.asarray(max_speed, dtype=np.float64), (n,))
        a = rng.uniform(-1.0, 1.0, size=(n, n_sinusoids))
        w = rng.uniform(*omega_range, size=(n, n_sinusoids)) * rng.choice([-1.0, 1.0], (n, 1))
        phi = rng.uniform(-math.pi, math.pi, size=(n, n_sinusoids))
        scale = np.minimum(amplitude / np.abs(a).sum(axis=1), max_speed / np.abs(a * w).sum(axis=1))
        return cls(centre, a * scale[:, None], w, phi, duration)


@dataclass(frozen=True)
class Push:
    """An external force on a link: ramps up over ``ramp`` s, holds, ramps down.

    Attributes:
        t_start: onset time [s] (episode time).
        duration: total length [s].
        link: index of the pushed link (1-based, body ``link{link}``).
        force: force vector in the world frame [N], applied at the link's centre of mass.
        ramp: onset/release ramp time [s].
    """

    t_start: float
    duration: float
    link: int
    force: tuple[float, float, float]
    ramp: float = 0.05

    def scale(self, t: float) -> float:
        """Ramp factor in ``[0, 1]`` at time ``t`` (0 outside the push)."""
        s = t - self.t_start
        if s < 0.0 or s > self.duration:
            return 0.0
        if self.ramp <= 0.0:
            return 1.0
        return float(min(1.0, s / self.ramp, (self.duration - s) / self.ramp))


PUSH_RANGES: dict[str, tuple[float, float]] = dict(
    magnitude=(10.0, 80.0),  # [N]
    duration=(0.2, 1.5),  # [s]
    gap=(1.0, 4.0),  # time between pushes [s]
    ramp=(0.02, 0.1),  # onset/release ramp [s]
)
"""Uniform ranges of the random pushes of ``disturbances=True`` (:meth:`random_pushes`):
force magnitude, total duration, pause before each push, onset/release ramp time."""


# ----------------------------------------------------------------------------- env


class ArmTrackingEnv(gym.Env):
    """Track a joint reference with a torque-driven arm behind a PD + gravity controller.

    ## Description
    A serial arm built from its DH table (:mod:`mcpilco.envs.arm_builder`) is driven by
    joint torque motors. A black-box low-level controller like a UR robot's runs at 500 Hz:
    ``tau_c = Kp (q_ref - q) + Kd (qd_ref - qd) + g(q) + u``, where ``g(q)`` is the gravity
    torque of the (exact) model and ``u`` is the agent's correction. Joints have viscous,
    Coulomb and static friction (on by default) and reflected rotor inertia. Measurements
    are taken every 8 ms: joint positions, velocities, the causal finite-difference
    acceleration and the motor currents ``i = tau_m / (K_tau K_r)`` with Gaussian noise.

    ## Action Space
    ``Box(-1, 1, (n,), float32)``; joint ``j``'s torque correction is
    ``u_j = action_j * action_scale_j`` [N m, N for prismatic joints], constant over the
    8 ms sample. Actuators ``m1..mn`` act on joints ``j1..jn``.

    ## Observation Space
    ``Box(-inf, inf, (4n,), float64)``:

    | Num        | Observation                          | Joint | Unit               |
    |------------|--------------------------------------|-------|--------------------|
    | 0..n-1     | measured joint position ``q_j``      | jj    | rad (m for P)      |
    | n..2n-1    | measured joint velocity ``qd_j``     | jj    | rad/s (m/s for P)  |
    | 2n..3n-1   | reference position ``q_ref_j(t)``    | jj    | rad (m for P)      |
    | 3n..4n-1   | reference velocity ``qd_ref_j(t)``   | jj    | rad/s (m/s for P)  |

    ## Rewards
    ``reward = -cost`` with
    ``cost = (1/n) sum_j [(e_q,j / l_q)^2 + (e_qd,j / l_qd)^2] + w_u |action|^2 / n``,
    ``e_q = q_ref - q``, ``e_qd = qd_ref - qd`` after the step, ``l_q = 0.01`` (rad or m),
    ``l_qd = 0.1`` (rad/s or m/s), ``w_u = 0.01``. ``info["cost"]`` holds the cost.

    ## Starting State
    A new reference is drawn at every reset (a sum of ``n_sinusoids`` sinusoids per joint
    around the home pose, seeded by the env's ``np_random``) unless one is passed as
    ``reset(options={"reference": trajectory})``; the arm starts exactly on the
    reference (``q = q_ref(0)``, ``qd = qd_ref(0)``) plus ``init_noise`` on ``q``.

    ## Episode End
    No termination; ``gym.make`` truncates after ``max_episode_steps`` (1250 = 10 s). A
    non-finite simulation state raises ``RuntimeError``.

    ## Info
    ``cost``; ``current`` (``i``, [A], mean over the sample + noise); ``current_cmd``
    (``i_c``); ``tau`` (mean applied motor torque ``tau_m``); ``qdd`` (measured
    acceleration); ``q_ref``, ``qd_ref``, ``qdd_ref``; ``e_q``, ``e_qd``; ``contact``
    (1 while an external push is active); ``f_ext`` (world force on the pushed link [N]);
    ``tau_ext`` (its joint torques ``J_c^T f_ext``, mean over the sample [N m]); ``t`` [s].

    ## Arguments
    ``arm``; controller gains ``kp``, ``kd``; ``action_scale``; ``current_noise_std`` [A];
    ``q_noise_std``, ``qd_noise_std`` (encoder noise, 0 by default); ``qdd_filter``;
    ``friction``; ``sample_time``, ``n_substeps``; ``home``, ``amplitude``,
    ``n_sinusoids``; ``init_noise``; ``disturbances`` (``False``, ``True`` for random pushes,
    or a sequence of :class:`Push`); ``render_mode``.

    ## Version History
    * v0: initial version.
    """

    metadata = {"render_modes": render_modes(*MUJOCO_OFFSCREEN_MODES), "render_fps": 125}

    def __init__(
        self,
        arm: ArmSpec,
        kp: ArrayLike,
        kd: ArrayLike,
        action_scale: ArrayLike,
        current_noise_std: ArrayLike = 0.0,
        q_noise_std: float = 0.0,
        qd_noise_std: float = 0.0,
        qdd_filter: float = 1.0,
        friction: bool = True,
        sample_time: float = 0.008,
        n_substeps: int = 4,
        home: ArrayLike | None = None,
        amplitude: ArrayLike = 0.5,
        n_sinusoids: int = 5,
        speed_fraction: float = 0.5,
        init_noise: float = 0.0,
        cost_lengths: tuple[float, float] = (0.01, 0.1),
        action_cost: float = 0.01,
        disturbances: bool | Sequence[Push] = False,
        render_mode: str | None = None,
    ) -> None:
        n = arm.n_joints
        if n_substeps < 1 or not sample_time > 0:
            raise ValueError("n_substeps must be >= 1 and sample_time > 0")
        if not 0.0 < qdd_filter <= 1.0:
            raise ValueError(f"qdd_filter must be in (0, 1], got {qdd_filter}")
        check_render_mode(render_mode, MUJOCO_OFFSCREEN_MODES)
        self.arm = arm
        self.n_joints = n
        self.sample_time = float(sample_time)
        self.n_substeps = int(n_substeps)
        self.model = build_arm_model(
            arm, timestep=self.sample_time / self.n_substeps, friction=friction, floor=True
        )
        self.data = mujoco.MjData(self.model)
        self._gdata = mujoco.MjData(self.model)  # scratch data for g(q)
        self._link_body = [0] + [self.model.body(f"link{i}").id for i in range(1, n + 1)]
        self.friction = friction
        self.kp = self._per_joint(kp, "kp")
        self.kd = self._per_joint(kd, "kd")
        self.action_scale = self._per_joint(action_scale, "action_scale")
        self.current_noise_std = self._per_joint(current_noise_std, "current_noise_std")
        self.q_noise_std = float(q_noise_std)
        self.qd_noise_std = float(qd_noise_std)
        self.qdd_filter = float(qdd_filter)
        self.torque_limit = arm.joint_array("torque_limit")
        self.current_gain = np.array([j.current_gain for j in arm.joints])
        self._stribeck = np.array(
            [j.static_friction - j.coulomb if friction else 0.0 for j in arm.joints]
        )
        self._v_s = arm.joint_array("stribeck_velocity")
        ranges = arm.joint_ranges
        self.home = (
            np.clip(np.zeros(n), ranges[:, 0], ranges[:, 1])
            if home is None
            else self._per_joint(home, "home")
        )
        self.amplitude = self._per_joint(amplitude, "amplitude")
        self.n_sinusoids = int(n_sinusoids)
        self.speed_fraction = float(speed_fraction)
        self.init_noise = float(init_noise)
        self.cost_lengths = (float(cost_lengths[0]), float(cost_lengths[1]))
        self.action_cost = float(action_cost)
        self.disturbances = disturbances
        self.pushes: list[Push] = []
        self.render_mode = render_mode
        self._renderer = None

        self.action_space = spaces.Box(-1.0, 1.0, shape=(n,), dtype=np.float32)
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(4 * n,), dtype=np.float64)
        self.reference: JointTrajectory | None = None
        self._qd_meas_prev = np.zeros(n)
        self._qdd_meas = np.zeros(n)

    # ---------------------------------------------------------------- helpers
    def _per_joint(self, value: ArrayLike, name: str) -> FloatArray:
        arr = np.asarray(value, dtype=np.float64)
        if arr.ndim == 0:
            arr = np.full(self.n_joints, float(arr))
        if arr.shape != (self.n_joints,):
            raise ValueError(
                f"{name} needs {self.n_joints} values (one per joint), got {arr.shape}"
            )
        return arr.copy()

    @property
    def dt(self) -> float:
        """Sampling time ``T`` [s] of one ``step``."""
        return self.sample_time

    @property
    def time(self) -> float:
        """Episode time [s]."""
        return float(self.data.time)

    def gravity_torque(self, q: ArrayLike) -> FloatArray:
        """``g(q)``: generalised gravity force of the model (RNE at zero velocity/accel.)."""
        d = self._gdata
        d.qpos[:] = q
        d.qvel[:] = 0.0
        mujoco.mj_kinematics(self.model, d)
        mujoco.mj_comPos(self.model, d)
        out = np.zeros(self.model.nv)
        mujoco.mj_rne(self.model, d, 0, out)
        return out

    def stribeck_correction(self, qd: ArrayLike) -> FloatArray:
        """Generalised force that turns the ``F_s`` of ``frictionloss`` into a Stribeck curve:
        ``(F_s - F_c)(1 - exp(-(qd/v_s)^2)) sign(qd)`` (sliding friction -> ``F_c``)."""
        qd = np.asarray(qd, dtype=np.float64)
        return self._stribeck * (1.0 - np.exp(-((qd / self._v_s) ** 2))) * np.sign(qd)

    def feedforward_action(self, t0: float, duration: float, samples: int = 4) -> FloatArray:
        """The action of the known-model feed-forward over ``[t0, t0 + duration]``:
        ``a = clip(mean_t [ID(q_r, qd_r, qdd_r) - g(q_r)] / action_scale, -1, 1)``, the mean
        over ``samples`` midpoints per 8 ms sample.

        ``ID`` is MuJoCo's inverse dynamics (``mj_inverse``) of this env's own model on the
        reference: inertia with the reflected rotor inertia, Coriolis and centrifugal terms,
        gravity, viscous friction and the dry friction of ``frictionloss`` (not the Stribeck
        term, nor pushes). On the reference the PD terms vanish, so this is the correction
        an ideal model would hold over a control period of ``duration``: the reference line
        of what a learned correction can achieve within the action bounds.
        """
        if self.reference is None:
            raise RuntimeError("call reset() before feedforward_action()")
        n = max(1, int(round(duration / self.sample_time))) * int(samples)
        d = self._gdata
        u = np.zeros(self.n_joints)
        for t in t0 + duration * (np.arange(n) + 0.5) / n:
            q, qd, qdd = self.reference(float(t))
            d.qpos[:], d.qvel[:], d.qacc[:] = q, qd, qdd
            mujoco.mj_inverse(self.model, d)
            tau = d.qfrc_inverse.copy()  # gravity_torque reuses the scratch data
            u += tau - self.gravity_torque(q)
        return np.clip(u / n / self.action_scale, -1.0, 1.0)

    def controller_torque(
        self, q: FloatArray, qd: FloatArray, q_ref: FloatArray, qd_ref: FloatArray, u: FloatArray
    ) -> FloatArray:
        """``tau_c = Kp (q_ref - q) + Kd (qd_ref - qd) + g(q) + u`` (before saturation)."""
        return self.kp * (q_ref - q) + self.kd * (qd_ref - qd) + self.gravity_torque(q) + u

    def external_force(self, t: float) -> tuple[FloatArray, int]:
        """World force [N] of the active pushes at time ``t`` and the pushed link (0 = none)."""
        force = np.zeros(3)
        link = 0
        for push in self.pushes:
            s = push.scale(t)
            if s > 0.0:
                force += s * np.asarray(push.force, dtype=np.float64)
                link = push.link
        return force, link

    def apply_external_force(
        self, link: int, force: ArrayLike, duration: float, ramp: float = 0.0
    ) -> Push:
        """Push ``link`` (1-based) with the world ``force`` [N] from now for ``duration`` s.

        The force goes to ``data.xfrc_applied`` of body ``link{link}`` at its centre of mass,
        and ``info["contact"]`` is 1 while it acts (the collision data's ground truth).
        """
        if not 1 <= link <= self.n_joints:
            raise ValueError(f"link must be in 1..{self.n_joints}, got {link}")
        f = np.asarray(force, dtype=np.float64)
        if f.shape != (3,) or not np.all(np.isfinite(f)):
            raise ValueError(f"force must be 3 finite numbers [N], got {force}")
        push = Push(self.time, float(duration), int(link), tuple(f.tolist()), float(ramp))
        self.pushes.append(push)
        return push

    def random_pushes(self, duration: float, rng: np.random.Generator) -> list[Push]:
        """Random push schedule over ``[0, duration]``: pushes at random times (a pause drawn
        from ``PUSH_RANGES["gap"]`` before each), so they fall in motion and in rest phases
        alike. Magnitude, duration and ramp from :data:`PUSH_RANGES`; links drawn among the
        last half of the chain; directions uniform on the sphere."""
        pushes, t = [], float(rng.uniform(*PUSH_RANGES["gap"]))
        first_link = max(1, self.n_joints // 2 + 1)
        while t < duration:
            length = float(rng.uniform(*PUSH_RANGES["duration"]))
            direction = rng.normal(size=3)
            direction /= np.linalg.norm(direction)
            force = float(rng.uniform(*PUSH_RANGES["magnitude"])) * direction
            link = int(rng.integers(first_link, self.n_joints + 1))
            ramp = min(float(rng.uniform(*PUSH_RANGES["ramp"])), 0.5 * length)
            pushes.append(Push(t, length, link, tuple(force.tolist()), ramp))
            t += length + float(rng.uniform(*PUSH_RANGES["gap"]))
        return pushes

    def external_joint_torque(self, force: ArrayLike, link: int) -> FloatArray:
        """``tau_ext = J_c(q)^T f``: joint torques of the world force ``f`` [N] on the centre
        of mass of ``link`` (1-based; 0 = none) at the current state (``J_c`` the body's
        centre-of-mass position Jacobian)."""
        if link == 0:
            return np.zeros(self.n_joints)
        jacp = np.zeros((3, self.model.nv))
        mujoco.mj_jacBodyCom(self.model, self.data, jacp, None, self._link_body[link])
        return jacp.T @ np.asarray(force, dtype=np.float64)

    def random_reference(self, rng: np.random.Generator) -> SumOfSinusoids:
        """The task's reference: sinusoids around ``home`` within the joint range."""
        ranges = self.arm.joint_ranges
        room = np.minimum(self.home - ranges[:, 0], ranges[:, 1] - self.home)
        amplitude = np.minimum(self.amplitude, 0.95 * room)
        max_speed = self.speed_fraction * self.arm.joint_array("velocity_limit")
        return SumOfSinusoids.random(
            rng, self.home, amplitude, max_speed, n_sinusoids=self.n_sinusoids
        )

    # ---------------------------------------------------------------- gym API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[FloatArray, dict[str, Any]]:
        """Reset to the start of a (new or given) reference; see the class docstring."""
        super().reset(seed=seed)
        mujoco.mj_resetData(self.model, self.data)
        options = options or {}
        self.reference = options.get("reference") or self.random_reference(self.np_random)
        if "pushes" in options:
            self.pushes = list(options["pushes"])
        elif self.disturbances is True:
            horizon = options.get("disturbance_horizon", 60.0)
            self.pushes = self.random_pushes(horizon, self.np_random)
        elif self.disturbances:
            self.pushes = list(self.disturbances)
        else:
            self.pushes = []
        return self.reset_model(), self._info(np.zeros(self.n_joints), None, 0.0)

    def reset_model(self) -> FloatArray:
        """Place the arm on the reference at ``t = 0`` and clear the measurement filters."""
        q0, qd0, _ = self.reference(0.0)
        noise = self.init_noise * self.np_random.standard_normal(self.n_joints)
        ranges = self.arm.joint_ranges
        self.data.qpos[:] = np.clip(q0 + noise, ranges[:, 0], ranges[:, 1])
        self.data.qvel[:] = qd0
        mujoco.mj_forward(self.model, self.data)
        self._q_meas, self._qd_meas = self._measure()
        self._qd_meas_prev = self._qd_meas.copy()
        self._qdd_meas = np.zeros(self.n_joints)
        self._tau_mean = self.gravity_torque(self.data.qpos)
        self._tau_cmd_mean = self._tau_mean.copy()
        self._tau_ext_mean = np.zeros(self.n_joints)
        return self._get_obs()

    def step(self, action: ArrayLike) -> tuple[FloatArray, float, bool, bool, dict[str, Any]]:
        """Hold the torque correction for one 8 ms sample (``n_substeps`` controller ticks)."""
        if self.reference is None:
            raise RuntimeError("call reset() before step()")
        a = np.asarray(action, dtype=np.float64)
        if a.shape != (self.n_joints,):
            raise ValueError(f"action must have shape ({self.n_joints},), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"action must be finite (no NaN/inf), got {a}")
        a = np.clip(a, -1.0, 1.0)
        u = a * self.action_scale
        tau_sum = np.zeros(self.n_joints)
        cmd_sum = np.zeros(self.n_joints)
        ext_sum = np.zeros(self.n_joints)
        contact = 0
        for _ in range(self.n_substeps):
            q, qd = self.data.qpos.copy(), self.data.qvel.copy()
            q_ref, qd_ref, _ = self.reference(self.time)
            tau_c = self.controller_torque(q, qd, q_ref, qd_ref, u)
            tau_m = np.clip(tau_c, -self.torque_limit, self.torque_limit)
            self.data.ctrl[:] = tau_m
            self.data.qfrc_applied[:] = self.stribeck_correction(qd)
            force, link = self.external_force(self.time)
            self.data.xfrc_applied[:] = 0.0
            if link:
                self.data.xfrc_applied[self._link_body[link], :3] = force
                contact = 1
                ext_sum += self.external_joint_torque(force, link)
            mujoco.mj_step(self.model, self.data)
            tau_sum += tau_m
            cmd_sum += tau_c
        if not (np.all(np.isfinite(self.data.qpos)) and np.all(np.isfinite(self.data.qvel))):
            raise RuntimeError(
                f"simulation diverged at t={self.time:.3f} s; lower the gains or the timestep"
            )
        self._tau_mean = tau_sum / self.n_substeps
        self._tau_cmd_mean = cmd_sum / self.n_substeps
        self._tau_ext_mean = ext_sum / self.n_substeps
        self._q_meas, self._qd_meas = self._measure()
        diff = (self._qd_meas - self._qd_meas_prev) / self.sample_time
        self._qdd_meas = self.qdd_filter * diff + (1.0 - self.qdd_filter) * self._qdd_meas
        self._qd_meas_prev = self._qd_meas.copy()

        obs = self._get_obs()
        q_ref, qd_ref, _ = self.reference(self.time)
        e_q, e_qd = q_ref - self._q_meas, qd_ref - self._qd_meas
        l_q, l_qd = self.cost_lengths
        cost = float(
            np.mean((e_q / l_q) ** 2 + (e_qd / l_qd) ** 2) + self.action_cost * np.mean(a**2)
        )
        info = self._info(a, contact, cost)
        if self.render_mode == "human":
            self.render()
        return obs, -cost, False, False, info

    def _measure(self) -> tuple[FloatArray, FloatArray]:
        q = self.data.qpos.copy()
        qd = self.data.qvel.copy()
        if self.q_noise_std > 0:
            q += self.q_noise_std * self.np_random.standard_normal(self.n_joints)
        if self.qd_noise_std > 0:
            qd += self.qd_noise_std * self.np_random.standard_normal(self.n_joints)
        return q, qd

    def _get_obs(self) -> FloatArray:
        q_ref, qd_ref, _ = self.reference(self.time)
        return np.concatenate([self._q_meas, self._qd_meas, q_ref, qd_ref]).astype(np.float64)

    def _info(self, action: FloatArray, contact: int | None, cost: float) -> dict[str, Any]:
        q_ref, qd_ref, qdd_ref = self.reference(self.time)
        noise = self.current_noise_std * self.np_random.standard_normal(self.n_joints)
        force, link = self.external_force(self.time)
        if contact is None:
            contact = int(link > 0)
        return dict(
            t=self.time,
            cost=cost,
            current=self._tau_mean / self.current_gain + noise,
            current_cmd=self._tau_cmd_mean / self.current_gain,
            tau=self._tau_mean.copy(),
            q=self._q_meas.copy(),
            qd=self._qd_meas.copy(),
            qdd=self._qdd_meas.copy(),
            q_ref=q_ref,
            qd_ref=qd_ref,
            qdd_ref=qdd_ref,
            e_q=q_ref - self._q_meas,
            e_qd=qd_ref - self._qd_meas,
            contact=int(contact),
            f_ext=force,
            tau_ext=self._tau_ext_mean.copy(),
            action=np.asarray(action, dtype=np.float64),
        )

    # ---------------------------------------------------------------- rendering
    def render(self) -> Any:
        """Render with gymnasium's ``MujocoRenderer`` (``render_mode`` given at construction)."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode=...")
            return None
        if self._renderer is None:
            from gymnasium.envs.mujoco.mujoco_rendering import MujocoRenderer

            self._renderer = MujocoRenderer(
                self.model,
                self.data,
                {"distance": 3.0, "elevation": -20.0, "lookat": [0, 0, 0.5]},
                width=480,
                height=480,
            )
        return self._renderer.render(self.render_mode)

    def close(self) -> None:
        """Release the renderer."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


UR10_HOME = (0.0, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0)
"""UR10 home pose [rad]: upper arm vertical, forearm horizontal, wrist down."""

UR10_CURRENT_NOISE_STD = 0.17
"""[A]: the thesis measured a current noise variance of about 0.03 A^2 on its UR10 (3.4.2)."""


class UR10Env(ArmTrackingEnv):
    """``mcpilco/UR10-v0``: :class:`ArmTrackingEnv` on the UR10 of :func:`mcpilco.envs.arms.ur10`.

    Defaults: ``Kp = [5000, 5000, 3000, 800, 800, 400]`` N m/rad,
    ``Kd = [300, 300, 150, 30, 30, 15]`` N m s/rad (closed-loop bandwidth 20-60 rad/s),
    ``action_scale = [50, 50, 25, 10, 10, 10]`` N m, current noise std 0.17 A
    (:data:`UR10_CURRENT_NOISE_STD`), reference amplitude 0.5 rad around :data:`UR10_HOME`,
    speeds up to half the UR10's joint speed limits.
    """

    def __init__(
        self,
        kp: ArrayLike = (5000.0, 5000.0, 3000.0, 800.0, 800.0, 400.0),
        kd: ArrayLike = (300.0, 300.0, 150.0, 30.0, 30.0, 15.0),
        action_scale: ArrayLike = (50.0, 50.0, 25.0, 10.0, 10.0, 10.0),
        current_noise_std: ArrayLike = UR10_CURRENT_NOISE_STD,
        home: ArrayLike = UR10_HOME,
        amplitude: ArrayLike = 0.5,
        **kwargs: Any,
    ) -> None:
        super().__init__(
            ur10(),
            kp=kp,
            kd=kd,
            action_scale=action_scale,
            current_noise_std=current_noise_std,
            home=home,
            amplitude=amplitude,
            **kwargs,
        )


SCARA_HOME = (0.0, 0.5, 0.1, 0.0)
"""SCARA home pose: elbow bent 0.5 rad, quill 0.1 m down."""


class SCARAEnv(ArmTrackingEnv):
    """``mcpilco/SCARA-v0``: :class:`ArmTrackingEnv` on the AdeptOne-like SCARA (``RRPR``).

    Defaults: ``Kp = [3000, 1500, 20000, 20]`` (N m/rad; N/m for the quill),
    ``Kd = [150, 60, 1000, 2]``, ``action_scale = [20, 10, 50, 2]``, current noise std
    ``0.01 N m / K_eq`` per joint (the thesis's 0.01 N m torque noise, section 3.4.1),
    amplitudes ``[1.0, 1.0, 0.09, 1.5]`` around :data:`SCARA_HOME`.
    """

    def __init__(
        self,
        kp: ArrayLike = (3000.0, 1500.0, 20000.0, 100.0),
        kd: ArrayLike = (150.0, 60.0, 1000.0, 2.0),
        action_scale: ArrayLike = (20.0, 10.0, 50.0, 2.0),
        current_noise_std: ArrayLike | None = None,
        home: ArrayLike = SCARA_HOME,
        amplitude: ArrayLike = (1.0, 1.0, 0.09, 1.5),
        **kwargs: Any,
    ) -> None:
        arm = scara()
        if current_noise_std is None:
            current_noise_std = 0.01 / np.array([j.current_gain for j in arm.joints])
        super().__init__(
            arm,
            kp=kp,
            kd=kd,
            action_scale=action_scale,
            current_noise_std=current_noise_std,
            home=home,
            amplitude=amplitude,
            **kwargs,
        )

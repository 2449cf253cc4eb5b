"""Data collection on the arm envs: reference programs, inverse kinematics, rollouts.

The thesis's UR10 data (sections 3.4.2 and 4.6) are random explorations of the workspace
(random points reached with variable velocity), circle tracking (radius 30 cm at a tool
speed of 30 mm/s), rest phases, and (SCARA, 3.4.1) sums of sinusoids. This module builds
those joint references and rolls them out on :class:`~mcpilco.envs.arm_env.ArmTrackingEnv`.

A rollout returns plain numpy arrays keyed like the dataset schema of
``mcpilco.models.robot_data`` (``t, q, qd, qdd, tau, i, i_cmd, e_q, e_qd, contact`` plus
``q_ref, qd_ref, f_ext``); ``mcpilco-collect-arm-data`` turns them into a file. Nothing
here imports ``mcpilco.models``.

Glossary
--------
quintic rest-to-rest move
    ``q(t) = q0 + (q1 - q0) s(t/D)``, ``s(x) = 10x^3 - 15x^4 + 6x^5``: zero velocity and
    acceleration at both ends; peak speed ``1.875 |q1 - q0| / D``.
damped least squares (DLS) IK
    ``dq = J^T (J J^T + lambda^2 I)^{-1} e`` with ``e`` the 6-D pose error of site ``ee``
    (position; orientation as the axis-angle of ``R_target R^T``, weighted by ``w_rot``).
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import CubicSpline

from mcpilco.envs.arm_builder import ArmSpec, build_arm_model
from mcpilco.envs.arm_env import ArmTrackingEnv, JointTrajectory, SCARAEnv, SumOfSinusoids, UR10Env

FloatArray = NDArray[np.float64]

PROGRAMS = ("exploration", "circle", "sinusoids", "rest", "mixed")
"""Reference programs of :func:`make_program`."""

CIRCLE_DEFAULTS: dict[str, dict[str, float]] = {
    "ur10": dict(radius=0.3, speed=0.03),  # thesis 3.4.2
    "scara": dict(radius=0.2, speed=0.03),  # a 0.3 m circle does not fit the SCARA's annulus
}
"""Circle of each robot in :func:`collect` (radius [m], tool speed [m/s])."""


# ----------------------------------------------------------------------------- trajectories


@dataclass(frozen=True)
class QuinticMove:
    """Rest-to-rest move from ``q0`` to ``q1`` in ``duration`` s (``q0 == q1``: a rest)."""

    q0: FloatArray
    q1: FloatArray
    duration: float

    def __call__(self, t: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        x = min(max(t / self.duration, 0.0), 1.0) if self.duration > 0 else 1.0
        s = x**3 * (10 - 15 * x + 6 * x * x)
        ds = 30 * x**2 * (1 - x) ** 2 / self.duration
        dds = 60 * x * (1 - x) * (1 - 2 * x) / self.duration**2
        dq = self.q1 - self.q0
        return self.q0 + dq * s, dq * ds, dq * dds


@dataclass(frozen=True)
class SampledTrajectory:
    """A reference sampled on a time grid, interpolated by a cubic spline (``qd``, ``qdd``
    from the spline's derivatives; ``clamped`` ends: zero velocity at both ends)."""

    t: FloatArray
    q: FloatArray

    def __post_init__(self) -> None:
        object.__setattr__(self, "_spline", CubicSpline(self.t, self.q, bc_type="clamped"))

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])

    def __call__(self, t: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        tt = min(max(t, 0.0), self.duration) + self.t[0]
        sp = self._spline  # type: ignore[attr-defined]
        return sp(tt), sp(tt, 1), sp(tt, 2)


class PiecewiseTrajectory:
    """Trajectories played one after the other; after the end the last pose is held.

    Each piece is evaluated on its own clock ``[0, piece.duration]``. Consecutive pieces must
    join (end pose of one = start pose of the next within ``1e-6``).
    """

    def __init__(self, pieces: Sequence[JointTrajectory]) -> None:
        if not pieces:
            raise ValueError("a piecewise trajectory needs at least one piece")
        for k, piece in enumerate(pieces):
            if not math.isfinite(piece.duration):
                raise ValueError(f"piece {k} has an infinite duration; give it a finite one")
        for k in range(1, len(pieces)):
            end = pieces[k - 1](pieces[k - 1].duration)[0]
            start = pieces[k](0.0)[0]
            if np.max(np.abs(end - start)) > 1e-6:
                raise ValueError(f"piece {k} starts at {start} but piece {k - 1} ends at {end}")
        self.pieces = list(pieces)
        self.starts = np.concatenate([[0.0], np.cumsum([p.duration for p in pieces])])
        self.duration = float(self.starts[-1])

    def __call__(self, t: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        if t >= self.duration:
            q = self.pieces[-1](self.pieces[-1].duration)[0]
            return q, np.zeros_like(q), np.zeros_like(q)
        k = max(bisect.bisect_right(self.starts, t) - 1, 0)
        return self.pieces[k](t - self.starts[k])


def exploration_bounds(arm: ArmSpec, revolute_span: float = math.pi) -> FloatArray:
    """``(n, 2)`` box for random waypoints: the joint range, revolute joints cut to
    ``+-revolute_span``, with a 5% margin inside the limits."""
    ranges = arm.joint_ranges.copy()
    for j, joint in enumerate(arm.joints):
        if joint.type == "R":
            ranges[j] = np.clip(ranges[j], -revolute_span, revolute_span)
    margin = 0.05 * (ranges[:, 1] - ranges[:, 0])
    return np.stack([ranges[:, 0] + margin, ranges[:, 1] - margin], axis=1)


def random_waypoints(
    arm: ArmSpec,
    rng: np.random.Generator,
    q_start: ArrayLike,
    n_waypoints: int = 10,
    bounds: ArrayLike | None = None,
    speed_range: tuple[float, float] = (0.1, 0.6),
    rest_range: tuple[float, float] = (0.0, 1.0),
) -> PiecewiseTrajectory:
    """Random exploration: quintic moves through uniform random waypoints with variable speed.

    Args:
        arm: the arm (joint velocity limits ``v_max``).
        rng: random generator.
        q_start: start pose (first waypoint).
        n_waypoints: number of random waypoints reached after ``q_start``.
        bounds: ``(n, 2)`` box of the waypoints; default :func:`exploration_bounds`.
        speed_range: each move's peak joint speed is ``f v_max`` with ``f ~ U(speed_range)``
            on the joint that limits it (variable velocity).
        rest_range: rest time at each waypoint ``~ U(rest_range)`` [s] (rest phases).

    Returns:
        the trajectory (moves and rests alternate).
    """
    box = exploration_bounds(arm) if bounds is None else np.asarray(bounds, dtype=np.float64)
    v_max = arm.joint_array("velocity_limit")
    q = np.asarray(q_start, dtype=np.float64).copy()
    pieces: list[JointTrajectory] = []
    for _ in range(n_waypoints):
        target = rng.uniform(box[:, 0], box[:, 1])
        frac = rng.uniform(*speed_range)
        duration = max(float(np.max(1.875 * np.abs(target - q) / (frac * v_max))), 0.1)
        pieces.append(QuinticMove(q, target, duration))
        rest_time = float(rng.uniform(*rest_range))
        if rest_time > 0:
            pieces.append(QuinticMove(target, target, rest_time))
        q = target
    return PiecewiseTrajectory(pieces)


def ik_dls(
    model: mujoco.MjModel,
    target_pos: ArrayLike,
    target_rot: ArrayLike | None,
    q_init: ArrayLike,
    *,
    site: str = "ee",
    w_rot: float = 1.0,
    damping: float = 1e-3,
    tol: float = 1e-7,
    max_iter: int = 100,
    data: mujoco.MjData | None = None,
) -> tuple[FloatArray, float]:
    """Damped-least-squares IK of ``site`` on a MuJoCo model (glossary above).

    Args:
        model: the arm model (joint limits are respected by clipping).
        target_pos: world position [m].
        target_rot: world rotation matrix ``(3, 3)``; ``None`` = position only.
        q_init: start guess (warm start).
        w_rot: weight of the orientation error [m/rad].
        damping: ``lambda``.
        tol: stop when the weighted error norm is below this.
        max_iter: iteration cap.
        data: scratch ``MjData`` to reuse (faster in loops); a new one when ``None``.

    Returns:
        ``(q, error_norm)``.
    """
    data = mujoco.MjData(model) if data is None else data
    sid = model.site(site).id
    q = np.asarray(q_init, dtype=np.float64).copy()
    lo, hi = model.jnt_range[:, 0], model.jnt_range[:, 1]
    limited = model.jnt_limited.astype(bool)
    jacp = np.zeros((3, model.nv))
    jacr = np.zeros((3, model.nv))
    target_pos = np.asarray(target_pos, dtype=np.float64)
    err = math.inf
    for _ in range(max_iter):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        e_pos = target_pos - data.site_xpos[sid]
        if target_rot is not None and w_rot > 0:
            r_err = np.asarray(target_rot) @ data.site_xmat[sid].reshape(3, 3).T
            quat = np.zeros(4)
            mujoco.mju_mat2Quat(quat, r_err.ravel())
            e_rot = np.zeros(3)
            mujoco.mju_quat2Vel(e_rot, quat, 1.0)
            e = np.concatenate([e_pos, w_rot * e_rot])
        else:
            e = e_pos
        err = float(np.linalg.norm(e))
        if err < tol:
            break
        mujoco.mj_jacSite(model, data, jacp, jacr, sid)
        jac = np.vstack([jacp, w_rot * jacr]) if e.shape[0] == 6 else jacp
        dq = jac.T @ np.linalg.solve(jac @ jac.T + damping**2 * np.eye(jac.shape[0]), e)
        q = q + dq
        q[limited] = np.clip(q[limited], lo[limited], hi[limited])
    return q, err


def circle_trajectory(
    arm: ArmSpec,
    q_start: ArrayLike,
    radius: float = 0.3,
    speed: float = 0.03,
    sample_time: float = 0.008,
    w_rot: float | None = None,
    centre_angle: float | None = None,
    tol: float = 1e-4,
) -> SampledTrajectory:
    """The tool tracks a horizontal circle (thesis: radius 30 cm, tool speed 30 mm/s).

    The circle passes through the tool position ``p0`` at ``q_start``; its centre is
    ``radius`` metres from ``p0`` in the horizontal direction at ``centre_angle`` from the
    direction towards the base's vertical axis (``None``: the first of 60, 75, 45, 90, 30,
    ... degrees (15-degree steps, then the mirrored ones) whose circle a coarse 24-point IK
    reaches). The tool orientation is held
    (``w_rot`` default 1 for 6+ joints, 0 = position only otherwise). Joint references come
    from DLS IK (:func:`ik_dls`) at every sample with a warm start, then a cubic spline.

    Raises:
        ValueError: when a circle point is out of reach (IK error above ``tol`` [m]).
    """
    model = build_arm_model(arm, friction=False)
    data = mujoco.MjData(model)
    q_start = np.asarray(q_start, dtype=np.float64).copy()
    data.qpos[:] = q_start
    mujoco.mj_kinematics(model, data)
    sid = model.site("ee").id
    p0 = data.site_xpos[sid].copy()
    r0 = data.site_xmat[sid].reshape(3, 3).copy()
    if w_rot is None:
        w_rot = 1.0 if arm.n_joints >= 6 else 0.0
    base = np.asarray(arm.base_pos, dtype=np.float64)
    inward = base[:2] - p0[:2]
    norm = float(np.linalg.norm(inward))
    inward = inward / norm if norm > 1e-6 else np.array([-1.0, 0.0])
    omega = speed / radius

    def points(angle_deg: float, times: FloatArray) -> FloatArray:
        c, s_ = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
        d = np.array([c * inward[0] - s_ * inward[1], s_ * inward[0] + c * inward[1], 0.0])
        perp = np.array([-d[1], d[0], 0.0])
        ang = omega * times[:, None]
        return p0 + radius * (d - np.cos(ang) * d + np.sin(ang) * perp)

    def track(targets: FloatArray) -> tuple[FloatArray, int, float]:
        q, qs = q_start, np.empty((targets.shape[0], arm.n_joints))
        for k, target in enumerate(targets):
            q, err = ik_dls(model, target, r0, q, w_rot=w_rot, data=data)
            if err > tol:
                return qs, k, err
            qs[k] = q
        return qs, -1, 0.0

    duration = 2 * math.pi / omega
    times = np.arange(0.0, duration + 0.5 * sample_time, sample_time)
    candidates = [60.0, 75.0, 45.0, 90.0, 30.0, 105.0, 15.0, 120.0, 0.0, 135.0, 150.0, 180.0]
    candidates += [-a for a in candidates if 0.0 < a < 180.0]
    if centre_angle is None:
        coarse = np.linspace(0.0, duration, 25)
        centre_angle = next((a for a in candidates if track(points(a, coarse))[1] < 0), None)
        if centre_angle is None:
            raise ValueError(
                f"no circle of radius {radius} m through the tool position {p0.round(3)} is "
                "reachable; choose another q_start or a smaller radius"
            )
    targets = points(centre_angle, times)
    qs, bad, err = track(targets)
    if bad >= 0:
        raise ValueError(
            f"circle point {bad} ({targets[bad].round(3)} m) unreachable (IK error {err:.2e}); "
            "choose another q_start, centre_angle or a smaller radius"
        )
    return SampledTrajectory(times, qs)


def sinusoids(
    arm: ArmSpec,
    rng: np.random.Generator,
    centre: ArrayLike,
    duration: float,
    amplitude: ArrayLike = 0.5,
    speed_fraction: float = 0.5,
    n_sinusoids: int = 10,
    omega_range: tuple[float, float] = (0.2, 2.0),
) -> SumOfSinusoids:
    """A sum of sinusoids around ``centre`` (see :meth:`SumOfSinusoids.random`), amplitudes
    cut to stay 5% inside the joint range."""
    centre = np.asarray(centre, dtype=np.float64)
    ranges = arm.joint_ranges
    room = np.minimum(centre - ranges[:, 0], ranges[:, 1] - centre)
    amp = np.minimum(np.broadcast_to(amplitude, centre.shape), 0.95 * room)
    v = speed_fraction * arm.joint_array("velocity_limit")
    return SumOfSinusoids.random(rng, centre, amp, v, n_sinusoids, omega_range, duration)


def _join(q_from: FloatArray, traj: JointTrajectory, arm: ArmSpec) -> list[JointTrajectory]:
    """A quintic move from ``q_from`` to the start of ``traj`` (if needed), then ``traj``."""
    q0 = traj(0.0)[0]
    dist = np.abs(q0 - q_from)
    if np.max(dist) < 1e-9:
        return [traj]
    v = 0.3 * arm.joint_array("velocity_limit")
    return [QuinticMove(q_from, q0, max(float(np.max(1.875 * dist / v)), 0.5)), traj]


class _SinusoidPiece:
    """A sum of sinusoids faded in and out over ``fade`` s so that it starts and ends at rest."""

    def __init__(self, base: SumOfSinusoids, duration: float, fade: float = 1.0) -> None:
        self.base, self.duration, self.fade = base, float(duration), float(fade)

    def __call__(self, t: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        q, qd, qdd = self.base(t)
        c = self.base.centre
        # w(t): quintic fade-in on [0, fade], fade-out on [D - fade, D]
        x = min(t, self.duration - t, self.fade) / self.fade
        x = min(max(x, 0.0), 1.0)
        w = x**3 * (10 - 15 * x + 6 * x * x)
        sign = 1.0 if t < self.duration / 2 else -1.0
        inner = 0.0 < x < 1.0
        dw = sign * 30 * x**2 * (1 - x) ** 2 / self.fade if inner else 0.0
        ddw = 60 * x * (1 - x) * (1 - 2 * x) / self.fade**2 if inner else 0.0
        dev = q - c
        return c + w * dev, w * qd + dw * dev, w * qdd + 2 * dw * qd + ddw * dev


def make_program(
    arm: ArmSpec,
    program: str,
    rng: np.random.Generator,
    q_start: ArrayLike,
    duration: float = 60.0,
    circle_kwargs: dict[str, Any] | None = None,
    sinusoid_kwargs: dict[str, Any] | None = None,
    waypoint_kwargs: dict[str, Any] | None = None,
) -> PiecewiseTrajectory:
    """A reference program of about ``duration`` s starting (at rest) from ``q_start``.

    ``program`` is one of :data:`PROGRAMS`: ``"exploration"`` (random waypoints with rests
    until ``duration`` is reached), ``"circle"`` (move to ``q_start``'s tool position, one
    full circle; its duration is set by radius and speed, ~63 s by default), ``"sinusoids"``
    (sum of sinusoids around ``q_start``, faded in and out), ``"rest"`` (hold ``q_start``),
    ``"mixed"`` (exploration, rest, sinusoids, circle, each about a quarter of ``duration``
    except the circle).
    """
    q_start = np.asarray(q_start, dtype=np.float64)
    if program not in PROGRAMS:
        raise ValueError(f"program must be one of {PROGRAMS}, got {program!r}")
    if not duration > 0:
        raise ValueError(f"duration must be > 0 s, got {duration}")
    waypoint_kwargs = dict(waypoint_kwargs or {})
    if program == "rest":
        return PiecewiseTrajectory([QuinticMove(q_start, q_start, duration)])
    if program == "exploration":
        pieces: list[JointTrajectory] = []
        q, total = q_start, 0.0
        while total < duration:
            chunk = random_waypoints(arm, rng, q, n_waypoints=1, **waypoint_kwargs)
            pieces.extend(chunk.pieces)
            total += chunk.duration
            q = chunk(chunk.duration)[0]
        return PiecewiseTrajectory(pieces)
    if program == "sinusoids":
        base = sinusoids(arm, rng, q_start, duration, **(sinusoid_kwargs or {}))
        return PiecewiseTrajectory([_SinusoidPiece(base, duration, fade=min(1.0, duration / 4))])
    if program == "circle":
        return PiecewiseTrajectory([circle_trajectory(arm, q_start, **(circle_kwargs or {}))])
    # mixed
    quarter = duration / 4
    explo = make_program(arm, "exploration", rng, q_start, quarter, waypoint_kwargs=waypoint_kwargs)
    q = explo(explo.duration)[0]
    rest = QuinticMove(q, q, min(2.0, quarter))
    sines = make_program(arm, "sinusoids", rng, q, quarter, sinusoid_kwargs=sinusoid_kwargs)
    circle = circle_trajectory(arm, q_start, **(circle_kwargs or {}))
    pieces = [*explo.pieces, rest, *sines.pieces, *_join(q, circle, arm)]
    return PiecewiseTrajectory(pieces)


# ----------------------------------------------------------------------------- rollouts

ROLLOUT_KEYS = ("t", "q", "qd", "qdd", "tau", "i", "i_cmd", "e_q", "e_qd", "contact")
"""Keys of :func:`rollout`'s arrays that are dataset columns (see ``models.robot_data``)."""

INFO_NAMES = {"i": "current", "i_cmd": "current_cmd"}
"""Dataset column group -> the arm env's ``info`` key, where the two differ."""


def log_from_infos(
    rows: Sequence[Mapping[str, Any]], keys: Sequence[str] = ROLLOUT_KEYS
) -> dict[str, FloatArray]:
    """The dataset arrays ``keys`` (``models.robot_data`` groups) of a sequence of the arm
    env's per-sample ``info`` dicts; ``contact`` as int."""
    out = {key: np.array([r[INFO_NAMES.get(key, key)] for r in rows]) for key in keys}
    if "contact" in out:
        out["contact"] = out["contact"].astype(np.int64)
    return out


def make_arm_env(robot: str, **kwargs: Any) -> ArmTrackingEnv:
    """``"ur10"`` -> :class:`UR10Env`, ``"scara"`` -> :class:`SCARAEnv` (keyword arguments
    go to the env's constructor)."""
    envs = {"ur10": UR10Env, "scara": SCARAEnv}
    if robot.lower() not in envs:
        raise ValueError(f"robot must be one of {sorted(envs)}, got {robot!r}")
    return envs[robot.lower()](**kwargs)


def rollout(
    env: ArmTrackingEnv,
    reference: JointTrajectory,
    *,
    seed: int | None = None,
    duration: float | None = None,
    policy: Callable[[FloatArray], ArrayLike] | None = None,
    pushes: Sequence[Any] | None = None,
    progress: bool = False,
) -> dict[str, FloatArray]:
    """Track ``reference`` with ``env`` and log every 8 ms sample (the reset sample included).

    Args:
        env: an arm env.
        reference: the joint reference (finite ``duration`` unless ``duration`` is given).
        seed: reset seed (noise streams).
        duration: length [s]; default the reference's duration.
        policy: ``obs -> action``; default zero actions (controller only).
        pushes: external pushes (:class:`~mcpilco.envs.arm_env.Push`) for this rollout.
        progress: show a tqdm bar.

    Returns:
        arrays ``t (N,)``, ``q, qd, qdd, tau, i, i_cmd, e_q, e_qd, q_ref, qd_ref (N, n)``,
        ``contact (N,)`` int, ``f_ext (N, 3)``, ``tau_ext (N, n)`` (joint torques of the
        push, ground truth); units as in ``models.robot_data``.
    """
    duration = reference.duration if duration is None else float(duration)
    if not math.isfinite(duration) or duration <= 0:
        raise ValueError(f"give a finite positive duration, got {duration}")
    options: dict[str, Any] = {"reference": reference}
    if pushes is not None:
        options["pushes"] = list(pushes)
    obs, info = env.reset(seed=seed, options=options)
    n_steps = int(round(duration / env.dt))
    rows = [info]
    steps = range(n_steps)
    if progress:
        from tqdm import tqdm

        steps = tqdm(steps, desc="rollout", unit="sample")
    zero = np.zeros(env.n_joints)
    for _ in steps:
        action = zero if policy is None else policy(obs)
        obs, _, _, _, info = env.step(action)
        rows.append(info)
    return log_from_infos(rows, (*ROLLOUT_KEYS, "q_ref", "qd_ref", "f_ext", "tau_ext"))


def inverse_dynamics_samples(
    arm: ArmSpec,
    reference: JointTrajectory,
    times: ArrayLike,
    *,
    noise_std: float = 0.0,
    rng: np.random.Generator | None = None,
    friction: bool = False,
) -> dict[str, FloatArray]:
    """Torques of the exact inverse dynamics along a reference (thesis 3.4.1 data generation).

    ``tau = M(q) qdd + C(q, qd) qd + g(q)`` (+ armature; + viscous friction when
    ``friction``), from MuJoCo's ``mj_inverse`` on the reference's ``(q, qd, qdd)``, plus
    Gaussian noise of std ``noise_std``. Returns ``t, q, qd, qdd, tau``.
    """
    model = build_arm_model(arm.without_friction() if not friction else arm)
    if friction:  # keep viscous damping, drop the dry-friction constraint (not invertible)
        model.dof_frictionloss[:] = 0.0
    data = mujoco.MjData(model)
    times = np.asarray(times, dtype=np.float64)
    n = arm.n_joints
    out = {k: np.empty((times.size, n)) for k in ("q", "qd", "qdd", "tau")}
    for k, t in enumerate(times):
        q, qd, qdd = reference(float(t))
        data.qpos[:], data.qvel[:], data.qacc[:] = q, qd, qdd
        mujoco.mj_inverse(model, data)
        out["q"][k], out["qd"][k], out["qdd"][k] = q, qd, qdd
        out["tau"][k] = data.qfrc_inverse
    if noise_std > 0:
        rng = np.random.default_rng() if rng is None else rng
        out["tau"] = out["tau"] + noise_std * rng.standard_normal(out["tau"].shape)
    out["t"] = times
    return out


def collect(
    robot: str = "ur10",
    program: str = "mixed",
    duration: float = 60.0,
    seed: int = 0,
    q_start: ArrayLike | None = None,
    progress: bool = False,
    env_kwargs: dict[str, Any] | None = None,
    **program_kwargs: Any,
) -> tuple[dict[str, FloatArray], dict[str, Any]]:
    """Build a reference program and roll it out: the data-collection entry point.

    Args:
        robot: ``"ur10"`` or ``"scara"``.
        program: one of :data:`PROGRAMS` (see :func:`make_program`).
        duration: length of the program [s] (the circle sets its own, ~63 s on the UR10).
        seed: seeds the program (``numpy.random.default_rng(seed)``) and the env's noise.
        q_start: start pose; default the env's home pose.
        progress: tqdm bar over the samples.
        env_kwargs: keyword arguments of the env (e.g. ``current_noise_std=0``).
        **program_kwargs: ``circle_kwargs``/``sinusoid_kwargs``/``waypoint_kwargs`` of
            :func:`make_program` (the circle defaults to :data:`CIRCLE_DEFAULTS`).

    Returns:
        ``(arrays, metadata)``: the :func:`rollout` arrays and a JSON-serialisable dict
        (robot, joint types, program, seed, sample time, controller and drive constants).
    """
    env = make_arm_env(robot, **(env_kwargs or {}))
    rng = np.random.default_rng(seed)
    q0 = env.home if q_start is None else np.asarray(q_start, dtype=np.float64)
    program_kwargs.setdefault("circle_kwargs", dict(CIRCLE_DEFAULTS.get(robot.lower(), {})))
    reference = make_program(env.arm, program, rng, q0, duration, **program_kwargs)
    length = reference.duration if program in ("circle", "mixed") else duration
    arrays = rollout(env, reference, seed=seed, duration=length, progress=progress)
    metadata = dict(
        robot=robot.lower(),
        joint_types=env.arm.joint_types,
        program=program,
        seed=int(seed),
        sample_time=env.dt,
        physics_timestep=float(env.model.opt.timestep),
        kp=env.kp.tolist(),
        kd=env.kd.tolist(),
        current_gain=env.current_gain.tolist(),
        current_noise_std=env.current_noise_std.tolist(),
        friction=bool(env.friction),
        qdd="causal backward difference of measured qd",
    )
    return arrays, metadata

"""Joint trajectories of the UR10 of ``mcpilco/MarkerCamera-v0`` through random waypoints.

The kinematics benchmark (:mod:`mcpilco.experiments.kinematics.parts`) and the marker
detection benchmark (:mod:`mcpilco.experiments.kinematics.marker_detection`) collect their data
the same way: waypoints drawn uniformly in a box around :data:`UR10_HOME` (optionally kept
only where every marker is seen, by rejection sampling), visited by equal joint increments
of :class:`~mcpilco.envs.marker_camera.MarkerCameraEnv`.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from tqdm.auto import tqdm

from mcpilco.envs.marker_camera import MarkerCameraEnv

__all__ = [
    "UR10_HOME",
    "draw_accepted",
    "drive_to",
    "ur10_waypoints",
    "visible_configuration",
    "waypoint_trajectory",
]

# UR10 configuration at the centre of the sampled region (elbow up, wrist down) [rad]
UR10_HOME = np.array([0.0, -np.pi / 2, np.pi / 2, 0.0, np.pi / 2, 0.0])


def draw_accepted(
    draw: Callable[[], np.ndarray],
    count: int,
    accept: Callable[[np.ndarray], bool],
    max_draws: int,
    what: str,
) -> np.ndarray:
    """``count`` results of ``draw()`` that pass ``accept``, in draw order (rejection
    sampling); ``ValueError`` after ``max_draws`` draws."""
    kept: list[np.ndarray] = []
    for _ in range(max_draws):
        q = draw()
        if accept(q):
            kept.append(q)
            if len(kept) == count:
                return np.array(kept)
    raise ValueError(
        f"only {len(kept)} of {count} {what} accepted in {max_draws} draws; widen the "
        "visibility cone or change the span"
    )


def ur10_waypoints(
    rng: np.random.Generator,
    span: float,
    count: int = 25,
    accept: Callable[[np.ndarray], bool] | None = None,
    max_draws: int = 100_000,
) -> np.ndarray:
    """``count`` random waypoints ``UR10_HOME + U(-span, span)`` per joint, ``(count, 6)``;
    with ``accept``, only configurations that pass it (:func:`draw_accepted`)."""
    if accept is None:
        return UR10_HOME + rng.uniform(-span, span, (count, 6))
    return draw_accepted(
        lambda: UR10_HOME + rng.uniform(-span, span, 6), count, accept, max_draws, "waypoints"
    )


def visible_configuration(env: MarkerCameraEnv) -> Callable[[np.ndarray], bool] | None:
    """``q -> every marker within env.visibility_cone``, or None without a cone."""
    if env.visibility_cone is None:
        return None
    cos_min = math.cos(math.radians(env.visibility_cone))
    return lambda q: bool(env.facing_cosines(q).min() >= cos_min)


def waypoint_trajectory(
    env: MarkerCameraEnv,
    first_obs: np.ndarray,
    waypoints: np.ndarray,
    samples: int,
    progress: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Drive ``env`` (at ``waypoints[0]``, observation ``first_obs``) through ``waypoints``
    (chain order) by equal joint increments, about ``samples`` frames in all.

    Returns the observed marker poses ``(T, n+1, 6)`` and joints ``(T, n)`` (shuffled, as the
    env gives them) and the true joint positions ``(T, n)`` (chain order).
    """
    n = env.n_joints
    per_segment = max(1, samples // (len(waypoints) - 1))
    perm = env.joint_permutation
    rows, q_true = [first_obs], [env.q.copy()]
    bar = tqdm(total=per_segment * (len(waypoints) - 1), disable=not progress, desc="frames")
    for k in range(len(waypoints) - 1):
        delta = (waypoints[k + 1] - waypoints[k]) / per_segment
        for _ in range(per_segment):
            action = (delta / env.max_increment)[perm].astype(np.float32)
            obs, _, _, _, info = env.step(action)
            rows.append(obs)
            q_true.append(info["q"])
            bar.update()
    bar.close()
    rows = np.array(rows)
    poses = rows[:, : 6 * (n + 1)].reshape(-1, n + 1, 6)
    return poses, rows[:, 6 * (n + 1) : 6 * (n + 1) + n], np.array(q_true)


def drive_to(env: MarkerCameraEnv, q_goal: np.ndarray, max_steps: int = 200) -> list[np.ndarray]:
    """Track a reference to ``q_goal`` (chain order) with increments; returns the observations."""
    rows = []
    for _ in range(max_steps):
        step = np.clip((q_goal - env.q) / env.max_increment, -1, 1)
        obs, *_ = env.step(step[env.joint_permutation].astype(np.float32))
        rows.append(obs)
        if np.abs(env.q - q_goal).max() < 1e-9:
            break
    return rows

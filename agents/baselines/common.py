"""What every baseline shares: task envs, the learning-curve format, evaluation of a policy.

Glossary
--------
task env
    a registered ``mcpilco/...`` env whose episodes end with ``info["success"]`` (the
    cartpole swing-ups: upright over the last 1 s with ``|x| < 0.5`` m, see
    :mod:`mcpilco.envs.cartpole_task`). Only these can be compared by success rate.
control period ``dt``
    seconds per env step (``env.unwrapped.dt``; 0.05 s on the cartpoles).
experience ``T``
    seconds of real interaction, ``T = n dt`` after ``n`` env steps. For MC-PILCO and PILCO
    ``n = (k + 1) H`` after trial ``k`` (exploration included), i.e. ``T = 3 (k + 1)`` s.
success rate ``p(T)``
    fraction of evaluation episodes that end with ``info["success"]``: for SB3, 10
    deterministic episodes every ``K`` env steps; for MC-PILCO / PILCO, the one episode of
    each trial (as in thesis Table 5.1, the rate over seeds is the fraction of seeds).
learning curve
    one run (method, env, seed): a list of points ``(steps n, experience T, p(T))`` plus the
    run's config and timings, stored as JSON with ``format = CURVE_FORMAT``.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.agents.common.trials import env_dt, make_env, run_episode
from mcpilco.models.files import write_atomic

CURVE_FORMAT = "mcpilco-curve/1"
"""Tag of a learning-curve JSON file (one run: method, env, seed, points)."""

POINT_KEYS = ("steps", "experience_s", "success_rate", "episodes")
"""Keys every point of a learning curve must have."""


# ------------------------------------------------------------------------------- tasks
def env_has_task(env_id: str) -> bool:
    """True when a task specification ships for ``env_id`` (:mod:`mcpilco.envs.tasks`)."""
    from mcpilco.envs.tasks import task_ids

    return env_id in task_ids()


def task_env_ids() -> list[str]:
    """The env ids with a shipped task specification."""
    from mcpilco.envs.tasks import task_ids

    return task_ids()


def check_task_env(env_id: str) -> None:
    """Raise ``ValueError`` naming the valid ids when ``env_id`` has no task specification."""
    if not env_has_task(env_id):
        raise ValueError(
            f"env {env_id!r} has no task specification (state, cost, success test); "
            f"valid env ids: {', '.join(task_env_ids())}"
        )


def episode_steps(env_id: str) -> int:
    """Steps per episode of a task env: its task's horizon, where success is scored."""
    from mcpilco.envs.tasks.spec import TaskSpec

    return TaskSpec.for_env(env_id).horizon


# -------------------------------------------------------------------------- evaluation
def evaluate_success(
    env,
    act: Callable[[np.ndarray], np.ndarray],
    seeds: Sequence[int],
    horizon: int,
    task: Any,
) -> dict[str, Any]:
    """Run one episode per reset seed with ``act`` and score it as MC-PILCO's trials are.

    Uses :func:`mcpilco.agents.common.trials.run_episode` with the env's ``task``
    (:class:`~mcpilco.envs.tasks.spec.TaskSpec`), so the success flag, cost and time
    in the goal region are the same quantities as in MC-PILCO's records.

    Returns:
        ``success_rate`` = (number of successful episodes) / ``len(seeds)``, the mean episode
        cost, mean time in the goal region, the per-episode flags, and the median over the
        episodes of each numeric scalar of the env's last ``info`` (``final_info_median``;
        e.g. the marker camera's final ``position_error``).
    """
    if len(seeds) == 0:
        raise ValueError("evaluate_success needs at least one seed (one evaluation episode)")
    eps = [run_episode(env, act, int(s), horizon, task) for s in seeds]
    flags = [bool(e["success"]) for e in eps]
    common = set.intersection(*(set(e["final_info"]) for e in eps))
    return {
        "success_rate": float(np.mean(flags)),
        "episodes": len(eps),
        "successes": flags,
        "mean_cost": float(np.mean([e["cost"] for e in eps])),
        "time_in_goal_s": float(np.mean([e["time_in_goal"] for e in eps])),
        "final_info_median": {
            k: float(np.median([e["final_info"][k] for e in eps])) for k in sorted(common)
        },
    }


def task_step_wrapper(env, task: Any):
    """``env`` as a task's agent sees it (a ``gymnasium.Wrapper``): every reset passes the
    task's ``reset_options()`` (its joint reference) unless options are given, and each
    action is held for the task's ``action_repeat`` env steps, the rewards summed, the
    observation after the last returned (stopping early at a termination or truncation).
    What MC-PILCO's :func:`~mcpilco.agents.common.trials.run_episode` does, so that a
    model-free learner trains on the same control period and reference it is scored on."""
    import gymnasium as gym

    class TaskSteps(gym.Wrapper):
        def reset(self, *, seed=None, options=None):
            opts = task.reset_options() if options is None else options
            return self.env.reset(seed=seed, options=opts)

        def step(self, action):
            total = 0.0
            for _ in range(task.action_repeat):
                obs, reward, terminated, truncated, info = self.env.step(action)
                total += float(reward)
                if terminated or truncated:
                    break
            return obs, total, terminated, truncated, info

    return TaskSteps(env)


def eval_seeds(seed: int, n: int) -> list[int]:
    """Reset seeds of the ``n`` evaluation episodes of run ``seed`` (fixed for the whole run,
    disjoint from the training trials' seeds ``10007 seed + k`` of MC-PILCO / PILCO)."""
    return [1_000_000 + 1_000 * int(seed) + i for i in range(int(n))]


# ----------------------------------------------------------------------- curve records
def trial_records_to_points(records: Sequence[dict[str, Any]], horizon: int) -> list[dict]:
    """Learning-curve points of an MC-PILCO / PILCO run: one per trial (exploration too).

    ``steps``: the env steps taken up to and including trial ``k`` (the sum of the records'
    ``steps``; ``(k + 1) H`` for records without them), ``experience_s`` as recorded
    (``3 (k + 1)`` s on the cartpoles), ``success_rate`` = 1.0 or 0.0 from the trial's
    single episode.
    """
    pts = []
    counted = all("steps" in r for r in records)
    taken = 0
    for r in records:
        k = int(r["index"])
        taken += int(r["steps"]) if counted else 0
        pts.append(
            {
                "steps": taken if counted else (k + 1) * int(horizon),
                "experience_s": float(r["experience_s"]),
                "success_rate": float(bool(r["success"])),
                "episodes": 1,
                "kind": r.get("kind"),
                "mean_cost": float(r.get("cost", float("nan"))),
                "time_in_goal_s": float(r.get("time_in_goal", float("nan"))),
            }
        )
    return pts


def make_curve(
    method: str,
    env_id: str,
    seed: int,
    dt: float,
    points: list[dict[str, Any]],
    **extra: Any,
) -> dict[str, Any]:
    """A learning-curve dict (validated)."""
    curve = {
        "format": CURVE_FORMAT,
        "method": str(method),
        "env_id": str(env_id),
        "seed": int(seed),
        "dt": float(dt),
        "points": list(points),
        **extra,
    }
    validate_curve(curve)
    return curve


def validate_curve(curve: dict[str, Any], source: str = "curve") -> None:
    """Check the keys and values of a learning curve; ``ValueError`` says what is wrong."""
    if not isinstance(curve, dict):
        raise TypeError(f"{source}: a learning curve is a JSON object, got {type(curve).__name__}")
    if curve.get("format") != CURVE_FORMAT:
        raise ValueError(
            f"{source}: format is {curve.get('format')!r}, expected {CURVE_FORMAT!r} "
            "(write curves with mcpilco.agents.baselines.common.save_curve)"
        )
    for key in ("method", "env_id", "seed", "dt", "points"):
        if key not in curve:
            raise ValueError(f"{source}: missing key {key!r}")
    if not curve["dt"] > 0:
        raise ValueError(f"{source}: dt must be > 0 s, got {curve['dt']}")
    last = -np.inf
    for i, p in enumerate(curve["points"]):
        missing = [k for k in POINT_KEYS if k not in p]
        if missing:
            raise ValueError(f"{source}: point {i} lacks {missing} (needs {POINT_KEYS})")
        if not 0.0 <= float(p["success_rate"]) <= 1.0:
            raise ValueError(
                f"{source}: point {i} success_rate={p['success_rate']} is outside [0, 1]"
            )
        if float(p["experience_s"]) < last:
            raise ValueError(f"{source}: points must be in increasing experience_s (point {i})")
        last = float(p["experience_s"])


def save_curve(path: str | os.PathLike, curve: dict[str, Any]) -> Path:
    """Write a learning curve atomically (:func:`~mcpilco.models.files.write_atomic`)."""
    validate_curve(curve, str(path))
    path = Path(path)
    write_atomic(path, json.dumps(curve, indent=1))
    return path


def load_curves(path: str | os.PathLike) -> list[dict[str, Any]]:
    """Learning curves of a JSON file: one curve, a list of curves, ``{"curves": [...]}`` or a
    comparison's result file (its ``curves`` case entry, :mod:`mcpilco.experiments.results`)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no result file at {path}")
    try:
        data = json.loads(path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as err:
        raise ValueError(
            f"{path} is not a JSON file of learning curves ({type(err).__name__})"
        ) from None
    if isinstance(data, dict) and isinstance(data.get("cases"), dict) and "schema" in data:
        data = data["cases"]
    if isinstance(data, dict) and "curves" in data:
        data = data["curves"]
    curves = data if isinstance(data, list) else [data]
    for i, c in enumerate(curves):
        validate_curve(c, f"{path}[{i}]")
    return curves


__all__ = [
    "CURVE_FORMAT",
    "check_task_env",
    "env_dt",
    "env_has_task",
    "episode_steps",
    "eval_seeds",
    "evaluate_success",
    "load_curves",
    "make_curve",
    "make_env",
    "save_curve",
    "task_env_ids",
    "trial_records_to_points",
    "validate_curve",
]

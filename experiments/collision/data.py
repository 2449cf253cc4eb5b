"""Simulated UR10 data of the collision-detection benchmark (thesis section 4.6).

Every set is a rollout of ``mcpilco/UR10-v0`` (PD + gravity controller, stiction + Coulomb +
Stribeck friction, motor-current noise, 8 ms samples), collision-free unless stated:

training
    ``train_waypoints`` random waypoints (quintic moves at 20-60% of the joint speed limits,
    rests of 0-1 s; joint box :data:`HALF_WIDTH` around the home pose).
validation (the thesis' "test set")
    ``test_waypoints`` new waypoints with rests of 0.5-3 s, a move to the start of the tool
    circle (radius 30 cm at 30 mm/s), the circle, a final rest of ``final_rest`` s. It gives
    the RMSE of ``i_hat`` and calibrates the thresholds.
push-free
    ``push_free_minutes`` of the same kind of program (new seed): false alarms per minute.
pushes
    ``push_waypoints`` waypoints with rests of 1.5-3 s and one push per move or rest piece
    (:func:`schedule_pushes`).
figure scenario (thesis Fig. 4.3)
    the circle then a 15 s rest; five 1 s pushes of ``scenario_force`` N on link 4,
    horizontal and tangential, three while tracking and two at rest (:func:`scenario`).

:func:`simulated_sets` keeps the sets in a safe file of arrays and plain data
(``data.pt``, :mod:`mcpilco.models.torch_files`: loading it cannot run code; never a pickle)
and reads them back, checked against the sets' format, while the options that made them
(:data:`DATA_OPTIONS`) are the same.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import math
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from mcpilco.envs.arm_builder import dh_forward_kinematics
from mcpilco.envs.arm_data import (
    PiecewiseTrajectory,
    QuinticMove,
    circle_trajectory,
    random_waypoints,
    rollout,
)
from mcpilco.envs.arm_env import PUSH_RANGES, UR10_HOME, Push, UR10Env
from mcpilco.models.torch_files import atomic_torch_save, load_torch_file

FloatArray = np.ndarray

HALF_WIDTH = (1.2, 0.6, 0.9, 1.2, 1.2, 1.5)
"""Half widths [rad] of the joint box of the random waypoints around ``UR10_HOME``."""

SPEED_RANGE = (0.2, 0.6)
"""Peak speed of each move as a fraction of the joint speed limit."""

PUSH_LINKS = (4, 5, 6)
"""Links pushed in the statistics (the env's ``random_pushes`` convention)."""


def waypoint_box() -> FloatArray:
    """``(6, 2)`` bounds of the random waypoints: ``UR10_HOME`` +- :data:`HALF_WIDTH`."""
    home = np.asarray(UR10_HOME)
    half = np.asarray(HALF_WIDTH)
    return np.stack([home - half, home + half], axis=1)


def waypoints(
    env: UR10Env, rng: np.random.Generator, q0: FloatArray, n: int, rest: tuple[float, float]
) -> PiecewiseTrajectory:
    """``n`` random waypoints from ``q0`` in :func:`waypoint_box`, rests uniform in ``rest``."""
    return random_waypoints(
        env.arm, rng, q0, n, bounds=waypoint_box(), speed_range=SPEED_RANGE, rest_range=rest
    )


def join(env: UR10Env, q_from: FloatArray, q_to: FloatArray) -> QuinticMove:
    """Quintic move at <= 30% of the speed limits (at least 0.5 s)."""
    v = 0.3 * env.arm.joint_array("velocity_limit")
    duration = max(float(np.max(1.875 * np.abs(q_to - q_from) / v)), 0.5)
    return QuinticMove(q_from, q_to, duration)


def test_program(
    env: UR10Env,
    rng: np.random.Generator,
    n_waypoints: int,
    circle: PiecewiseTrajectory,
    final_rest: float,
) -> PiecewiseTrajectory:
    """Waypoints (rests 0.5-3 s), a move to the circle's start, the circle, a final rest."""
    home = np.asarray(UR10_HOME)
    wp = waypoints(env, rng, home, n_waypoints, (0.5, 3.0))
    q_end = wp(wp.duration)[0]
    q_circle = circle(0.0)[0]
    q_last = circle(circle.duration)[0]
    pieces = [*wp.pieces, join(env, q_end, q_circle), *circle.pieces]
    pieces.append(QuinticMove(q_last, q_last, final_rest))
    return PiecewiseTrajectory(pieces)


def schedule_pushes(
    program: PiecewiseTrajectory, rng: np.random.Generator, min_gap: float = 1.0
) -> tuple[list[Push], list[bool]]:
    """One random push per move or rest piece of ``program``; returns the pushes and whether
    each starts in a rest piece.

    Pieces shorter than 1 s get none, and a push starts at least ``min_gap`` s after the
    previous one ends. Onset 0.2-0.5 s into a rest or at 20-60% of a move; magnitude,
    duration and ramp uniform in the env's ``PUSH_RANGES``; link from :data:`PUSH_LINKS`;
    direction uniform on the sphere.
    """
    pushes, at_rest = [], []
    last_end = -math.inf
    for k, piece in enumerate(program.pieces):
        start, duration = float(program.starts[k]), float(piece.duration)
        rest = bool(np.allclose(piece.q0, piece.q1))
        if duration < 1.0:
            continue
        onset = start + (rng.uniform(0.2, 0.5) if rest else rng.uniform(0.2, 0.6) * duration)
        if onset < last_end + min_gap:
            continue
        length = float(rng.uniform(*PUSH_RANGES["duration"]))
        ramp = min(float(rng.uniform(*PUSH_RANGES["ramp"])), 0.5 * length)
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        force = float(rng.uniform(*PUSH_RANGES["magnitude"])) * direction
        link = int(rng.choice(PUSH_LINKS))
        pushes.append(Push(float(onset), length, link, tuple(force.tolist()), ramp))
        at_rest.append(rest)
        last_end = onset + length
    return pushes, at_rest


def scenario(
    env: UR10Env, circle: PiecewiseTrajectory, force: float, rest: float = 15.0
) -> tuple[PiecewiseTrajectory, list[Push], list[bool]]:
    """Thesis Fig. 4.3: circle then rest; 3 pushes while tracking, 2 at rest (link 4,
    horizontal, tangential to the base axis)."""
    q_last = circle(circle.duration)[0]
    program = PiecewiseTrajectory([*circle.pieces, QuinticMove(q_last, q_last, rest)])
    t_circle = circle.duration
    onsets = [0.2 * t_circle, 0.45 * t_circle, 0.7 * t_circle, t_circle + 3.0, t_circle + 9.0]
    pushes = []
    for k, t0 in enumerate(onsets):
        p = dh_forward_kinematics(env.arm, program(t0)[0])[:3, 3]
        radial = p[:2] / max(np.linalg.norm(p[:2]), 1e-9)
        sign = 1.0 if k % 2 == 0 else -1.0
        f = sign * force * np.array([-radial[1], radial[0], 0.0])
        pushes.append(Push(float(t0), 1.0, 4, tuple(f.tolist()), 0.1))
    return program, pushes, [t0 > t_circle for t0 in onsets]


def simulate(args: argparse.Namespace, bar: tqdm) -> dict[str, Any]:
    """Every set of the module docstring (the options ``args`` of :data:`DATA_OPTIONS`), with
    the env's current gain and current-noise std."""
    env = UR10Env()
    home = np.asarray(UR10_HOME)
    seed = args.seed
    bar.set_postfix_str("circle IK")
    circle = PiecewiseTrajectory([circle_trajectory(env.arm, home)])
    out: dict[str, Any] = {}

    bar.set_postfix_str("training rollout")
    train_ref = waypoints(env, np.random.default_rng([seed, 1]), home, args.train_waypoints, (0, 1))
    out["train"] = rollout(env, train_ref, seed=seed * 100 + 1)
    bar.update(1)

    bar.set_postfix_str("validation rollout")
    val_ref = test_program(
        env, np.random.default_rng([seed, 2]), args.test_waypoints, circle, args.final_rest
    )
    out["validation"] = rollout(env, val_ref, seed=seed * 100 + 2)
    bar.update(1)

    bar.set_postfix_str("push-free rollout")
    target = 60.0 * args.push_free_minutes
    rng = np.random.default_rng([seed, 3])
    n_wp = max(1, args.test_waypoints)
    chunks, total = [], 0.0
    while total < target:  # waypoint programs with the circle until the time is reached
        ref = test_program(env, rng, n_wp, circle, args.final_rest)
        chunks.append(rollout(env, ref, seed=seed * 100 + 3 + len(chunks)))
        total += ref.duration
    out["push_free"] = concat(chunks, target)
    bar.update(1)

    bar.set_postfix_str("push rollout")
    rng = np.random.default_rng([seed, 4])
    push_ref = waypoints(env, rng, home, args.push_waypoints, (1.5, 3.0))
    pushes, at_rest = schedule_pushes(push_ref, rng)
    out["pushes"] = rollout(env, push_ref, seed=seed * 100 + 4, pushes=pushes)
    out["push_list"], out["push_at_rest"] = pushes, at_rest
    bar.update(1)

    bar.set_postfix_str("scenario rollout")
    sc_ref, sc_pushes, sc_rest = scenario(env, circle, args.scenario_force)
    out["scenario"] = rollout(env, sc_ref, seed=seed * 100 + 5, pushes=sc_pushes)
    out["scenario_pushes"], out["scenario_at_rest"] = sc_pushes, sc_rest
    bar.update(1)
    out["current_gain"] = env.current_gain.copy()
    out["current_noise_std"] = env.current_noise_std.copy()
    return out


def concat(chunks: list[dict[str, FloatArray]], seconds: float) -> dict[str, FloatArray]:
    """Rollouts one after the other on one clock (each chunk restarts at rest), cut to
    ``seconds``."""
    out: dict[str, list[FloatArray]] = {k: [] for k in chunks[0]}
    offset = 0.0
    for c in chunks:
        for k, v in c.items():
            out[k].append(v + offset if k == "t" else v)
        offset += float(c["t"][-1]) + float(c["t"][1] - c["t"][0])
    merged = {k: np.concatenate(v) for k, v in out.items()}
    keep = merged["t"] < seconds
    return {k: v[keep] for k, v in merged.items()}


DATA_OPTIONS = (
    "seed", "train_waypoints", "test_waypoints", "final_rest", "push_free_minutes",
    "push_waypoints", "scenario_force",
)  # fmt: skip
"""Options that set the simulated data (:func:`simulate`)."""


DATA_FILE = "data.pt"  # name of the simulated sets' file in the benchmark's runs folder
ROLLOUT_SETS = ("train", "validation", "push_free", "pushes", "scenario")  # sets of rollouts
PUSH_LISTS = ("push_list", "scenario_pushes")  # sets that are lists of Push
_REMEDY = "delete it to simulate the data again"  # what to do with a file that is refused


def _to_plain(sets: dict[str, Any]) -> dict[str, Any]:
    """``sets`` with every :class:`Push` as a plain dict (a safe file holds plain data)."""
    return {
        k: [dataclasses.asdict(p) for p in v] if k in PUSH_LISTS else v for k, v in sets.items()
    }


def _from_plain(sets: Any, path: Path) -> dict[str, Any]:
    """Inverse of :func:`_to_plain`, checked against the format of :func:`simulate`'s sets:
    each rollout set a mapping of equally long arrays, each push a :class:`Push`'s fields.

    Raises:
        ValueError: naming ``path`` and what does not match.
    """

    def fail(what: str) -> ValueError:
        return ValueError(f"collision data {path} does not match its format ({what}); {_REMEDY}")

    expected = {*ROLLOUT_SETS, *PUSH_LISTS, "push_at_rest", "scenario_at_rest"}
    expected |= {"current_gain", "current_noise_std"}
    if not isinstance(sets, dict) or set(sets) != expected:
        raise fail("not the simulated sets")
    for name in ROLLOUT_SETS:
        data = sets[name]
        if not isinstance(data, dict) or not data:
            raise fail(f"{name} is not a mapping of arrays")
        lengths = {len(v) if isinstance(v, np.ndarray) else -1 for v in data.values()}
        if len(lengths) != 1 or -1 in lengths:
            raise fail(f"{name} does not hold arrays of one length")
    fields = {f.name for f in dataclasses.fields(Push)}
    out = dict(sets)
    for name in PUSH_LISTS:
        pushes = sets[name]
        if not isinstance(pushes, list) or not all(
            isinstance(p, dict) and set(p) == fields for p in pushes
        ):
            raise fail(f"{name} is not a list of pushes")
        out[name] = [Push(**{**p, "force": tuple(p["force"])}) for p in pushes]
    return out


def simulated_sets(args: argparse.Namespace, path: Path, bar: tqdm) -> dict[str, Any]:
    """:func:`simulate`, kept in ``path`` (a safe file, :data:`DATA_FILE`, with the
    :data:`DATA_OPTIONS` it was made with) and read back from it while those options are
    the same."""
    options = {k: getattr(args, k) for k in DATA_OPTIONS}
    if path.is_file() or path.is_symlink():
        saved = load_torch_file(path, "collision data", _REMEDY, follow_links=False)
        if isinstance(saved, dict) and saved.get("options") == options:
            sets = _from_plain(saved.get("sets"), path)
            bar.update(5)
            return sets
    sets = simulate(args, bar)
    atomic_torch_save({"options": options, "sets": _to_plain(sets)}, path)
    return sets


@functools.lru_cache(maxsize=1)
def _load_sets(path: str, mtime_ns: int) -> dict[str, Any]:
    """The simulated sets in ``path`` (cached per worker process while the file is the same)."""
    saved = load_torch_file(path, "collision data", _REMEDY, follow_links=False)
    return _from_plain(saved.get("sets") if isinstance(saved, dict) else None, Path(path))


def load_sets(data_path: str) -> dict[str, Any]:
    """The simulated sets written by :func:`simulated_sets` (read once per process while the
    file is unchanged)."""
    return _load_sets(data_path, Path(data_path).stat().st_mtime_ns)

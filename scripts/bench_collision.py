"""Benchmark: proprioceptive collision detection on the simulated UR10 (thesis section 4.6).

Data (``mcpilco/UR10-v0`` defaults: PD + gravity controller, stiction + Coulomb + Stribeck
friction, motor-current noise 0.17 A, 8 ms samples; all collision-free unless stated):

training
    ``--train-waypoints`` random waypoints (quintic moves at 20-60% of the joint speed
    limits, rests of 0-1 s; joint box :data:`HALF_WIDTH` around the home pose): ~80,000
    samples for 200 waypoints (thesis: 200 points, 80,000 samples). The GPs are conditioned
    on ``--gp-points`` rows taken with a constant step (thesis: 5000); hyperparameters by
    marginal likelihood on ``--hyper-points`` random rows of those.
validation ("test set" of the thesis)
    ``--test-waypoints`` new waypoints with rests of 0.5-3 s, a move to the home pose, the
    tool circle (radius 30 cm at 30 mm/s, ~63 s), a final rest of ``--final-rest`` s. Gives
    the RMSE of ``i_hat`` per joint on quasi-static (``|qd_j| < sigma_v``) and dynamic
    samples (thesis Fig. 4.2) and calibrates the thresholds (thesis: ``sigma_CD`` = the
    largest ``|s|`` on it).
push-free
    ``--push-free-minutes`` of the same kind of program (new seed): false alarms per minute.
pushes
    ``--push-waypoints`` waypoints with rests of 1.5-3 s; one push per move or rest piece
    (the pause before each push at least 1 s): onset 0.2-0.5 s into a rest or at 20-60% of
    a move; magnitude, duration and ramp from ``PUSH_RANGES`` of the env (10-80 N,
    0.2-1.5 s, 0.02-0.1 s); link 4, 5 or 6 (the env's "last half of the chain"); direction
    uniform on the sphere. A push counts as "at rest" when its onset falls in a rest piece.
figure scenario (thesis Fig. 4.3)
    the circle then a 15 s rest; five 1 s pushes of ``--scenario-force`` N on link 4,
    horizontal and tangential (they turn joint 1): three while tracking, two at rest.

Estimators (:mod:`mcpilco.models.collision`): PP (eq. 4.7), SP (eq. 3.7), FC
(eqs. 4.8-4.10) with ``sigma_v`` chosen by hold-out cross-validation among
``--sigma-v-candidates`` (train on the first 80% of the training run, score on the last 20%).
Also "PP-sign": PP with the exact ``sign(qd)`` (``coulomb_velocity = 0``), RMSE only.

Detection: thresholds by the thesis rule (``"max"``: ``sigma_CD,j = max |s_j|`` on the
validation set) and by the variance rule (``k_j sigma_j(x)``, ``k_j = max |s_j| / sigma_j``
on the validation set), alarms after ``m`` samples of persistence for every ``m`` in
``--persistence``. Table: detection rate (all pushes, pushes >= 30 N, moving / at rest),
median latency, false alarms per minute on the push-free data. Curves: detection rate vs
false alarms per minute for both rules, thresholds from the validation quantiles
``1 - alpha`` (``--alphas``), one panel per persistence in ``--roc-persistence``.

Cost (2-core machine, one torch thread): the reduced run ``--gp-points 2000 --hyper-points
600`` takes ~20 min CPU, most of it the FC predictive variance on ~140,000 rows. At the
issue's 5000 conditioning rows a prediction costs ~3.9 ms per row (mean) and ~13 ms per row
(with variance), so the default run needs about an hour.

Jobs: the simulated data are kept in ``RUNS_DIR/data.pkl`` (reused while the data options
are the same); the ``sigma_v`` cross-validation and each estimator's fit and evaluation are
sweep jobs (:mod:`mcpilco.experiments.sweep`) in ``--jobs`` local processes or on Ray
(``--ray [ADDRESS]``; the jobs read ``RUNS_DIR/data.pkl``, so a multi-node cluster needs
``--runs-dir`` on a shared file system), FC after the cross-validation. Each writes
``RUNS_DIR/<label>.json``: a rerun computes only the jobs without one.

Outputs (``--out-dir``, default ``results/``): ``collision.json``, ``collision.md``,
``collision_rmse.png`` (Fig. 4.2), ``collision_detection.png`` (Fig. 4.3),
``collision_roc.png``.

Usage::

    python -m mcpilco.scripts.bench_collision                        # issue sizes
    python -m mcpilco.scripts.bench_collision --gp-points 2000 --hyper-points 600
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import math
import os
import pickle
import platform
import time
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from mcpilco.agents.common.cli import console_main
from mcpilco.envs.arm_builder import dh_forward_kinematics
from mcpilco.envs.arm_data import (
    PiecewiseTrajectory,
    QuinticMove,
    circle_trajectory,
    random_waypoints,
    rollout,
)
from mcpilco.envs.arm_env import PUSH_RANGES, UR10_HOME, Push, UR10Env
from mcpilco.experiments.sweep import (
    Job,
    SweepError,
    add_sweep_arguments,
    runner_from_args,
    write_atomic,
)
from mcpilco.models.collision import (
    CollisionDetector,
    CollisionInputs,
    alarm_flags,
    as_collision_inputs,
    evaluate_detection,
    make_estimator,
    persistent,
    quantile_threshold,
    rmse_split,
    select_sigma_v,
)
from mcpilco.scripts.detect_collisions import nominal_model

FloatArray = np.ndarray

HALF_WIDTH = (1.2, 0.6, 0.9, 1.2, 1.2, 1.5)
"""Half widths [rad] of the joint box of the random waypoints around ``UR10_HOME``."""

SPEED_RANGE = (0.2, 0.6)
"""Peak speed of each move as a fraction of the joint speed limit."""

PUSH_LINKS = (4, 5, 6)
"""Links pushed in the statistics (the env's ``random_pushes`` convention)."""

ESTIMATOR_NAMES = ("PP", "SP", "FC")


# ----------------------------------------------------------------------------- data


def waypoint_box() -> FloatArray:
    home = np.asarray(UR10_HOME)
    half = np.asarray(HALF_WIDTH)
    return np.stack([home - half, home + half], axis=1)


def waypoints(
    env: UR10Env, rng: np.random.Generator, q0: FloatArray, n: int, rest: tuple[float, float]
) -> PiecewiseTrajectory:
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
    """One random push per move / rest piece (module docstring); returns the pushes and
    whether each starts in a rest piece."""
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
    """All rollouts (module docstring)."""
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


# ----------------------------------------------------------------------------- models


def gp_options(args: argparse.Namespace, hyper_points: int | None = None) -> dict[str, Any]:
    return dict(
        hyper_points=args.hyper_points if hyper_points is None else hyper_points,
        adam_iters=args.adam_iters,
        lbfgs_iters=args.lbfgs_iters,
        seed=args.seed,
    )


def fit(name: str, xml: str, X: CollisionInputs, y: FloatArray, **kwargs: Any) -> Any:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # L-BFGS fallbacks and jitter notices
        return make_estimator(name, xml, **kwargs).fit(X, y)


def choose_sigma_v(
    args: argparse.Namespace, xml: str, data: dict[str, FloatArray]
) -> dict[str, Any]:
    """Hold-out CV of ``sigma_v`` (first 80% of the training run / last 20%)."""
    X = as_collision_inputs(data)
    y = data["i"]
    cut = int(0.8 * X.n_samples)
    tr = np.arange(0, cut, max(cut // args.cv_points, 1))[: args.cv_points]
    va = np.arange(cut, X.n_samples, max((X.n_samples - cut) // args.cv_validation, 1))
    opts = gp_options(args, min(args.cv_hyper_points, args.cv_points))

    def factory(sigma_v: float) -> Any:
        return make_estimator("FC", xml, sigma_v=sigma_v, **opts)

    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        best, scores = select_sigma_v(
            factory, X.rows(tr), y[tr], X.rows(va), y[va], args.sigma_v_candidates
        )
    return {
        "best": best,
        "scores": {f"{k:g}": v for k, v in scores.items()},
        "n_train": int(tr.size),
        "n_validation": int(va.size),
        "seconds": time.perf_counter() - t0,
    }


# ----------------------------------------------------------------------------- detection


def push_records(
    data: dict[str, Any], pushes: list[Push], at_rest: list[bool], gain: FloatArray
) -> list[dict[str, Any]]:
    """Ground truth of every push: magnitude, link, rest/moving, peak ``|tau_ext| / K_eq``."""
    t = data["t"]
    recs = []
    for p, rest in zip(pushes, at_rest, strict=True):
        m = (t >= p.t_start) & (t <= p.t_start + p.duration + 1e-9)
        peak = np.abs(data["tau_ext"][m]).max(axis=0) / gain if m.any() else np.zeros(gain.size)
        recs.append(
            {
                "t_start": p.t_start,
                "duration": p.duration,
                "link": p.link,
                "force": float(np.linalg.norm(p.force)),
                "at_rest": bool(rest),
                "peak_tau_ext_A": peak.tolist(),
            }
        )
    return recs


def score(
    alarm: FloatArray,
    data: dict[str, Any],
    records: list[dict[str, Any]],
    free: dict[str, Any],
    free_alarm: FloatArray,
) -> dict[str, Any]:
    """Detection on the push run (matched to ``records`` by onset) + false alarms/min on
    the push-free run."""
    ev = evaluate_detection(alarm, data["contact"], data["t"])
    starts = np.array([p["start"] for p in ev["pushes"]])
    detected, latency = [], []
    for rec in records:  # runs of contact = pushes, in order; match by onset time
        k = int(np.argmin(np.abs(starts - rec["t_start"])))
        detected.append(bool(ev["pushes"][k]["detected"]))
        latency.append(ev["pushes"][k]["latency"])
    detected_arr = np.array(detected)
    force = np.array([r["force"] for r in records])
    rest = np.array([r["at_rest"] for r in records])
    fa = evaluate_detection(free_alarm, np.zeros_like(free["contact"]), free["t"])

    def rate(mask: FloatArray) -> float:
        return float(detected_arr[mask].mean()) if mask.any() else float("nan")

    lat = [v for v in latency if v is not None]
    return {
        "detected": detected,
        "latency": latency,
        "rate_all": rate(np.ones_like(rest)),
        "rate_ge30": rate(force >= 30.0),
        "rate_moving": rate(~rest),
        "rate_rest": rate(rest),
        "rate_ge30_rest": rate((force >= 30.0) & rest),
        "rate_ge30_moving": rate((force >= 30.0) & ~rest),
        "median_latency": float(np.median(lat)) if lat else float("nan"),
        "false_alarms": fa["false_alarms"],
        "false_alarms_per_minute": fa["false_alarms_per_minute"],
        "push_free_minutes": fa["push_free_minutes"],
        "false_alarms_in_push_run": ev["false_alarms"],
    }


def evaluate_estimator(
    est: Any, sets: dict[str, dict[str, Any]], args: argparse.Namespace, variance: bool
) -> dict[str, Any]:
    """Signals on every set; RMSE split; thresholds; detection tables; ROC points."""
    sigma_v_split = args.rmse_sigma_v
    noise = np.sqrt(np.asarray(est.noise_variance_, dtype=np.float64))
    sig: dict[str, dict[str, FloatArray]] = {}
    t0 = time.perf_counter()
    for key in ("validation", "push_free", "pushes", "scenario"):
        data = sets[key]
        need_var = variance and key != "scenario"  # the scenario uses the max rule only
        mean, var = est.predict(as_collision_inputs(data), return_var=need_var)
        s = data["i"] - mean
        sd = np.sqrt((np.zeros_like(s) if var is None else np.maximum(var, 0.0)) + noise**2)
        sig[key] = {"i_hat": mean, "s": s, "sigma": sd}
    seconds_predict = time.perf_counter() - t0
    val = sets["validation"]
    rmse = rmse_split(val["i"], sig["validation"]["i_hat"], val["qd"], sigma_v_split)
    rules = {"max": sig["validation"]["s"]}
    if variance:
        rules["variance"] = sig["validation"]["s"] / sig["validation"]["sigma"]
    out: dict[str, Any] = {
        "rmse": {k: np.asarray(v).tolist() for k, v in rmse.items()},
        "noise_std": noise.tolist(),
        "predict_seconds": seconds_predict,
        "thresholds": {},
        "detection": {},
        "roc": {},
    }
    recs = sets["push_records"]
    for rule, z in rules.items():
        scale = quantile_threshold(z, 0.0)
        out["thresholds"][rule] = scale.tolist()
        for m in args.persistence:
            alarms = {}
            for key in ("pushes", "push_free"):
                thr = scale if rule == "max" else scale * sig[key]["sigma"]
                alarms[key] = persistent(alarm_flags(sig[key]["s"], thr), m)
            out["detection"][f"{rule}/m={m}"] = score(
                alarms["pushes"], sets["pushes"], recs, sets["push_free"], alarms["push_free"]
            )
        for m in args.roc_persistence:
            roc = []
            for alpha in args.alphas:
                scale_a = quantile_threshold(z, alpha)
                alarms = {}
                for key in ("pushes", "push_free"):
                    thr = scale_a if rule == "max" else scale_a * sig[key]["sigma"]
                    alarms[key] = persistent(alarm_flags(sig[key]["s"], thr), m)
                sc = score(
                    alarms["pushes"], sets["pushes"], recs, sets["push_free"], alarms["push_free"]
                )
                roc.append(
                    {
                        "alpha": alpha,
                        "rate_all": sc["rate_all"],
                        "rate_ge30": sc["rate_ge30"],
                        "false_alarms_per_minute": sc["false_alarms_per_minute"],
                    }
                )
            out["roc"][f"{rule}/m={m}"] = roc
    # the scenario (thesis Fig. 4.3): max rule, m = 1
    sc = sets["scenario"]
    thr = np.asarray(out["thresholds"]["max"])
    alarm = alarm_flags(sig["scenario"]["s"], thr)
    ev = evaluate_detection(alarm, sc["contact"], sc["t"])
    out["scenario"] = {
        "detected": [p["detected"] for p in ev["pushes"]],
        "latency": [p["latency"] for p in ev["pushes"]],
        "false_alarms": ev["false_alarms"],
    }
    out["_signals"] = {k: sig[k] for k in ("scenario",)}
    return out


# ----------------------------------------------------------------------------- jobs

DATA_OPTIONS = (
    "seed", "train_waypoints", "test_waypoints", "final_rest", "push_free_minutes",
    "push_waypoints", "scenario_force",
)  # fmt: skip
"""Options that set the simulated data (:func:`simulate`)."""

MODEL_OPTIONS = (
    "seed", "gp_points", "hyper_points", "adam_iters", "lbfgs_iters", "cv_points",
    "cv_validation", "cv_hyper_points", "sigma_v_candidates", "rmse_sigma_v", "persistence",
    "alphas", "roc_persistence",
)  # fmt: skip
"""Options of the cross-validation, the fits and the evaluation (the jobs' arguments)."""


def simulated_sets(args: argparse.Namespace, path: Path, bar: tqdm) -> dict[str, Any]:
    """:func:`simulate`, kept in ``path`` (a pickle with the :data:`DATA_OPTIONS` it was made
    with) and read back from it while those options are the same."""
    options = {k: getattr(args, k) for k in DATA_OPTIONS}
    if path.is_file():
        with open(path, "rb") as fh:
            saved = pickle.load(fh)
        if saved["options"] == options:
            bar.update(5)
            return saved["sets"]
    sets = simulate(args, bar)
    data = {"options": options, "sets": sets}
    write_atomic(path, pickle.dumps(data, protocol=pickle.HIGHEST_PROTOCOL))
    return sets


@functools.lru_cache(maxsize=1)
def _load_sets(path: str, mtime_ns: int) -> dict[str, Any]:
    """The simulated sets in ``path`` (cached per worker process while the file is the same)."""
    with open(path, "rb") as fh:
        return pickle.load(fh)["sets"]


def _sets(data_path: str) -> dict[str, Any]:
    return _load_sets(data_path, Path(data_path).stat().st_mtime_ns)


def _gp_rows(train: dict[str, FloatArray], gp_points: int) -> tuple[CollisionInputs, FloatArray]:
    """The GP's conditioning rows: ``gp_points`` rows of the training run, a constant step."""
    X = as_collision_inputs(train)
    step = max(X.n_samples // gp_points, 1)
    rows = np.arange(0, X.n_samples, step)[:gp_points]
    return X.rows(rows), train["i"][rows]


def cv_job(data_path: str, data: dict[str, Any], options: dict[str, Any]) -> dict[str, Any]:
    """The ``sigma_v`` cross-validation (:func:`choose_sigma_v`) as a sweep job; ``data``:
    the :data:`DATA_OPTIONS` of the file (they identify it)."""
    args = argparse.Namespace(**options)
    return choose_sigma_v(args, nominal_model("ur10"), _sets(data_path)["train"])


def estimator_job(
    label: str,
    name: str,
    kwargs: dict[str, Any],
    data_path: str,
    data: dict[str, Any],
    options: dict[str, Any],
    variance: bool,
    save_detector: str | None = None,
) -> dict[str, Any]:
    """Fit estimator ``name`` (``kwargs``) on the GP rows and evaluate it on every set
    (:func:`evaluate_estimator`; ``PP-sign``: the RMSE split only), as a sweep job; ``data``
    as in :func:`cv_job`. ``save_detector``: also write the FC detector (max rule) there."""
    args = argparse.Namespace(**options)
    sets = dict(_sets(data_path))
    sets["push_records"] = push_records(
        sets["pushes"], sets["push_list"], sets["push_at_rest"], sets["current_gain"]
    )
    xml = nominal_model("ur10")
    Xs, ys = _gp_rows(sets["train"], args.gp_points)
    t0 = time.perf_counter()
    est = fit(name, xml, Xs, ys, **kwargs)
    fit_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    if label == "PP-sign":  # RMSE only
        mean, _ = est.predict(as_collision_inputs(sets["validation"]), return_var=False)
        val = sets["validation"]
        r = rmse_split(val["i"], mean, val["qd"], args.rmse_sigma_v)
        result = {"rmse": {k: np.asarray(v).tolist() for k, v in r.items()}}
    else:
        result = evaluate_estimator(est, sets, args, variance=variance)
    if save_detector:
        det = CollisionDetector(est, "max", 0.0, args.persistence[0], 0.008)
        det.scale_ = np.asarray(result["thresholds"]["max"])
        det.save(save_detector)
    return {"fit_s": fit_s, "evaluate_s": time.perf_counter() - t0, "result": result}


# ----------------------------------------------------------------------------- plots


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_rmse(results: dict[str, Any], path: Path) -> None:
    """Thesis Fig. 4.2: RMSE per joint, dynamic (top) and quasi-static (bottom)."""
    plt = _plt()
    names = [n for n in (*ESTIMATOR_NAMES, "PP-sign") if n in results["estimators"]]
    fig, axes = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    n = len(results["estimators"][names[0]]["rmse"]["all"])
    x = np.arange(1, n + 1)
    width = 0.8 / len(names)
    noise = np.asarray(results["current_noise_std"])
    for ax, regime in zip(axes, ("dynamic", "quasi_static"), strict=True):
        for k, name in enumerate(names):
            vals = results["estimators"][name]["rmse"][regime]
            ax.bar(x + (k - (len(names) - 1) / 2) * width, vals, width, label=name)
        ax.plot(x, noise, "k_", ms=25, mew=2, label="noise std")
        title = "|qd_j| >= sigma_v (dynamic)" if regime == "dynamic" else "|qd_j| < sigma_v"
        ax.set_title(f"{title}, sigma_v = {results['config']['rmse_sigma_v']:g} rad/s")
        ax.set_ylabel("RMSE of i_hat [A]")
        ax.grid(axis="y", alpha=0.3)
    axes[1].set_xticks(x, [f"joint {j}" for j in x])
    axes[0].legend(ncol=len(names) + 1, fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_scenario(results: dict[str, Any], sets: dict[str, Any], path: Path) -> None:
    """Thesis Fig. 4.3: i1 with the SP and FC estimates; s with sigma_CD; pushes shaded."""
    plt = _plt()
    sc = sets["scenario"]
    t = sc["t"]
    names = [n for n in ("SP", "FC") if n in results["estimators"]]
    fig, axes = plt.subplots(1 + len(names), 1, figsize=(10, 2.4 * (1 + len(names))), sharex=True)
    axes = np.atleast_1d(axes)
    j = results["config"]["scenario_joint"] - 1
    axes[0].plot(t, sc["i"][:, j], color="0.4", lw=0.6, label=f"i{j + 1} measured")
    for k, name in enumerate(names):
        sig = results["estimators"][name]["_signals"]["scenario"]
        axes[0].plot(t, sig["i_hat"][:, j], lw=0.9, color=f"C{k}", label=f"{name} estimate")
        ax = axes[k + 1]
        thr = results["estimators"][name]["thresholds"]["max"][j]
        ax.plot(t, sig["s"][:, j], lw=0.6, color=f"C{k}", label=f"s{j + 1} ({name})")
        ax.axhline(thr, color="C3", ls="--", lw=1, label=f"sigma_CD = {thr:.2f} A")
        ax.axhline(-thr, color="C3", ls="--", lw=1)
        ax.set_ylabel("[A]")
        ax.legend(loc="upper left", fontsize=8)
    axes[0].set_ylabel("[A]")
    axes[0].legend(loc="upper left", fontsize=8)
    for ax in axes:
        for p in sets["scenario_pushes"]:
            ax.axvspan(p.t_start, p.t_start + p.duration, color="0.85", zorder=0)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("t [s] (circle tracking, then rest; pushes shaded)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_roc(results: dict[str, Any], path: Path) -> None:
    """Detection rate vs false alarms per minute, thresholds from validation quantiles."""
    plt = _plt()
    ms = results["config"]["roc_persistence"]
    fig, axes = plt.subplots(1, len(ms), figsize=(6 * len(ms), 4.5), squeeze=False)
    for ax, m in zip(axes[0], ms, strict=True):
        for k, (name, res) in enumerate(results["estimators"].items()):
            for rule, style in (("max", "-o"), ("variance", "--s")):
                pts = res.get("roc", {}).get(f"{rule}/m={m}")
                if not pts:
                    continue
                fa = [max(p["false_alarms_per_minute"], 1e-2) for p in pts]
                rate = [p["rate_all"] for p in pts]
                ax.plot(fa, rate, style, color=f"C{k}", label=f"{name} {rule}")
        ax.set_xscale("log")
        ax.set_xlabel("false alarms per minute on push-free data (0 plotted at 0.01)")
        ax.set_ylabel("fraction of pushes detected")
        ax.set_title(f"persistence m = {m}")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# ----------------------------------------------------------------------------- report


def _f(v: Any, digits: int = 2) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    return f"{v:.{digits}f}"


def goals(results: dict[str, Any]) -> dict[str, Any]:
    """The issue's figures (recorded, not asserted)."""
    est = results["estimators"]
    g: dict[str, Any] = {}
    if all(n in est for n in ESTIMATOR_NAMES):
        fc = np.asarray(est["FC"]["rmse"]["quasi_static"])
        pp = np.asarray(est["PP"]["rmse"]["quasi_static"])
        sp = np.asarray(est["SP"]["rmse"]["quasi_static"])
        g["FC quasi-static RMSE below PP and SP on every joint"] = bool(
            np.all(fc < pp) and np.all(fc < sp)
        )
        if "PP-sign" in est:
            pps = np.asarray(est["PP-sign"]["rmse"]["quasi_static"])
            g["FC quasi-static RMSE below PP-sign on every joint"] = bool(np.all(fc < pps))
        s_fc = np.asarray(est["FC"]["thresholds"]["max"])
        s_sp = np.asarray(est["SP"]["thresholds"]["max"])
        g["FC sigma_CD below SP on every joint"] = bool(np.all(s_fc < s_sp))
        g["FC sigma_CD below SP, max over joints"] = bool(s_fc.max() < s_sp.max())
    if "FC" in est:
        m = results["config"]["persistence"]
        for mm in m:
            d = est["FC"]["detection"][f"max/m={mm}"]
            g[f"FC max m={mm}: all >=30 N pushes detected"] = d["rate_ge30"] == 1.0
            g[f"FC max m={mm}: zero false alarms on push-free data"] = d["false_alarms"] == 0
            g[f"FC max m={mm}: median latency <= 40 ms"] = d["median_latency"] <= 0.040 + 1e-9
        for m in results["config"]["roc_persistence"]:
            roc = est["FC"]["roc"]
            if f"variance/m={m}" not in roc:
                continue
            better = []
            for pv in roc[f"variance/m={m}"]:
                # max-rule detection at a false-alarm rate <= the variance rule's
                cands = [
                    pm["rate_all"]
                    for pm in roc[f"max/m={m}"]
                    if pm["false_alarms_per_minute"] <= pv["false_alarms_per_minute"] + 1e-12
                ]
                if cands:
                    better.append(pv["rate_all"] >= max(cands))
            key = f"FC m={m}: variance rule detects >= max rule at <= the same false-alarm rate"
            g[key + " (every alpha)"] = bool(all(better)) if better else None
    return g


def markdown(results: dict[str, Any]) -> str:
    cfg = results["config"]
    est = results["estimators"]
    sizes = results["sizes"]
    lines = [
        "# Collision detection benchmark (UR10, thesis section 4.6)",
        "",
        f"Machine: {results['machine']}; torch threads {cfg['threads']}; seed {cfg['seed']}; "
        f"wall {results['seconds']:.0f} s, CPU {results['cpu_seconds']:.0f} s.",
        "",
        f"Data: training {sizes['train']} samples ({cfg['train_waypoints']} waypoints), GP "
        f"conditioned on {sizes['gp']} rows (constant step), hyperparameters on "
        f"{cfg['hyper_points']} rows ({cfg['adam_iters']} Adam + {cfg['lbfgs_iters']} L-BFGS); "
        f"validation {sizes['validation']} samples ({cfg['test_waypoints']} waypoints + circle + "
        f"rests); push-free {sizes['push_free']} samples "
        f"({sizes['push_free'] * 0.008 / 60:.1f} min); push run {sizes['pushes']} samples with "
        f"{sizes['n_pushes']} pushes ({sizes['n_pushes_rest']} at rest).",
        "",
        "## sigma_v by cross-validation (FC)",
        "",
        "| sigma_v [rad/s] | validation sum of MSE [A^2] |",
        "|---|---|",
    ]
    cv = results["sigma_v_cv"]
    for k, v in cv["scores"].items():
        mark = " (chosen)" if float(k) == cv["best"] else ""
        lines.append(f"| {k}{mark} | {v:.4f} |")
    lines += [
        "",
        f"FC uses sigma_v = {cv['best']:g} rad/s; the RMSE split below uses "
        f"sigma_v = {cfg['rmse_sigma_v']:g} rad/s (thesis value).",
        "",
        "## RMSE of i_hat on the validation set [A] (thesis Fig. 4.2)",
        "",
        "| estimator | regime | " + " | ".join(f"joint {j}" for j in range(1, 7)) + " |",
        "|---|---|" + "---|" * 6,
    ]
    for name, res in est.items():
        for regime in ("quasi_static", "dynamic"):
            vals = " | ".join(_f(v, 3) for v in res["rmse"][regime])
            lines.append(f"| {name} | {regime.replace('_', '-')} | {vals} |")
    noise = " | ".join(_f(v, 3) for v in results["current_noise_std"])
    lines += [f"| noise std | | {noise} |", ""]
    lines += [
        "PP-sign = PP with the exact sign(qd) feature (reference; see COULOMB_VELOCITY in "
        "models/collision/estimators.py).",
        "",
        "## Thresholds sigma_CD = max |s| on the validation set [A] (thesis: FC 1.28, SP 2.10, "
        "PP 2.09)",
        "",
        "| estimator | " + " | ".join(f"joint {j}" for j in range(1, 7)) + " | max |",
        "|---|" + "---|" * 7,
    ]
    for name, res in est.items():
        if "max" in res.get("thresholds", {}):
            thr = res["thresholds"]["max"]
            lines.append(f"| {name} | " + " | ".join(_f(v) for v in thr) + f" | {_f(max(thr))} |")
    lines += [
        "",
        "## Detection (push run) and false alarms (push-free run)",
        "",
        "| estimator | rule | m | detected all | >= 30 N | moving | at rest | >= 30 N at rest | "
        "median latency [ms] | false alarms / min (count) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, res in est.items():
        for key, d in res.get("detection", {}).items():
            rule, m = key.split("/m=")
            lines.append(
                f"| {name} | {rule} | {m} | {_f(d['rate_all'])} | {_f(d['rate_ge30'])} | "
                f"{_f(d['rate_moving'])} | {_f(d['rate_rest'])} | {_f(d['rate_ge30_rest'])} | "
                f"{_f(1000 * d['median_latency'], 0)} | {_f(d['false_alarms_per_minute'], 3)} "
                f"({d['false_alarms']}) |"
            )
    lines += ["", "## Missed pushes (FC, max rule, m = 1)", ""]
    if "FC" in est and "max/m=1" in est["FC"]["detection"]:
        d = est["FC"]["detection"]["max/m=1"]
        thr = np.asarray(est["FC"]["thresholds"]["max"])
        rows = [
            (r, det)
            for r, det in zip(results["push_records"], d["detected"], strict=True)
            if not det
        ]
        lines += [
            "| t [s] | force [N] | link | at rest | max_j peak abs(tau_ext_j)/K_eq_j [A] | "
            "max_j ratio to sigma_CD,j |",
            "|---|---|---|---|---|---|",
        ]
        for r, _ in rows:
            peak = np.asarray(r["peak_tau_ext_A"])
            lines.append(
                f"| {r['t_start']:.1f} | {r['force']:.0f} | {r['link']} | {r['at_rest']} | "
                f"{peak.max():.2f} | {(peak / thr).max():.2f} |"
            )
        if not rows:
            lines.append("(none)")
    lines += ["", "## Detection vs false alarms (thresholds from validation quantiles)", ""]
    lines += [
        "| estimator | rule | m | alpha | detected | false alarms / min |",
        "|---|---|---|---|---|---|",
    ]
    for name, res in est.items():
        for key, pts in res.get("roc", {}).items():
            rule, m = key.split("/m=")
            for p in pts:
                lines.append(
                    f"| {name} | {rule} | {m} | {p['alpha']:g} | {_f(p['rate_all'])} | "
                    f"{_f(p['false_alarms_per_minute'], 3)} |"
                )
    lines += ["", "## Thesis Fig. 4.3 scenario (max rule, m = 1)", ""]
    for name, res in est.items():
        if "scenario" in res:
            s = res["scenario"]
            det = ", ".join("yes" if d else "no" for d in s["detected"])
            lines.append(
                f"- {name}: pushes detected [{det}] (3 moving, 2 at rest); false alarms "
                f"{s['false_alarms']}"
            )
    lines += ["", "## Goals", ""]
    lines += [f"- {k}: {v}" for k, v in results["goals"].items()]
    lines += ["", "## Timing [s]", ""]
    lines += [f"- {k}: {v:.1f}" for k, v in results["timing"].items()]
    return "\n".join(lines) + "\n"


def strip(obj: Any) -> Any:
    """JSON-ready copy (drops ``_signals``, converts numpy)."""
    if isinstance(obj, dict):
        return {k: strip(v) for k, v in obj.items() if not str(k).startswith("_")}
    if isinstance(obj, list | tuple):
        return [strip(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


# ----------------------------------------------------------------------------- main


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--train-waypoints", type=int, default=200)
    p.add_argument("--gp-points", type=int, default=5000, help="GP conditioning rows")
    p.add_argument("--hyper-points", type=int, default=800, help="rows for hyperparameters")
    p.add_argument("--adam-iters", type=int, default=80)
    p.add_argument("--lbfgs-iters", type=int, default=20)
    p.add_argument("--test-waypoints", type=int, default=50)
    p.add_argument("--final-rest", type=float, default=10.0, help="rest after the circle [s]")
    p.add_argument("--push-free-minutes", type=float, default=10.0)
    p.add_argument("--push-waypoints", type=int, default=40)
    p.add_argument("--scenario-force", type=float, default=40.0, help="Fig. 4.3 pushes [N]")
    p.add_argument("--scenario-joint", type=int, default=1, help="joint shown in Fig. 4.3")
    p.add_argument("--estimators", default=",".join(ESTIMATOR_NAMES))
    p.add_argument("--no-pp-sign", dest="pp_sign", action="store_false")
    p.add_argument("--variance-estimators", default="FC", help="also the variance rule")
    p.add_argument("--sigma-v-candidates", default="0.003,0.01,0.03,0.1")
    p.add_argument("--cv-points", type=int, default=1000, help="CV training rows")
    p.add_argument("--cv-validation", type=int, default=5000, help="CV validation rows")
    p.add_argument("--cv-hyper-points", type=int, default=400, help="CV hyperparameter rows")
    p.add_argument("--rmse-sigma-v", type=float, default=1e-2, help="RMSE split [rad/s]")
    p.add_argument("--persistence", default="1,2,3")
    p.add_argument("--alphas", default="0,1e-5,3e-5,1e-4,3e-4,1e-3,3e-3")
    p.add_argument("--roc-persistence", default="1,2")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=1, help="torch threads")
    p.add_argument("--out-dir", default="results")
    p.add_argument("--save-detector", default=None, help="write the FC detector (max rule)")
    p.add_argument(
        "--runs-dir",
        type=Path,
        default=Path("runs/bench_collision"),
        help="simulated data (data.pkl) and one result file per job, reused by a rerun",
    )
    p.add_argument("--no-progress", action="store_true")
    add_sweep_arguments(p)  # --jobs N (local processes), --ray [ADDRESS]: CV and estimators
    return p


def _list(value: str, kind: type = str) -> list:
    return [kind(v) for v in value.split(",") if v.strip()]


@console_main("mcpilco-bench-collision")
def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark; write JSON, PNGs and Markdown; print the Markdown. Returns 0 (1 when
    a job failed)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        runner = runner_from_args(args, progress=not args.no_progress)
    except SweepError as err:
        parser.error(str(err))
    args.estimators = _list(args.estimators)
    bad = [e for e in args.estimators if e not in ESTIMATOR_NAMES]
    if bad:
        raise SystemExit(f"unknown estimator(s) {bad}; choose from {ESTIMATOR_NAMES}")
    args.variance_estimators = _list(args.variance_estimators)
    args.sigma_v_candidates = _list(args.sigma_v_candidates, float)
    args.persistence = _list(args.persistence, int)
    args.alphas = _list(args.alphas, float)
    args.roc_persistence = _list(args.roc_persistence, int)
    torch.set_num_threads(args.threads)
    out_dir = Path(args.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    t_wall, t_cpu = time.perf_counter(), time.process_time()
    timing: dict[str, float] = {}
    bar = tqdm(total=5, disable=args.no_progress, desc="simulation")

    t0 = time.perf_counter()
    data_path = args.runs_dir / "data.pkl"
    sets = simulated_sets(args, data_path, bar)
    bar.close()
    timing["simulation"] = time.perf_counter() - t0
    gain = sets["current_gain"]
    sets["push_records"] = push_records(
        sets["pushes"], sets["push_list"], sets["push_at_rest"], gain
    )
    train = sets["train"]
    X = as_collision_inputs(train)
    Xs, _ = _gp_rows(train, args.gp_points)

    common = {
        "data_path": str(data_path),
        "data": {k: getattr(args, k) for k in DATA_OPTIONS},
        "options": {k: getattr(args, k) for k in MODEL_OPTIONS},
    }

    def estimator(label: str, name: str, kw: dict[str, Any]) -> Job:
        save = args.save_detector if label == "FC" else None
        kwargs = {"label": label, "name": name, "kwargs": kw, **common}
        kwargs.update(variance=label in args.variance_estimators, save_detector=save)
        return Job(label, estimator_job, kwargs, cpus=args.threads)

    first = [estimator(name, name, gp_options(args)) for name in args.estimators if name != "FC"]
    if args.pp_sign:
        first.append(estimator("PP-sign", "PP", {**gp_options(args), "coulomb_velocity": 0.0}))
    if "FC" in args.estimators:
        first.insert(0, Job("sigma_v_cv", cv_job, common, cpus=args.threads))
    sweeps = [runner.run(first, args.runs_dir, desc="sigma_v CV and estimators")]
    cv = sweeps[0].results.get("sigma_v_cv", {"best": 1e-2})
    timing["sigma_v_cv"] = cv.get("seconds", 0.0)
    if "FC" in args.estimators and "sigma_v_cv" in sweeps[0].results:
        fc = estimator("FC", "FC", {**gp_options(args), "sigma_v": cv["best"]})
        sweeps.append(runner.run([fc], args.runs_dir, desc="FC"))
    done = {k: v for sw in sweeps for k, v in sw.results.items() if k != "sigma_v_cv"}
    failed = [f for sw in sweeps for f in sw.failed]
    estimators: dict[str, Any] = {}
    for label in [*args.estimators, *(["PP-sign"] if args.pp_sign else [])]:
        if label not in done:
            continue
        res = done[label]["result"]
        if "_signals" in res:  # arrays again for the scenario figure
            res["_signals"] = {
                k: {kk: np.asarray(vv) for kk, vv in v.items()} for k, v in res["_signals"].items()
            }
        estimators[label] = res
        timing[f"fit {label}"] = done[label]["fit_s"]
        timing[f"evaluate {label}"] = done[label]["evaluate_s"]
    for sw in sweeps:
        print(sw.summary())

    results: dict[str, Any] = {
        "config": {k: v for k, v in vars(args).items()},
        "machine": f"{platform.machine()} {os.cpu_count()} CPUs, {platform.python_version()}, "
        f"torch {torch.__version__}",
        "sizes": {
            "train": int(X.n_samples),
            "gp": int(Xs.n_samples),
            "validation": int(sets["validation"]["t"].size),
            "push_free": int(sets["push_free"]["t"].size),
            "pushes": int(sets["pushes"]["t"].size),
            "n_pushes": len(sets["push_list"]),
            "n_pushes_rest": int(sum(sets["push_at_rest"])),
            "quasi_static_fraction_train": (np.abs(train["qd"]) < args.rmse_sigma_v)
            .mean(0)
            .tolist(),
        },
        "current_noise_std": np.asarray(sets["current_noise_std"]).tolist(),
        "current_gain": np.asarray(gain).tolist(),
        "sigma_v_cv": cv,
        "estimators": estimators,
        "push_records": sets["push_records"],
        "scenario_pushes": [dataclasses.asdict(p) for p in sets["scenario_pushes"]],
    }
    results["timing"] = timing
    results["seconds"] = time.perf_counter() - t_wall
    results["cpu_seconds"] = time.process_time() - t_cpu
    results["goals"] = goals(results)
    plot_rmse(results, out_dir / "collision_rmse.png")
    if "FC" in estimators or "SP" in estimators:
        plot_scenario(results, sets, out_dir / "collision_detection.png")
    plot_roc(results, out_dir / "collision_roc.png")
    (out_dir / "collision.json").write_text(json.dumps(strip(results), indent=1, default=str))
    text = markdown(results)
    (out_dir / "collision.md").write_text(text)
    print(text)
    if failed:
        print(f"failed jobs (see their .error.txt in {args.runs_dir}): {[f.key for f in failed]}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())

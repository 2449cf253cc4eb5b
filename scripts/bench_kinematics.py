r"""Kinematics learning benchmark: structure identification, FK GP, kinematic controller (ch. 2).

Parts (thesis section 2.6):

(a) **Monte Carlo** (2.6.1, Fig. 2.4): ``--robots`` random robots with 6 links (5 joints, 6
    markers) from :func:`mcpilco.models.kinematics.synthetic.random_chain` (random joint
    types, DH parameters, marker placements, camera pose); each joint a sum of 10 random
    sinusoids; ``T = 50`` noiseless samples; all ``15 x 5 = 75`` triplets per robot classified
    by the three tests (:func:`~mcpilco.models.kinematics.classify_all_triplets`). The data
    are noiseless, so the thresholds are the exact-feasibility tolerances
    ``xi_t = xi_o = 1e-6``. Confusion matrices for Prop. 2.3.1, 2.3.2, 2.3.3 and 2.3.2+2.3.3
    (class 1 = connected through a prismatic, resp. revolute, joint). The iterative
    algorithm is also run on every robot with shuffled markers and joints.
Marker protocol of parts (b)-(d) (``--facing-cone``, ``--visibility-cone``; defaults
:data:`FACING_CONE` = 40 and :data:`VISIBILITY_CONE` = 70 deg): the markers are attached facing
the camera at ``UR10_HOME``, a marker turned more than 70 deg from its line of sight to the
camera is not seen (NaN), and the waypoints and the controller's targets are drawn only where
every marker is seen, as in the thesis' data, where every marker was detected in every frame.
``--facing-cone none --visibility-cone none`` is the earlier protocol (random marker
orientations, every marker seen from any side).

(b) **Noise vs samples** (2.6.2, Fig. 2.6): the UR10 of ``mcpilco/MarkerCamera-v0`` with its
    default AprilTag-like noise follows a trajectory through 25 random waypoints (about
    ``--samples`` frames); for growing prefixes of it, all 126 triplets are classified with
    ``xi_t = 0.02`` m, ``xi_o = 0.1`` rad; misclassified triplets and the residual
    statistics ``f_r1`` (connected) / ``f_r2`` (not connected) of the linear (2.18) and
    non-linear (2.19) revolute tests are recorded; ``--repeats`` trajectories.
(c) **FK GP** (2.6.3, Table 2.1): the structure is identified on the whole training
    trajectory ``D_tr``; the GP with the kernels ``k_R``/``k_l`` (eqs. 2.22-2.23) is trained
    on ``--fk-train`` (100) samples of ``D_tr`` and tested on ``D_test`` (the same
    waypoints in another order). The samples are picked by ``--train-selection``: ``design``
    (default, beyond the thesis) greedily by the prior variance of ``k_l`` from the joint
    signals alone (:func:`~mcpilco.models.kinematics.forward.design_subset`), ``random`` at
    random as in the thesis. RMSE against the measured (noisy) test poses, as in the
    thesis, and against the true poses. Baseline: an RBF GP (ARD, on raw ``q``) on the same
    samples. Options beyond the thesis, reported separately: the GP on all nine rotation
    elements with the mean projected onto SO(3); the GP with leave-one-out outlier trimming
    (``outlier_threshold=4``, :meth:`ForwardKinematicsGP.fit`); the chain model
    (:class:`~mcpilco.models.kinematics.ChainForwardKinematicsGP`: one-joint GPs on the
    relative poses of consecutive markers of the identified chain, composed), trained on the
    same frames with every marker they show. Diagnostics: the
    measurement noise itself (measured vs true test poses: the floor of any RMSE against
    measured poses; per axis, as a 3-D norm, and the distance / incidence that scale it),
    the same GP trained on noise-free poses of the same 100 configurations, of 100
    configurations drawn i.i.d. in the waypoint box, and of 4x as many of each (is the gap
    noise, the number of samples or the trajectory design?), the numerical rank of the
    ``3^6`` monomials of ``k_R`` on ``D_tr``, and the errors restricted to test poses with
    ``|beta| < 1`` (yaw and roll of eq. 2.20 are ill-conditioned near ``beta = +-pi/2``).
    ``--measurement aruco`` (parts a and c only) measures the poses from rendered images
    with ArUco detection instead of the env's noise model; identification tests each triplet
    on the frames that show both of its markers, the GP trains and tests on the frames whose
    end marker was found, and the true structure stands in if identification fails.
    ``--fk-seeds 0 1 2 3 4`` runs part (c) alone on each seed (its own markers, waypoints
    and noise) and writes ``kinematics_c_seeds.{json,md}``: per-seed RMSEs, their mean and
    range, and on how many seeds each pose element meets the goal (6 mm, 0.04 rad).
(d) **Controller** (2.6.4, Table 2.2): the GP trained on ``--ctrl-train`` samples of
    ``D_tr`` drawn at random (``--ctrl-selection``, default ``random``: with the design of
    (c) seed 0 gave no gain after the refits and a larger round-0 error on the same
    targets; the thesis uses all of ``D_tr``, and a subset keeps the run short); 5 random
    targets (configurations uniform in the joint box of the waypoints) from a fixed start;
    reference by eq. 2.24 (with backtracking), from the start and from the ``--ctrl-starts``
    data configurations nearest to the target (the lowest predicted
    ``e_p`` wins; against local minima), clipped to the joint box of the training data
    (against extrapolation); the env tracks it and the camera measures the reached pose.
    Online improvement: the frames measured while executing the references are added to
    the data with ``--ctrl-hold`` more frames measured at rest at each reached reference,
    the GP is refitted and the targets are tried again (``--online-rounds``), from the
    reference reached in the previous round and from the round-0 starts (``--ctrl-refine``).
    ``--ctrl-starts 0 --ctrl-unlimited`` is the thesis' plain controller.

Outputs (``--out-dir``, default ``results/``; ``--merge`` keeps the parts not run from an
existing ``kinematics.json``): ``kinematics.json``,
``kinematics_confusion.png``, ``kinematics_noise_vs_samples.png``,
``kinematics_controller.png`` and ``kinematics.md``.

Examples::

    python -m mcpilco.scripts.bench_kinematics                 # full (~30 min on 2 busy cores)
    python -m mcpilco.scripts.bench_kinematics --quick         # ~1-2 min smoke run
    python -m mcpilco.scripts.bench_kinematics --parts a --robots 16
    python -m mcpilco.scripts.bench_kinematics --parts cd --merge
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from mcpilco.agents.common.cli import console_main
from mcpilco.envs.marker_camera import NOISE_DEFAULTS, MarkerCameraEnv
from mcpilco.experiments.sweep import (
    Job,
    SweepError,
    SweepRunner,
    add_sweep_arguments,
    runner_from_args,
)
from mcpilco.models.gp import GPRegressor
from mcpilco.models.kinematics import (
    ChainForwardKinematicsGP,
    KinematicStructure,
    classify_all_triplets,
    identify_structure,
    random_chain,
    sum_of_sinusoids,
)
from mcpilco.models.kinematics.forward import (
    ForwardKinematicsGP,
    design_subset,
    multi_start_controller,
    nearest_data_starts,
)
from mcpilco.models.kinematics.rotations import matrix_to_ypr, wrap_angle, ypr_to_matrix

OUTLIER_THRESHOLD = 4.0
"""(c) leave-one-out score above which the trimmed FK GP drops a training sample."""

PROPS = ("Prop. 2.3.1", "Prop. 2.3.2", "Prop. 2.3.3", "Prop. 2.3.2 + 2.3.3")
POSE_NAMES = ("x", "y", "z", "gamma", "beta", "alpha")
ERR_NAMES = (*POSE_NAMES, "geodesic")
UR10_HOME = np.array([0.0, -np.pi / 2, np.pi / 2, 0.0, np.pi / 2, 0.0])
"""UR10 configuration at the centre of the sampled region (elbow up, wrist down)."""
THESIS_TABLE_2_1 = (0.0052, 0.0051, 0.0069, 0.0169, 0.0265, 0.0358)
FACING_CONE = 40.0
"""(b-d) markers are attached facing the camera at ``UR10_HOME`` within this angle [deg]
(``MarkerCameraEnv(marker_facing_cone=...)``), as one attaches them on a real robot."""
VISIBILITY_CONE = 70.0
"""(b-d) a marker turned more than this [deg] from its line of sight to the camera is not seen
(``MarkerCameraEnv(visibility_cone=...)``); the waypoints and the controller's targets are
configurations where every marker is seen. The rendered ArUco detector of
``mcpilco-bench-markers`` finds 37 % of the markers 60-70 deg off, 9 % at 70-80 deg and none
beyond (``results/marker_detection.md``; misses include occlusions)."""
REFINE_CHOICES = ("previous", "restart", "both")
"""(d) starts of the online rounds: see :func:`controller_part`."""
PART_KEYS = ("monte_carlo", "noise_vs_samples", "fk_gp", "controller")
"""Result keys of the parts a, b, c, d."""
QUICK = dict(
    robots=4, samples=600, sizes=(25, 100, 300, 600), repeats=1, ctrl_train=150, online_rounds=1
)


# ----------------------------------------------------------------------------- (a) Monte Carlo


def _confusion(truth: list[bool], pred: list[bool]) -> list[list[int]]:
    """``[[TP, FP], [FN, TN]]`` (rows: output class 1/2, columns: target class 1/2)."""
    t, p = np.array(truth), np.array(pred)
    return [
        [int((p & t).sum()), int((p & ~t).sum())],
        [int((~p & t).sum()), int((~p & ~t).sum())],
    ]


def monte_carlo(robots: int, seed: int, progress: bool) -> dict[str, Any]:
    n_joints, T = 5, 50
    truth = {k: [] for k in PROPS}
    pred = {k: [] for k in PROPS}
    recovered, per_robot = 0, []
    for i in tqdm(range(robots), desc="(a) Monte Carlo robots", disable=not progress):
        rng = np.random.default_rng([seed, 0, i])
        chain = random_chain(n_joints, rng)
        amp = np.where(np.array(list(chain.joint_types)) == "R", 3 * np.pi, 1.0)
        q = sum_of_sinusoids(np.linspace(0.0, 10.0, T), n_joints, rng, amplitude=amp)
        P = chain.marker_poses(q)
        results = classify_all_triplets(P, q, xi_t=1e-6, xi_o=1e-6, max_nfev=40)
        errors = 0
        for r in results:
            conn = r.marker_b == r.marker_a + 1 and r.joint == r.marker_a
            is_p = conn and chain.joint_types[r.joint] == "P"
            is_r = conn and chain.joint_types[r.joint] == "R"
            truth[PROPS[0]].append(is_p)
            pred[PROPS[0]].append(r.prismatic)
            for k, v in zip(
                PROPS[1:],
                (
                    r.revolute_linear,
                    r.revolute_nonlinear,
                    r.revolute_linear and r.revolute_nonlinear,
                ),
                strict=True,
            ):
                truth[k].append(is_r)
                pred[k].append(bool(v))
            expected = chain.joint_types[r.joint] if conn else None
            errors += r.joint_type != expected
        mperm, qperm = rng.permutation(n_joints + 1), rng.permutation(n_joints)
        s = identify_structure(P[:, mperm], q[:, qperm], xi_t=1e-6, xi_o=1e-6)
        ok = (
            s.complete
            and mperm[list(s.markers)].tolist() == list(range(n_joints + 1))
            and qperm[list(s.joints)].tolist() == list(range(n_joints))
            and s.joint_types == chain.joint_types
        )
        recovered += ok
        per_robot.append(dict(types=chain.joint_types, misclassified=int(errors), structure_ok=ok))
    confusion = {k: _confusion(truth[k], pred[k]) for k in PROPS}
    n_trip = len(truth[PROPS[0]])
    wrong = sum(r["misclassified"] for r in per_robot)
    return dict(
        robots=robots,
        n_joints=n_joints,
        samples=T,
        thresholds=dict(xi_t=1e-6, xi_o=1e-6),
        triplets=n_trip,
        misclassified_triplets=int(wrong),
        percent_correct=100.0 * (n_trip - wrong) / max(n_trip, 1),
        structures_recovered=int(recovered),
        confusion=confusion,
        per_robot=per_robot,
    )


# ----------------------------------------------------------------------------- UR10 data


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


def ur10_datasets(
    seed: int,
    samples: int,
    span: float = 1.0,
    noise_scale: float = 1.0,
    measurement: str = "ideal",
    facing_cone: float | None = FACING_CONE,
    visibility_cone: float | None = VISIBILITY_CONE,
) -> dict[str, Any]:
    """``D_tr`` and ``D_test``: 25 random waypoints, visited in two different orders.

    Waypoints: ``UR10_HOME + U(-span, span)`` per joint, kept only where every marker is
    seen (the "available region of the workspace" of the thesis, whose camera saw every
    marker in every frame; ``span = pi`` explores every joint fully, which 100 samples
    cannot cover). One env episode (fixed markers and permutations) holds both trajectories.
    ``noise_scale`` multiplies the env's default ``position_noise`` and ``angle_noise`` (a
    sensitivity study; 1 = the env's defaults).

    Marker protocol (``measurement="ideal"``): ``facing_cone`` attaches the markers facing the
    camera at ``UR10_HOME``; ``visibility_cone`` hides the markers turned further away (NaN
    rows) and restricts the waypoints to configurations where none is hidden (frames between
    waypoints can still hide one). Both None: the earlier protocol, markers at uniformly
    random orientations, every marker seen from any side. ``measurement="aruco"`` renders the
    frames and detects the markers instead (the env's rendered path, its own facing cone at
    the first waypoint; markers not found are NaN); the two cones are then not used.
    """
    if not noise_scale >= 0:
        raise ValueError(f"noise_scale must be >= 0, got {noise_scale}")
    ideal = measurement == "ideal"
    facing_cone = facing_cone if ideal else None
    visibility_cone = visibility_cone if ideal else None
    env = MarkerCameraEnv(
        max_increment=0.2,
        position_noise=noise_scale * NOISE_DEFAULTS["position_noise"],
        angle_noise=noise_scale * NOISE_DEFAULTS["angle_noise"],
        measurement=measurement,
        marker_facing_cone=facing_cone,
        visibility_cone=visibility_cone,
    )
    rng = np.random.default_rng([seed, 1])
    if facing_cone is None and visibility_cone is None:
        waypoints = ur10_waypoints(rng, span)
        obs, _ = env.reset(seed=seed, options={"q": waypoints[0]})
    else:  # markers attached at home, then only configurations where all are seen
        env.reset(seed=seed, options={"q": UR10_HOME})
        waypoints = ur10_waypoints(rng, span, accept=visible_configuration(env))
        obs = _drive_to(env, waypoints[0])[-1]
    tr = waypoint_trajectory(env, obs, waypoints, samples)
    order = np.concatenate([[0], 1 + rng.permutation(24)])
    obs = _drive_to(env, waypoints[0])[-1]  # back to the start (not recorded)
    te = waypoint_trajectory(env, obs, waypoints[order], samples)
    return dict(env=env, train=tr, test=te, waypoints=waypoints)


# ----------------------------------------------------------------------------- (b) noise


def noise_vs_samples(
    seed: int,
    samples: int,
    sizes: tuple[int, ...],
    repeats: int,
    progress: bool,
    span: float,
    facing_cone: float | None = FACING_CONE,
    visibility_cone: float | None = VISIBILITY_CONE,
) -> dict[str, Any]:
    """Fig. 2.6; frames where a marker is hidden count for the triplets that do not use it."""
    out = []
    for rep in range(repeats):
        data = ur10_datasets(
            seed + rep, samples, span, facing_cone=facing_cone, visibility_cone=visibility_cone
        )
        env = data["env"]
        poses, q, _ = data["train"]
        mperm, qperm = env.marker_permutation, env.joint_permutation
        for size in tqdm(sizes, desc=f"(b) sample sizes, repeat {rep}", disable=not progress):
            size = min(size, poses.shape[0])
            res = classify_all_triplets(poses[:size], q[:size], max_nfev=60, nan_policy="pairwise")
            wrong, f_lin, f_ang = 0, {True: [], False: []}, {True: [], False: []}
            for r in res:
                a, b, k = int(mperm[r.marker_a]), int(mperm[r.marker_b]), int(qperm[r.joint])
                conn = abs(a - b) == 1 and k == min(a, b)
                wrong += r.joint_type != ("R" if conn else None)
                f_lin[conn].append(r.revolute_linear_rms)
                f_ang[conn].append(r.revolute_angle_rms)
            out.append(
                dict(
                    repeat=rep,
                    samples=size,
                    triplets=len(res),
                    misclassified=int(wrong),
                    **{
                        f"{name}_{'r1' if c else 'r2'}_{stat}": float(fn(d[c]))
                        for name, d in (("linear", f_lin), ("angle", f_ang))
                        for c in (True, False)
                        for stat, fn in (("mean", np.mean), ("min", np.min), ("max", np.max))
                    },
                )
            )
    return dict(thresholds=dict(xi_t=0.02, xi_o=0.1), rows=out, samples_total=samples)


# ----------------------------------------------------------------------------- (c) FK GP


def _pose_rmse(pred: np.ndarray, true: np.ndarray) -> list[float]:
    """RMSE of ``x, y, z, gamma, beta, alpha`` (wrapped) and of the geodesic angle [rad]."""
    err = np.concatenate([pred[:, :3] - true[:, :3], wrap_angle(pred[:, 3:] - true[:, 3:])], 1)
    R_err = np.swapaxes(ypr_to_matrix(pred[:, 3:]), -1, -2) @ ypr_to_matrix(true[:, 3:])
    cos = np.clip((np.trace(R_err, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    geodesic = float(np.sqrt(np.mean(np.arccos(cos) ** 2)))
    return [*np.sqrt((err**2).mean(0)).tolist(), geodesic]


def _rbf_gp(q: np.ndarray, poses: np.ndarray, q_test: np.ndarray) -> np.ndarray:
    """RBF GP on raw ``q`` (ARD): the same 8 outputs, orientation by eq. 2.20."""
    import gpytorch

    def factory(batch):
        return gpytorch.kernels.ScaleKernel(
            gpytorch.kernels.RBFKernel(ard_num_dims=q.shape[1], batch_shape=batch),
            batch_shape=batch,
        )

    R = ypr_to_matrix(poses[:, 3:])
    Y = np.column_stack([poses[:, :3], R[:, 0, 0], R[:, 1, 0], R[:, 2, 0], R[:, 2, 1], R[:, 2, 2]])
    gp = GPRegressor(factory, noise_init=1e-3).fit(q, Y, adam_iters=100, lbfgs_iters=50)
    m, _ = gp.predict(q_test)
    m = m.numpy()
    Rhat = np.zeros((len(m), 3, 3))
    Rhat[:, 0, 0], Rhat[:, 1, 0], Rhat[:, 2, 0], Rhat[:, 2, 1], Rhat[:, 2, 2] = m[:, 3:].T
    return np.column_stack([m[:, :3], matrix_to_ypr(Rhat)])


def true_structure(env: MarkerCameraEnv) -> KinematicStructure:
    """The UR10's structure in the env's observed (shuffled) slots: what identification
    should return."""
    return KinematicStructure(
        markers=tuple(int(np.nonzero(env.marker_permutation == j)[0][0]) for j in range(7)),
        joint_types="RRRRRR",
        joints=tuple(int(np.nonzero(env.joint_permutation == j)[0][0]) for j in range(6)),
        complete=True,
    )


def identify_ur10(data: dict[str, Any]) -> dict[str, Any]:
    """Structure identification on ``D_tr``; with markers missing in some frames (rendered
    measurements) each triplet is tested on the frames that show both of its markers
    (``nan_policy="pairwise"``); a failure is returned as ``structure=None``."""
    env = data["env"]
    poses, q, _ = data["train"]
    t0 = time.perf_counter()
    try:
        s = identify_structure(poses, q, nan_policy="pairwise")
    except ValueError as exc:  # e.g. no frame shows every marker
        return dict(structure=None, correct=False, seconds=time.perf_counter() - t0,
                    error=str(exc))  # fmt: skip
    elapsed = time.perf_counter() - t0
    ok = (
        s.complete
        and env.marker_permutation[list(s.markers)].tolist() == list(range(7))
        and env.joint_permutation[list(s.joints)].tolist() == list(range(6))
    )
    return dict(structure=s, correct=bool(ok), seconds=elapsed,
                dropped_frames=int(s.n_dropped_frames))  # fmt: skip


def _feature_rank(q: np.ndarray, rtol: float = 1e-8) -> int:
    """Numerical rank of the ``3^n`` monomials spanning the RKHS of ``k_R`` (Prop. 2.5.1 (i))
    evaluated at the rows of ``q`` (all revolute): products over ``b`` of ``[1, cos q_b,
    sin q_b]``. Directions of that space outside the span are fixed by the prior alone."""
    F = np.stack([np.ones_like(q), np.cos(q), np.sin(q)], -1)
    phi = np.ones((len(q), 1))
    for b in range(q.shape[1]):
        phi = (phi[:, :, None] * F[:, b, None, :]).reshape(len(q), -1)
    s = np.linalg.svd(phi, compute_uv=False)
    return int((s > rtol * s[0]).sum())


def measurement_noise_stats(env: MarkerCameraEnv, measured: np.ndarray, q_true: np.ndarray):
    """End-marker measurement error of ``measured`` poses ``(T, 6)`` against the truth at the
    true joint positions ``q_true`` ``(T, n)`` (chain order); the camera distance ``d``, the
    incidence ``|cos theta|`` and the env's noise scale ``f`` along the data."""
    l, R = zip(*(env.marker_transforms(qq) for qq in q_true), strict=True)
    l, R = np.array(l)[:, -1], np.array(R)[:, -1]
    err = measured[:, :3] - l
    R_err = np.swapaxes(R, -1, -2) @ ypr_to_matrix(measured[:, 3:])
    ang = np.arccos(np.clip((np.trace(R_err, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0))
    d = np.linalg.norm(l, axis=1)
    cos = np.abs(R[:, 2, 2])
    f = np.array([env.noise_scale(qq)[-1] for qq in q_true])
    return dict(
        position_rmse_per_axis=np.sqrt((err**2).mean(0)).tolist(),
        position_rmse_3d=float(np.sqrt((err**2).sum(1).mean())),
        geodesic_rmse=float(np.sqrt((ang**2).mean())),
        distance_mean=float(d.mean()),
        distance_range=[float(d.min()), float(d.max())],
        abs_cos_incidence_mean=float(cos.mean()),
        scale_mean=float(f.mean()),
        scale_rms=float(np.sqrt((f**2).mean())),
        reference_position_std=env.position_noise,
        reference_angle_std=env.angle_noise,
    )


TRAIN_SELECTIONS = ("design", "random")
"""How parts (c) and (d) take their training samples from ``D_tr``: ``"design"`` (default of (c)) by
:func:`~mcpilco.models.kinematics.forward.design_subset` (greedy prior variance of ``k_l``, from
the joint signals alone), ``"random"`` uniformly at random (the thesis; default of (d))."""


def training_indices(
    q_model: np.ndarray,
    valid: np.ndarray,
    n_train: int,
    selection: str,
    rng: np.random.Generator,
    joint_types: str,
) -> np.ndarray:
    """``n_train`` rows of ``D_tr`` among the ``valid`` ones (end marker measured) to train on.

    ``q_model``: ``(N, n)`` joint signals in model order. A random draw is always taken from
    ``rng`` (the random selection, and the same random stream after it for both choices).
    """
    if selection not in TRAIN_SELECTIONS:
        raise ValueError(f"selection must be one of {TRAIN_SELECTIONS}, got {selection!r}")
    cand = np.flatnonzero(valid)
    drawn = rng.choice(cand, min(n_train, len(cand)), replace=False)
    if selection == "random":
        return drawn
    return cand[design_subset(q_model[cand], joint_types, len(drawn))]


def fk_gp_part(
    data: dict[str, Any],
    structure,
    n_train: int,
    seed: int,
    diagnostics: bool = True,
    selection: str = "design",
) -> dict[str, Any]:
    """Table 2.1 and, with ``diagnostics``, the diagnostics of the module docstring (part (c)):
    the outlier-trimmed fit, the noise-free fits, the feature rank and the ``|beta| < 1`` rows
    (without them: the polynomial, nine-element and RBF GPs and the noise floor only).
    ``selection``: one of :data:`TRAIN_SELECTIONS`."""
    poses, q, _ = data["train"]
    poses_te, q_te, q_te_true = data["test"]
    env = data["env"]
    ee, joints = structure.markers[-1], list(structure.joints)
    rng = np.random.default_rng([seed, 3])
    # frames whose end marker was measured (all of them with the noise model; rendered
    # measurements miss some)
    valid_tr = np.isfinite(poses[:, ee]).all(1)
    valid_te = np.isfinite(poses_te[:, ee]).all(1)
    idx = training_indices(q[:, joints], valid_tr, n_train, selection, rng, structure.joint_types)
    n_train = len(idx)
    X, Y = q[idx][:, joints], poses[idx, ee]
    poses_te, q_te, q_te_true = poses_te[valid_te], q_te[valid_te], q_te_true[valid_te]
    Xte, Yte = q_te[:, joints], poses_te[:, ee]
    true_te = np.array([env.marker_poses(qq)[-1] for qq in q_te_true])
    fit_kw = dict(adam_iters=50, lbfgs_iters=100)
    t0 = time.perf_counter()
    fk = ForwardKinematicsGP(structure.joint_types).fit(X, Y, **fit_kw)
    t_fit = time.perf_counter() - t0
    pred = fk.predict(Xte)
    pred9 = ForwardKinematicsGP(structure.joint_types, rotation_outputs="nine").fit(X, Y, **fit_kw)
    pred9 = pred9.predict(Xte)
    pred_rbf = _rbf_gp(X, Y, Xte)
    try:  # rendered measurements can leave a link with too few frames showing both markers
        chain = ChainForwardKinematicsGP(structure.joint_types).fit(
            X, poses[idx][:, list(structure.markers)]
        )
    except ValueError as err:
        chain, chain_result = None, dict(chain_error=str(err))
    else:
        pred_chain = chain.predict(Xte)
        chain_result = dict(
            chain_rmse_measured=_pose_rmse(pred_chain, Yte),
            chain_rmse_true=_pose_rmse(pred_chain, true_te),
            chain_frames_used=chain.frames_used_,
        )
    result = dict(
        n_train=n_train,
        train_selection=selection,
        n_test=len(Xte),
        end_marker_measured=dict(
            train=int(valid_tr.sum()),
            test=int(valid_te.sum()),
            train_frames=len(valid_tr),
            test_frames=len(valid_te),
        ),  # fmt: skip
        fit_seconds=t_fit,
        polynomial_rmse_measured=_pose_rmse(pred, Yte),
        polynomial_rmse_true=_pose_rmse(pred, true_te),
        nine_elements_rmse_measured=_pose_rmse(pred9, Yte),
        nine_elements_rmse_true=_pose_rmse(pred9, true_te),
        rbf_rmse_measured=_pose_rmse(pred_rbf, Yte),
        rbf_rmse_true=_pose_rmse(pred_rbf, true_te),
        **chain_result,
        measurement_noise_rmse=_pose_rmse(Yte, true_te),
        measurement_noise=measurement_noise_stats(env, Yte, q_te_true),
    )
    if not diagnostics:
        return result
    trimmed = ForwardKinematicsGP(structure.joint_types).fit(
        X, Y, outlier_threshold=OUTLIER_THRESHOLD, **fit_kw
    )
    pred_trim = trimmed.predict(Xte)
    # diagnostics with noise-free q and poses (chain order = model order when the structure
    # is right): is the gap noise, the number of samples, or the trajectory design?
    _, _, q_tr_true = data["train"]
    chain_of_model = env.joint_permutation[joints]
    q_te_model = q_te_true[:, chain_of_model]

    def noise_free(q_chain: np.ndarray) -> list[float]:
        Y_clean = np.array([env.marker_poses(qq)[-1] for qq in q_chain])
        m = ForwardKinematicsGP(structure.joint_types).fit(
            q_chain[:, chain_of_model], Y_clean, **fit_kw
        )
        return _pose_rmse(m.predict(q_te_model), true_te)

    idx_big = rng.choice(len(q), min(4 * n_train, len(q)), replace=False)
    box = data["waypoints"].min(0), data["waypoints"].max(0)
    noise_free_rows = {
        f"{n_train} samples of D_tr": noise_free(q_tr_true[idx]),
        f"{n_train} i.i.d. uniform in the waypoint box": noise_free(
            rng.uniform(*box, (n_train, 6))
        ),
        f"{len(idx_big)} samples of D_tr": noise_free(q_tr_true[idx_big]),
        f"{len(idx_big)} i.i.d. uniform in the waypoint box": noise_free(
            rng.uniform(*box, (len(idx_big), 6))
        ),
    }
    small_beta = np.abs(true_te[:, 4]) < 1.0  # away from the yaw-pitch-roll singularity
    all_revolute = set(structure.joint_types) == {"R"}
    result.update(
        trimmed_rmse_measured=_pose_rmse(pred_trim, Yte),
        trimmed_rmse_true=_pose_rmse(pred_trim, true_te),
        trimmed_outliers=int(len(trimmed.outliers_)),
        trimmed_threshold=OUTLIER_THRESHOLD,
        polynomial_noiseless_training_rmse_true=noise_free_rows[f"{n_train} samples of D_tr"],
        noise_free_training_rmse_true=noise_free_rows,
        feature_rank=dict(
            D_tr=_feature_rank(q_tr_true) if all_revolute else None,
            iid_same_size=_feature_rank(rng.uniform(*box, (len(q_tr_true), 6)))
            if all_revolute
            else None,
            monomials=3 ** len(structure.joint_types),
        ),
        small_beta_test_samples=int(small_beta.sum()),
        polynomial_rmse_true_small_beta=_pose_rmse(pred[small_beta], true_te[small_beta]),
        nine_elements_rmse_true_small_beta=_pose_rmse(pred9[small_beta], true_te[small_beta]),
        measurement_noise_rmse_small_beta=_pose_rmse(Yte[small_beta], true_te[small_beta]),
    )
    return result


FK_GOAL = (0.006, 0.04)
"""Issue goal of part (c): RMSE <= 6 mm on x, y, z and <= 0.04 rad on each angle."""

FK_MODELS = ("end", "chain")
"""FK models of part (d): the thesis' GP on the end marker, or the chain of one-joint GPs."""

GOAL_MODELS = ("polynomial", "nine_elements", "chain")
"""Models of the seed study checked against :data:`FK_GOAL`."""

SEED_STUDY_KEYS = ("polynomial", "polynomial_true", "nine_elements", "chain", "chain_true", "rbf",
                   "noise")  # fmt: skip
"""Per-seed RMSE rows of the seed study that get a mean / min / max summary."""


def fk_seed_row(
    seed: int,
    samples: int,
    span: float,
    noise_scale: float,
    n_train: int,
    facing_cone: float | None,
    visibility_cone: float | None,
    selection: str = "design",
) -> dict[str, Any]:
    """Part (c) on one seed (its own markers, permutations, waypoints and noise): the RMSEs
    of each model against the measured poses. A sweep job of :func:`fk_seed_study`."""
    data = ur10_datasets(
        seed, samples, span, noise_scale, facing_cone=facing_cone,
        visibility_cone=visibility_cone,
    )  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        idn = identify_ur10(data)
    structure = idn["structure"] if idn["correct"] else true_structure(data["env"])
    fk = fk_gp_part(data, structure, n_train, seed, diagnostics=False, selection=selection)
    if "chain_error" in fk:
        raise RuntimeError(f"seed {seed}: the chain model was not fitted: {fk['chain_error']}")
    return dict(
        seed=seed,
        identified=bool(idn["correct"]),
        polynomial=fk["polynomial_rmse_measured"],
        polynomial_true=fk["polynomial_rmse_true"],
        nine_elements=fk["nine_elements_rmse_measured"],
        rbf=fk["rbf_rmse_measured"],
        chain=fk["chain_rmse_measured"],
        chain_true=fk["chain_rmse_true"],
        noise=fk["measurement_noise_rmse"],
    )


def fk_seed_study(
    seeds: list[int],
    samples: int,
    span: float,
    noise_scale: float,
    n_train: int,
    facing_cone: float | None,
    visibility_cone: float | None,
    progress: bool,
    selection: str = "design",
    runner: SweepRunner | None = None,
    runs_dir: str | Path = "runs/bench_kinematics",
) -> dict[str, Any]:
    """Part (c) on several seeds (:func:`fk_seed_row`, sweep jobs of ``runner``, default in
    this process, kept in ``runs_dir/c_seeds``): per-seed RMSEs against the measured poses,
    their mean and range, and on how many seeds each axis meets :data:`FK_GOAL`.

    Raises:
        RuntimeError: when a seed failed (its traceback is in ``runs_dir/c_seeds``).
    """
    runner = runner if runner is not None else SweepRunner(progress=progress)
    settings = dict(
        samples=samples, span=span, noise_scale=noise_scale, n_train=n_train,
        facing_cone=facing_cone, visibility_cone=visibility_cone, selection=selection,
    )  # fmt: skip
    jobs = [Job(f"seed{seed}", fk_seed_row, {"seed": seed, **settings}) for seed in seeds]
    sweep = runner.run(jobs, Path(runs_dir) / "c_seeds", desc="(c) seeds")
    if sweep.failed:
        raise RuntimeError(sweep.summary())
    rows = list(sweep.results.values())
    summary = {}
    for key in SEED_STUDY_KEYS:
        table = np.array([r[key] for r in rows])
        summary[key] = dict(
            mean=table.mean(0).tolist(), min=table.min(0).tolist(), max=table.max(0).tolist()
        )
    limits = np.array([FK_GOAL[0]] * 3 + [FK_GOAL[1]] * 3)
    met = {
        key: (np.array([r[key][:6] for r in rows]) <= limits).sum(0).tolist() for key in GOAL_MODELS
    }
    all_met = {
        key: int((np.array([r[key][:6] for r in rows]) <= limits).all(1).sum())
        for key in GOAL_MODELS
    }
    return dict(
        seeds=list(seeds),
        n_train=n_train,
        train_selection=selection,
        marker_protocol=dict(facing_cone=facing_cone, visibility_cone=visibility_cone),
        rows=rows,
        summary=summary,
        goal=dict(position=FK_GOAL[0], angle=FK_GOAL[1], met_per_axis=met, met_all=all_met),
    )


def fk_seed_markdown(study: dict[str, Any], command: str) -> str:
    """Markdown table of :func:`fk_seed_study`."""

    def mm(v: list[float]) -> str:  # x, y, z cells in mm
        return " | ".join(f"{1e3 * x:.1f}" for x in v[:3])

    def rad(v: list[float]) -> str:  # gamma, beta, alpha cells in rad
        return " | ".join(f"{x:.3f}" for x in v[3:6])

    lines = [
        f"# FK GP over {len(study['seeds'])} seeds (part (c), thesis Table 2.1)",
        "",
        f"Command: `{command}`",
        "",
        *_protocol_line(study),
        f"{study['n_train']} training samples of D_tr per seed "
        f"({_selection_text(study)}), tested on D_test. RMSE "
        "against the measured poses: x, y, z in mm, gamma, beta, alpha in rad. Nine: the GP "
        "on all nine rotation elements projected onto SO(3) (same positions). Chain (beyond "
        "the thesis): one-joint GPs on the relative poses of consecutive markers of the "
        "identified chain, composed (`ChainForwardKinematicsGP`; the same frames, every "
        "marker in them).",
        "",
        "| seed | identified | x | y | z | gamma | beta | alpha | nine: gamma | beta | alpha "
        "| chain: x | y | z | gamma | beta | alpha | RBF x | y | z | noise x | y | z |",
        "|---|---|" + "---:|" * 21,
    ]
    rows = [(str(r["seed"]), "yes" if r["identified"] else "no", r) for r in study["rows"]]
    summ = study["summary"]
    for label, pick in (("mean", "mean"), ("min", "min"), ("max", "max")):
        rows.append(
            (
                label,
                "",
                {
                    k: summ[k][pick]
                    for k in ("polynomial", "nine_elements", "chain", "rbf", "noise")
                },
            )  # fmt: skip
        )
    for seed, ident, r in rows:
        lines.append(
            f"| {seed} | {ident} | {mm(r['polynomial'])} | {rad(r['polynomial'])} | "
            f"{rad(r['nine_elements'])} | {mm(r['chain'])} | {rad(r['chain'])} | "
            f"{mm(r['rbf'])} | {mm(r['noise'])} |"
        )
    g = study["goal"]
    n = len(study["seeds"])

    def per(key: str) -> str:  # seeds meeting the goal, per pose element
        met = g["met_per_axis"][key]
        return ", ".join(f"{name} {c}/{n}" for name, c in zip(POSE_NAMES, met, strict=True))

    lines += [
        "",
        f"Goal (<= {1e3 * g['position']:.0f} mm on x, y, z and <= {g['angle']} rad on each "
        f"angle), seeds meeting it: five elements {per('polynomial')}; all six on "
        f"{g['met_all']['polynomial']}/{n}. Nine elements {per('nine_elements')}; all six on "
        f"{g['met_all']['nine_elements']}/{n}. Chain {per('chain')}; all six on "
        f"{g['met_all']['chain']}/{n}.",
        "",
    ]

    def against_truth(key: str) -> str:  # mean and range over the seeds, x / y / z in mm
        t = summ[key]
        return (
            "mean "
            + " / ".join(f"{1e3 * x:.1f}" for x in t["mean"][:3])
            + " mm, range "
            + " / ".join(
                f"{1e3 * a:.1f}-{1e3 * b:.1f}"
                for a, b in zip(t["min"][:3], t["max"][:3], strict=True)
            )
            + " mm"
        )

    lines += [
        f"Against the truth: five elements {against_truth('polynomial_true')}; chain "
        f"{against_truth('chain_true')}.",
    ]
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------- (d) controller


def _drive_to(env: MarkerCameraEnv, q_goal: np.ndarray, max_steps: int = 200) -> list[np.ndarray]:
    """Track a reference to ``q_goal`` (chain order) with increments; returns the observations."""
    rows = []
    for _ in range(max_steps):
        step = np.clip((q_goal - env.q) / env.max_increment, -1, 1)
        obs, *_ = env.step(step[env.joint_permutation].astype(np.float32))
        rows.append(obs)
        if np.abs(env.q - q_goal).max() < 1e-9:
            break
    return rows


def controller_part(
    data: dict[str, Any],
    structure,
    n_train: int,
    rounds: int,
    seed: int,
    progress: bool,
    steps: int = 300,
    span: float = 1.0,
    starts: int = 4,
    limit_to_data: bool = True,
    orientation: str = "ypr",
    refine: str = "both",
    rotation_outputs: str = "five",
    hold: int = 5,
    selection: str = "random",
    fk_model: str = "end",
) -> dict[str, Any]:
    """Table 2.2: reach 5 random targets with eq. 2.24, then refit with the executed frames.

    ``starts`` > 0 adds that many data configurations nearest to the target to the start
    ``q(0)`` (:func:`multi_start_controller`); ``limit_to_data`` clips ``q_des`` to the joint
    box of the GP's training data. ``starts=0, limit_to_data=False`` is the thesis' plain
    controller; ``orientation`` is the orientation error of
    :func:`~mcpilco.models.kinematics.forward.pose_error` (``"ypr"``: the thesis). The target
    configurations are uniform in the joint box of the waypoints (the region the robot
    explored while collecting ``D_tr``: the "workspace" of the thesis' targets). Errors of the
    reached poses are reported as measured by the camera (as in the thesis) and against the
    true (noise-free) poses.

    ``refine`` sets the starts of the online rounds (``rnd >= 1``): ``"previous"`` runs
    eq. 2.24 once more from the reference reached in the previous round for the same target
    (the refitted GP now holds the frames measured around it, so the update corrects the
    remaining local model error); ``"restart"`` repeats the round-0 multi-start search;
    ``"both"`` puts the previous reference first among the round-0 starts (the lowest
    predicted ``e_p`` wins, ties go to the previous reference).
    ``rotation_outputs`` is that of :class:`ForwardKinematicsGP`. ``hold`` more frames are
    measured while the robot rests at each reached reference (they join the data; the
    reported reached pose is the single frame at arrival). ``selection`` picks the
    ``n_train`` initial samples (:data:`TRAIN_SELECTIONS`). ``fk_model``: ``"end"`` (the
    thesis' GP on the end marker) or ``"chain"`` (:class:`ChainForwardKinematicsGP` on every
    marker of the same frames); either way a frame joins the data when it shows the end
    marker.
    """
    if fk_model not in FK_MODELS:
        raise ValueError(f"fk_model must be one of {FK_MODELS}, got {fk_model!r}")
    if hold < 0:
        raise ValueError(f"hold must be >= 0, got {hold}")
    if refine not in REFINE_CHOICES:
        raise ValueError(f"refine must be one of {REFINE_CHOICES}, got {refine!r}")
    env = data["env"]
    poses, q, _ = data["train"]
    ee, joints = structure.markers[-1], list(structure.joints)
    rng = np.random.default_rng([seed, 4])
    valid = np.isfinite(poses[:, ee]).all(1)
    idx = training_indices(q[:, joints], valid, n_train, selection, rng, structure.joint_types)
    markers = list(structure.markers)
    X, Y = q[idx][:, joints], poses[idx][:, markers]  # every marker, chain order
    q_start = data["waypoints"][0]
    wp = data["waypoints"]
    lo, hi = wp.min(0), wp.max(0)
    accept = visible_configuration(env)
    q_targets = (
        rng.uniform(lo, hi, (5, wp.shape[1]))
        if accept is None
        else draw_accepted(lambda: rng.uniform(lo, hi), 5, accept, 5000, "targets")
    )
    targets = np.array([env.marker_poses(qt)[-1] for qt in q_targets])
    # model joint k is observed slot S_q[k], i.e. chain joint joint_permutation[S_q[k]]
    chain_of_model = env.joint_permutation[joints]
    n = env.n_joints
    if fk_model == "chain":
        fk = ChainForwardKinematicsGP(structure.joint_types)
    else:
        fk = ForwardKinematicsGP(structure.joint_types, rotation_outputs=rotation_outputs)
    rows = []
    previous: list[np.ndarray] = []
    for rnd in range(rounds + 1):
        if fk_model == "chain":
            fk.fit(X, Y)
        else:
            fk.fit(X, Y[:, -1], adam_iters=50, lbfgs_iters=100)
        pred = fk.predictor()
        limits = np.column_stack([X.min(0), X.max(0)]) if limit_to_data else None
        reached, reached_true, predicted, chosen, new_X, new_Y = [], [], [], [], [], []
        for k in tqdm(range(5), desc=f"(d) controller round {rnd}", disable=not progress):
            _drive_to(env, q_start)
            q0 = env.q[chain_of_model]
            q_starts = [q0]
            if starts > 0:
                q_starts += list(
                    nearest_data_starts(X, Y[:, -1], targets[k], starts, 0.1, orientation)
                )
            if rnd > 0 and refine == "previous":
                q_starts = [previous[k]]
            elif rnd > 0 and refine == "both":
                q_starts = [previous[k], *q_starts]
            res, s = multi_start_controller(
                pred, q_starts, targets[k], nu=0.5, steps=steps, q_limits=limits,
                orientation=orientation,
            )  # fmt: skip
            predicted.append(float(res.predicted_error[-1]))
            chosen.append(s - 1 if rnd > 0 and refine != "restart" else s)
            obs_rows = []
            for q_model in (res.q[0], res.q_final):  # via the chosen start, then q_des
                q_goal = env.q.copy()
                q_goal[chain_of_model] = q_model
                obs_rows += _drive_to(env, np.clip(q_goal, env.q_low, env.q_high))
            arrival = obs_rows[-1][: 6 * (n + 1)].reshape(n + 1, 6)[ee]
            for _ in range(hold):  # the robot rests at q_des while the camera keeps measuring
                obs_rows.append(env.step(np.zeros(n, dtype=np.float32))[0])
            for o in obs_rows:
                y = o[: 6 * (n + 1)].reshape(n + 1, 6)[markers]
                if np.isfinite(y[-1]).all():  # frames that show the end marker join the data
                    new_X.append(o[6 * (n + 1) : 6 * (n + 1) + n][joints])
                    new_Y.append(y)
            reached.append(arrival)
            reached_true.append(env.marker_poses(env.q)[-1])
            if rnd == 0:
                previous.append(res.q_final.copy())
            else:
                previous[k] = res.q_final.copy()
        reached, reached_true = np.array(reached), np.array(reached_true)
        seen = np.isfinite(reached).all(1)  # arrivals whose end marker the camera saw
        rows.append(
            dict(
                round=rnd,
                n_data=len(X),
                arrivals_seen=int(seen.sum()),
                rmse=_pose_rmse(reached[seen], targets[seen]) if seen.any() else None,
                rmse_true=_pose_rmse(reached_true, targets),
                position_error_norm=[  # None: the camera did not see the end marker
                    float(v) if np.isfinite(v) else None
                    for v in np.linalg.norm(reached[:, :3] - targets[:, :3], axis=1)
                ],
                position_error_norm_true=np.linalg.norm(
                    reached_true[:, :3] - targets[:, :3], axis=1
                ).tolist(),
                predicted_error=predicted,
                chosen_start=chosen,
            )
        )
        X = np.concatenate([X, np.array(new_X)])
        Y = np.concatenate([Y, np.array(new_Y)])
    return dict(
        n_train=len(idx),
        train_selection=selection,
        starts=starts,
        limit_to_data=limit_to_data,
        orientation=orientation,
        refine=refine,
        rotation_outputs=rotation_outputs,
        hold=hold,
        fk_model=fk_model,
        targets=targets.tolist(),
        rounds=rows,
    )


# ----------------------------------------------------------------------------- outputs


def _plots(res: dict[str, Any], out: Path) -> dict[str, str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = {}
    if "monte_carlo" in res:
        fig, axes = plt.subplots(1, 4, figsize=(14, 4.0))
        for ax, name in zip(axes, PROPS, strict=True):
            cm = np.array(res["monte_carlo"]["confusion"][name])
            ax.imshow(cm, cmap="Blues")
            for (i, j), v in np.ndenumerate(cm):
                ax.text(j, i, str(v), ha="center", va="center", fontsize=12)
            ax.set_xticks([0, 1], ["1", "2"])
            ax.set_yticks([0, 1], ["1", "2"])
            ax.set_xlabel("target class")
            ax.set_ylabel("output class")
            ax.set_title(f"Eq. {name}")
        fig.suptitle(f"Monte Carlo, {res['monte_carlo']['robots']} robots (thesis Fig. 2.4)")
        fig.tight_layout()
        paths["confusion"] = str(out / "kinematics_confusion.png")
        fig.savefig(paths["confusion"], dpi=100)
        plt.close(fig)
    if "noise_vs_samples" in res:
        rows = res["noise_vs_samples"]["rows"]
        fig, axes = plt.subplots(1, 3, figsize=(14, 3.6))
        for rep in sorted({r["repeat"] for r in rows}):
            rr = [r for r in rows if r["repeat"] == rep]
            s = [r["samples"] for r in rr]
            axes[0].plot(s, [r["misclassified"] for r in rr], "o-", label=f"repeat {rep}")
            for ax, name, xi in ((axes[1], "linear", 0.02), (axes[2], "angle", 0.1)):
                for c, color in (("r1", "tab:green"), ("r2", "tab:red")):
                    ax.plot(s, [r[f"{name}_{c}_mean"] for r in rr], "-", color=color)
                    ax.fill_between(
                        s,
                        [r[f"{name}_{c}_min"] for r in rr],
                        [r[f"{name}_{c}_max"] for r in rr],
                        color=color,
                        alpha=0.15,
                    )
                ax.axhline(xi, color="k", ls="--", lw=1)
        axes[0].set_ylabel("misclassified triplets")
        axes[1].set_ylabel("f_r linear revolute test (2.18) [m]")
        axes[2].set_ylabel("f_r non-linear test (2.19) [rad]")
        axes[1].set_yscale("log")
        axes[2].set_yscale("log")
        for ax in axes:
            ax.set_xlabel("samples")
        axes[0].legend()
        fig.suptitle("UR10 with noise: green f_r1 (connected), red f_r2 (not) (thesis Fig. 2.6)")
        fig.tight_layout()
        paths["noise"] = str(out / "kinematics_noise_vs_samples.png")
        fig.savefig(paths["noise"], dpi=100)
        plt.close(fig)
    if "controller" in res:
        rows = res["controller"]["rounds"]
        fig, ax = plt.subplots(figsize=(6, 3.6))
        for r in rows:
            ax.semilogy(range(1, 6), r["position_error_norm"], "o-", label=f"round {r['round']}")
        ax.set_xlabel("target")
        ax.set_ylabel("reached position error [m]")
        ax.legend()
        ax.set_title("Gradient kinematic controller (thesis Table 2.2)")
        fig.tight_layout()
        paths["controller"] = str(out / "kinematics_controller.png")
        fig.savefig(paths["controller"], dpi=100)
        plt.close(fig)
    return paths


def _fmt(values, digits=4) -> str:
    return " | ".join(f"{v:.{digits}f}" for v in values)


def _part_command(res: dict[str, Any], part: dict[str, Any]) -> list[str]:
    """``Command: ...`` line for a part produced by another run (``--merge``)."""
    cmd = part.get("command")
    return [f"Command: `{cmd}`", ""] if cmd and cmd != res["command"] else []


def _markdown(res: dict[str, Any]) -> str:
    lines = [
        "# Kinematics learning benchmark (thesis chapter 2)",
        "",
        f"Command: `{res['command']}`",
        "",
    ]
    if "monte_carlo" in res:
        mc = res["monte_carlo"]
        lines += [
            "## (a) Monte Carlo, noiseless (section 2.6.1)",
            "",
            *_part_command(res, mc),
            f"{mc['robots']} robots x {mc['triplets'] // max(mc['robots'], 1)} triplets, "
            f"T = {mc['samples']}: **{mc['percent_correct']:.2f}% of {mc['triplets']} triplets "
            f"correct** ({mc['misclassified_triplets']} misclassified); structure recovered "
            f"from shuffled data on {mc['structures_recovered']} / {mc['robots']} robots.",
            "",
            "| test | TP | FP | FN | TN |",
            "|---|---|---|---|---|",
        ]
        for k in PROPS:
            (tp, fp), (fn, tn) = mc["confusion"][k]
            lines.append(f"| Eq. {k} | {tp} | {fp} | {fn} | {tn} |")
        lines.append("")
    if "noise_vs_samples" in res:
        lines += [
            "## (b) UR10 with noise: misclassified triplets vs samples (Fig. 2.6)",
            "",
            *_part_command(res, res["noise_vs_samples"]),
            *_protocol_line(res["noise_vs_samples"]),
            "| repeat | samples | misclassified / triplets | f_r1 lin (mean) | f_r2 lin (min) "
            "| f_r1 ang (mean) | f_r2 ang (min) |",
            "|---|---|---|---|---|---|---|",
        ]
        for r in res["noise_vs_samples"]["rows"]:
            lines.append(
                f"| {r['repeat']} | {r['samples']} | {r['misclassified']} / {r['triplets']} | "
                f"{r['linear_r1_mean']:.4f} | {r['linear_r2_min']:.4f} | "
                f"{r['angle_r1_mean']:.4f} | {r['angle_r2_min']:.4f} |"
            )
        lines.append("")
    if "identification" in res:
        idn = res["identification"]
        lines += [
            "## UR10 structure identified on D_tr",
            "",
            f"{idn['samples']} samples: correct = **{idn['correct']}**, types "
            f"`{idn['joint_types']}`, {idn['seconds']:.1f} s."
            + (f" Frames dropped for a missing marker: {idn['dropped_frames']}."
               if idn.get("dropped_frames") else "")
            + (f" Error: {idn['error']}" if idn.get("error") else "")
            + (f" Note: {idn['note']}." if idn.get("note") else ""),
            "",
        ]  # fmt: skip
    if "fk_gp" in res:
        fk = res["fk_gp"]
        head = " | ".join(ERR_NAMES)
        lines += [
            f"## (c) FK GP, {fk['n_train']} training samples, {fk['n_test']} test samples "
            "(Table 2.1)",
            "",
            f"Training samples {_selection_text(fk)}.",
            "",
            *_part_command(res, fk),
            *(_protocol_line(fk) if res.get("measurement", "ideal") == "ideal" else []),
            *(
                [
                    f"Measurement: **{res['measurement']}** (rendered images + ArUco "
                    "detection). End marker found in "
                    f"{fk['end_marker_measured']['train']} of "
                    f"{fk['end_marker_measured']['train_frames']} D_tr frames and "
                    f"{fk['end_marker_measured']['test']} of "
                    f"{fk['end_marker_measured']['test_frames']} D_test frames; training "
                    "samples and test samples are drawn from those.",
                    "",
                ]
                if res.get("measurement", "ideal") != "ideal"
                else []
            ),
            f"| model | {head} |",
            "|---|" + "---|" * 7,
            f"| thesis Table 2.1 (real UR10) | {_fmt(THESIS_TABLE_2_1)} | - |",
            f"| polynomial k_R/k_l vs measured | {_fmt(fk['polynomial_rmse_measured'])} |",
            f"| polynomial k_R/k_l vs true | {_fmt(fk['polynomial_rmse_true'])} |",
        ]
        if "trimmed_rmse_true" in fk:
            lines += [
                f"| polynomial, outlier-trimmed (LOO score > {fk['trimmed_threshold']:g}, "
                f"{fk['trimmed_outliers']} of {fk['n_train']} dropped), vs measured | "
                f"{_fmt(fk['trimmed_rmse_measured'])} |",
                f"| polynomial, outlier-trimmed, vs true | {_fmt(fk['trimmed_rmse_true'])} |",
            ]
        if "nine_elements_rmse_true" in fk:
            lines += [
                "| polynomial, nine elements + SO(3) projection, vs measured | "
                f"{_fmt(fk['nine_elements_rmse_measured'])} |",
                "| polynomial, nine elements + SO(3) projection, vs true | "
                f"{_fmt(fk['nine_elements_rmse_true'])} |",
            ]
        if "chain_rmse_true" in fk:
            lines += [
                "| chain of one-joint GPs (every marker of the same frames), vs measured | "
                f"{_fmt(fk['chain_rmse_measured'])} |",
                f"| chain of one-joint GPs, vs true | {_fmt(fk['chain_rmse_true'])} |",
            ]
        elif "chain_error" in fk:
            cells = " - |" * 7
            lines.append(f"| chain of one-joint GPs: not fitted ({fk['chain_error']}) |{cells}")
        lines += [
            f"| RBF on raw q vs measured | {_fmt(fk['rbf_rmse_measured'])} |",
            f"| RBF on raw q vs true | {_fmt(fk['rbf_rmse_true'])} |",
            f"| measurement noise (measured vs true) | {_fmt(fk['measurement_noise_rmse'])} |",
        ]
        rows = fk.get("noise_free_training_rmse_true") or {
            f"{fk['n_train']} samples of D_tr": fk["polynomial_noiseless_training_rmse_true"]
        }
        for name, v in rows.items():
            lines.append(f"| polynomial, noise-free training: {name}, vs true | {_fmt(v)} |")
        lines += [
            f"| polynomial vs true, {fk['small_beta_test_samples']} test samples with "
            f"abs(beta) < 1 | {_fmt(fk['polynomial_rmse_true_small_beta'])} |",
        ]
        if "nine_elements_rmse_true_small_beta" in fk:
            lines.append(
                "| nine elements vs true, same samples | "
                f"{_fmt(fk['nine_elements_rmse_true_small_beta'])} |"
            )
        lines += [
            "| measurement noise, same samples | "
            f"{_fmt(fk['measurement_noise_rmse_small_beta'])} |",
            "",
            "Units: m for x, y, z; rad for gamma, beta, alpha and the geodesic angle "
            "between the predicted and the reference orientation.",
            "",
        ]
        if "measurement_noise" in fk:
            mn = fk["measurement_noise"]
            lines += [
                f"End-marker measurement noise on D_test: {_fmt(mn['position_rmse_per_axis'])} m "
                f"per axis, {mn['position_rmse_3d']:.4f} m as a 3-D norm, "
                f"{mn['geodesic_rmse']:.4f} rad geodesic (RMS). The marker is "
                f"{mn['distance_mean']:.2f} m from the camera on average "
                f"({mn['distance_range'][0]:.2f}-{mn['distance_range'][1]:.2f} m), mean "
                f"abs(cos theta) = {mn['abs_cos_incidence_mean']:.2f}: noise scale "
                f"f = {mn['scale_mean']:.2f} on average (1 = {mn['reference_position_std']:.4g} m "
                f"per axis and {mn['reference_angle_std']:.4g} rad per rotation-vector component "
                "at 2 m, face-on).",
                "",
            ]
        if fk.get("feature_rank", {}).get("D_tr") is not None:
            r = fk["feature_rank"]
            lines += [
                f"Numerical rank (1e-8) of the {r['monomials']} monomials of k_R on D_tr: "
                f"{r['D_tr']}; on as many i.i.d. configurations in the waypoint box: "
                f"{r['iid_same_size']}.",
                "",
            ]
    if "controller" in res:
        c = res["controller"]
        lines += [
            f"## (d) Controller, 5 targets, GP on {c['n_train']} samples of D_tr (Table 2.2)",
            "",
            f"Training samples {_selection_text(c)}.",
            "",
            *_part_command(res, c),
            *_protocol_line(c),
            f"Extra starts: {c.get('starts', 0)} nearest data configurations; q_des clipped to "
            f"the data's joint box: {c.get('limit_to_data', False)}; orientation error in e_p: "
            f"{c.get('orientation', 'ypr')}; rotation outputs: "
            f"{c.get('rotation_outputs', 'five')}; FK model: {c.get('fk_model', 'end')}; "
            "online rounds start from: "
            f"{c.get('refine', 'restart')}; frames measured at rest after each reference: "
            f"{c.get('hold', 0)}. RMSE of the reached pose (one frame at arrival) "
            "as measured by the camera (as in the thesis) and against the true pose.",
            "",
            f"| data | {' | '.join(ERR_NAMES)} |",
            "|---|" + "---|" * 7,
            "| thesis D_tr | 0.0065 | 0.0111 | 0.0228 | 0.1853 | 0.0853 | 0.1167 | - |",
            "| thesis D̄_tr | 0.0017 | 0.0016 | 0.0020 | 0.0988 | 0.0269 | 0.0419 | - |",
        ]
        for r in c["rounds"]:
            seen = r.get("arrivals_seen", 5)
            label = "measured" if seen == 5 else f"measured ({seen} of 5 arrivals seen)"
            lines.append(
                f"| round {r['round']} ({r['n_data']} samples), {label} | "
                + ("- | " * 7 if r["rmse"] is None else f"{_fmt(r['rmse'])} |")
            )
            if "rmse_true" in r:
                lines.append(f"| round {r['round']}, true | {_fmt(r['rmse_true'])} |")
        lines.append("")
        if c["rounds"] and "predicted_error" in c["rounds"][0]:
            lines += ["| round | predicted e_p per target | true position error [m] | start |",
                      "|---|---|---|---|"]  # fmt: skip
            for r in c["rounds"]:
                lines.append(
                    f"| {r['round']} | {', '.join(f'{v:.4f}' for v in r['predicted_error'])} | "
                    f"{', '.join(f'{v:.4f}' for v in r['position_error_norm_true'])} | "
                    f"{', '.join('prev' if v < 0 else str(v) for v in r['chosen_start'])} |"
                )
            lines.append("")
    lines.append(f"Total time: {res['seconds']:.0f} s.")
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------- main


def _optional_degrees(text: str) -> float | None:
    """``"none"`` -> None, else a float angle in (0, 180] deg (argparse type)."""
    if text.lower() == "none":
        return None
    value = float(text)
    if not 0 < value <= 180:
        raise argparse.ArgumentTypeError(f"an angle in (0, 180] deg or 'none', got {text}")
    return value


def _selection_text(part: dict[str, Any]) -> str:
    """How a part's training samples were taken from ``D_tr`` (results before the option
    existed were random)."""
    if part.get("train_selection", "random") == "random":
        return "drawn at random, as in the thesis"
    return "picked by the greedy design on the prior variance of k_l"


def _protocol_line(part: dict[str, Any]) -> list[str]:
    """The marker protocol a part (b-d) ran with, as a Markdown line."""
    mp = part.get("marker_protocol")
    if mp is None:  # parts computed before the protocol was recorded
        return ["Markers: uniformly random orientations, every marker seen from any side.", ""]
    face, vis = mp["facing_cone"], mp["visibility_cone"]
    text = (
        "uniformly random orientations"
        if face is None
        else f"attached facing the camera at home (within {face:g} deg)"
    )
    text += (
        ", every marker seen from any side"
        if vis is None
        else f"; a marker turned more than {vis:g} deg from the camera is not seen, and the "
        "waypoints (and targets) show every marker"
    )
    return [f"Markers: {text}.", ""]


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--parts", default="abcd", help="subset of 'abcd' to run")
    p.add_argument("--robots", type=int, default=64, help="(a) Monte Carlo robots")
    p.add_argument("--samples", type=int, default=2100, help="(b-d) frames per UR10 trajectory")
    p.add_argument(
        "--sizes", type=int, nargs="+", default=[25, 50, 100, 200, 400, 800, 1300, 2100],
        help="(b) prefixes of the trajectory",
    )  # fmt: skip
    p.add_argument("--repeats", type=int, default=1, help="(b) trajectories")
    p.add_argument("--fk-train", type=int, default=100, help="(c) training samples")
    p.add_argument("--ctrl-train", type=int, default=300, help="(d) training samples")
    p.add_argument(
        "--train-selection", choices=TRAIN_SELECTIONS, default="design",
        help="(c) training samples of D_tr: greedy design by the prior variance of k_l "
        "(default) or uniformly at random (thesis)",
    )  # fmt: skip
    p.add_argument(
        "--ctrl-selection", choices=TRAIN_SELECTIONS, default="random",
        help="(d) initial training samples of D_tr, as --train-selection (default random)",
    )  # fmt: skip
    p.add_argument(
        "--ctrl-model", choices=FK_MODELS, default="end",
        help="(d) FK model: the thesis' GP on the end marker (default) or the chain of "
        "one-joint GPs on every marker (ChainForwardKinematicsGP)",
    )  # fmt: skip
    p.add_argument("--online-rounds", type=int, default=3, help="(d) refits with new data")
    p.add_argument("--ctrl-steps", type=int, default=300, help="(d) controller updates")
    p.add_argument(
        "--ctrl-starts", type=int, default=4,
        help="(d) data configurations nearest to the target tried as extra starts (0: thesis)",
    )  # fmt: skip
    p.add_argument(
        "--ctrl-unlimited", action="store_true",
        help="(d) do not clip q_des to the joint box of the training data (thesis)",
    )  # fmt: skip
    p.add_argument(
        "--ctrl-orientation", choices=("ypr", "chordal"), default="ypr",
        help="(d) orientation error in e_p: wrapped yaw-pitch-roll (thesis) or chordal",
    )  # fmt: skip
    p.add_argument(
        "--ctrl-refine", choices=REFINE_CHOICES, default="both",
        help="(d) online rounds: refine the previous reference, search again, or both",
    )  # fmt: skip
    p.add_argument(
        "--ctrl-hold", type=int, default=5,
        help="(d) extra frames measured at rest at each reached reference (added to the data)",
    )  # fmt: skip
    p.add_argument(
        "--rotation-outputs", choices=("five", "nine"), default="five",
        help="(d) GP rotation outputs: five elements + eq. 2.20 (thesis) or nine + SO(3)",
    )  # fmt: skip
    p.add_argument("--span", type=float, default=1.0, help="(b-d) waypoints: home +- span rad")
    p.add_argument(
        "--facing-cone", type=_optional_degrees, default=FACING_CONE,
        help=f"(b-d) markers attached facing the camera at home within this angle [deg] "
        f"(default {FACING_CONE:g}; 'none': uniformly random orientations)",
    )  # fmt: skip
    p.add_argument(
        "--visibility-cone", type=_optional_degrees, default=VISIBILITY_CONE,
        help=f"(b-d) markers turned further from the camera are not seen, and waypoints and "
        f"targets show every marker (default {VISIBILITY_CONE:g}; 'none': every marker seen "
        "from any side, the protocol before 2026-11-26)",
    )  # fmt: skip
    p.add_argument(
        "--noise-scale", type=float, default=1.0,
        help="(c, d) multiply the env's default marker position and angle noise (sensitivity)",
    )  # fmt: skip
    p.add_argument(
        "--measurement", choices=("ideal", "aruco"), default="ideal",
        help="(c) marker poses from the env's noise model, or rendered + ArUco detection "
        "(needs OpenCV and MUJOCO_GL=egl/osmesa; ~0.3 s per frame)",
    )  # fmt: skip
    p.add_argument(
        "--fk-seeds", type=int, nargs="+", default=None,
        help="part (c) alone over these seeds: writes kinematics_c_seeds.{json,md} (per-seed "
        "RMSEs, mean and range, seeds meeting the goal) instead of the other outputs",
    )  # fmt: skip
    p.add_argument(
        "--merge", action="store_true",
        help="keep the results of the parts not run from an existing kinematics.json in --out-dir",
    )  # fmt: skip
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--quick", action="store_true", help="tiny sizes for a smoke run")
    p.add_argument("--out-dir", default="results")
    p.add_argument(
        "--runs-dir",
        default="runs/bench_kinematics",
        help="--fk-seeds: one result file per seed (reused by a later call, same options)",
    )
    p.add_argument("--no-progress", action="store_true")
    add_sweep_arguments(p)  # --jobs N (local processes), --ray [ADDRESS]: the --fk-seeds seeds
    return p


@console_main("mcpilco-bench-kinematics")
def main(argv: list[str] | None = None) -> int:
    """Command-line entry point; returns 0 (1 when a seed of ``--fk-seeds`` failed)."""
    parser = _parser()
    args = parser.parse_args(argv)
    if args.quick:
        for k, v in QUICK.items():
            setattr(args, k, v)
    if args.measurement == "aruco" and set(args.parts) & set("bd"):
        parser.error(
            "--measurement aruco supports parts a and c only: (b) counts misclassified "
            "triplets over all 126 and (d) measures every reached pose, and both need the "
            "markers seen in every frame"
        )
    if args.fk_seeds is not None and (args.measurement != "ideal" or args.merge):
        parser.error("--fk-seeds runs part (c) with the noise model alone (no --merge)")
    try:
        runner = runner_from_args(args, progress=not args.no_progress)
    except SweepError as err:
        parser.error(str(err))
    torch.set_num_threads(1)
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    progress = not args.no_progress
    cmd = "python -m mcpilco.scripts.bench_kinematics " + " ".join(
        sys.argv[1:] if argv is None else argv
    )
    if args.fk_seeds is not None:
        try:
            study = fk_seed_study(
                args.fk_seeds, args.samples, args.span, args.noise_scale, args.fk_train,
                args.facing_cone, args.visibility_cone, progress, args.train_selection,
                runner=runner, runs_dir=args.runs_dir,
            )  # fmt: skip
        except RuntimeError as err:  # a seed failed: the others are kept for the next call
            print(err, file=sys.stderr)
            return 1
        study["command"] = cmd.strip()
        (out / "kinematics_c_seeds.json").write_text(json.dumps(study, indent=1))
        text = fk_seed_markdown(study, cmd.strip())
        (out / "kinematics_c_seeds.md").write_text(text)
        print(text)
        return 0
    res: dict[str, Any] = dict(
        command=cmd.strip(), seed=args.seed, span=args.span, noise_scale=args.noise_scale,
        measurement=args.measurement,
    )  # fmt: skip
    old_json = out / "kinematics.json"
    if args.merge and old_json.exists():
        old = json.loads(old_json.read_text())
        for key in (*PART_KEYS, "identification"):
            if key in old:
                if key != "identification":
                    old[key].setdefault("command", old.get("command", ""))
                res[key] = old[key]
    for key, part in zip(PART_KEYS, "abcd", strict=True):
        if part in args.parts:
            res.pop(key, None)  # recomputed below
    t0 = time.perf_counter()
    ideal = args.measurement == "ideal"  # the rendered path has its own markers (docstring)
    protocol = dict(
        facing_cone=args.facing_cone if ideal else None,
        visibility_cone=args.visibility_cone if ideal else None,
    )
    if "a" in args.parts:
        res["monte_carlo"] = monte_carlo(args.robots, args.seed, progress)
    if "b" in args.parts:
        sizes = tuple(s for s in args.sizes if s <= args.samples) or (args.samples,)
        res["noise_vs_samples"] = noise_vs_samples(
            args.seed, args.samples, sizes, args.repeats, progress, args.span,
            args.facing_cone, args.visibility_cone,
        )  # fmt: skip
        res["noise_vs_samples"]["marker_protocol"] = protocol
    if "c" in args.parts or "d" in args.parts:
        data = ur10_datasets(
            args.seed, args.samples, args.span, args.noise_scale, args.measurement,
            args.facing_cone, args.visibility_cone,
        )  # fmt: skip
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            idn = identify_ur10(data)
        s = idn["structure"]
        res["identification"] = dict(
            samples=int(data["train"][0].shape[0]),
            correct=idn["correct"],
            joint_types=None if s is None else s.joint_types,
            markers=None if s is None else list(s.markers),
            joints=None if s is None else list(s.joints),
            seconds=idn["seconds"],
            dropped_frames=idn.get("dropped_frames"),
            error=idn.get("error"),
        )
        if not idn["correct"]:  # fall back to the true structure so (c)/(d) still run
            s = true_structure(data["env"])
            res["identification"]["note"] = "identification failed; (c)/(d) use the true structure"
        if "c" in args.parts:
            res["fk_gp"] = fk_gp_part(
                data, s, args.fk_train, args.seed, selection=args.train_selection
            )
            res["fk_gp"]["marker_protocol"] = protocol
        if "d" in args.parts:
            res["controller"] = controller_part(
                data,
                s,
                args.ctrl_train,
                args.online_rounds,
                args.seed,
                progress,
                args.ctrl_steps,
                args.span,
                starts=args.ctrl_starts,
                limit_to_data=not args.ctrl_unlimited,
                orientation=args.ctrl_orientation,
                refine=args.ctrl_refine,
                rotation_outputs=args.rotation_outputs,
                hold=args.ctrl_hold,
                selection=args.ctrl_selection,
                fk_model=args.ctrl_model,
            )
            res["controller"]["marker_protocol"] = protocol
    for key in PART_KEYS:  # which command produced each part (they may come from --merge)
        if key in res:
            res[key].setdefault("command", res["command"])
    res["seconds"] = time.perf_counter() - t0
    res["paths"] = _plots(res, out)
    res["paths"]["json"] = str(out / "kinematics.json")
    res["paths"]["markdown"] = str(out / "kinematics.md")
    Path(res["paths"]["json"]).write_text(json.dumps(res, indent=1))
    Path(res["paths"]["markdown"]).write_text(_markdown(res))
    print(_markdown(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

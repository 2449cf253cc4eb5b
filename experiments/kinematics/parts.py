r"""The four parts of the kinematics learning benchmark (thesis chapter 2, section 2.6).

(a) **Monte Carlo** (:func:`monte_carlo`, section 2.6.1, Fig. 2.4): random robots with 6
    links (5 joints, 6 markers) from :func:`mcpilco.models.kinematics.synthetic.random_chain`
    (random joint types, DH parameters, marker placements, camera pose); each joint a sum of
    10 random sinusoids; ``T = 50`` noiseless samples; all ``15 x 5 = 75`` triplets per robot
    classified by the three tests (:func:`~mcpilco.models.kinematics.classify_all_triplets`).
    The data are noiseless, so the thresholds are the exact-feasibility tolerances
    ``xi_t = xi_o = 1e-6``. Confusion matrices for Prop. 2.3.1, 2.3.2, 2.3.3 and 2.3.2+2.3.3
    (class 1 = connected through a prismatic, resp. revolute, joint). The iterative
    algorithm is also run on every robot with shuffled markers and joints.

Marker protocol of parts (b)-(d) (:data:`FACING_CONE`, :data:`VISIBILITY_CONE`): the markers
are attached facing the camera at :data:`~mcpilco.experiments.kinematics.trajectories.UR10_HOME`,
a marker turned more than the visibility cone from its line of sight to the camera is not
seen (NaN), and the waypoints and the controller's targets are drawn only where every marker
is seen, as in the thesis' data, where every marker was detected in every frame. With both
cones None the markers have uniformly random orientations and every marker is seen from any
side.

(b) **Noise vs samples** (:func:`noise_vs_samples`, 2.6.2, Fig. 2.6): the UR10 of
    ``mcpilco/MarkerCamera-v0`` with its default AprilTag-like noise follows a trajectory
    through 25 random waypoints; for growing prefixes of it, all 126 triplets are classified
    with ``xi_t = 0.02`` m, ``xi_o = 0.1`` rad; misclassified triplets and the residual
    statistics ``f_r1`` (connected) / ``f_r2`` (not connected) of the linear (2.18) and
    non-linear (2.19) revolute tests are recorded.
(c) **FK GP** (:func:`fk_gp_part`, 2.6.3, Table 2.1): the structure is identified on the
    whole training trajectory ``D_tr``; the GP with the kernels ``k_R``/``k_l``
    (eqs. 2.22-2.23) is trained on samples of ``D_tr`` and tested on ``D_test`` (the same
    waypoints in another order). The samples are picked by :func:`training_indices`:
    ``"design"`` greedily by the prior variance of ``k_l`` from the joint signals alone
    (:func:`~mcpilco.models.kinematics.forward.design_subset`), ``"random"`` at random as in
    the thesis. RMSE against the measured (noisy) test poses, as in the thesis, and against
    the true poses. Baseline: an RBF GP (ARD, on raw ``q``) on the same samples. Further
    models: the GP on all nine rotation elements with the mean projected onto SO(3); the GP
    with leave-one-out outlier trimming (:data:`OUTLIER_THRESHOLD`,
    :meth:`ForwardKinematicsGP.fit`); the chain model
    (:class:`~mcpilco.models.kinematics.ChainForwardKinematicsGP`: one-joint GPs on the
    relative poses of consecutive markers of the identified chain, composed), trained on the
    same frames with every marker they show. Diagnostics: the measurement noise itself
    (measured vs true test poses: the floor of any RMSE against measured poses; per axis, as
    a 3-D norm, and the distance / incidence that scale it), the same GP trained on
    noise-free poses of the same configurations, of as many configurations drawn i.i.d. in
    the waypoint box, and of 4x as many of each (is the gap noise, the number of samples or
    the trajectory design?), the numerical rank of the ``3^6`` monomials of ``k_R`` on
    ``D_tr`` (:func:`feature_rank`), and the errors restricted to test poses with
    ``|beta| < 1`` (yaw and roll of eq. 2.20 are ill-conditioned near ``beta = +-pi/2``).
    With ``measurement="aruco"`` the poses are measured from rendered images with ArUco
    detection instead of the env's noise model; identification tests each triplet on the
    frames that show both of its markers, and the GP trains and tests on the frames whose
    end marker was found. :func:`fk_seed_study` runs part (c) alone on several seeds (their
    own markers, waypoints and noise) and counts the seeds on which each pose element meets
    :data:`FK_GOAL`.
(d) **Controller** (:func:`controller_part`, 2.6.4, Table 2.2): the GP trained on samples of
    ``D_tr``; 5 random targets (configurations uniform in the joint box of the waypoints)
    from a fixed start; reference by eq. 2.24 (with backtracking), from the start and from
    the data configurations nearest to the target (the lowest predicted ``e_p`` wins;
    against local minima), clipped to the joint box of the training data (against
    extrapolation); the env tracks it and the camera measures the reached pose. Online
    improvement: the frames measured while executing the references are added to the data,
    with more frames measured at rest at each reached reference, the GP is refitted and the
    targets are tried again, from the reference reached in the previous round and from the
    round-0 starts. No extra starts and no clipping is the thesis' plain controller; the
    thesis trains on all of ``D_tr``, a random subset keeps the run short.

Reports: :mod:`mcpilco.experiments.kinematics.report`; the command that runs the parts:
:mod:`mcpilco.experiments.kinematics.bench`.
"""

from __future__ import annotations

import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from mcpilco.envs.marker_camera import NOISE_DEFAULTS, MarkerCameraEnv
from mcpilco.experiments.infra.sweep import Job, SweepRunner
from mcpilco.experiments.kinematics.trajectories import (
    UR10_HOME,
    draw_accepted,
    drive_to,
    ur10_waypoints,
    visible_configuration,
    waypoint_trajectory,
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

# (c) leave-one-out score above which the trimmed FK GP drops a training sample
OUTLIER_THRESHOLD = 4.0
# (a) the revolute/prismatic tests whose confusion matrices are reported
PROPS = ("Prop. 2.3.1", "Prop. 2.3.2", "Prop. 2.3.3", "Prop. 2.3.2 + 2.3.3")
# pose elements: position [m] and yaw-pitch-roll angles [rad] (eq. 2.20)
POSE_NAMES = ("x", "y", "z", "gamma", "beta", "alpha")
# pose-error columns: the pose elements and the geodesic angle [rad]
ERR_NAMES = (*POSE_NAMES, "geodesic")
# (b-d) markers are attached facing the camera at UR10_HOME within this angle [deg]
FACING_CONE = 40.0
# (b-d) a marker turned further than this [deg] from the camera is not seen (cf. the rendered
# detection rate against the facing angle in results/marker_detection.md)
VISIBILITY_CONE = 70.0
# (d) starts of the online rounds: see controller_part
REFINE_CHOICES = ("previous", "restart", "both")
# how parts (c) and (d) take their training samples from D_tr: see training_indices
TRAIN_SELECTIONS = ("design", "random")
# (d) FK models: the thesis' GP on the end marker, or the chain of one-joint GPs
FK_MODELS = ("end", "chain")
# (c) goal: RMSE <= 6 mm on x, y, z and <= 0.04 rad on each angle
FK_GOAL = (0.006, 0.04)
# models of the seed study checked against FK_GOAL
GOAL_MODELS = ("polynomial", "nine_elements", "chain")
# per-seed RMSE rows of the seed study that get a mean / min / max summary
SEED_STUDY_KEYS = ("polynomial", "polynomial_true", "nine_elements", "chain", "chain_true", "rbf",
                   "noise")  # fmt: skip


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
    waypoints can still hide one). Both None: markers at uniformly random orientations,
    every marker seen from any side. ``measurement="aruco"`` renders the
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
        obs = drive_to(env, waypoints[0])[-1]
    tr = waypoint_trajectory(env, obs, waypoints, samples)
    order = np.concatenate([[0], 1 + rng.permutation(24)])
    obs = drive_to(env, waypoints[0])[-1]  # back to the start (not recorded)
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
    geodesic = float(np.sqrt(np.mean(geodesic_errors(pred, true) ** 2)))
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


def feature_rank(q: np.ndarray, rtol: float = 1e-8) -> int:
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


def training_indices(
    q_model: np.ndarray,
    valid: np.ndarray,
    n_train: int,
    selection: str,
    rng: np.random.Generator,
    joint_types: str,
) -> np.ndarray:
    """``n_train`` rows of ``D_tr`` among the ``valid`` ones (end marker measured) to train on.

    ``q_model``: ``(N, n)`` joint signals in model order. ``selection`` (one of
    :data:`TRAIN_SELECTIONS`): ``"design"`` greedily by the prior variance of ``k_l``
    (:func:`~mcpilco.models.kinematics.forward.design_subset`, from the joint signals alone),
    ``"random"`` uniformly at random (the thesis). A random draw is always taken from ``rng``
    (the random selection, and the same random stream after it for both choices).
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
            D_tr=feature_rank(q_tr_true) if all_revolute else None,
            iid_same_size=feature_rank(rng.uniform(*box, (len(q_tr_true), 6)))
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


# ----------------------------------------------------------------------------- (d) controller


def reaching_problem(
    data: dict[str, Any], structure, n_train: int, selection: str, seed: int
) -> dict[str, Any]:
    """The start of part (d) and of the MC-PILCO reaching benchmark: ``n_train`` samples of
    ``D_tr`` (:func:`training_indices`), every marker in chain order (``X`` joints in the
    model's order ``S_q``, ``Y`` poses ``(N, n + 1, 6)``), and 5 target configurations
    uniform in the joint box of the waypoints (where every marker is seen, with a visibility
    cone) with their end-marker poses; ``chain_of_model[k]``: the chain joint of model
    joint ``k``. Both agents draw the same samples and targets for a seed."""
    env = data["env"]
    poses, q, _ = data["train"]
    ee, joints = structure.markers[-1], list(structure.joints)
    rng = np.random.default_rng([seed, 4])
    valid = np.isfinite(poses[:, ee]).all(1)
    idx = training_indices(q[:, joints], valid, n_train, selection, rng, structure.joint_types)
    X, Y = q[idx][:, joints], poses[idx][:, list(structure.markers)]
    wp = data["waypoints"]
    lo, hi = wp.min(0), wp.max(0)
    accept = visible_configuration(env)
    q_targets = (
        rng.uniform(lo, hi, (5, wp.shape[1]))
        if accept is None
        else draw_accepted(lambda: rng.uniform(lo, hi), 5, accept, 5000, "targets")
    )
    return dict(
        idx=idx,
        X=X,
        Y=Y,
        q_targets=q_targets,
        targets=np.array([env.marker_poses(qt)[-1] for qt in q_targets]),
        # model joint k is observed slot S_q[k], i.e. chain joint joint_permutation[S_q[k]]
        chain_of_model=env.joint_permutation[joints],
    )


def measured_joints(obs: np.ndarray, structure) -> np.ndarray:
    """The measured joint positions of a marker-camera observation, in the model's order
    ``S_q`` (n,)."""
    n = len(structure.joints)
    return obs[6 * (n + 1) : 6 * (n + 1) + n][list(structure.joints)]


def trial_frames(obs_rows: list[np.ndarray], structure) -> tuple[list, list]:
    """The frames of a trial that join the model's data: those showing the end marker, as
    ``(joints in the model's order (n,), every marker in chain order (n + 1, 6))`` lists."""
    n = len(structure.joints)
    markers = list(structure.markers)
    X, Y = [], []
    for o in obs_rows:
        y = o[: 6 * (n + 1)].reshape(n + 1, 6)[markers]
        if np.isfinite(y[-1]).all():
            X.append(measured_joints(o, structure))
            Y.append(y)
    return X, Y


def geodesic_errors(poses: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """Rotation angle [rad] between the orientations of ``poses`` and ``targets`` (..., 6)."""
    R = ypr_to_matrix(poses[..., 3:])
    R_star = ypr_to_matrix(targets[..., 3:])
    cos = (np.einsum("...ij,...ij->...", R, R_star) - 1.0) / 2.0
    return np.arccos(np.clip(cos, -1.0, 1.0))


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
    problem = reaching_problem(data, structure, n_train, selection, seed)
    idx, X, Y, targets = problem["idx"], problem["X"], problem["Y"], problem["targets"]
    ee = structure.markers[-1]
    q_start = data["waypoints"][0]
    chain_of_model = problem["chain_of_model"]
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
            drive_to(env, q_start)
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
                obs_rows += drive_to(env, np.clip(q_goal, env.q_low, env.q_high))
            arrival = obs_rows[-1][: 6 * (n + 1)].reshape(n + 1, 6)[ee]
            for _ in range(hold):  # the robot rests at q_des while the camera keeps measuring
                obs_rows.append(env.step(np.zeros(n, dtype=np.float32))[0])
            frames_X, frames_Y = trial_frames(obs_rows, structure)
            new_X += frames_X
            new_Y += frames_Y
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
                orientation_error_true=geodesic_errors(reached_true, targets).tolist(),
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

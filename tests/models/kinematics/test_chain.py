"""FK composed along the marker chain (:mod:`mcpilco.models.kinematics.chain`).

Truth: the numpy DH chains of :mod:`mcpilco.models.kinematics.synthetic` (their marker
poses and, by central differences, their Jacobians).
"""

import numpy as np
import pytest
import torch

from mcpilco.models.kinematics import ChainForwardKinematicsGP
from mcpilco.models.kinematics.forward import ForwardKinematicsGP, gradient_kinematic_controller
from mcpilco.models.kinematics.rotations import wrap_angle
from mcpilco.models.kinematics.synthetic import random_chain

FIT = dict(adam_iters=10, lbfgs_iters=30)


def _pose_err(pred: np.ndarray, true: np.ndarray) -> tuple[float, float]:
    """Largest position [m] and yaw-pitch-roll [rad] error."""
    return (
        float(np.abs(pred[:, :3] - true[:, :3]).max()),
        float(np.abs(wrap_angle(pred[:, 3:] - true[:, 3:])).max()),
    )


def _data(types: str, n_frames: int, seed: int):
    rng = np.random.default_rng(seed)
    chain = random_chain(len(types), rng, joint_types=types)
    span = np.where(np.array(list(types)) == "R", 1.5, 0.2)
    q = rng.uniform(-span, span, (n_frames, len(types)))
    return chain, q, chain.marker_poses(q), rng, span


@pytest.mark.parametrize("types", ["RRR", "RPRP"])
def test_noiseless_chain_is_exact(types):
    """Each relative marker pose is A + B cos q_k + C sin q_k (or linear in a prismatic q_k),
    inside the one-joint kernel's RKHS: 30 noiseless frames give the chain to ~1e-6."""
    chain, q, poses, rng, span = _data(types, 30, 0)
    fk = ChainForwardKinematicsGP(types).fit(q, poses)
    q_test = rng.uniform(-span, span, (200, len(types)))
    pos_err, ang_err = _pose_err(fk.predict(q_test), chain.marker_poses(q_test)[:, -1])
    assert pos_err < 1e-5 and ang_err < 1e-4
    assert fk.frames_used_ == {"base": 30, "links": [30] * len(types)}


def test_hidden_markers_drop_only_their_links_frames():
    chain, q, poses, rng, span = _data("RRR", 40, 1)
    poses = poses.copy()
    poses[:8, 1] = np.nan  # marker 1 out of view: links 1 and 2 lose 8 frames
    poses[8:11, 0] = np.nan  # the base marker: the base and link 1 lose 3 more
    fk = ChainForwardKinematicsGP("RRR").fit(q, poses)
    assert fk.frames_used_ == {"base": 37, "links": [29, 32, 40]}
    q_test = rng.uniform(-span, span, (100, 3))
    pos_err, ang_err = _pose_err(fk.predict(q_test), chain.marker_poses(q_test)[:, -1])
    assert pos_err < 1e-5 and ang_err < 1e-4


def test_noise_averages_out_along_the_chain():
    """2 mm / 0.01 rad noise on every marker of 100 frames of a random 6-R chain, joints
    within +-1.5 rad: the composed model stays within a few mm and 0.02 rad of the truth,
    where the end-to-end GP of eqs. 2.22-2.23 (729 monomials, end marker only) misses by
    centimetres on the same frames."""
    chain, q, poses, rng, span = _data("RRRRRR", 100, 2)
    noisy = poses.copy()
    noisy[..., :3] += 0.002 * rng.standard_normal(poses[..., :3].shape)
    noisy[..., 3:] += 0.01 * rng.standard_normal(poses[..., 3:].shape)
    q_test = rng.uniform(-span, span, (300, 6))
    true = chain.marker_poses(q_test)[:, -1]

    def rmse(model) -> tuple[np.ndarray, np.ndarray]:
        err = model.predict(q_test) - true
        return np.sqrt((err[:, :3] ** 2).mean(0)), np.sqrt((wrap_angle(err[:, 3:]) ** 2).mean(0))

    pos, ang = rmse(ChainForwardKinematicsGP("RRRRRR").fit(q, noisy))
    assert (pos < 0.005).all() and (ang < 0.02).all(), (pos, ang)
    pos_e2e, _ = rmse(ForwardKinematicsGP("RRRRRR").fit(q, noisy[:, -1], **FIT))
    assert (pos_e2e > 5 * pos).all(), (pos_e2e, pos)


def test_predictor_gradient_matches_the_chain_and_drives_the_controller():
    chain, q, poses, rng, span = _data("RPR", 30, 3)
    fk = ChainForwardKinematicsGP("RPR").fit(q, poses)
    pred = fk.predictor()
    q0 = np.array([0.3, 0.05, -0.4])
    qt = torch.tensor(q0, requires_grad=True)
    jac = torch.autograd.functional.jacobian(lambda x: pred(x)[0], qt).numpy()
    h = 1e-6

    def end_position(qq: np.ndarray) -> np.ndarray:
        return chain.marker_poses(qq)[0, -1, :3]

    fd = np.stack(
        [(end_position(q0 + h * e) - end_position(q0 - h * e)) / (2 * h) for e in np.eye(3)],
        axis=1,
    )
    np.testing.assert_allclose(jac, fd, atol=1e-4)
    target = chain.marker_poses(np.array([0.6, -0.1, 0.2]))[0, -1]
    res = gradient_kinematic_controller(pred, q0, target, steps=400)
    reached = chain.marker_poses(res.q[-1])[0, -1]
    assert np.linalg.norm(reached[:3] - target[:3]) < 1e-3


def test_bad_inputs_raise():
    _, q, poses, _, _ = _data("RR", 20, 4)
    fk = ChainForwardKinematicsGP("RR")
    with pytest.raises(RuntimeError, match="not fitted"):
        fk.predict(q)
    with pytest.raises(ValueError, match=r"marker_poses must have shape \(20, 3, 6\)"):
        fk.fit(q, poses[:, :2])
    bad = poses.copy()
    bad[0, 1, 2] = np.nan
    with pytest.raises(ValueError, match="partly-NaN"):
        fk.fit(q, bad)
    hidden = poses.copy()
    hidden[:17, 2] = np.nan
    with pytest.raises(ValueError, match=r"too few frames for link 2 \(markers 1, 2\): \[3\]"):
        fk.fit(q, hidden)
    q_nan = q.copy()
    q_nan[3, 0] = np.nan
    with pytest.raises(ValueError, match="q contains NaN"):
        fk.fit(q_nan, poses)
    with pytest.raises(ValueError, match="joint_types"):
        ChainForwardKinematicsGP("RX")


def test_weight_space_link_fit_matches_the_function_space_gp():
    """The link GP in weight space (``fit_link``, evidence in O(N p^2)) against the same
    kernel, eq. 2.22 with one factor, fitted in function space by the GP core (GPyTorch):
    the posterior means agree to a small fraction of the noise."""
    from mcpilco.models.gp import GPRegressor
    from mcpilco.models.kinematics.chain import fit_link, link_features
    from mcpilco.models.kinematics.forward import fk_features, rotation_kernel_factory

    rng = np.random.default_rng(7)
    q = rng.uniform(-1.5, 1.5, 80)
    coef = rng.normal(0.0, 0.3, (3, 3))
    phi = np.stack([np.ones_like(q), np.cos(q), np.sin(q)], 1)
    y = phi @ coef + 0.003 * rng.standard_normal((80, 3))
    W = fit_link(q, y, "R")
    gp = GPRegressor(rotation_kernel_factory("R"), standardize_x=False, noise_init=1e-3)
    gp.fit(fk_features(q[:, None], "R"), y, adam_iters=50, lbfgs_iters=100)
    q_test = np.linspace(-1.5, 1.5, 50)
    phi_test = link_features(torch.from_numpy(q_test[:, None]), "R")
    mean_w = (phi_test @ torch.from_numpy(W)).numpy()
    mean_f = gp.predict(fk_features(q_test[:, None], "R"))[0].numpy()
    assert np.abs(mean_w - mean_f).max() < 0.1 * 0.003  # the two implementations agree
    assert np.abs(mean_w - phi_test.numpy() @ coef).max() < 0.003  # and both find the link

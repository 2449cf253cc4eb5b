"""Forward-kinematics GP (thesis 2.5) and the gradient controller (eq. 2.24) on small arms.

Truth: the numpy DH chain of :mod:`mcpilco.models.kinematics.synthetic`; kernel values are
checked against the closed form of eq. 2.22 written out by hand.
"""

import numpy as np
import pytest
import torch

from mcpilco.models.kinematics.forward import (
    ForwardKinematicsGP,
    fk_features,
    gradient_kinematic_controller,
    position_kernel_factory,
    rotation_kernel_factory,
)
from mcpilco.models.kinematics.rotations import wrap_angle
from mcpilco.models.kinematics.synthetic import SyntheticChain, homogeneous, random_rotation

FIT = dict(adam_iters=10, lbfgs_iters=30)


def _planar_arm(tilted: bool) -> SyntheticChain:
    dh = np.array([[0.5, 0.0, 0.0, 0.0], [0.4, 0.0, 0.0, 0.0]])
    R = random_rotation(np.random.default_rng(0)) if tilted else np.eye(3)
    base = homogeneous(R, [0.1, -0.2, 2.0])
    return SyntheticChain("RR", dh, base, np.stack([np.eye(4)] * 3))


def _rmse(pred, true):
    err = np.concatenate([pred[:, :3] - true[:, :3], wrap_angle(pred[:, 3:] - true[:, 3:])], 1)
    return np.sqrt((err**2).mean(0))


def test_features_follow_eq_2_21():
    q = torch.tensor([[0.3, 0.1, -1.0]], dtype=torch.float64)
    x = fk_features(q, "RPR")
    expected = [np.cos(0.3), np.cos(-1.0), np.sin(0.3), np.sin(-1.0), 0.1]
    np.testing.assert_allclose(x.numpy()[0], expected)
    with pytest.raises(ValueError, match="3 columns"):
        fk_features(np.zeros((2, 2)), "RPR")


def test_kernels_match_the_products_of_eqs_2_22_and_2_23():
    rng = np.random.default_rng(0)
    q1, q2 = rng.uniform(-3, 3, (4, 2)), rng.uniform(-3, 3, (5, 2))
    x1, x2 = fk_features(q1, "RP"), fk_features(q2, "RP")
    kR = rotation_kernel_factory("RP")(torch.Size([]))
    kl = position_kernel_factory("RP")(torch.Size([]))
    # all hyperparameters 1: k_R = 1 + c c' + s s' = 1 + cos(q - q'), k_l = k_R (1 + p p')
    dq = q1[:, None, 0] - q2[None, :, 0]
    k_r_true = 1.0 + np.cos(dq)
    k_l_true = k_r_true * (1.0 + q1[:, None, 1] * q2[None, :, 1])
    np.testing.assert_allclose(kR(x1, x2).to_dense().detach().numpy(), k_r_true, atol=1e-12)
    np.testing.assert_allclose(kl(x1, x2).to_dense().detach().numpy(), k_l_true, atol=1e-12)


def _fit_planar(tilted: bool):
    chain = _planar_arm(tilted)
    q_train = np.random.default_rng(1).uniform(-np.pi, np.pi, (40, 2))
    return chain, ForwardKinematicsGP("RR").fit(q_train, chain.marker_poses(q_train)[:, -1], **FIT)


@pytest.fixture(scope="module")
def planar_tilted():
    return _fit_planar(tilted=True)


@pytest.mark.parametrize("tilted", [True, False])
def test_planar_two_link_fk_gp_reaches_sub_millimetre_rmse(tilted, planar_tilted):
    chain, fk = planar_tilted if tilted else _fit_planar(tilted=False)
    q_test = np.random.default_rng(2).uniform(-np.pi, np.pi, (200, 2))
    p_test = chain.marker_poses(q_test)[:, -1]
    rmse = _rmse(fk.predict(q_test), p_test)
    assert rmse[:3].max() < 1e-3 and rmse[3:].max() < 1e-3, rmse
    if not tilted:  # the plane faces the camera: R31, R32 and z are constant
        assert fk.rotation_varying_.tolist() == [True, True, False, False, False]
        assert fk.position_varying_.tolist() == [True, True, False]


def test_revolute_prismatic_arm_fk_gp():
    dh = np.array([[0.3, 1.2, 0.1, 0.4], [0.2, -0.7, 0.2, 0.0]])
    rng = np.random.default_rng(2)
    chain = SyntheticChain(
        "RP", dh, homogeneous(random_rotation(rng), [0, 0, 2.0]), np.stack([np.eye(4)] * 3)
    )
    q_train = np.column_stack([rng.uniform(-3, 3, 40), rng.uniform(0, 0.3, 40)])
    q_test = np.column_stack([rng.uniform(-3, 3, 100), rng.uniform(0, 0.3, 100)])
    fk = ForwardKinematicsGP("RP").fit(q_train, chain.marker_poses(q_train)[:, -1], **FIT)
    rmse = _rmse(fk.predict(q_test), chain.marker_poses(q_test)[:, -1])
    assert rmse[:3].max() < 1e-3 and rmse[3:].max() < 1e-3, rmse


def test_gradient_controller_reaches_a_reachable_target(planar_tilted):
    chain, fk = planar_tilted
    target = chain.marker_poses(np.array([[0.7, -1.2]]))[0, -1]
    res = gradient_kinematic_controller(fk.predictor(), np.zeros(2), target, steps=250)
    assert res.q.shape == (251, 2)
    assert np.all(np.diff(res.predicted_error) <= 1e-12)  # backtracking: monotone
    reached = chain.marker_poses(res.q_final[None])[0, -1]
    assert np.linalg.norm(reached[:3] - target[:3]) < 2e-3
    plain = gradient_kinematic_controller(
        fk.predictor(), np.zeros(2), target, nu=0.05, steps=20, backtrack=False
    )
    assert plain.predicted_error[-1] < plain.predicted_error[0]


def test_bad_inputs_raise():
    fk = ForwardKinematicsGP("RR")
    with pytest.raises(RuntimeError, match="not fitted"):
        fk.predict(np.zeros((1, 2)))
    with pytest.raises(ValueError, match=r"shape \(N, 2\)"):
        fk.fit(np.zeros((5, 3)), np.zeros((5, 6)))
    q = np.random.default_rng(0).uniform(-1, 1, (5, 2))
    with pytest.raises(ValueError, match=r"poses must have shape \(5, 6\)"):
        fk.fit(q, np.zeros((5, 3)))
    bad = np.ones((5, 6))
    bad[2, 4] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        fk.fit(q, bad)
    with pytest.raises(ValueError, match="joint_types"):
        ForwardKinematicsGP("RX")

"""Forward-kinematics GP (thesis 2.5) and the gradient controller (eq. 2.24) on small arms.

Truth: the numpy DH chain of :mod:`mcpilco.models.kinematics.synthetic`; kernel values are
checked against the closed form of eq. 2.22 written out by hand.
"""

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from mcpilco.models.kinematics.forward import (
    ForwardKinematicsGP,
    design_subset,
    fk_features,
    gradient_kinematic_controller,
    multi_start_controller,
    nearest_data_starts,
    pose_error,
    position_kernel_factory,
    rotation_kernel_factory,
)
from mcpilco.models.kinematics.rotations import (
    matrix_to_ypr,
    nearest_rotation,
    nearest_rotation_torch,
    wrap_angle,
    ypr_to_matrix,
    ypr_to_matrix_torch,
)
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


def test_outlier_trimming_drops_exactly_the_corrupted_poses():
    """Tilted 2-link arm, 60 poses with 2 mm noise and 4 gross errors (a 10 cm depth error,
    a flipped orientation): leave-one-out trimming drops those 4 and the fit is back at the
    noise level, while the untrimmed fit is pulled off by them."""
    chain = _planar_arm(tilted=True)
    rng = np.random.default_rng(5)
    q_train = rng.uniform(-np.pi, np.pi, (60, 2))
    poses = chain.marker_poses(q_train)[:, -1].copy()
    poses[:, :3] += 0.002 * rng.standard_normal((60, 3))
    bad = np.array([4, 17, 33, 50])
    poses[bad[:2], 2] += 0.1
    R = ypr_to_matrix(poses[bad[2:], 3:]) @ np.diag([-1.0, 1.0, -1.0])  # pi about y
    poses[bad[2:], 3:] = matrix_to_ypr(R)
    q_test = rng.uniform(-np.pi, np.pi, (200, 2))
    p_test = chain.marker_poses(q_test)[:, -1]
    plain = ForwardKinematicsGP("RR").fit(q_train, poses, **FIT)
    trimmed = ForwardKinematicsGP("RR").fit(q_train, poses, outlier_threshold=4.0, **FIT)
    assert trimmed.outliers_.tolist() == bad.tolist()
    err_plain, err_trim = (
        _rmse(plain.predict(q_test), p_test),
        _rmse(trimmed.predict(q_test), p_test),
    )
    assert err_trim[:3].max() < 0.002 and err_trim[3:].max() < 0.01, err_trim
    assert err_plain.max() > 3 * err_trim.max(), (err_plain, err_trim)
    with pytest.raises(ValueError, match="outlier_threshold"):
        ForwardKinematicsGP("RR").fit(q_train, poses, outlier_threshold=0.0)


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


def test_ypr_to_matrix_torch_matches_scipy():
    rng = np.random.default_rng(3)
    o = np.column_stack(
        [rng.uniform(-np.pi, np.pi, 10), rng.uniform(-1.5, 1.5, 10), rng.uniform(-np.pi, np.pi, 10)]
    )
    R = ypr_to_matrix_torch(torch.as_tensor(o)).numpy()
    np.testing.assert_allclose(R, Rotation.from_euler("ZYX", o).as_matrix(), atol=1e-12)


def test_chordal_orientation_error_is_2_sin_half_angle_even_at_gimbal_lock():
    rng = np.random.default_rng(4)
    R0 = Rotation.from_euler("ZYX", [0.3, np.pi / 2 - 1e-4, -0.2])  # beta ~ pi/2: gimbal lock
    for theta in (0.05, 0.5, 2.0):
        axis = rng.standard_normal(3)
        R1 = Rotation.from_rotvec(theta * axis / np.linalg.norm(axis)) * R0
        o0, o1 = (torch.as_tensor(matrix_to_ypr(R.as_matrix())) for R in (R0, R1))
        target = torch.cat([torch.zeros(3), o0])
        e = pose_error(torch.zeros(3), o1, target, orientation_weight=1.0, orientation="chordal")
        np.testing.assert_allclose(float(e), 2 * np.sin(theta / 2), rtol=1e-6)
    # position part: a pure translation of (3, 4, 0) cm gives 5 cm with either metric
    o = torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64)
    shift = torch.tensor([0.03, 0.04, 0.0], dtype=torch.float64)
    for kind in ("ypr", "chordal"):
        e = pose_error(shift, o, torch.cat([torch.zeros(3, dtype=torch.float64), o]),
                       orientation=kind)  # fmt: skip
        np.testing.assert_allclose(float(e), 0.05, rtol=1e-9)
    with pytest.raises(ValueError, match="orientation must be one of"):
        pose_error(torch.zeros(3), o, torch.zeros(6), orientation="quaternion")


def test_nearest_data_starts_orders_by_pose_error():
    q = np.arange(8.0).reshape(4, 2)
    poses = np.zeros((4, 6))
    poses[:, 0] = [0.3, 0.1, 0.2, 0.0]  # x distances to the target at x = 0.0
    poses[1, 3] = 1.0  # 1 rad of yaw: 0.1 m at w_o = 0.1 -> e_p = sqrt(0.01 + 0.01)
    starts = nearest_data_starts(q, poses, np.zeros(6), k=3)
    np.testing.assert_array_equal(starts, q[[3, 1, 2]])  # 0.0 < 0.141 < 0.2
    assert nearest_data_starts(q, poses, np.zeros(6), k=10).shape == (4, 2)
    with pytest.raises(ValueError, match="positive int"):
        nearest_data_starts(q, poses, np.zeros(6), k=0)


def test_multi_start_controller_escapes_a_bad_start(planar_tilted):
    chain, fk = planar_tilted
    q_target = np.array([0.7, -1.2])
    target = chain.marker_poses(q_target[None])[0, -1]
    kw = dict(steps=60, orientation="chordal")
    # from q = (0.7 + pi, 1.2) the arm starts on the far side of the workspace; a start near
    # q_target (as nearest_data_starts would give) must win
    starts = np.array([[0.7 + np.pi, 1.2], q_target + 0.05])
    res, s = multi_start_controller(fk.predictor(), starts, target, **kw)
    single = gradient_kinematic_controller(fk.predictor(), starts[1], target, **kw)
    assert s == 1
    np.testing.assert_allclose(res.predicted_error, single.predicted_error)
    reached = chain.marker_poses(res.q_final[None])[0, -1]
    assert np.linalg.norm(reached[:3] - target[:3]) < 2e-3


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


def test_nearest_rotation_is_the_polar_factor_in_numpy_and_torch():
    rng = np.random.default_rng(5)
    R = random_rotation(rng, 20)
    A = rng.standard_normal((20, 3, 3))
    S = A @ np.swapaxes(A, -1, -2) + 0.1 * np.eye(3)  # symmetric positive definite
    M = R @ S  # polar decomposition: its orthogonal factor is R
    np.testing.assert_allclose(nearest_rotation(M), R, atol=1e-10)
    np.testing.assert_allclose(nearest_rotation_torch(torch.as_tensor(M)).numpy(), R, atol=1e-10)
    # det M < 0: the nearest *rotation* flips the direction of the smallest singular value
    D = np.diag([2.0, 1.5, -0.2])
    np.testing.assert_allclose(nearest_rotation(R[0] @ D), R[0], atol=1e-12)
    with pytest.raises(ValueError, match="3, 3"):
        nearest_rotation(np.eye(2))


def test_nearest_rotation_torch_has_finite_gradients_at_a_rotation():
    # an SVD backward divides by s_i^2 - s_j^2, which vanishes here
    R = torch.as_tensor(random_rotation(np.random.default_rng(6)))
    M = (R + 1e-3 * torch.randn(3, 3, dtype=torch.float64)).requires_grad_(True)
    assert torch.autograd.gradcheck(nearest_rotation_torch, (M,))
    M0 = R.clone().requires_grad_(True)
    (g,) = torch.autograd.grad(nearest_rotation_torch(M0)[0, 0], M0)
    assert torch.isfinite(g).all()


@pytest.mark.parametrize("tilted", [True, False])
def test_nine_element_fk_gp_is_accurate_and_keeps_constant_elements(tilted):
    chain = _planar_arm(tilted)
    rng = np.random.default_rng(1)
    q_train, q_test = rng.uniform(-np.pi, np.pi, (40, 2)), rng.uniform(-np.pi, np.pi, (100, 2))
    fk = ForwardKinematicsGP("RR", rotation_outputs="nine")
    fk.fit(q_train, chain.marker_poses(q_train)[:, -1], **FIT)
    truth = chain.marker_transforms(q_test)[:, -1]
    pred = fk.predict(q_test)
    np.testing.assert_allclose(pred[:, :3], truth[:, :3, 3], atol=1e-3)
    R_err = np.swapaxes(truth[:, :3, :3], -1, -2) @ ypr_to_matrix(pred[:, 3:])
    angle = np.arccos(np.clip((np.trace(R_err, axis1=-2, axis2=-1) - 1) / 2, -1, 1))
    assert angle.max() < 1e-3, angle.max()
    if not tilted:  # rotation about the camera z axis: R13, R23, R31, R32, R33 constant
        assert fk.rotation_varying_.tolist() == [True, True, False, True, True] + [False] * 4
    with pytest.raises(ValueError, match="rotation_outputs"):
        ForwardKinematicsGP("RR", rotation_outputs="six")


def _monomials(q: np.ndarray, joint_types: str) -> np.ndarray:
    """Explicit feature map of k_l with unit hyperparameters: the Kronecker product of
    ``[1, cos q_b, sin q_b]`` (revolute) and ``[1, q_b]`` (prismatic) over the joints."""
    rows = []
    for qi in q:
        phi = np.ones(1)
        for b, t in enumerate(joint_types):
            f = [1.0, np.cos(qi[b]), np.sin(qi[b])] if t == "R" else [1.0, qi[b]]
            phi = np.kron(phi, f)
        rows.append(phi)
    return np.array(rows)


@pytest.mark.parametrize("joint_types", ["RR", "RP", "RRR"])
def test_design_subset_is_greedy_determinant_maximisation(joint_types):
    """Each pick after the first maximises det(Phi_S Phi_S^T) over the remaining rows (greedy
    D-optimal design), with Phi the explicit monomial features written above, each row scaled
    to unit length (the prior correlation of k_l)."""
    q = np.random.default_rng(1).uniform(-2, 2, (60, len(joint_types)))
    phi = _monomials(q, joint_types)
    k = min(8, phi.shape[1])  # beyond the rank every determinant is 0
    idx = design_subset(q, joint_types, k)
    assert idx.shape == (k,) and len(set(idx.tolist())) == k
    phi /= np.linalg.norm(phi, axis=1, keepdims=True)
    for j in range(1, k):
        chosen = list(idx[:j])
        dets = np.full(len(q), -np.inf)
        for i in set(range(len(q))) - set(chosen):
            s = phi[chosen + [i]]
            dets[i] = np.linalg.slogdet(s @ s.T)[1]
        assert dets[idx[j]] >= dets.max() - 1e-8, f"pick {j}"


def test_design_subset_skips_repeated_configurations():
    """A trajectory dwelling at one configuration: one revolute joint spans [1, cos, sin], so
    3 distinct angles are picked, never two copies of the same one."""
    q = np.concatenate([np.zeros((50, 1)), [[0.0], [1.0], [2.0], [-1.5], [3.0]]])
    idx = design_subset(q, "R", 3)
    assert len({float(q[i, 0]) for i in idx}) == 3
    with pytest.raises(ValueError, match=r"columns \[0\]"):
        design_subset(np.array([[np.nan], [1.0]]), "R", 1)
    with pytest.raises(ValueError, match=r"k must be in \[1, 55\]"):
        design_subset(q, "R", 56)
    with pytest.raises(ValueError, match=r"shape \(N >= 1, 2\)"):
        design_subset(q, "RR", 2)

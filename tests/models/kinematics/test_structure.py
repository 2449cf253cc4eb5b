"""Structure identification (thesis 2.3-2.4) on noiseless synthetic chains with known answers.

Truth comes from a numpy DH chain (:mod:`mcpilco.models.kinematics.synthetic`) that knows
which markers are adjacent and through which joint; yaw-pitch-roll is checked against scipy.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mcpilco.models.kinematics import (
    classify_all_triplets,
    classify_triplet,
    identify_structure,
    matrix_to_ypr,
    prismatic_test,
    random_chain,
    relative_poses,
    sum_of_sinusoids,
    ypr_to_matrix,
)

EXACT = dict(xi_t=1e-6, xi_o=1e-6)  # noiseless data: the tests become exact feasibility checks


def _data(chain, T=50, seed=0):
    rng = np.random.default_rng(seed)
    amp = np.where(np.array(list(chain.joint_types)) == "R", 3 * np.pi, 1.5)
    q = sum_of_sinusoids(np.linspace(0.0, 10.0, T), chain.n_joints, rng, amplitude=amp)
    return chain.marker_poses(q), q


def test_ypr_matches_scipy_intrinsic_zyx():
    rng = np.random.default_rng(0)
    o = np.column_stack(
        [rng.uniform(-np.pi, np.pi, 20), rng.uniform(-1.5, 1.5, 20), rng.uniform(-np.pi, np.pi, 20)]
    )
    R_ref = Rotation.from_euler("ZYX", o).as_matrix()  # Rz(gamma) Ry(beta) Rx(alpha)
    np.testing.assert_allclose(ypr_to_matrix(o), R_ref, atol=1e-12)
    np.testing.assert_allclose(matrix_to_ypr(R_ref), o, atol=1e-10)


def test_prismatic_pair_passes_and_recovers_the_axis():
    chain = random_chain(1, np.random.default_rng(1), joint_types="P")
    P, q = _data(chain)
    res = classify_triplet(P[:, 0], P[:, 1], q[:, 0], **EXACT, evaluate_all=True)
    assert res.prismatic and res.joint_type == "P"
    assert res.prismatic_rms < 1e-9 and res.orientation_std < 1e-9
    # z = third column of R^{M_0}_{L_0}: the joint axis z_0 seen from marker 0
    l_ab, R_ab = relative_poses(P[:, 0], P[:, 1])
    _, _, b = prismatic_test(l_ab, R_ab, q[:, 0])
    z_true = chain.markers[0, :3, :3].T @ np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(b[3:], z_true, atol=1e-9)


def test_revolute_pair_passes_linear_and_nonlinear_tests():
    chain = random_chain(1, np.random.default_rng(2), joint_types="R")
    P, q = _data(chain)
    res = classify_triplet(P[:, 0], P[:, 1], q[:, 0], **EXACT)
    assert not res.prismatic
    assert res.revolute_linear and res.revolute_nonlinear and res.joint_type == "R"
    assert res.revolute_angle_rms < 1e-9


def test_revolute_pair_with_the_wrong_joint_signal_fails():
    chain = random_chain(2, np.random.default_rng(3), joint_types="RR")
    P, q = _data(chain)
    res = classify_triplet(P[:, 0], P[:, 1], q[:, 1], **EXACT)  # markers 0-1 move with q_0
    assert res.revolute_linear  # the linear test does not see q (a necessary condition only)
    assert res.revolute_nonlinear is False and res.joint_type is None


@pytest.mark.parametrize("types", ["RR", "PR", "RP", "PP"])
def test_non_adjacent_pair_fails_every_joint(types):
    chain = random_chain(2, np.random.default_rng(4), joint_types=types)
    P, q = _data(chain)
    for k in range(2):
        res = classify_triplet(P[:, 0], P[:, 2], q[:, k], **EXACT, evaluate_all=True)
        assert res.joint_type is None, (types, k, res)


def test_all_triplets_of_a_chain_are_classified_correctly():
    chain = random_chain(4, np.random.default_rng(5), joint_types="RPRR")
    P, q = _data(chain)
    results = classify_all_triplets(P, q, **EXACT, max_nfev=40)
    assert len(results) == 10 * 4  # C(5, 2) pairs x 4 joint signals
    for r in results:
        connected = r.marker_b == r.marker_a + 1 and r.joint == r.marker_a
        assert r.joint_type == (chain.joint_types[r.joint] if connected else None), r


@pytest.mark.parametrize(("n", "seed"), [(4, 10), (6, 11)])
def test_algorithm_recovers_a_shuffled_chain(n, seed):
    rng = np.random.default_rng(seed)
    chain = random_chain(n, rng)
    P, q = _data(chain, seed=seed)
    mperm, qperm = rng.permutation(n + 1), rng.permutation(n)
    s = identify_structure(P[:, mperm], q[:, qperm], **EXACT)
    assert s.complete
    assert [int(mperm[m]) for m in s.markers] == list(range(n + 1))
    assert [int(qperm[k]) for k in s.joints] == list(range(n))
    assert s.joint_types == chain.joint_types


def test_algorithm_with_thesis_thresholds_on_noisy_data():
    rng = np.random.default_rng(7)
    chain = random_chain(3, rng, joint_types="RPR")
    P, q = _data(chain, T=300, seed=7)
    P = P + rng.normal(0, 1e-3, P.shape) * np.array([1, 1, 1, 5, 5, 5])  # 1 mm, 5 mrad
    s = identify_structure(P, q, selection="first")  # xi_t = 0.02 m, xi_o = 0.1 rad
    assert s.complete and s.markers == (0, 1, 2, 3) and s.joints == (0, 1, 2)
    assert s.joint_types == "RPR"


def test_missing_marker_frames_raise_or_are_dropped_with_a_count():
    chain = random_chain(2, np.random.default_rng(8), joint_types="RR")
    P, q = _data(chain)
    P[[3, 7, 9], 2] = np.nan  # marker 2 not detected in three frames
    with pytest.raises(ValueError, match=r"3 of 50 frames contain NaN.*missing markers \[2\]"):
        identify_structure(P, q, **EXACT)
    with pytest.warns(UserWarning, match="dropped 3 of 50 frames"):
        s = identify_structure(P, q, **EXACT, nan_policy="drop")
    assert s.complete and s.n_dropped_frames == 3 and s.markers == (0, 1, 2)


def test_pairwise_nan_policy_recovers_a_chain_whose_markers_come_and_go():
    """Each moving marker of a shuffled 5-joint chain is missing in 65 % of the frames
    (independently): fewer than 3 frames show all six, so dropping frames fails, while testing
    each pair on the frames that show both markers recovers the structure exactly."""
    rng = np.random.default_rng(12)
    chain = random_chain(5, rng)
    P, q = _data(chain, T=200, seed=12)
    P[:, 1:][rng.random((200, 5)) < 0.65] = np.nan  # the base marker stays visible
    assert np.isfinite(P).all(axis=(1, 2)).sum() < 3
    mperm, qperm = rng.permutation(6), rng.permutation(5)
    P, q = P[:, mperm], q[:, qperm]
    with pytest.raises(ValueError, match="at least 3 complete frames"):
        with pytest.warns(UserWarning, match="dropped"):
            identify_structure(P, q, **EXACT, nan_policy="drop")
    s = identify_structure(P, q, **EXACT, nan_policy="pairwise")
    assert s.complete and s.n_dropped_frames == 0
    assert [int(mperm[m]) for m in s.markers] == list(range(6))
    assert [int(qperm[k]) for k in s.joints] == list(range(5))
    assert s.joint_types == chain.joint_types
    res = classify_all_triplets(P, q, **EXACT, nan_policy="pairwise")
    assert len(res) == 15 * 5  # every pair is seen together in >= 10 frames here
    for r in res:
        a, b, k = int(mperm[r.marker_a]), int(mperm[r.marker_b]), int(qperm[r.joint])
        connected = abs(a - b) == 1 and k == min(a, b)
        assert r.joint_type == (chain.joint_types[k] if connected else None)


@pytest.mark.parametrize(
    ("poses_shape", "q_shape", "match"),
    [((10, 3, 5), (10, 2), "marker_poses must have shape"), ((10, 3, 6), (9, 2), "T = 10")],
)
def test_bad_shapes_raise(poses_shape, q_shape, match):
    with pytest.raises(ValueError, match=match):
        identify_structure(np.zeros(poses_shape), np.zeros(q_shape))


def test_inf_raises():
    P, q = np.zeros((10, 3, 6)), np.zeros((10, 2))
    P[0, 0, 0] = np.inf
    with pytest.raises(ValueError, match="inf"):
        identify_structure(P, q)

"""``mcpilco/MarkerCamera-v0``: geometry against a numpy DH chain, shuffling, noise, and the
structure-identification pipeline on the env's data (the generic contract is in
test_env_contract.py)."""

import gymnasium as gym
import numpy as np
import pytest

import mcpilco.envs  # noqa: F401  (registers the ids)
from mcpilco.envs.arms import ur10
from mcpilco.envs.marker_camera import MarkerCameraEnv, ypr_to_matrix
from mcpilco.models.kinematics import identify_structure
from mcpilco.models.kinematics.synthetic import SyntheticChain, homogeneous

NOISELESS = dict(position_noise=0.0, angle_noise=0.0, encoder_noise=0.0, time_offset=0.0)


def _numpy_chain(env: MarkerCameraEnv) -> SyntheticChain:
    """The env's arm and markers as a numpy DH chain (independent of MuJoCo)."""
    arm = env.arm
    dh = np.array([[j.a, j.alpha, j.d, j.theta] for j in arm.joints])
    camera = homogeneous(env.camera_R.T, -env.camera_R.T @ env.camera_position)  # c <- world
    base = homogeneous(np.eye(3), arm.base_pos)  # identity base_quat for these arms
    pos, R = env.marker_placements()
    sites = homogeneous(R, pos)  # marker j in body link{j} (marker 0 in the world)
    markers = np.empty_like(sites)
    markers[0] = np.linalg.inv(base) @ sites[0]
    for j, joint in enumerate(arm.joints, start=1):
        # {j} = B_j Tx(a_j) Rx(alpha_j)  =>  T^{j}_{M_j} = (Tx Rx)^-1 T^{B_j}_{M_j}
        ca, sa = np.cos(joint.alpha), np.sin(joint.alpha)
        tx_rx = homogeneous([[1, 0, 0], [0, ca, -sa], [0, sa, ca]], [joint.a, 0, 0])
        markers[j] = np.linalg.inv(tx_rx) @ sites[j]
    return SyntheticChain(arm.joint_types, dh, camera @ base, markers)


@pytest.mark.parametrize("kwargs", [{}, {"arm": "random", "joint_types": "RPRRP", "arm_seed": 3}])
def test_marker_poses_match_a_numpy_dh_chain(kwargs):
    env = MarkerCameraEnv(**kwargs, **NOISELESS)
    env.reset(seed=1)
    chain = _numpy_chain(env)
    rng = np.random.default_rng(0)
    for _ in range(5):
        q = rng.uniform(env.q_low.clip(-3, 3), env.q_high.clip(-3, 3))
        mj, ref = env.marker_poses(q), chain.marker_poses(q[None])[0]
        np.testing.assert_allclose(mj[:, :3], ref[:, :3], atol=1e-9)
        np.testing.assert_allclose(ypr_to_matrix(mj[:, 3:]), ypr_to_matrix(ref[:, 3:]), atol=1e-9)


def test_registered_and_observation_layout_with_shuffling():
    env = gym.make("mcpilco/MarkerCamera-v0", **NOISELESS)
    obs, info = env.reset(seed=4)
    n = 6
    assert env.spec.max_episode_steps == 100
    assert obs.shape == (6 * (n + 1) + n + 6,) and obs.dtype == np.float64
    perm_m, perm_q = info["marker_permutation"], info["joint_permutation"]
    assert sorted(perm_m) == list(range(n + 1)) and sorted(perm_q) == list(range(n))
    np.testing.assert_allclose(obs[: 6 * (n + 1)].reshape(n + 1, 6), info["marker_poses"][perm_m])
    np.testing.assert_allclose(obs[6 * (n + 1) : 6 * (n + 1) + n], info["q"][perm_q])
    assert perm_m[info["ee_slot"]] == n
    # action slot s moves chain joint perm_q[s] by max_increment
    q0 = info["q"].copy()
    action = np.zeros(n, dtype=np.float32)
    action[2] = 1.0
    _, reward, _, _, info = env.step(action)
    moved = np.nonzero(np.abs(info["q"] - q0) > 1e-12)[0]
    assert moved.tolist() == [perm_q[2]]
    assert np.isclose(info["q"][perm_q[2]] - q0[perm_q[2]], 0.05)
    assert reward == -info["cost"]


def test_cost_is_zero_at_the_target_configuration():
    env = MarkerCameraEnv(**NOISELESS)
    _, info = env.reset(seed=2)
    _, info = env.reset(seed=2, options={"q": info["target_q"]})
    assert info["cost"] < 1e-7 and info["position_error"] < 1e-9


def test_noise_magnitude_is_apriltag_like():
    env = MarkerCameraEnv(time_offset=0.0)
    env.reset(seed=0)
    pos_err, ang_err = [], []
    for _ in range(40):
        obs, _, _, _, info = env.step(np.zeros(6, dtype=np.float32))
        meas = obs[:42].reshape(7, 6)
        true = info["marker_poses"][info["marker_permutation"]]
        pos_err.append(meas[:, :3] - true[:, :3])
        R_err = np.swapaxes(ypr_to_matrix(true[:, 3:]), -1, -2) @ ypr_to_matrix(meas[:, 3:])
        ang_err.append(np.arccos(np.clip((np.trace(R_err, axis1=-2, axis2=-1) - 1) / 2, -1, 1)))
    pos_std = np.std(np.concatenate(pos_err))
    assert 0.5e-3 < pos_std < 6e-3, pos_std  # 1-5 mm at ~2 m
    assert 0.005 < np.sqrt(np.mean(np.concatenate(ang_err) ** 2)) < 0.06  # ~0.01-0.03 rad


def test_outliers_appear_with_their_probability():
    env = MarkerCameraEnv(outlier_prob=0.5, time_offset=0.0)
    env.reset(seed=0)
    obs, _, _, _, info = env.step(np.zeros(6, dtype=np.float32))
    err = np.linalg.norm(obs[:42].reshape(7, 6)[:, :3] - info["marker_poses"][
        info["marker_permutation"]][:, :3], axis=1)  # fmt: skip
    assert (err > 0.03).any()


def test_structure_identification_recovers_the_shuffled_ur10():
    env = MarkerCameraEnv(max_increment=0.4, **NOISELESS)
    obs, info = env.reset(seed=5)
    rng = np.random.default_rng(5)
    rows = [obs]
    for _ in range(40):
        rows.append(env.step(rng.uniform(-1, 1, 6).astype(np.float32))[0])
    rows = np.array(rows)
    poses, q = rows[:, :42].reshape(-1, 7, 6), rows[:, 42:48]
    s = identify_structure(poses, q, xi_t=1e-6, xi_o=1e-6)
    assert s.complete and s.joint_types == ur10().joint_types
    assert info["marker_permutation"][list(s.markers)].tolist() == list(range(7))
    assert info["joint_permutation"][list(s.joints)].tolist() == list(range(6))


def test_bad_arguments_raise():
    with pytest.raises(ValueError, match="arm must be"):
        MarkerCameraEnv(arm="nope")
    with pytest.raises(ValueError, match="start_centre must be 6"):
        MarkerCameraEnv(start_centre=[0.0, 1.0])
    with pytest.raises(ValueError, match="success_tolerance"):
        MarkerCameraEnv(success_tolerance=(0.01, 0.0))
    with pytest.raises(ValueError, match="marker_seed"):
        MarkerCameraEnv(marker_seed=-1)
    with pytest.raises(ValueError, match="outlier_prob"):
        MarkerCameraEnv(outlier_prob=2.0)
    with pytest.raises(ValueError, match="position_noise"):
        MarkerCameraEnv(position_noise=-1.0)


def test_noise_std_follows_distance_and_incidence_and_matches_the_draws():
    env = MarkerCameraEnv(time_offset=0.0, encoder_noise=0.0)
    env.reset(seed=3)
    q = env.q.copy()
    # independent geometry: the numpy DH chain gives d and the marker normal in the camera
    T = _numpy_chain(env).marker_transforms(q[None])[0]
    d = np.linalg.norm(T[:, :3, 3], axis=1)
    f = (d / 2.0) ** 2 * (2.0 - np.abs(T[:, 2, 2]))
    pos_std, ang_std = env.measurement_noise_std(q)
    np.testing.assert_allclose(pos_std, 0.002 * f, rtol=1e-9)
    np.testing.assert_allclose(ang_std, 0.007 * f, rtol=1e-9)
    # the draws: standing still, 400 frames; per-marker std of the 3 position errors
    errs, true = [], env.marker_poses(q)
    for _ in range(400):
        obs, *_ = env.step(np.zeros(6, dtype=np.float32))
        meas = np.empty((7, 6))
        meas[env.marker_permutation] = obs[:42].reshape(7, 6)
        errs.append(meas[:, :3] - true[:, :3])
    std = np.sqrt((np.array(errs) ** 2).mean(axis=(0, 2)))
    np.testing.assert_allclose(std, pos_std, rtol=0.12)  # 1200 draws each: ~2 % sampling error


def test_visibility_cone_hides_exactly_the_markers_turned_away_and_keeps_the_draws():
    """Independent geometry (numpy DH chain): a marker is seen iff its normal is within the
    cone of its line of sight to the camera; the seen rows equal those of the same env without
    a cone (same noise draws), the hidden ones are NaN in their observed slots."""
    kw = dict(position_noise=0.002, angle_noise=0.007)
    env, ref = MarkerCameraEnv(visibility_cone=70.0, **kw), MarkerCameraEnv(**kw)
    seen_any, hidden_any = False, False
    for seed in range(4):
        obs, info = env.reset(seed=seed)
        obs_ref, _ = ref.reset(seed=seed)
        T = _numpy_chain(env).marker_transforms(info["q"][None])[0]  # chain order, camera frame
        los = -T[:, :3, 3] / np.linalg.norm(T[:, :3, 3], axis=1, keepdims=True)
        cos_phi = np.einsum("mi,mi->m", T[:, :3, 2], los)
        np.testing.assert_allclose(env.facing_cosines(info["q"]), cos_phi, atol=1e-9)
        expected = cos_phi >= np.cos(np.radians(70.0))
        np.testing.assert_array_equal(info["detected"], expected)
        rows = obs[:42].reshape(7, 6)[np.argsort(info["marker_permutation"])]  # chain order
        rows_ref = obs_ref[:42].reshape(7, 6)[np.argsort(info["marker_permutation"])]
        assert np.isnan(rows[~expected]).all()
        np.testing.assert_array_equal(rows[expected], rows_ref[expected])
        np.testing.assert_array_equal(obs[42:], obs_ref[42:])  # joints and target unchanged
        seen_any |= bool(expected.any())
        hidden_any |= bool((~expected).any())
    assert seen_any and hidden_any  # random placements: some markers face away
    with pytest.raises(ValueError, match="visibility_cone"):
        MarkerCameraEnv(visibility_cone=0.0)
    with pytest.raises(ValueError, match="ideal"):
        MarkerCameraEnv(measurement="aruco", visibility_cone=60.0)


def _placements(env):
    pos, R = env.unwrapped.marker_placements()
    return pos.copy(), R.copy()


def test_marker_seed_attaches_the_markers_once_whatever_the_reset_seeds():
    """With ``marker_seed`` the placements and permutations are the same at every reset and in
    every env made with that seed; without it each reset draws new ones."""
    a = MarkerCameraEnv(marker_seed=7, marker_facing_cone=40.0, **NOISELESS)
    b = MarkerCameraEnv(marker_seed=7, marker_facing_cone=40.0, **NOISELESS)
    _, info_a = a.reset(seed=1)
    first = _placements(a)
    for seed in (2, 3):
        _, info = a.reset(seed=seed)
        np.testing.assert_array_equal(info["joint_permutation"], info_a["joint_permutation"])
        for x, y in zip(_placements(a), first, strict=True):
            np.testing.assert_array_equal(x, y)
    _, info_b = b.reset(seed=99)
    np.testing.assert_array_equal(info_b["marker_permutation"], info_a["marker_permutation"])
    for x, y in zip(_placements(b), first, strict=True):
        np.testing.assert_array_equal(x, y)
    other = MarkerCameraEnv(marker_seed=8, marker_facing_cone=40.0, **NOISELESS)
    other.reset(seed=1)
    assert not np.allclose(_placements(other)[0], first[0])
    free = MarkerCameraEnv(**NOISELESS)
    free.reset(seed=1)
    p1 = _placements(free)[0]
    free.reset(seed=2)
    assert not np.allclose(_placements(free)[0], p1)
    # facing the camera at start_centre (the origin here): within the 40 deg cone
    assert np.all(a.facing_cosines(np.zeros(6)) >= np.cos(np.radians(40.0)) - 1e-9)


def test_reach_env_draws_around_its_home_and_flags_success_at_the_target():
    """``mcpilco/MarkerCameraReach-v0``: 20-step episodes, starts and targets within 1 rad of
    the camera-facing home, every marker seen; ``info["success"]`` is True exactly when the
    end marker is within 1 cm and 0.05 rad, checked against the noise-free marker poses."""
    env = gym.make("mcpilco/MarkerCameraReach-v0")
    home = np.array([0.0, -np.pi / 2, np.pi / 2, 0.0, np.pi / 2, 0.0])
    assert env.spec.max_episode_steps == 20
    for seed in range(20):
        obs, info = env.reset(seed=seed)
        assert np.all(np.abs(info["q"] - home) <= 1.0 + 1e-12)
        assert np.all(np.abs(info["target_q"] - home) <= 1.0 + 1e-12)
        assert np.isfinite(obs).all()
        reached = info["position_error"] <= 0.01 and info["orientation_error"] <= 0.05
        assert info["success"] == reached
    # drive to the target: increments of at most 0.2 rad, so 10 steps cover the 2 rad box
    _, info = env.reset(seed=5)
    target, steps = info["target_q"], 0
    while not info["success"]:
        _, _, _, truncated, info = env.step(np.clip((target - info["q"]) / 0.2, -1, 1))
        steps += 1
        assert steps <= 10 and not truncated
    ee, goal = info["marker_poses"][-1], env.unwrapped.target_pose
    assert np.linalg.norm(ee[:3] - goal[:3]) <= 0.01
    # 0.06 rad off on the last joint: the marker turns by 0.06 rad and moves by less than
    # 1 cm (it sits within 0.1 m of the axis), within the position tolerance only
    _, info = env.reset(seed=5, options={"q": target + np.array([0, 0, 0, 0, 0, 0.06])})
    assert info["position_error"] < 0.01 and info["orientation_error"] > 0.05
    assert not info["success"]

"""UR10/SCARA tracking envs and the data-collection API: physics and contract checks."""

from __future__ import annotations

import math

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import mcpilco.envs  # noqa: F401  (registers the ids)
from mcpilco.envs.arm_builder import dh_forward_kinematics
from mcpilco.envs.arm_data import (
    PiecewiseTrajectory,
    QuinticMove,
    circle_trajectory,
    make_program,
    random_waypoints,
    rollout,
)
from mcpilco.envs.arm_env import SCARA_HOME, UR10_HOME, SCARAEnv, SumOfSinusoids, UR10Env


def hold(q: np.ndarray) -> SumOfSinusoids:
    n = len(q)
    zeros = np.zeros((n, 1))
    return SumOfSinusoids(np.asarray(q, dtype=float), zeros, zeros, zeros)


@pytest.mark.parametrize("env_id", ["mcpilco/UR10-v0", "mcpilco/SCARA-v0"])
def test_check_env_gymnasium_and_sb3(env_id: str) -> None:
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gym.make(env_id)
    assert env.spec.max_episode_steps == 1250
    with pytest.warns(UserWarning):  # unbounded Box observation (like gymnasium's MuJoCo envs)
        check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(env.unwrapped, warn=False)


def test_same_seed_same_trajectory() -> None:
    def run(seed: int) -> tuple[np.ndarray, np.ndarray]:
        env = UR10Env()
        obs, _ = env.reset(seed=seed)
        rng = np.random.default_rng(5)
        obs_log, cur_log = [obs], []
        for _ in range(40):
            obs, _, _, _, info = env.step(rng.uniform(-1, 1, 6))
            obs_log.append(obs)
            cur_log.append(info["current"])
        return np.array(obs_log), np.array(cur_log)

    a, b, c = run(3), run(3), run(4)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert not np.allclose(a[0], c[0])


def test_currents_equal_torque_over_keq_and_qdd_is_backward_difference() -> None:
    env = SCARAEnv(current_noise_std=0.0)
    env.reset(seed=0)
    prev = None
    for _ in range(30):
        _, _, _, _, info = env.step(np.full(4, 0.3))
        keq = np.array([j.torque_constant * j.gear for j in env.arm.joints])
        np.testing.assert_allclose(info["current"], info["tau"] / keq, rtol=1e-12)
        if np.all(np.abs(env.data.ctrl) < env.torque_limit):  # no saturation: i_cmd = i
            np.testing.assert_allclose(info["current_cmd"], info["current"], rtol=1e-9)
        if prev is not None:
            np.testing.assert_allclose(info["qdd"], (info["qd"] - prev) / 0.008, rtol=1e-12)
        prev = info["qd"]
    assert env.dt == 0.008 and env.model.opt.timestep == pytest.approx(0.002)


def test_current_noise_has_the_documented_std() -> None:
    env = UR10Env()
    env.reset(seed=0, options={"reference": hold(np.array(UR10_HOME))})
    resid = []
    for _ in range(400):
        _, _, _, _, info = env.step(np.zeros(6))
        resid.append(info["current"] - info["tau"] / env.current_gain)
    assert np.std(resid) == pytest.approx(0.17, rel=0.1)


def test_gravity_feedforward_is_the_model_gravity() -> None:
    env = UR10Env()
    q = np.array([0.3, -1.0, 1.2, -0.4, 0.7, 0.1])
    d = mujoco.MjData(env.model)
    d.qpos[:] = q
    mujoco.mj_forward(env.model, d)  # qvel = 0: qfrc_bias = g(q)
    np.testing.assert_allclose(env.gravity_torque(q), d.qfrc_bias, atol=1e-10)
    # shoulder holding the stretched arm: about (12.7*0.23 + 4.27*0.85 + 4.4*1.18) g [N m]
    g = env.gravity_torque(np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0]))
    assert 80 < abs(g[1]) < 160


@pytest.mark.parametrize("fraction, moves", [(0.8, False), (1.3, True)])
def test_stiction_holds_the_joint_below_the_static_level(fraction: float, moves: bool) -> None:
    # SCARA joint 1 has a vertical axis (no gravity torque); controller gains off, so the
    # only torque on it is the agent's correction
    env = SCARAEnv(kp=0.0, kd=0.0, current_noise_std=0.0)
    q0 = np.array(SCARA_HOME)
    env.reset(seed=0, options={"reference": hold(q0)})
    f_s = env.arm.joints[0].static_friction
    action = np.zeros(4)
    action[0] = fraction * f_s / env.action_scale[0]
    for _ in range(125):  # 1 s
        obs, *_ = env.step(action)
    moved = abs(obs[0] - q0[0])
    if moves:
        assert moved > 1e-2
    else:
        assert moved < 1e-5


def test_external_push_sets_contact_and_changes_currents() -> None:
    env = UR10Env(current_noise_std=0.0)
    env.reset(seed=0, options={"reference": hold(np.array(UR10_HOME))})
    for _ in range(20):
        _, _, _, _, info = env.step(np.zeros(6))
    before = info["current"].copy()
    assert info["contact"] == 0
    env.apply_external_force(link=3, force=(0.0, 0.0, -60.0), duration=0.2)
    for _ in range(20):
        _, _, _, _, info = env.step(np.zeros(6))
    assert info["contact"] == 1 and info["f_ext"][2] == -60.0
    assert np.max(np.abs(info["current"] - before)) > 1.0  # the controller fights the push
    for _ in range(10):
        _, _, _, _, info = env.step(np.zeros(6))
    assert info["contact"] == 0


def test_bad_actions_are_rejected() -> None:
    env = SCARAEnv()
    env.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(3))
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([np.nan, 0, 0, 0]))


def test_waypoints_stay_in_bounds_and_speed_limits() -> None:
    env = UR10Env()
    traj = random_waypoints(env.arm, np.random.default_rng(0), UR10_HOME, n_waypoints=4)
    t = np.linspace(0.0, traj.duration, 2000)
    q, qd = map(np.array, zip(*[traj(s)[:2] for s in t], strict=True))
    assert np.all(np.abs(q[:, 1:]) <= math.pi)
    assert np.all(np.abs(qd) <= 0.6 * env.arm.joint_array("velocity_limit") + 1e-9)
    np.testing.assert_allclose(traj(0.0)[0], UR10_HOME)
    with pytest.raises(ValueError, match="starts at"):
        PiecewiseTrajectory(
            [QuinticMove(np.zeros(2), np.ones(2), 1.0), QuinticMove(np.zeros(2), np.zeros(2), 1.0)]
        )


def test_circle_reference_is_a_30cm_circle_at_30mm_per_s() -> None:
    env = UR10Env()
    traj = circle_trajectory(env.arm, UR10_HOME, sample_time=0.25)
    assert traj.duration == pytest.approx(2 * math.pi * 0.3 / 0.03, abs=0.25)
    pts = np.array([dh_forward_kinematics(env.arm, traj(s)[0])[:3, 3] for s in traj.t])
    centre = pts.mean(axis=0)
    np.testing.assert_allclose(np.linalg.norm(pts - centre, axis=1), 0.3, atol=2e-3)
    np.testing.assert_allclose(pts[:, 2], pts[0, 2], atol=1e-6)  # horizontal
    speed = np.linalg.norm(np.diff(pts, axis=0), axis=1) / 0.25
    np.testing.assert_allclose(speed, 0.03, rtol=0.01)


def test_rollout_logs_the_schema_arrays() -> None:
    env = SCARAEnv()
    ref = make_program(env.arm, "exploration", np.random.default_rng(0), SCARA_HOME, 1.0)
    out = rollout(env, ref, seed=0, duration=0.4)
    assert out["t"].shape == (51,) and out["q"].shape == (51, 4)
    np.testing.assert_allclose(np.diff(out["t"]), 0.008, atol=1e-12)
    for key in ("qd", "qdd", "tau", "i", "i_cmd", "e_q", "e_qd"):
        assert out[key].shape == (51, 4) and np.all(np.isfinite(out[key]))
    assert out["contact"].dtype == np.int64


def test_known_model_feedforward_removes_the_lag_within_the_bounds() -> None:
    """Physics: with the model's own inverse dynamics as feed-forward (held 40 ms, as the
    tracking task's agent holds its correction) the PD loop no longer lags the reference;
    with the default correction bounds the heavy joints saturate and keep part of it."""
    ref = SumOfSinusoids(
        np.asarray(UR10_HOME), np.full((6, 1), 0.3), np.array([[6.0], [5.4], [6.6], [7.2],
        [7.8], [8.4]]), np.zeros((6, 1)), duration=4.0,
    )  # fmt: skip

    def tracking_rms(env: UR10Env, feedforward: bool) -> np.ndarray:
        env.reset(seed=0, options={"reference": ref})
        errors, a = [], np.zeros(6)
        for k in range(250):
            if feedforward and k % 5 == 0:
                a = env.feedforward_action(env.time, 5 * env.sample_time)
            _, _, _, _, info = env.step(a)
            errors.append(info["e_q"])
        return np.sqrt(np.mean(np.square(errors), axis=0))

    wide = UR10Env(action_scale=(150.0, 150.0, 75.0, 30.0, 30.0, 30.0))
    alone = tracking_rms(wide, False)
    assert np.all(tracking_rms(wide, True) < 0.25 * alone)
    bounded = UR10Env()
    np.testing.assert_allclose(tracking_rms(bounded, False), alone, rtol=1e-9)
    ratio = tracking_rms(bounded, True) / alone
    assert np.all(ratio < 0.5) and ratio[2] > 0.3  # q3 needs ~2.7x its 25 N m bound

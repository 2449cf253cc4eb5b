"""The dm-control cartpole/swingup adapter: control period, angle convention, task scoring."""

import numpy as np
import pytest

from mcpilco.envs.cartpole import CartpoleSwingUpEnv
from mcpilco.envs.dmc_cartpole import DMCCartpoleSwingUpEnv


@pytest.fixture(scope="module")
def env():
    e = DMCCartpoleSwingUpEnv(obs_noise_std=0.0)
    yield e
    e.close()


def test_action_repeat_gives_50_ms_control_period(env):
    env.reset(seed=0)
    assert env.physics.timestep() == pytest.approx(0.01)
    assert env.action_repeat == 5 and env.dt == pytest.approx(0.05)
    t0 = env.physics.data.time
    for k in range(1, 4):
        env.step(np.array([0.2]))
        assert env.physics.data.time - t0 == pytest.approx(0.05 * k)


def test_angle_convention_from_pole_geometry(env):
    """theta = 0 hangs down, positive theta puts the pole towards +x, as in the MuJoCo env.

    dm-control's pole is a 1 m capsule from the hinge (at height 1 on the cart); its centre
    must sit at (x + 0.5 sin(theta), 1 - 0.5 cos(theta)) in the adapter's coordinates.
    """
    env.reset(seed=3)
    rng = np.random.default_rng(0)
    for _ in range(30):
        obs, *_, info = env.step(rng.uniform(-1, 1, size=1))
        x, theta = info["state"][0], info["state"][2]
        centre = env.physics.named.data.geom_xpos["pole_1"]
        np.testing.assert_allclose(
            [centre[0], centre[2]], [x + 0.5 * np.sin(theta), 1 - 0.5 * np.cos(theta)], atol=1e-9
        )
        np.testing.assert_array_equal(obs, info["state"])  # obs_noise_std = 0


def test_start_hanging_down_near_zero(env):
    obs, info = env.reset(seed=1)
    assert np.all(np.abs(info["state"]) < 0.05)
    assert not info["upright"] and info["cost"] > 0.99


def test_same_push_same_signs_as_mujoco_env():
    """From rest hanging down, pushing +x accelerates the cart to +x and swings theta < 0."""
    for e in (DMCCartpoleSwingUpEnv(obs_noise_std=0.0), CartpoleSwingUpEnv(obs_noise_std=0.0)):
        e.reset(seed=0)
        state = e.step(np.array([1.0]))[4]["state"]
        assert state[1] > 0.1 and state[3] < -0.1, type(e).__name__


def test_upright_hold_is_a_success(env):
    env.reset(seed=0)
    with env.physics.reset_context():
        env.physics.named.data.qpos["slider"] = 0.1
        env.physics.named.data.qpos["hinge_1"] = 0.0  # dm-control upright
        env.physics.named.data.qvel[:] = 0.0
    for t in range(1, 61):
        _, reward, terminated, truncated, info = env.step(np.array([0.0]))
        assert info["upright"] and not terminated and truncated == (t == 60)
    assert info["success"] is True
    assert abs(abs(info["state"][2]) - np.pi) < 1e-6


def test_seeding():
    a, b = DMCCartpoleSwingUpEnv(), DMCCartpoleSwingUpEnv()
    oa, ia = a.reset(seed=7)
    ob, ib = b.reset(seed=7)
    np.testing.assert_array_equal(oa, ob)
    np.testing.assert_array_equal(ia["state"], ib["state"])
    assert not np.array_equal(a.reset()[1]["state"], ia["state"])  # unseeded: stream goes on
    assert not np.array_equal(b.reset(seed=8)[1]["state"], ia["state"])


def test_bad_control_dt():
    with pytest.raises(ValueError, match="multiple"):
        DMCCartpoleSwingUpEnv(control_dt=0.025)

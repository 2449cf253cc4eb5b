"""Contract test over every environment that ``import mcpilco.envs`` registers: the
``mcpilco/*`` envs and the dm-control suite's ``dm_control/<domain>-<task>-v0``."""

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import mcpilco.envs  # noqa: F401  (registers the ids)
from tests.conftest import run_python

ENV_IDS = sorted(i for i in gym.registry if i.startswith("mcpilco/"))
DMC_IDS = sorted(i for i in gym.registry if i.startswith("dm_control/"))
# dm-control tasks that build their scene through OpenGL (quadruped/escape uploads its terrain)
DMC_NEEDS_GL = {"dm_control/quadruped-escape-v0"}


def test_cartpole_ids_registered():
    assert {"mcpilco/CartpoleSwingUp-v0", "mcpilco/DMCCartpoleSwingUp-v0"} <= set(ENV_IDS)
    assert gym.spec("mcpilco/CartpoleSwingUp-v0").max_episode_steps == 60
    assert gym.spec("mcpilco/DMCCartpoleSwingUp-v0").max_episode_steps == 60


def _is_swingup(env_id: str) -> bool:
    return "SwingUp" in env_id


@pytest.fixture(params=ENV_IDS)
def env_id(request):
    return request.param


def _rollout(env, seed, n):
    obs, _ = env.reset(seed=seed)
    env.action_space.seed(seed)
    out = [obs]
    for _ in range(n):
        out.append(env.step(env.action_space.sample())[0])
    return np.array(out)


def test_checkers_pass(env_id):
    env = gym.make(env_id)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # unbounded Box warnings
        # render modes (incl. "human") need a display; rendering is tested separately below
        gym_check_env(env.unwrapped, skip_render_check=True)
        sb3_check_env(env.unwrapped, warn=False)
    env.close()


def test_reset_step_shapes_dtypes_and_info(env_id):
    env = gym.make(env_id)
    obs, info = env.reset(seed=0)
    assert obs.shape == env.observation_space.shape and obs.dtype == env.observation_space.dtype
    assert env.observation_space.contains(obs)
    horizon = env.spec.max_episode_steps
    steps = 0
    for _ in range(horizon or 5):
        steps += 1
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert obs.shape == env.observation_space.shape
        assert obs.dtype == env.observation_space.dtype
        assert isinstance(reward, float) and np.isfinite(reward)
        assert isinstance(terminated, bool) and isinstance(truncated, bool)
        assert "cost" in info and np.isfinite(info["cost"])
        if _is_swingup(env_id):
            assert reward == -info["cost"] and isinstance(info["upright"], bool)
            assert info["state"].shape == (4,) and info["state"].dtype == np.float64
        if terminated or truncated:
            break
    if horizon is not None:
        assert truncated and steps == horizon
        if _is_swingup(env_id):
            assert isinstance(info["success"], bool)
    env.close()


def test_same_seed_same_trajectory(env_id):
    a, b = gym.make(env_id), gym.make(env_id)
    ta, tb = _rollout(a, 11, 20), _rollout(b, 11, 20)
    np.testing.assert_array_equal(ta, tb)
    assert not np.array_equal(ta, _rollout(b, 12, 20))


def test_bad_actions_raise_value_error(env_id):
    env = gym.make(env_id)
    env.reset(seed=0)
    dim = env.action_space.shape[0]
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(dim + 1, dtype=np.float32))
    bad = np.zeros(dim, dtype=np.float32)
    bad[0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        env.step(bad)
    env.close()


_RENDER_CODE = """
import mcpilco.envs, gymnasium as gym, numpy as np
env = gym.make({env_id!r}, render_mode="rgb_array")
env.reset(seed=0)
img = env.render()
assert img.ndim == 3 and img.shape[2] == 3 and img.dtype == np.uint8, img.shape
# a lit scene, not a black frame (a camera whose pose was never computed renders black)
assert img.mean() > 10 and img.std() > 5, (img.mean(), img.std())
env.close()
print("RENDER_OK")
"""


@pytest.mark.parametrize("env_id", [*ENV_IDS, "dm_control/pendulum-swingup-v0"])
def test_rgb_array_render_headless(env_id, gl_backend):
    """Offscreen rendering of every env in a subprocess, with a backend that works: a lit
    image, not a black frame. Any failure here is the env's, so the test fails."""
    proc = run_python(_RENDER_CODE.format(env_id=env_id), gl_backend)
    assert "RENDER_OK" in proc.stdout, proc.stderr[-3000:]


def test_every_dm_control_suite_task_is_registered():
    from dm_control import suite

    assert DMC_IDS == sorted(f"dm_control/{d}-{t}-v0" for d, t in suite.ALL_TASKS)


@pytest.mark.parametrize("env_id", DMC_IDS)
def test_dm_control_contract(env_id, request):
    """Each dm-control id: the Gymnasium and SB3 checkers pass; observations, actions, the
    named entries and the physics state have their declared shapes; a seed fixes the
    trajectory; a bad action is a ValueError."""
    if env_id in DMC_NEEDS_GL:
        request.getfixturevalue("gl_in_process")
    env = gym.make(env_id)
    base = env.unwrapped
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        gym_check_env(base, skip_render_check=True)
        sb3_check_env(base, warn=False)
    obs, info = env.reset(seed=3)
    assert env.observation_space.contains(obs) and len(base.observation_names) == obs.size
    assert info["physics"].shape == (len(base.physics_names),)
    assert len(set(base.physics_names)) == len(base.physics_names)
    ta = _rollout(env, 11, 5)
    np.testing.assert_array_equal(ta, _rollout(env, 11, 5))
    for _ in range(3):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert isinstance(reward, float) and np.isfinite(reward)
        assert obs.dtype == np.float64 and info["physics"].dtype == np.float64
    dim = env.action_space.shape[0]
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(dim + 1, dtype=np.float32))
    with pytest.raises(ValueError, match="NaN"):
        env.step(np.full(dim, np.nan, dtype=np.float32))
    env.close()

"""The dm-control suite adapter: names of the flattened observation and of the physics state,
dm-control's own time limit and control timestep, action repeat, episode length, and that
registration imports no dm-control."""

import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest

import mcpilco.envs  # noqa: F401  (registers the ids)
from mcpilco.envs.dmc import DMControlEnv


def test_registration_does_not_import_dm_control():
    code = "import sys, mcpilco.envs; print('dm_control' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_observation_is_dm_controls_dict_flattened_with_names():
    env = DMControlEnv("cartpole", "swingup")
    obs, info = env.reset(seed=2)
    assert env.observation_names == (
        "position[0]", "position[1]", "position[2]", "velocity[0]", "velocity[1]"
    )  # fmt: skip
    assert env.physics_names == ("qpos[slider]", "qpos[hinge_1]", "qvel[slider]", "qvel[hinge_1]")
    data = env.physics.data
    np.testing.assert_array_equal(info["physics"], np.concatenate([data.qpos, data.qvel]))
    # dm-control's cartpole: position = [x, cos phi, sin phi], velocity = [x_dot, phi_dot]
    x, phi = data.qpos
    np.testing.assert_allclose(obs, [x, np.cos(phi), np.sin(phi), *data.qvel], atol=1e-12)


def test_free_joint_entries_are_named_per_coordinate():
    env = DMControlEnv("fish", "swim")
    qpos = [n for n in env.physics_names if n.startswith("qpos[root]")]
    qvel = [n for n in env.physics_names if n.startswith("qvel[root]")]
    assert len(qpos) == 7 and len(qvel) == 6 and qpos[0] == "qpos[root][0]"
    assert len(env.physics_names) == env.physics.model.nq + env.physics.model.nv


def test_dm_controls_time_limit_truncates_and_the_control_timestep_is_kept():
    env = gym.make("dm_control/pendulum-swingup-v0")
    assert env.unwrapped.dt == pytest.approx(0.02)  # dm-control's pendulum control timestep
    env.reset(seed=0)
    steps, truncated = 0, False
    while not truncated:
        *_, terminated, truncated, _ = env.step(np.zeros(1, dtype=np.float32))
        steps += 1
        assert not terminated
    assert steps == 1000  # 20 s of 0.02 s


def test_action_repeat_and_episode_steps():
    env = DMControlEnv("pendulum", "swingup", action_repeat=3, episode_steps=4)
    assert env.dt == pytest.approx(0.06)
    env.reset(seed=1)
    t0 = env.physics.data.time
    for k in range(1, 5):
        *_, truncated, _ = env.step(np.array([0.5]))
        assert env.physics.data.time - t0 == pytest.approx(0.06 * k)
        assert truncated == (k == 4)


def test_rewards_sum_over_the_repeat():
    """An upright pendulum at rest earns dm-control's reward 1 per control step."""
    env = DMControlEnv("pendulum", "swingup", action_repeat=2)
    env.reset(seed=0)
    with env.physics.reset_context():
        env.physics.named.data.qpos["hinge"] = 0.0
        env.physics.named.data.qvel["hinge"] = 0.0
    assert env.step(np.zeros(1))[1] == pytest.approx(2.0)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"domain": "pendulum", "task": "spin"}, "unknown dm-control task pendulum/spin"),
        ({"domain": "pendulum", "task": "swingup", "action_repeat": 0}, "action_repeat"),
        ({"domain": "pendulum", "task": "swingup", "episode_steps": 0}, "episode_steps"),
        ({"domain": "pendulum", "task": "swingup", "obs_noise_std": -1.0}, "obs_noise_std"),
    ],
)
def test_bad_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        DMControlEnv(**kwargs)

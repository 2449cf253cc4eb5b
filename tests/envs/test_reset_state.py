"""Evaluation starts: the named entries of an env's state set after its reset (dm-control's
physics, a classic-control ``state``), the observation recomputed from them, and the
evaluation episode of the env's own length judged by the task's success test."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import mcpilco.envs  # noqa: F401  (registers the ids)
from mcpilco.agents.common.trials import evaluate, make_env
from mcpilco.agents.mc_pilco.trainer import evaluation_steps
from mcpilco.envs.dmc import DMControlEnv
from mcpilco.envs.reset_state import set_env_state
from mcpilco.envs.tasks.spec import TaskSpec, TaskSpecError


def test_dm_control_pendulum_starts_where_it_is_set():
    """dm-control observes orientation = (cos, sin) of the hinge angle: the observation after
    the set state is that of the angle set, and the state stays set under a zero torque
    (hanging at rest is an equilibrium)."""
    env = DMControlEnv("pendulum", "swingup")
    obs, info = env.reset(seed=3)
    obs, info = set_env_state(env, {"qpos[hinge]": np.pi, "qvel[hinge]": 0.0}, obs, info)
    np.testing.assert_allclose(obs, [-1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(info["physics"], [np.pi, 0.0])
    obs, *_ = env.step(np.zeros(1))
    np.testing.assert_allclose(obs[:2], [-1.0, 0.0], atol=1e-9)
    with pytest.raises(ValueError, match=r"eval_init.qpos\[pole\]: not a physics entry"):
        env.set_physics_state({"qpos[pole]": 0.0})


def test_gymnasium_pendulum_starts_where_it_is_set():
    env = gym.make("Pendulum-v1")
    obs, info = env.reset(seed=0)
    obs, _ = set_env_state(env, {"state[0]": 0.5, "state[1]": -1.0}, obs, info)
    np.testing.assert_allclose(obs, [np.cos(0.5), np.sin(0.5), -1.0], rtol=1e-6)
    with pytest.raises(ValueError, match=r"takes entries named state\[index\]"):
        set_env_state(env, {"qpos[0]": 0.0}, obs, info)


def test_large_reset_seeds_reach_dm_control():
    """Evaluation seeds exceed numpy's RandomState range; the adapter still resets
    reproducibly from them."""
    env = DMControlEnv("pendulum", "swingup")
    a = env.reset(seed=10**12 + 5)[0]
    b = env.reset(seed=10**12 + 5)[0]
    c = env.reset(seed=10**12 + 6)[0]
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


@pytest.mark.parametrize(
    ("env_id", "steps"), [("Pendulum-v1", 200), ("dm_control/pendulum-swingup-v0", 500)]
)
def test_evaluation_is_the_env_own_episode_from_hanging(env_id, steps):
    """Pendulum-v1 episodes last 200 steps; dm-control's pendulum 20 s of 0.02 s steps,
    500 control steps of 2. Started hanging, a zero torque never swings up: 0 of 3."""
    task = TaskSpec.for_env(env_id)
    env = make_env(env_id, task.horizon, task)
    n = evaluation_steps(task, env)
    assert n == steps
    eval_env = make_env(env_id, n, task)
    out = evaluate(eval_env, lambda x: np.zeros(1), 0, 1, 3, task, n)
    assert (out["eval_counted"], out["eval_successes"]) == (3, 0)


def test_eval_init_field_is_checked():
    base = TaskSpec.for_env("Pendulum-v1")
    with pytest.raises(TaskSpecError, match=r"eval_init.state\[0\]: needs finite lo <= hi"):
        base.replace(eval_init={"state[0]": [1.0, 0.0]})
    with pytest.raises(TaskSpecError, match="eval_steps"):
        base.replace(eval_steps=0)
    draw = base.sample_eval_init(np.random.default_rng(0))
    assert abs(draw["state[0]"] - np.pi) <= 0.1 and draw["state[1]"] == 0.0

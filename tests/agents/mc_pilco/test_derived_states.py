"""Derived states of a task file (``state_from``): an angle from an observed (cos, sin) pair,
selection and scaling, entries by name, the env's reset options, and the checks that refuse
a task that cannot be learned as declared."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from mcpilco.agents.common.trials import make_env
from mcpilco.envs.tasks import task_data
from mcpilco.envs.tasks.spec import TaskSpec, TaskSpecError, wrap


def _random_episode(env, task: TaskSpec, seed: int, steps: int):
    """(derived state, info) after each reset/step of a random-action episode."""
    obs, info = env.reset(seed=seed, options=task.reset_options())
    env.action_space.seed(seed)
    out = [(task.state_from_obs(obs, info), info)]
    for _ in range(steps):
        obs, _, terminated, truncated, info = env.step(env.action_space.sample())
        out.append((task.state_from_obs(obs, info), info))
        if terminated or truncated:
            break
    return out


def test_pendulum_v1_angle_is_the_envs_true_angle():
    """Gymnasium's Pendulum-v1 observes [cos th, sin th, thdot]; the shipped task derives
    theta = atan2(sin, cos): it equals the env's own state (env.unwrapped.state), wrapped,
    over a random episode, up to the float32 observation."""
    task = TaskSpec.for_env("Pendulum-v1")
    env = make_env("Pendulum-v1", task.horizon, task)
    obs, _ = env.reset(seed=5)
    env.action_space.seed(5)
    angles = []
    for _ in range(task.horizon):
        truth = np.array(env.unwrapped.state, dtype=np.float64)
        state = task.state_from_obs(obs)
        np.testing.assert_allclose(wrap(state[0] - truth[0]), 0.0, atol=1e-6)
        np.testing.assert_allclose(state[1], truth[1], rtol=1e-6, atol=1e-6)
        assert -np.pi <= state[0] <= np.pi
        angles.append(truth[0])
        obs, *_ = env.step(env.action_space.sample())
    assert np.ptp(angles) > 0.5  # the episode moved the pendulum
    env.close()


def test_pendulum_v1_reset_options_narrow_the_start():
    """``env_reset_options`` reach every reset: Pendulum-v1 draws theta ~ U(-x_init, x_init)."""
    data = {**task_data("Pendulum-v1"), "env_reset_options": {"x_init": 0.2, "y_init": 0.1}}
    data["success"] = {"window": None, "full_horizon": True, "bounds": data["success"]["bounds"]}
    task = TaskSpec.from_dict(data)
    env = make_env("Pendulum-v1", task.horizon, task)
    starts = np.array([env.reset(seed=s, options=task.reset_options())[0] for s in range(30)])
    theta = np.arctan2(starts[:, 1], starts[:, 0])
    assert np.all(np.abs(theta) <= 0.2 + 1e-6) and np.ptp(theta) > 0.1
    task.check_reset(env)  # a balance task (success over the whole episode) may start there
    env.close()


def test_dm_control_pendulum_angle_is_the_physics_angle():
    """dm-control's pendulum observes orientation = (cos, sin) of the hinge angle; the shipped
    task derives theta by entry names, equal to the physics state qpos[hinge] (wrapped)."""
    task = TaskSpec.for_env("dm_control/pendulum-swingup-v0")
    env = make_env(task.env_id, task.horizon, task)
    names = env.unwrapped.physics_names
    q, qd = names.index("qpos[hinge]"), names.index("qvel[hinge]")
    episode = _random_episode(env, task, seed=3, steps=60)
    for state, info in episode:
        np.testing.assert_allclose(wrap(state[0] - info["physics"][q]), 0.0, atol=1e-9)
        np.testing.assert_allclose(state[1], info["physics"][qd], atol=1e-9)
    env.close()


def test_dm_control_cartpole_state_from_names_and_physics_reader():
    """The suite cart-pole's task reads x, x_dot, phi, phi_dot from dm-control's observation
    by name; a reader of info["physics"] with scale and offset gives the convention of
    mcpilco/DMCCartpoleSwingUp-v0 (theta = pi - phi), unwrapped."""
    task = TaskSpec.for_env("dm_control/cartpole-swingup-v0")
    env = make_env(task.env_id, task.horizon, task)
    names = env.unwrapped.physics_names
    for state, info in _random_episode(env, task, seed=1, steps=40):
        phys = info["physics"]
        want = [phys[names.index(n)] for n in ("qpos[slider]", "qvel[slider]")]
        np.testing.assert_allclose(state[:2], want, atol=1e-9)
        np.testing.assert_allclose(
            wrap(state[2] - phys[names.index("qpos[hinge_1]")]), 0, atol=1e-9
        )
        np.testing.assert_allclose(state[3], phys[names.index("qvel[hinge_1]")], atol=1e-9)
    data = task_data("dm_control/cartpole-swingup-v0")
    data["state_from"] = {
        "x": {"info": "physics", "index": "qpos[slider]"},
        "x_dot": {"info": "physics", "index": "qvel[slider]"},
        "phi": {"info": "physics", "index": "qpos[hinge_1]", "scale": -1.0, "offset": np.pi},
        "phi_dot": {"info": "physics", "index": "qvel[hinge_1]", "scale": -1.0},
    }
    physics_task = TaskSpec.from_dict(data)
    physics_task.check_env(env)
    with gym.make("mcpilco/DMCCartpoleSwingUp-v0", obs_noise_std=0.0) as legacy:
        _, li = legacy.reset(seed=4)
        _, info = env.reset(seed=4)
        np.testing.assert_allclose(physics_task.state_from_obs(None, info), li["state"], atol=1e-12)
        for a in np.linspace(-1, 1, 25):
            for _ in range(5):
                _, _, _, _, info = env.step(np.array([a], dtype=np.float32))
            li = legacy.step(np.array([a], dtype=np.float32))[4]
            np.testing.assert_allclose(
                physics_task.state_from_obs(None, info), li["state"], atol=1e-9
            )
    env.close()


def test_scale_and_offset_select_and_transform():
    task = TaskSpec.from_dict(
        {
            **task_data("Pendulum-v1"),
            "state_from": {
                "theta": {"cos": 0, "sin": 1, "scale": -1.0, "offset": 0.5},
                "theta_dot": {"index": 2, "scale": 0.5},
            },
        }
    )
    obs = np.array([[np.cos(0.3), np.sin(0.3), 4.0], [np.cos(-2.0), np.sin(-2.0), -1.0]])
    np.testing.assert_allclose(task.state_from_obs(obs), [[0.2, 2.0], [2.5, -0.5]], atol=1e-12)


@pytest.mark.parametrize(
    ("state_from", "field"),
    [
        ({"theta": {"cos": 0}, "theta_dot": {"index": 2}}, "task.state_from.theta.sin"),
        ({"theta": {"sin": 1}, "theta_dot": {"index": 2}}, "task.state_from.theta.cos"),
        ({"theta": {"cos": 0, "sin": 1}}, "task.state_from.theta_dot"),
        ({"theta": {"cos": 0, "sin": 1, "index": 0}, "theta_dot": {"index": 2}}, "theta"),
        ({"theta": {"cos": 0, "sin": 1}, "theta_dot": {"index": -1}}, "theta_dot.index"),
        ({"theta": {"cos": 0, "sin": 1}, "theta_dot": {"index": 2, "scale": 0}}, "scale"),
        ({"theta": {"cos": 0, "sin": 1}, "theta_dot": {"index": 2, "gain": 1}}, "theta_dot"),
        ({"theta": {"cos": 0, "sin": 1}, "theta_dot": {"index": 2}, "phi": {"index": 0}}, "phi"),
    ],
)
def test_bad_readers_name_their_field(state_from, field):
    with pytest.raises(TaskSpecError, match=field.replace(".", r"\.")):
        TaskSpec.from_dict({**task_data("Pendulum-v1"), "state_from": state_from})


def test_unobservable_states_are_refused_naming_the_field():
    """An index beyond the observation, an entry name the env does not have, an info vector
    the env does not give: each a TaskSpecError naming the reader's field."""
    env = gym.make("Pendulum-v1")
    beyond = {"theta": {"cos": 0, "sin": 3}, "theta_dot": {"index": 2}}
    with pytest.raises(TaskSpecError, match=r"state_from\.theta\.sin.*not observed"):
        TaskSpec.from_dict({**task_data("Pendulum-v1"), "state_from": beyond}).check_env(env)
    named = {"theta": {"cos": "c", "sin": "s"}, "theta_dot": {"index": 2}}
    with pytest.raises(TaskSpecError, match=r"state_from\.theta\.cos.*names no entries"):
        TaskSpec.from_dict({**task_data("Pendulum-v1"), "state_from": named}).check_env(env)
    from_info = {"theta": {"cos": 0, "sin": 1}, "theta_dot": {"index": 0, "info": "physics"}}
    task = TaskSpec.from_dict({**task_data("Pendulum-v1"), "state_from": from_info})
    task.check_env(env)  # info vectors are checked on a reset: check_reset
    with pytest.raises(TaskSpecError, match=r"state_from\.theta_dot\.info"):
        task.check_reset(env)
    both = {**task_data("Pendulum-v1"), "obs_indices": [0, 1]}
    with pytest.raises(TaskSpecError, match="obs_indices or state_from"):
        TaskSpec.from_dict(both)
    env.close()
    dmc = task_data("dm_control/pendulum-swingup-v0")
    dmc["state_from"] = {
        "theta": {"cos": "orientation[0]", "sin": "angle"},
        "theta_dot": {"index": 2},
    }
    env = gym.make("dm_control/pendulum-swingup-v0")
    with pytest.raises(TaskSpecError, match=r"state_from\.theta\.sin: unknown entry 'angle'"):
        TaskSpec.from_dict(dmc).check_env(env)
    env.close()


def test_a_discrete_action_space_is_refused():
    data = {**task_data("Pendulum-v1"), "env_id": "CartPole-v1"}
    data["state_from"] = {"theta": {"cos": 0, "sin": 1}, "theta_dot": {"index": 2}}
    with pytest.raises(TaskSpecError, match=r"task\.action_low: .*Discrete\(2\), not a Box"):
        TaskSpec.from_dict(data).check_env(gym.make("CartPole-v1"))


def test_a_success_set_every_reset_lies_in_is_refused():
    """Pendulum-v1 started within 0.1 rad of upright, success within 0.3 rad over the last
    second: every sampled reset is already a success; a swing-up window task is refused."""
    data = {**task_data("Pendulum-v1"), "env_reset_options": {"x_init": 0.1, "y_init": 0.1}}
    task = TaskSpec.from_dict(data)
    env = make_env("Pendulum-v1", task.horizon, task)
    with pytest.raises(TaskSpecError, match=r"task\.success\.bounds: all 10 sampled resets"):
        task.check_reset(env)
    TaskSpec.for_env("Pendulum-v1").check_reset(env)  # from U(-pi, pi): nothing refused
    env.close()


def test_a_trial_that_starts_in_the_goal_set_is_no_success():
    """Pendulum-v1 resets at a random angle: an episode that starts within the success bounds
    is recorded as ``started_in_goal`` and does not count as the first success; a balance
    task (judged over the whole episode) starts inside its set by design and is not marked."""
    from mcpilco.agents.common.records import RunSummary
    from mcpilco.agents.common.trials import run_episode

    task = TaskSpec.for_env("Pendulum-v1")
    assert task.starts_in_goal(np.array([0.1, 0.0])) and task.starts_in_goal([-0.29, 5.0])
    assert not task.starts_in_goal(np.array([0.31, 0.0]))
    assert not task.starts_in_goal(np.array([np.pi, 0.0]))
    balance = TaskSpec.for_env("InvertedPendulum-v5")
    assert not balance.starts_in_goal(np.zeros(4))
    env = make_env("Pendulum-v1", task.horizon, task)
    hold = task.replace(env_reset_options={"x_init": 0.05, "y_init": 0.0})
    ep = run_episode(env, lambda x: np.zeros(1), seed=0, horizon=5, task=hold)
    assert ep["started_in_goal"] is True
    upright = task.replace(env_reset_options={"x_init": 0.0, "y_init": 0.0})  # theta = 0
    assert run_episode(env, lambda x: np.zeros(1), seed=0, horizon=5, task=upright)[
        "started_in_goal"
    ]
    env.close()
    records = [
        {"kind": "exploration", "index": 0, "success": False, "started_in_goal": False},
        {"kind": "policy", "index": 1, "success": True, "started_in_goal": True},
        {"kind": "policy", "index": 2, "success": True, "started_in_goal": False},
    ]
    summary = RunSummary({}, records, None, None, None, [], 0.0)
    assert summary.first_success_trial == 2

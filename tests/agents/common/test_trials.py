"""Trials on the system, shared by every agent: episodes, exploration, the model's
transitions, reset seeds, outcomes, and the env factory's errors."""

from __future__ import annotations

import numpy as np
import pytest

import mcpilco.envs  # noqa: F401  (registers the ids)
from mcpilco.agents.common.trials import (
    DEFAULT_ENV_ID,
    episode_outcome,
    exploration_actions,
    exploration_episodes,
    make_env,
    registered_ids,
    run_episode,
    transitions,
    trial_seed,
)
from mcpilco.envs.tasks.spec import TaskSpec
from tests.agents.mc_pilco import toy_env

TOY = TaskSpec.from_dict(toy_env.TASK)


def test_exploration_actions_hold_each_draw_and_keep_the_iid_stream():
    iid = np.random.default_rng(5).uniform(-1.0, 1.0, size=(60, 1))
    np.testing.assert_array_equal(exploration_actions(np.random.default_rng(5), 60, 1), iid)
    held = exploration_actions(np.random.default_rng(5), 7, 2)
    assert held.shape == (7, 1)
    # draws 0..3 of the same stream, each repeated twice, cut at 7 steps
    np.testing.assert_array_equal(held[:, 0], np.repeat(iid[:4, 0], 2)[:7])
    with pytest.raises(ValueError, match="hold must be an integer >= 1"):
        exploration_actions(np.random.default_rng(0), 60, 0)
    # two actions, each uniform within its own bounds
    wide = exploration_actions(np.random.default_rng(5), 500, 1, low=(-3.0, 0.0), high=(3.0, 0.5))
    assert wide.shape == (500, 2)
    assert wide[:, 0].min() >= -3.0 and wide[:, 0].max() <= 3.0 and wide[:, 0].min() < -2.5
    assert wide[:, 1].min() >= 0.0 and wide[:, 1].max() <= 0.5 and wide[:, 1].max() > 0.45


def test_exploration_resets_until_its_steps_are_taken():
    """``min_steps`` random steps in episodes that end at termination (|theta| > 0.2) or at
    the horizon, the last one cut to the exact total; the first episode is the one-episode
    exploration trial's, the later ones start from fresh resets."""
    task = TaskSpec.for_env("InvertedPendulum-v5")
    env = make_env(task.env_id, task.horizon, task)
    (one,) = exploration_episodes(env, np.random.default_rng(5), 5, task.horizon, task)
    eps = exploration_episodes(env, np.random.default_rng(5), 5, task.horizon, task, 1, 120)
    env.close()
    assert sum(e["steps"] for e in eps) == 120 and len(eps) > 2
    np.testing.assert_array_equal(eps[0]["obs"], one["obs"])
    for e in eps[:-1]:
        theta = np.abs(e["states"][1:, 1])
        assert e["steps"] == task.horizon or (theta[-1] > 0.2 and np.all(theta[:-1] <= 0.2))
    for e in eps[1:]:  # a reset state: U(-0.01, 0.01) around upright
        assert np.all(np.abs(e["states"][0]) <= 0.01)
    with pytest.raises(ValueError, match="min_steps must be a positive integer"):
        exploration_episodes(env, np.random.default_rng(0), 0, task.horizon, task, 1, 0)


def test_a_toy_episode_follows_the_exact_zero_order_hold():
    """Under a constant action the point mass moves as its exact ZOH discretisation
    (independent of the env's code: the closed form of v' = u - b v); the episode's
    observed and true states agree and its cost is the task's."""
    env = make_env(toy_env.ENV_ID, TOY.horizon, TOY)
    u = np.array([0.5, -0.25])
    ep = run_episode(env, lambda _x: u, 7, TOY.horizon, TOY)
    env.close()
    b, dt = toy_env.FRICTION, toy_env.DT
    e = np.exp(-b * dt)
    x = ep["obs"][0].copy()
    for t in range(TOY.horizon):
        for axis, k in ((0, 0), (2, 1)):
            p, v = x[axis], x[axis + 1]
            x[axis] = p + v * (1 - e) / b + u[k] * (dt - (1 - e) / b) / b
            x[axis + 1] = v * e + u[k] * (1 - e) / b
        np.testing.assert_allclose(ep["obs"][t + 1], x, rtol=0, atol=1e-12)
    assert ep["steps"] == TOY.horizon and ep["actions"].shape == (TOY.horizon, 2)
    np.testing.assert_array_equal(ep["obs"], ep["states"])
    np.testing.assert_allclose(ep["cost"], np.sum(TOY.cost(ep["states"][1:])))


def test_transitions_leave_out_limits_and_filtered_steps():
    """``(s_t, a_t, s_t+1)`` stacked over episodes; a transition that leaves a declared limit
    or that an episode's filter marks is left out."""
    task = TOY.replace(limits={"px": (-2.0, 2.0)})
    obs = np.zeros((4, 4))
    obs[:, 0] = [0.0, 1.0, 2.5, 1.0]  # the 2nd and 3rd transitions touch px > 2
    actions = np.arange(6.0).reshape(3, 2)
    a = {"obs": obs, "actions": actions}
    b = {"obs": obs + 0.1, "actions": actions + 10, "filtered": np.array([True, False, False])}
    s, u, s1 = transitions([a, b])  # no task: only b's marked transition is left out
    assert s.shape == (5, 4) and s1.shape == (5, 4)
    np.testing.assert_array_equal(u, np.concatenate([actions, actions[1:] + 10]))
    s, u, s1 = transitions([a, b], task)
    np.testing.assert_array_equal(u, [actions[0]])  # b's 1st is filtered, the rest at the limit
    a_free = {"obs": obs * 0.5, "actions": actions}  # px at most 1.25: all free
    s, u, s1 = transitions([a_free, b], task)
    np.testing.assert_array_equal(u, actions)
    np.testing.assert_array_equal(s1, obs[1:] * 0.5)


def test_trial_seeds_differ_between_trials_and_runs_and_outcome_reads_the_episode():
    seeds = {trial_seed(s, k) for s in range(20) for k in range(20)}
    assert len(seeds) == 400 and trial_seed(0, 0) == 0 and trial_seed(1, 2) == 10_009
    ep = {"cost": 3.0, "success": True, "started_in_goal": False, "time_in_goal": 0.5, "steps": 30}
    out = episode_outcome({**ep, "tracking_rms": {"q": 0.1}}, t0=0.0)
    assert {k: out[k] for k in ep} == ep and out["tracking_rms"] == {"q": 0.1}
    assert out["wall_s"] > 0 and "tracking_rms" not in episode_outcome(ep, 0.0)


def test_make_env_names_an_unknown_id_and_a_horizon_the_success_flag_cannot_use():
    assert DEFAULT_ENV_ID in registered_ids()
    with pytest.raises(ValueError, match="unknown env id 'mcpilco/Nope-v0'; registered"):
        make_env("mcpilco/Nope-v0", 10)
    task = TaskSpec.for_env(DEFAULT_ENV_ID)  # success: the env's flag at its last step
    assert task.success.info_key
    with pytest.raises(ValueError, match="horizon mismatch"):
        make_env(task.env_id, task.horizon + 1, task)

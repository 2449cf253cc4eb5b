"""Success evaluation and the SB3 callback against a fake env whose success is known exactly.

The fake env ends each 5-step episode with ``info["success"] = (sum of actions > 0)`` and
starts with ``obs[0] = reset seed mod 2``; a policy that pushes ``+1`` on odd seeds and
``-1`` on even seeds therefore succeeds exactly on the odd reset seeds.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.spaces import Box
from gymnasium.wrappers import TimeLimit

from mcpilco.agents.baselines.common import (
    check_task_env,
    env_has_task,
    eval_seeds,
    evaluate_success,
    trial_records_to_points,
)
from mcpilco.agents.baselines.sb3 import SB3Config, policy_act
from mcpilco.envs.tasks.spec import TaskSpec

STEPS = 5
COIN_TASK = TaskSpec.from_dict(
    {
        "env_id": "coin",
        "state_names": ["parity", "a", "b", "c"],
        "action_low": [-1.0],
        "action_high": [1.0],
        "dt": 0.1,
        "horizon": STEPS,
        "cost": {"terms": [{"state": "a"}]},
        "success": {"info_key": "success"},
    }
)  # the coin env's task: its success is the env's own flag


class CoinEnv(gym.Env):
    """Success iff the actions of the episode sum to a positive number; ``dt = 0.1`` s."""

    dt = 0.1

    def __init__(self) -> None:
        self.action_space = Box(-1.0, 1.0, (1,), np.float32)
        self.observation_space = Box(-np.inf, np.inf, (4,), np.float64)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self._parity = float(seed % 2) if seed is not None else 0.0
        self._sum, self._t = 0.0, 0
        return self._obs(), {}

    def _obs(self):
        return np.array([self._parity, 0.0, 0.0, 0.0])

    def step(self, action):
        self._sum += float(np.asarray(action).reshape(-1)[0])
        self._t += 1
        info = {"cost": 1.0, "upright": False}
        if self._t == STEPS:
            info["success"] = self._sum > 0
        return self._obs(), 0.0, False, self._t >= STEPS, info


def _env():
    return TimeLimit(CoinEnv(), max_episode_steps=STEPS)


def parity_policy(obs):
    return np.array([1.0 if obs[0] == 1.0 else -1.0])


def test_success_rate_is_the_fraction_of_successful_episodes():
    env = _env()
    seeds = eval_seeds(3, 10)
    assert len(set(seeds)) == 10
    odd = sum(s % 2 for s in seeds)
    res = evaluate_success(env, parity_policy, seeds, STEPS, COIN_TASK)
    assert res["success_rate"] == pytest.approx(odd / 10) and res["episodes"] == 10
    assert res["successes"] == [bool(s % 2) for s in seeds]
    up, down = (lambda o: np.array([1.0])), (lambda o: np.array([-1.0]))
    assert evaluate_success(env, up, seeds, STEPS, COIN_TASK)["success_rate"] == 1.0
    assert evaluate_success(env, down, seeds, STEPS, COIN_TASK)["success_rate"] == 0.0
    with pytest.raises(ValueError, match="at least one seed"):
        evaluate_success(env, parity_policy, [], STEPS, COIN_TASK)


class _StubModel:
    """The parts of an SB3 model the callback uses."""

    def __init__(self):
        self.num_timesteps = 0
        self.logger = None

    def get_env(self):
        return None

    def predict(self, obs, deterministic=True):
        assert deterministic
        return parity_policy(obs), None


def test_callback_evaluates_every_k_steps_with_experience_in_seconds():
    from mcpilco.agents.baselines.sb3 import SuccessEvalCallback

    points, evaluated, ckpts = [], [], []
    seeds = [10, 11, 12, 13]  # two odd -> 50%
    cb = SuccessEvalCallback(
        _env(),
        100,
        seeds,
        STEPS,
        CoinEnv.dt,
        COIN_TASK,
        points,
        on_eval=evaluated.append,
        on_checkpoint=ckpts.append,
        checkpoint_every=200,
    )
    model = _StubModel()
    cb.init_callback(model)
    cb.on_training_start({}, {})
    for n in range(30, 421, 30):  # 30, 60, ..., 420 env steps
        model.num_timesteps = n
        assert cb.on_step()
    cb.on_training_end()
    # first step count at or past each multiple of K = 100
    assert [p["steps"] for p in points] == [120, 210, 300, 420]
    assert [p["experience_s"] for p in points] == pytest.approx([12.0, 21.0, 30.0, 42.0])
    assert all(p["success_rate"] == 0.5 and p["episodes"] == 4 for p in points)
    assert evaluated == points
    assert ckpts == [210, 420]


def test_trial_records_become_curve_points():
    recs = [
        {"index": 0, "kind": "exploration", "experience_s": 3.0, "success": False, "cost": 59.0},
        {"index": 1, "kind": "policy", "experience_s": 6.0, "success": True, "cost": 20.0},
    ]
    pts = trial_records_to_points(recs, 60)
    assert [(p["steps"], p["experience_s"], p["success_rate"]) for p in pts] == [
        (60, 3.0, 0.0),
        (120, 6.0, 1.0),
    ]


def test_task_envs_are_those_with_a_shipped_task():
    assert env_has_task("mcpilco/CartpoleSwingUp-v0")
    assert env_has_task("InvertedPendulum-v5")
    assert not env_has_task("mcpilco/MarkerCamera-v0")
    assert not env_has_task("mcpilco/Nope-v0")
    with pytest.raises(ValueError, match="valid env ids: .*mcpilco/CartpoleSwingUp-v0"):
        check_task_env("mcpilco/MarkerCamera-v0")


def test_sb3_config_validation_names_the_valid_values():
    with pytest.raises(ValueError, match="valid: sac, td3, ppo"):
        SB3Config(algo="dqn")
    with pytest.raises(ValueError, match="valid: swingup, pendulum"):
        SB3Config(algo="sac", preset="atari")
    with pytest.raises(ValueError, match="steps must be a positive integer"):
        SB3Config(algo="sac", steps=0)
    assert SB3Config(algo="ppo").steps == 1_000_000 and SB3Config(algo="td3").steps == 200_000
    hp = SB3Config(algo="sac", overrides={"learning_starts": 5}).hyperparams()
    assert hp["learning_starts"] == 5 and hp["learning_rate"] == 7.3e-4


def test_policy_act_normalises_observations_when_asked():
    class Norm:
        def normalize_obs(self, o):
            return o * 0 + 1.0  # parity 1 -> push +1

    act = policy_act(_StubModel(), Norm())
    assert act(np.zeros(4))[0] == 1.0
    assert policy_act(_StubModel())(np.zeros(4))[0] == -1.0


def test_task_step_wrapper_holds_actions_and_passes_the_reference():
    """The two-link tracking arm with ``action_repeat = 2``: the wrapped env's reset gets the
    task's reference (its observation equals the raw env's reset with the options), each
    step equals two raw steps with the same action (observation; reward = their sum)."""
    from mcpilco.agents.baselines.common import task_step_wrapper
    from mcpilco.agents.common.trials import make_env
    from mcpilco.agents.mc_pilco import TaskSpec
    from tests.agents.mc_pilco.arm_env import ENV_ID, REFERENCE, TASK

    far = dict(REFERENCE, centre=[0.5, -0.5])  # not the env's default reference
    task = TaskSpec.from_dict(
        dict(TASK, dt=2 * TASK["dt"], action_repeat=2, horizon=10, reference=far)
    )
    raw = make_env(ENV_ID, task.horizon, task)
    wrapped = task_step_wrapper(make_env(ENV_ID, task.horizon, task), task)
    o_w, _ = wrapped.reset(seed=4)
    o_r, _ = raw.reset(seed=4, options=task.reset_options())
    np.testing.assert_array_equal(o_w, o_r)
    assert abs(o_w[4] - 0.5) < 0.6  # the task's reference, centred at 0.5
    for a in np.random.default_rng(0).uniform(-1, 1, (5, 2)).astype(np.float32):
        o_w, r_w, *_ = wrapped.step(a)
        _, r1, *_ = raw.step(a)
        o_r, r2, *_ = raw.step(a)
        np.testing.assert_array_equal(o_w, o_r)
        assert r_w == pytest.approx(r1 + r2, rel=1e-12)

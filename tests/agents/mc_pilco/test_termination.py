"""Terminating envs: trials collect their declared steps across resets, every step counts as
experience, the record says how many episodes a trial spanned, and the particle rollout
absorbs a particle that leaves the task's termination set at a cost of 1 per step; the
evaluation episodes after a trial are no experience and have seeds of their own."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch
from torch import nn

from mcpilco.agents.common.records import TrialRecord, record_line
from mcpilco.agents.common.trials import (
    EVAL_SEED_BASE,
    eval_seed,
    exploration_episodes,
    make_env,
    trial_seed,
)
from mcpilco.agents.mc_pilco import MCPilcoConfig, PolicyOptConfig, run_mcpilco
from mcpilco.agents.mc_pilco.fast import use_fast_rollout
from mcpilco.agents.mc_pilco.loss import MCPilcoLoss, TerminationSet
from mcpilco.envs.tasks.spec import TaskSpec, TaskSpecError
from mcpilco.models.stats import Z95
from tests.agents.mc_pilco import terminating_env
from tests.agents.mc_pilco.terminating_env import END, ENV_ID, TASK


def test_exploration_collects_the_declared_steps_across_resets():
    """Every episode but the last ends where the env terminates it (p > 0.5, after 4 to 10
    drift steps), which is where the task's termination set says it ends; the last is cut
    so that the trial takes exactly ``trial_steps`` steps."""
    task = TaskSpec.from_dict(TASK)
    env = make_env(ENV_ID, task.horizon, task)
    eps = exploration_episodes(
        env, np.random.default_rng(0), 0, task.horizon, task, 1, task.steps_per_trial
    )
    env.close()
    assert sum(e["steps"] for e in eps) == 30 and len(eps) >= 3
    for e in eps[:-1]:
        p = e["states"][:, 0]
        assert 4 <= e["steps"] <= 10 and p[-1] > END and np.all(p[:-1] <= END)
        assert task.terminated(e["states"]).tolist() == [False] * e["steps"] + [True]
        increments = np.diff(p)  # the env's own law: 0.1 + 0.05 u
        np.testing.assert_allclose(increments, 0.1 + 0.05 * e["actions"][:, 0], atol=1e-12)
    assert not task.terminated(eps[-1]["states"][:-1]).any()


def test_trainer_counts_every_step_and_records_the_episodes(tmp_path):
    """The exploration and a policy trial each take ``trial_steps = 30`` steps (the env ends
    episodes after at most 10): 3 s of experience per trial, the episodes counted. Four
    evaluation episodes follow the policy trial, none of them experience; none can last the
    20 steps success needs: 0 of 4, Wilson interval [0, z^2 / (4 + z^2)]."""
    cfg = MCPilcoConfig(
        env_id=ENV_ID, task=TASK, num_trials=1, num_particles=5, max_points=50,
        gp_adam_iters=10, gp_lbfgs_iters=5, num_basis=5, sim_obs_noise_std=0.0,
        torch_threads=1, opt=PolicyOptConfig(max_steps=3, min_steps=1), eval_episodes=4,
    )  # fmt: skip
    summary = run_mcpilco(cfg, tmp_path, progress=False, log=None, write_rrd=False)
    explore, policy = summary.trials
    assert explore.steps == policy.steps == 30
    assert explore.episodes >= 3 and policy.episodes >= 3
    assert explore.experience_s == pytest.approx(3.0) and policy.experience_s == pytest.approx(6.0)
    assert policy.n_data == 30  # the model of trial 1: every exploration transition
    assert explore.success is False and policy.success is False  # no episode lasts 20 steps
    z2 = Z95**2  # the package's 95 % quantile
    assert (policy.eval_episodes, policy.eval_counted, policy.eval_successes) == (4, 4, 0)
    assert policy.eval_ci == pytest.approx([0.0, z2 / (4 + z2)])
    assert explore.eval_episodes is None
    assert record_line(policy).split(", eval ")[1].startswith("0/4 (0 %, 95 % CI 0-49 %)")


def test_evaluation_seeds_are_disjoint_from_the_trial_seeds():
    trial = {trial_seed(s, k) for s in range(100) for k in range(50)}
    evals = [eval_seed(s, k, i) for s in range(100) for k in range(50) for i in (0, 1, 999)]
    assert len(set(evals)) == len(evals) and not trial & set(evals)
    assert max(trial) < EVAL_SEED_BASE <= min(evals)
    with pytest.raises(ValueError, match="eval_episodes"):
        MCPilcoConfig(env_id=ENV_ID, task=TASK, eval_episodes=-1)


class _Drift(nn.Module):
    """``x+ = x + 0.3 + u``: the hand computation's dynamics (eps unused)."""

    def forward(self, x, u, eps):
        return x + 0.3 + u


class _Constant(nn.Module):
    """``u = w`` whatever the state (one parameter)."""

    def __init__(self) -> None:
        super().__init__()
        self.w = nn.Parameter(torch.zeros(1))

    def forward(self, x):
        return self.w.expand(x.shape[0], 1)


class _Linear(nn.Module):
    """``c(x) = x / 10``."""

    def forward(self, x):
        return x[..., 0] / 10


def _toy_loss() -> MCPilcoLoss:
    return MCPilcoLoss(
        _Constant(), _Drift(), _Linear(), horizon=5, num_particles=2, init_mean=[0.0],
        init_std=0.0, delta_dim=1, termination=TerminationSet([0], [-1.0], [0.7], [False]),
    )  # fmt: skip


def test_a_particle_that_leaves_is_frozen_and_pays_one_per_step():
    """Particle 1 from 0: x = 0.3, 0.6 (inside), 0.9 (outside: absorbed), then frozen at
    0.9; costs 0.03, 0.06, 1, 1, 1. Particle 2 starts outside (0.8): frozen, costs 1 x 5.
    J^ = (3.09 + 5) / 2; its gradient in ``w`` comes from the costs while alive only:
    d/dw (x_1 + x_2) / 10 = (1 + 2) / 10 for particle 1, halved by the mean."""
    loss = _toy_loss()
    x0 = torch.tensor([[0.0], [0.8]])
    roll = loss.rollout(initial_state=x0, noise=torch.zeros(5, 2, 1))
    np.testing.assert_allclose(
        roll.states[:, :, 0].detach().numpy(),
        [[0.0, 0.3, 0.6, 0.9, 0.9, 0.9], [0.8] * 6],
        atol=1e-6,
    )
    np.testing.assert_allclose(
        roll.costs.detach().numpy(), [[0.03, 0.06, 1, 1, 1], [1, 1, 1, 1, 1]], atol=1e-6
    )
    td = loss(_td(x0))
    assert td["loss_cost"].item() == pytest.approx((3.09 + 5.0) / 2, abs=1e-6)
    td["loss_cost"].backward()
    assert loss.policy_module.w.grad.item() == pytest.approx(0.15, abs=1e-6)


def _td(x0):
    from tensordict import TensorDict

    return TensorDict({"initial_state": x0, "noise": torch.zeros(5, 2, 1)}, batch_size=[])


def test_fast_rollouts_refuse_a_terminating_task():
    """The chained backends do not mask the absorbing set: 'auto' runs eagerly with a
    warning, a named chained backend is refused, and no engine can be installed."""
    loss = _toy_loss()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fast = use_fast_rollout(loss, "auto")
    assert not fast.in_use and loss.fast_rollout == (None, None)
    assert "the task terminates" in str(caught[0].message)
    with pytest.raises(ValueError, match="native backend cannot run.*terminates"):
        use_fast_rollout(loss, "native")
    with pytest.raises(ValueError, match="does not mask the absorbing set"):
        loss.set_fast_rollout(engine=object())


def test_termination_set_wraps_angles_and_matches_the_task():
    task = TaskSpec.from_dict(
        {**TASK, "state_names": ["p", "a"], "angles": ["a"], "init_mean": [0.0, 0.0],
         "termination": {"p": [-1.0, 1.0], "a": [-0.2, 0.2]}}
    )  # fmt: skip
    x = np.array([[0.0, 2 * math.pi + 0.1], [0.0, 0.3], [1.5, 0.0], [0.5, -0.19]])
    assert task.terminated(x).tolist() == [False, True, True, False]
    module = TerminationSet.from_task(task)
    assert module(torch.tensor(x, dtype=torch.float32)).tolist() == [False, True, True, False]
    assert TerminationSet.from_task(task.replace(termination={})) is None


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"termination": {"q": [0, 1]}}, "task.termination.q"),
        ({"termination": {"p": [1, 0]}}, "task.termination.p"),
        ({"termination": {"p": [0, "x"]}}, "task.termination.p"),
        ({"trial_steps": 0}, "task.trial_steps"),
        ({"trial_steps": 2.5}, "task.trial_steps"),
    ],
)
def test_bad_termination_and_trial_steps_name_their_field(change, field):
    with pytest.raises(TaskSpecError, match=field.replace(".", r"\.")):
        TaskSpec.from_dict({**TASK, **change})


def test_records_of_the_former_field_name_load():
    rec = TrialRecord.from_dict({"index": 0, "kind": "exploration", "exploration_episodes": 4})
    assert rec.episodes == 4 and rec.extra == {}
    assert TaskSpec.from_dict({**TASK, "trial_steps": None}).steps_per_trial == TASK["horizon"]


@pytest.mark.parametrize("env_id", ["InvertedPendulum-v5", "InvertedDoublePendulum-v5"])
def test_shipped_termination_sets_hold_where_the_env_terminates(env_id):
    """Each episode the env ended early ends in the task's termination set; InvertedPendulum's
    set is the env's own (|theta| > 0.2), so no earlier state is in it; InvertedDoublePendulum's
    box lies inside the env's alive set (tip height > 1 m)."""
    task = TaskSpec.for_env(env_id)
    env = make_env(env_id, task.horizon, task)
    eps = exploration_episodes(env, np.random.default_rng(1), 1, task.horizon, task, 1, 60)
    env.close()
    ended = [e for e in eps[:-1] if e["steps"] < task.horizon]
    assert ended
    for e in ended:
        assert task.terminated(e["states"][-1])
        if env_id == "InvertedPendulum-v5":
            assert not task.terminated(e["states"][:-1]).any()
        inside = ~task.terminated(e["states"])
        if env_id == "InvertedDoublePendulum-v5":  # inside the box: the tip is above 1 m
            s = e["states"][inside]
            assert np.all(0.6 * (np.cos(s[:, 1]) + np.cos(s[:, 1] + s[:, 2])) > 1.0)


assert terminating_env.ENV_ID == ENV_ID  # the module registers the env on import

"""The rollout's GP posterior in float32 is checked against float64 on the training inputs:
on noise-free simulator data (dm-control's pendulum) the float32 mean cancels into
round-off and the trainer rolls out in float64; with the cart-pole's measurement noise
(0.01 on each observed entry) float32 is kept."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import mcpilco.envs  # noqa: F401  (registers the ids)
from mcpilco.agents.common.trials import exploration_episodes, make_env, transitions
from mcpilco.agents.mc_pilco.dynamics import GPDynamicsModel
from mcpilco.agents.mc_pilco.trainer import ROLLOUT_DTYPE_TOL
from mcpilco.envs.tasks.spec import TaskSpec

ENV_ID = "dm_control/pendulum-swingup-v0"


def _model(noise: float) -> GPDynamicsModel:
    task = TaskSpec.for_env(ENV_ID)
    env = make_env(ENV_ID, task.horizon, task, {"obs_noise_std": noise})
    eps = exploration_episodes(env, np.random.default_rng(0), 0, task.horizon, task)
    env.close()
    return GPDynamicsModel(task, max_points=300).fit(*transitions(eps, task))


@pytest.mark.slow
def test_float32_posterior_is_refused_on_noise_free_data_only():
    clean, noisy = _model(0.0), _model(0.01)
    assert clean.posterior_dtype_error(torch.float64) == 0.0
    assert clean.posterior_dtype_error(torch.float32) > ROLLOUT_DTYPE_TOL
    assert noisy.posterior_dtype_error(torch.float32) < ROLLOUT_DTYPE_TOL

"""The success-window objective ``J^_W`` (:mod:`mcpilco.agents.mc_pilco.loss` glossary) and
the predicted success (:mod:`mcpilco.agents.mc_pilco.horizon`) against hand-computed cases."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torch import nn

from mcpilco.agents.mc_pilco import load_config
from mcpilco.agents.mc_pilco.cost import SaturatingCost
from mcpilco.agents.mc_pilco.horizon import predicted_success, success_window
from mcpilco.agents.mc_pilco.loss import MCPilcoLoss
from mcpilco.agents.mc_pilco.trainer import success_cost_level
from mcpilco.envs.tasks.spec import TaskSpec
from tests.agents.mc_pilco.test_horizon import TOL, WINDOW, approach, line_task


class _Speed(nn.Module):
    """``u = w`` whatever the state."""

    def __init__(self, w: float) -> None:
        super().__init__()
        self.w = nn.Parameter(torch.tensor([w]))

    def forward(self, x):
        return self.w.expand(x.shape[0], 1)


class _Move(nn.Module):
    """``x_{t+1} = x_t + u`` (the noise is ignored)."""

    def forward(self, x, u, eps):
        return x + u


class _Tenth(nn.Module):
    """``c(x) = x / 10``."""

    def forward(self, x):
        return x[..., 0] / 10


def _loss(window: int | None, horizon: int = 5) -> MCPilcoLoss:
    return MCPilcoLoss(
        _Speed(0.3), _Move(), _Tenth(), horizon=horizon, num_particles=1, init_mean=[0.0],
        init_std=0.0, delta_dim=1, success_window=window,
    )  # fmt: skip


def test_late_and_early_arrival_of_equal_summed_cost_are_told_apart():
    # step costs 1 until the goal (cost 0); the late path is cheaper on the way but reaches
    # the goal two steps after the window of the last 4 steps began: equal sums (5.0)
    early = torch.tensor([1.0, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    late = torch.tensor([0.6, 0.6, 0.6, 0.6, 0.6, 0.6, 0.6, 0.8, 0.0, 0.0])
    costs = torch.stack([early, late])
    plain, windowed = _loss(None, 10), _loss(4, 10)
    assert plain.particle_costs(costs).tolist() == pytest.approx([5.0, 5.0])
    # early: 5 + (0 + 0 + 0 + 0); late: 5 + (0.6 + 0.8 + 0 + 0)
    assert windowed.particle_costs(costs).tolist() == pytest.approx([5.0, 6.4])
    # a rollout shorter than the window counts all its steps twice
    short = torch.tensor([[0.2, 0.3]])
    assert windowed.particle_costs(short).item() == pytest.approx(1.0)


def test_the_window_objective_and_its_gradient_through_a_rollout():
    # x_t = 0.3 t, c_t = 0.03 t for t = 1..5 (H = 5, W = 2): J^_W = 0.45 + (0.12 + 0.15)
    # = 0.72, dJ^_W/dw = (1 + 2 + 3 + 4 + 5) / 10 + (4 + 5) / 10 = 2.4; plain: 0.45, 1.5
    for window, value, grad in ((2, 0.72, 2.4), (None, 0.45, 1.5)):
        loss = _loss(window)
        td = TensorDict(
            {"initial_state": torch.zeros(1, 1), "noise": torch.zeros(5, 1, 1)}, batch_size=[]
        )
        out = loss(td)
        assert out["loss_cost"].item() == pytest.approx(value, abs=1e-6)
        out["loss_cost"].backward()
        assert loss.policy_module.w.grad.item() == pytest.approx(grad, abs=1e-5)


def test_the_success_level_bounds_the_window_objective_of_a_success():
    # the line task's saturating cost, goal |x| <= TOL for the last W steps; a
    # trajectory at the goal's edge from the start costs c_G at every step: J^_W = (H + W) c_G
    h = 40
    task = line_task(h)
    cost = SaturatingCost.from_task(task, None, None)
    c_goal = float(cost(torch.tensor([[TOL]]))[0])
    plain = success_cost_level(task, cost)
    level = success_cost_level(task, cost, window_objective=True)
    assert level == pytest.approx(plain + WINDOW * c_goal, rel=1e-6)
    edge = torch.full((1, h), c_goal)
    assert _loss(WINDOW, h).particle_costs(edge).item() == pytest.approx(level, rel=1e-5)
    # a balance task (no final window) keeps its level
    balance = line_task(h, full_horizon=True)
    assert success_cost_level(balance, cost, True) == success_cost_level(balance, cost)


@pytest.mark.parametrize("window", [0, 6, 2.5])
def test_a_bad_success_window_names_the_argument(window):
    with pytest.raises(ValueError, match="success_window"):
        _loss(window)


def test_only_a_goal_held_over_a_final_window_has_a_success_window():
    assert success_window(line_task(40)) == WINDOW
    assert success_window(line_task(40, info_key="success")) == WINDOW  # the same test
    assert success_window(line_task(40, full_horizon=True)) is None  # a balance task
    assert success_window(line_task(WINDOW)) == WINDOW
    flag_only = TaskSpec.from_dict(
        {
            "env_id": "Line-v0",
            "state_names": ["x"],
            "action_low": [-1.0],
            "action_high": [1.0],
            "dt": 0.1,
            "horizon": 40,
            "cost": {"terms": [{"state": "x", "target": 0.0}]},
            "success": {"info_key": "success", "window": WINDOW},
        }
    )
    assert success_window(flag_only) is None
    # the shipped tasks: the swing-ups hold the goal for their last second, the balance
    # and tracking tasks have none (their objective stays the plain sum)
    for env_id, w in (
        ("mcpilco/CartpoleSwingUp-v0", 20),
        ("mcpilco/DMCCartpoleSwingUp-v0", 20),
        ("InvertedDoublePendulum-v5", None),
        ("mcpilco/UR10-v0", None),
    ):
        assert success_window(TaskSpec.for_env(env_id)) == w, env_id


def test_predicted_success_counts_particles_in_the_goal_over_the_whole_window():
    h = 40
    # reach steps 5, 20, 30, 35 and never: only those in the goal by step H - W + 1 = 31 hold
    x0 = np.array([0.5, 2.0, 3.0, 3.5, 9.0]) + TOL
    assert predicted_success(approach(x0, 1.0, h), line_task(h)) == pytest.approx(3 / 5)
    with pytest.raises(ValueError, match="success window"):
        predicted_success(approach(x0, 1.0, h), line_task(h, full_horizon=True))


def test_the_config_switch_defaults_off_and_is_checked():
    assert load_config("mcpilco/CartpoleSwingUp-v0").window_objective is False
    on = load_config("mcpilco/CartpoleSwingUp-v0", overrides={"window_objective": True})
    assert on.window_objective is True
    with pytest.raises(ValueError, match="window_objective"):
        load_config("mcpilco/CartpoleSwingUp-v0", overrides={"window_objective": "yes"})

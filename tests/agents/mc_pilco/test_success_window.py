"""The success-window objective ``J^_W`` (:mod:`mcpilco.agents.mc_pilco.loss` glossary) and
the predicted success (:mod:`mcpilco.agents.mc_pilco.horizon`) against hand-computed cases."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torch import nn

from mcpilco.agents.mc_pilco import load_config
from mcpilco.agents.mc_pilco.horizon import predicted_success, success_window
from mcpilco.agents.mc_pilco.loss import WINDOW_TEMPERATURE, MCPilcoLoss
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


def _smax(c: np.ndarray) -> float:
    """``tau log(1/W sum exp(c / tau))`` in float64 (the soft maximum of the glossary)."""
    tau = WINDOW_TEMPERATURE
    return float(c.max() + tau * np.log(np.mean(np.exp((c - c.max()) / tau))))


def test_late_and_early_arrival_of_equal_summed_cost_are_told_apart():
    # step costs 1 until the goal (cost 0); the late path is cheaper on the way but reaches
    # the goal two steps after the window of the last 4 steps began: equal sums (5.0)
    early = torch.tensor([1.0, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    late = torch.tensor([0.6, 0.6, 0.6, 0.6, 0.6, 0.6, 0.6, 0.8, 0.0, 0.0])
    costs = torch.stack([early, late])
    plain, windowed = _loss(None, 10), _loss(4, 10)
    assert plain.particle_costs(costs).tolist() == pytest.approx([5.0, 5.0])
    got = windowed.particle_costs(costs).tolist()
    # early: 5 + 4 * 0; late: 6 * 0.6 + 4 smax(0.6, 0.8, 0, 0), near 3.6 + 4 * 0.8
    late_w = 3.6 + 4 * _smax(np.array([0.6, 0.8, 0.0, 0.0]))
    assert got == pytest.approx([5.0, late_w], abs=1e-5)
    assert 3.6 + 4 * (0.8 - WINDOW_TEMPERATURE * np.log(4)) <= late_w <= 3.6 + 4 * 0.8
    assert got[1] > got[0] + 1.5
    # a window held at a constant cost costs its sum: J^_W = J^ there, and never less
    held = torch.tensor([[0.5, 0.4, 0.2, 0.2, 0.2, 0.2]])
    assert _loss(4, 6).particle_costs(held).item() == pytest.approx(held.sum().item())
    r = torch.rand(50, 10)
    assert (windowed.particle_costs(r) >= plain.particle_costs(r) - 1e-5).all()
    # a rollout shorter than the window takes all its steps as the window
    short = torch.tensor([[0.2, 0.3]])
    assert windowed.particle_costs(short).item() == pytest.approx(
        2 * _smax(np.array([0.2, 0.3])), abs=1e-6
    )


def test_the_window_objective_and_its_gradient_through_a_rollout():
    # x_t = 0.3 t, c_t = 0.03 t for t = 1..5 (H = 5, W = 2): J^_W = (0.03 + 0.06 + 0.09)
    # + 2 smax(0.12, 0.15); dJ^_W/dw = (1 + 2 + 3) / 10 + 2 (p_4 4 + p_5 5) / 10 with p the
    # softmax weights of (c_4, c_5) / tau; plain: 0.45 and 1.5
    c = np.array([0.12, 0.15])
    p = np.exp(c / WINDOW_TEMPERATURE) / np.exp(c / WINDOW_TEMPERATURE).sum()
    windowed = (0.18 + 2 * _smax(c), 0.6 + 2 * (4 * p[0] + 5 * p[1]) / 10)
    for window, (value, grad) in ((2, windowed), (None, (0.45, 1.5))):
        loss = _loss(window)
        td = TensorDict(
            {"initial_state": torch.zeros(1, 1), "noise": torch.zeros(5, 1, 1)}, batch_size=[]
        )
        out = loss(td)
        assert out["loss_cost"].item() == pytest.approx(value, abs=1e-5)
        out["loss_cost"].backward()
        assert loss.policy_module.w.grad.item() == pytest.approx(grad, abs=1e-4)


def test_tied_window_costs_give_a_gradient_continuous_in_the_costs():
    # a hanging pole costs about 1 at every step of the window: a perturbation of the costs
    # by 1e-6 (two float32 rollouts) moves the gradient by about as little
    loss = _loss(20, 20)
    base = torch.full((1, 20), 0.999)
    noise = 1e-6 * torch.randn(1, 20)
    grads = []
    for c in (base, base + noise):
        c = c.clone().requires_grad_(True)
        loss.particle_costs(c).sum().backward()
        grads.append(c.grad)
    assert (grads[0] - grads[1]).norm() / grads[0].norm() < 1e-3


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


def test_the_config_switch_defaults_on_and_is_checked():
    assert load_config("mcpilco/CartpoleSwingUp-v0").window_objective is True
    off = load_config("mcpilco/CartpoleSwingUp-v0", overrides={"window_objective": False})
    assert off.window_objective is False
    with pytest.raises(ValueError, match="window_objective"):
        load_config("mcpilco/CartpoleSwingUp-v0", overrides={"window_objective": "yes"})

"""Plateau restarts of the policy search: a stall of ``J^`` above the task's success level
``J_succ`` draws the policy afresh (the plateau kept as a snapshot), a stall below it does
not; ``J_succ`` is the cost of the costliest trajectory that still succeeds."""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from mcpilco.agents.mc_pilco.config import load_config
from mcpilco.agents.mc_pilco.cost import SaturatingCost
from mcpilco.agents.mc_pilco.optimize import PolicyOptConfig, optimize_policy
from mcpilco.agents.mc_pilco.trainer import success_cost_level
from mcpilco.envs.tasks.spec import TaskSpec

HIGH, LOW = 10.0, 0.0  # the two basins' floors: J = min(HIGH + (t - 2)^2, LOW + (t + 2)^2)


class TwoBasins(nn.Module):
    """A one-parameter "policy" whose ``J`` has a poor basin at ``t = 2`` (``J = 10``) and
    a good one at ``t = -2`` (``J = 0``); a fresh draw is ``t ~ U(-3, 3)``."""

    def __init__(self, t0: float) -> None:
        super().__init__()
        self.t = nn.Parameter(torch.tensor(float(t0)))
        self.dropout = 0.0
        self.draws: list[int] = []

    def reset_parameters(self, seed: int | None = None) -> None:
        gen = torch.Generator().manual_seed(int(seed))
        self.draws.append(int(seed))
        with torch.no_grad():
            self.t.copy_(torch.rand((), generator=gen) * 6.0 - 3.0)


class NoisyJ(nn.Module):
    """``J(t)`` plus Monte Carlo-like noise (std 0.05), as the loss module returns it."""

    def __init__(self, policy: TwoBasins) -> None:
        super().__init__()
        self.policy = policy

    def forward(self) -> dict[str, torch.Tensor]:
        t = self.policy.t
        j = torch.minimum(HIGH + (t - 2.0) ** 2, LOW + (t + 2.0) ** 2) + 0.05 * torch.randn(())
        return {"loss_cost": j, "cost_std": torch.tensor(0.05), "candidate_costs": j[None]}


def _run(level: float | None, seed: int = 0):
    torch.manual_seed(seed)
    policy = TwoBasins(2.0)
    cfg = PolicyOptConfig(
        max_steps=3000,
        lr=0.05,
        lr_min=0.01,
        min_steps=50,
        monitor_patience=50,
        cuda_graph=False,
        snapshot_every=0,  # the snapshots are the plateaus' (and the final parameters)
    )
    return optimize_policy(NoisyJ(policy), policy, cfg, success_level=level), policy


def test_plateau_above_the_success_level_restarts():
    """Started in the poor basin (plateau 10 > level 5): the search restarts from a fresh
    draw, records why, keeps the plateau's parameters as a snapshot, and at most
    ``max_restarts`` (2) times."""
    res, policy = _run(5.0)
    assert 1 <= len(res.restarts) <= 2 and len(policy.draws) == len(res.restarts)
    assert "above the success level 5.00" in res.restarts[0]
    plateau = float(res.restarts[0].split("plateau ")[1].split()[0])
    assert abs(plateau - HIGH) < 0.5
    kept = [float(v[0]) for _, v in res.snapshots]
    assert abs(kept[0] - 2.0) < 0.2  # the plateau's parameters, kept
    assert min(abs(t + 2.0) for t in kept) < 0.2  # a restart found the good basin
    assert res.success_level == 5.0


def test_plateau_below_the_success_level_or_no_level_does_not_restart():
    """A plateau under the level (10 < 20), or no level, runs MC-PILCO's plain schedule."""
    for level in (20.0, None):
        res, policy = _run(level)
        assert res.restarts == [] and policy.draws == []
        assert res.stop_reason == "lr_min" and abs(float(policy.t.detach()) - 2.0) < 0.2


def test_success_level_is_the_costliest_successful_trajectory():
    """On the cart-pole: a trajectory that rests at ``x_0`` for ``H - W`` steps and then sits
    at the goal box's costliest corner for the last ``W`` steps succeeds by the task's own
    test, and its optimised cost ``sum_t c(x_t)`` is ``J_succ``."""
    config = load_config("mcpilco/CartpoleSwingUp-v0")
    task: TaskSpec = config.task_spec()
    cost = SaturatingCost.from_task(task, config.cost_length_scales, config.cost_angle_mode)
    level = success_cost_level(task, cost)
    h, w = task.horizon, task.success.window
    x0 = np.asarray(task.init_mean, dtype=np.float64)
    best = None
    for sx in (-1, 1):
        for st in (-1, 1):
            corner = x0.copy()
            for name, s in (("x", sx), ("theta", st)):
                b = task.success.bounds[name]
                corner[task.index(name)] = b.target + s * b.tol * (1 - 1e-9)
            traj = np.stack([x0] * (h - w) + [corner] * w)
            assert task.is_success(traj, {}, h)
            j = float(cost(torch.as_tensor(traj, dtype=torch.float32)).sum())
            best = j if best is None else max(best, j)
    assert abs(best - level) < 1e-3 * level
    assert success_cost_level(task.replace(success=type(task.success)(info_key="x")), cost) is None

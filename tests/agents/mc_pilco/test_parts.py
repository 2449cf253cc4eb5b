"""Unit tests of the MC-PILCO parts against independent truth (analytic cases, the env's cost)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn

from mcpilco.agents.mc_pilco import (
    CostMonitor,
    MCPilcoLoss,
    PolicyOptConfig,
    SaturatingCost,
    SpeedIntegrationDynamics,
    SquashedRBFPolicy,
    StateLayout,
    TaskSpec,
    make_policy_module,
    optimize_policy,
    speed_integration,
)
from mcpilco.agents.mc_pilco.optimize import choose_policy, snapshot_interval
from mcpilco.agents.mc_pilco.policy import dropout_mask
from mcpilco.envs.cartpole_task import cartpole_cost

DT = 0.05
TASK = TaskSpec.for_env("mcpilco/CartpoleSwingUp-v0")
LAYOUT = StateLayout.from_task(TASK)  # [x, x_dot, theta, theta_dot], theta an angle


def swingup_cost(l_x: float = 1.5, l_theta: float = 1.0, wrap: bool = True) -> SaturatingCost:
    """The cart-pole's saturating cost with the given length scales (the task's by default,
    thesis 5.5.1) and the wrapped angle or ``|theta| - pi``."""
    return SaturatingCost.from_task(
        TASK, length_scales={"x": l_x, "theta": l_theta}, angle_mode="wrap" if wrap else "abs"
    )


# ------------------------------------------------------------------------------ cost
def test_cost_matches_env_numpy_cost():
    rng = np.random.default_rng(0)
    states = rng.normal(size=(500, 4)) * np.array([1.0, 1.0, 8.0, 1.0])
    states[:5, 2] = [0.0, np.pi, -np.pi, 3 * np.pi, -5 * np.pi]
    states[:5, 0] = 0.0
    expected = cartpole_cost(states, l_theta=1.0, l_x=1.5)
    cost = swingup_cost(l_x=1.5, l_theta=1.0)
    assert cost.idx == (0, 2) and cost.targets == (0.0, math.pi)
    assert cost.length_scales == (1.5, 1.0)
    got = cost(torch.as_tensor(states)).numpy()
    np.testing.assert_allclose(got, expected, atol=1e-12)
    assert got[1] == pytest.approx(0.0, abs=1e-12)  # upright, cart at origin
    # the task's own cost (no overrides) and its numpy evaluation cost are the same cost
    np.testing.assert_allclose(
        SaturatingCost.from_task(TASK)(torch.as_tensor(states)).numpy(), expected, atol=1e-12
    )
    np.testing.assert_allclose(TASK.cost(states), expected, atol=1e-12)


def test_cost_rejects_bad_shape_and_lengthscale():
    with pytest.raises(ValueError, match="length scales"):
        swingup_cost(l_x=0.0)
    with pytest.raises(ValueError, match="no cost term"):
        SaturatingCost.from_task(TASK, length_scales={"x_dot": 1.0})
    with pytest.raises(ValueError, match="angle_mode"):
        SaturatingCost.from_task(TASK, angle_mode="spin")
    with pytest.raises(ValueError, match=r"\(\.\.\., 4\)"):
        swingup_cost()(torch.zeros(3, 5))


# ------------------------------------------------------------------- speed integration
class ConstantDelta(nn.Module):
    """Stub velocity-change model: Delta = a * dt, zero variance (constant acceleration)."""

    def __init__(self, accel):
        super().__init__()
        self.delta = torch.as_tensor(accel, dtype=torch.float64) * DT

    def forward(self, z):
        mean = self.delta.expand(*z.shape[:-1], 2)
        return mean, torch.zeros_like(mean)


def test_speed_integration_is_exact_for_constant_acceleration():
    accel = torch.tensor([0.7, -2.0], dtype=torch.float64)
    q0 = torch.tensor([0.1, 0.3], dtype=torch.float64)
    v0 = torch.tensor([-0.5, 1.2], dtype=torch.float64)
    x = torch.stack([q0, v0], -1).flatten()  # [x, x_dot, theta, theta_dot]
    dyn = SpeedIntegrationDynamics(ConstantDelta(accel), DT, LAYOUT)
    u = torch.zeros(1, dtype=torch.float64)
    for _ in range(40):
        x = dyn(x, u)
    t = 40 * DT
    q_true = q0 + v0 * t + 0.5 * accel * t**2  # kinematics of constant acceleration
    v_true = v0 + accel * t
    torch.testing.assert_close(x[[0, 2]], q_true, atol=1e-12, rtol=0)
    torch.testing.assert_close(x[[1, 3]], v_true, atol=1e-12, rtol=0)


def test_speed_integration_layout():
    state = torch.tensor([1.0, 2.0, 3.0, 4.0])
    nxt = speed_integration(state, torch.tensor([0.5, -1.0]), 0.1, LAYOUT)
    # x+ = 1 + 0.1*2 + 0.05*0.5, xd+ = 2.5, th+ = 3 + 0.4 - 0.05, thd+ = 3
    torch.testing.assert_close(nxt, torch.tensor([1.225, 2.5, 3.35, 3.0]))


# ------------------------------------------------------------- linear-model rollout
class LinearDelta(nn.Module):
    """Stub GP: Delta = B [x, x_dot, theta_dot, u] + c, constant variance sigma2 (per output).

    Reads the GP input x~ = [x, x_dot, theta_dot, sin, cos, u]; sin/cos are ignored so the
    closed loop with a linear policy is linear in the state.
    """

    def __init__(self, B, c, sigma2):
        super().__init__()
        self.B, self.c, self.sigma2 = B, c, sigma2

    def forward(self, z):
        lin = torch.cat([z[..., 0:3], z[..., 5:6]], -1)
        mean = lin @ self.B.T + self.c
        return mean, self.sigma2.expand_as(mean)


def _linear_setup(sigma2_val: float):
    f64 = torch.float64
    B = torch.tensor([[-0.02, -0.01, 0.0, 0.5], [0.05, 0.0, -0.03, -0.8]], dtype=f64)
    c = torch.tensor([0.01, -0.02], dtype=f64)
    k_pol = torch.tensor([[0.3, -0.2, 0.0, 0.1]], dtype=f64)  # u = k x (no theta weight)
    sigma2 = torch.full((2,), sigma2_val, dtype=f64)
    policy = nn.Linear(4, 1, bias=False, dtype=f64)
    with torch.no_grad():
        policy.weight.copy_(k_pol)
    dyn = SpeedIntegrationDynamics(LinearDelta(B, c, sigma2), DT, LAYOUT)
    # analytic closed loop x+ = F x + g + E eps with state [x, xd, th, thd]
    # Delta = B_s x + B_u u + c with B_s acting on [x, xd, thd]
    Bs = torch.zeros(2, 4, dtype=f64)
    Bs[:, [0, 1, 3]] = B[:, :3]
    Bd = Bs + B[:, 3:4] @ k_pol  # Delta = Bd x + c
    P = torch.zeros(4, 4, dtype=f64)  # speed integration: q+ = q + dt qd + dt/2 Delta
    P[0, 0] = P[2, 2] = 1.0
    P[0, 1] = P[2, 3] = DT
    P[1, 1] = P[3, 3] = 1.0
    S = torch.zeros(4, 2, dtype=f64)  # how Delta enters the state
    S[0, 0], S[1, 0], S[2, 1], S[3, 1] = DT / 2, 1.0, DT / 2, 1.0
    F = P + S @ Bd
    g = S @ c
    E = S * sigma2.sqrt()
    return policy, dyn, F, g, E


@pytest.mark.parametrize("horizon", [1, 25])
def test_rollout_with_linear_model_gives_analytic_mean_without_noise(horizon):
    policy, dyn, F, g, _ = _linear_setup(0.0)
    x0 = torch.tensor([[0.2, -0.1, 0.5, 0.3], [0.0, 0.4, -1.0, 0.0]], dtype=torch.float64)
    loss = MCPilcoLoss(
        policy, dyn, swingup_cost(), horizon=horizon, num_particles=2, init_mean=TASK.init_mean
    )
    ro = loss.rollout(initial_state=x0, noise=torch.zeros(horizon, 2, 2, dtype=torch.float64))
    x = x0.clone()
    expected_cost = torch.zeros((), dtype=torch.float64)
    for _ in range(horizon):
        x = x @ F.T + g
        expected_cost = expected_cost + swingup_cost()(x).mean()
    torch.testing.assert_close(ro.states[:, -1], x, atol=1e-10, rtol=0)
    td = loss(
        TensorDict(
            {"initial_state": x0, "noise": torch.zeros(horizon, 2, 2, dtype=torch.float64)}, []
        )
    )
    torch.testing.assert_close(td["loss_cost"], expected_cost, atol=1e-10, rtol=0)


def test_rollout_with_linear_gaussian_model_gives_analytic_mean_and_covariance():
    torch.manual_seed(0)
    H, M = 20, 20000
    policy, dyn, F, g, E = _linear_setup(1e-3)
    mu0 = torch.tensor([0.1, 0.0, 0.2, 0.0], dtype=torch.float64)
    std0 = 0.05
    loss = MCPilcoLoss(policy, dyn, swingup_cost(), H, M, init_mean=mu0, init_std=std0)
    x0 = mu0 + std0 * torch.randn(M, 4, dtype=torch.float64)
    with torch.no_grad():
        xs = loss.rollout(initial_state=x0).states[:, -1]
    mean, cov = mu0.clone(), torch.eye(4, dtype=torch.float64) * std0**2
    for _ in range(H):
        mean = F @ mean + g
        cov = F @ cov @ F.T + E @ E.T
    emp_mean = xs.mean(0)
    emp_cov = torch.cov(xs.T)
    se = (cov.diagonal() / M).sqrt()
    assert torch.all((emp_mean - mean).abs() < 5 * se), (emp_mean, mean)
    rel = (emp_cov - cov).abs() / (cov.diagonal()[:, None] * cov.diagonal()[None, :]).sqrt()
    assert rel.max() < 0.05, rel


def test_loss_validates_arguments():
    policy, dyn, *_ = _linear_setup(0.0)
    mu0 = TASK.init_mean
    with pytest.raises(ValueError, match="num_particles"):
        MCPilcoLoss(policy, dyn, swingup_cost(), horizon=10, num_particles=0, init_mean=mu0)
    with pytest.raises(ValueError, match="horizon"):
        MCPilcoLoss(policy, dyn, swingup_cost(), horizon=0, num_particles=3, init_mean=mu0)
    loss = MCPilcoLoss(policy, dyn, swingup_cost(), horizon=10, num_particles=3, init_mean=mu0)
    assert loss.delta_dim == 2  # one GP per velocity, from the dynamics' layout
    with pytest.raises(ValueError, match="horizon of the noise"):
        loss.rollout(
            initial_state=torch.zeros(3, 4, dtype=torch.float64),
            noise=torch.zeros(7, 3, 2, dtype=torch.float64),
        )


def test_loss_gradient_reaches_policy_parameters():
    policy = make_policy_module(SquashedRBFPolicy(LAYOUT, num_basis=20, seed=0))
    _, dyn, *_ = _linear_setup(1e-4)
    dyn.delta_model.B = dyn.delta_model.B.float()
    dyn.delta_model.c = dyn.delta_model.c.float()
    dyn.delta_model.sigma2 = dyn.delta_model.sigma2.float()
    loss = MCPilcoLoss(
        policy, dyn, swingup_cost(), horizon=15, num_particles=8, init_mean=TASK.init_mean
    )
    out = loss()
    assert set(out.keys()) >= {"loss_cost", "cost_std"}
    out["loss_cost"].backward()
    grads = [p.grad for p in policy.parameters()]
    assert all(g is not None and torch.isfinite(g).all() for g in grads)
    assert any(g.abs().sum() > 0 for g in grads)


# ---------------------------------------------------------------------------- policy
@pytest.mark.parametrize("low, high", [(-0.7, 0.7), (-0.2, 1.0)])
def test_policy_squashing_bounds_and_tensordict_keys(low, high):
    pol = SquashedRBFPolicy(LAYOUT, (low,), (high,), num_basis=50, seed=1)
    assert pol.u_max == pytest.approx((high - low) / 2)
    with torch.no_grad():
        pol.weights.mul_(1e4)  # saturate
    module = make_policy_module(pol)
    assert isinstance(module, TensorDictModule)
    assert module.in_keys == ["observation"] and module.out_keys == ["action"]
    obs = torch.randn(256, 4) * 3
    pol.eval()
    td = module(TensorDict({"observation": obs}, [256]))
    u = td["action"]
    assert u.shape == (256, 1)
    assert u.min() >= low - 1e-6 and u.max() <= high + 1e-6
    assert u.min() < low + 0.01 and u.max() > high - 0.01  # really saturates at both bounds


def test_policy_is_periodic_in_theta_and_matches_formula():
    pol = SquashedRBFPolicy(LAYOUT, num_basis=7, seed=3)
    pol.eval()
    obs = torch.tensor([[0.1, -0.2, 0.4, 1.0]])
    obs2 = obs.clone()
    obs2[0, 2] += 2 * math.pi
    torch.testing.assert_close(pol(obs), pol(obs2), atol=1e-5, rtol=0)
    # independent evaluation of u = u_max tanh(sum_i w_i phi_i / u_max) on the features
    # x~ = [x, x_dot, theta_dot, sin theta, cos theta]
    xt = torch.tensor([0.1, -0.2, 1.0, math.sin(0.4), math.cos(0.4)])
    ell = pol.log_lengthscales.exp()
    phi = torch.exp(-0.5 * (((xt - pol.centers) / ell) ** 2).sum(-1))
    expected = pol.u_max * torch.tanh((phi @ pol.weights) / pol.u_max)
    torch.testing.assert_close(pol(obs)[0], expected, atol=1e-5, rtol=0)


def test_policy_dropout_only_in_training():
    pol = SquashedRBFPolicy(LAYOUT, num_basis=50, dropout=0.5, seed=0)
    obs = torch.randn(10, 4)
    pol.eval()
    torch.testing.assert_close(pol(obs), pol(obs))
    pol.train()
    torch.manual_seed(0)
    a = pol(obs)
    b = pol(obs)
    assert not torch.allclose(a, b)


# --------------------------------------------------------------- monitoring rule
def test_monitor_detects_stall_and_not_steady_descent():
    rng = np.random.default_rng(0)
    mon = CostMonitor(alpha=0.99, threshold=0.08, patience=50)
    stalled_at = None
    for k in range(2000):  # flat cost with Monte Carlo noise: a stall
        if mon.update(30.0 + rng.normal(scale=0.3)):
            stalled_at = k
            break
    assert stalled_at is not None and stalled_at >= 50
    # steady descent of 0.1 per step under the same noise (a quarter of the std of d_k):
    # once the filters have settled (min_steps), never a stall
    mon = CostMonitor(alpha=0.99, threshold=0.08, patience=50, min_steps=300)
    for k in range(3000):
        assert not mon.update(30.0 - 0.1 * k + rng.normal(scale=0.3))


def test_monitor_signal_is_the_smoothed_change_over_its_spread():
    """Second implementation of the filters of the glossary, on a random cost sequence."""
    rng = np.random.default_rng(1)
    costs = 40.0 - 0.02 * np.arange(300) + rng.normal(scale=0.5, size=300)
    mon = CostMonitor(alpha=0.9, threshold=0.08, patience=10**6)
    m = v = s = 0.0
    for k, c in enumerate(costs):
        mon.update(float(c))
        if k:
            d = costs[k] - costs[k - 1]
            v = 0.9 * (v + 0.1 * (d - m) ** 2)
            m = 0.9 * m + 0.1 * d
            s = 0.9 * s + 0.1 * m / np.sqrt(v)
        assert mon.signal == pytest.approx(s, rel=1e-12, abs=1e-15)


def test_monitor_waits_min_steps_and_halves_threshold_on_stall():
    mon = CostMonitor(alpha=0.99, threshold=0.08, patience=5, min_steps=40, threshold_min=0.03)
    first = next(k for k in range(100) if mon.update(1.0 + 1e-3 * (-1) ** k))
    assert first == 40  # stalled long before, reported after min_steps
    mon.on_stall()
    assert mon.threshold == 0.04 and mon.count == 0
    mon.on_stall()
    assert mon.threshold == 0.03  # not below threshold_min


class StalledLoss(nn.Module):
    """A loss whose cost only fluctuates (Monte Carlo noise, no trend): a stalled
    optimisation; tiny gradient."""

    def __init__(self, policy, nan_first: int = 0):
        super().__init__()
        self.policy = policy
        self.calls = 0
        self.nan_first = nan_first
        self.rng = np.random.default_rng(0)

    def forward(self):
        self.calls += 1
        val = 1e-9 * self.policy.weights.sum() + 5.0 + float(self.rng.normal(scale=0.1))
        if self.calls <= self.nan_first:
            val = val * float("nan")
        return TensorDict({"loss_cost": val, "cost_std": torch.tensor(1.0)}, [])


def test_optimizer_halves_lr_and_reduces_dropout_on_stall():
    pol = SquashedRBFPolicy(LAYOUT, num_basis=5, seed=0)
    cfg = PolicyOptConfig(
        max_steps=5000, lr=0.01, lr_min=0.0025, dropout=0.25, monitor_patience=20, min_steps=20
    )
    res = optimize_policy(StalledLoss(pol), pol, cfg)
    lrs = sorted(set(res.lrs), reverse=True)
    assert lrs == [0.01, 0.005, 0.0025]  # halved twice, then a stall at a_min ends it
    assert sorted(set(res.dropouts), reverse=True) == [0.25, 0.125, 0.0]
    assert res.num_lr_reductions == 2
    assert res.stop_reason == "lr_min"
    assert res.num_steps < 5000
    first_half = res.lrs.index(0.005)
    assert first_half >= 20  # not before min_steps and patience
    assert not pol.training  # left in eval mode


def test_optimizer_reinitialises_policy_on_nan_cost():
    pol = SquashedRBFPolicy(LAYOUT, num_basis=5, seed=0)
    cfg = PolicyOptConfig(max_steps=10, monitor_patience=100)
    res = optimize_policy(StalledLoss(pol, nan_first=2), pol, cfg)
    assert res.num_reinits == 2
    assert res.num_steps == 8
    with pytest.raises(FloatingPointError, match="not finite"):
        optimize_policy(StalledLoss(pol, nan_first=100), pol, PolicyOptConfig(max_steps=10))


def test_optimizer_keeps_snapshots_of_the_parameters_it_had_after_those_steps():
    """``snapshot_every = 4`` over 10 steps: the starting parameters (step 0), copies after
    steps 4 and 8 and the final ones (10), each equal to the parameters seen by ``on_step``
    after that step (before the first step for step 0)."""
    pol = SquashedRBFPolicy(LAYOUT, num_basis=5, seed=0)
    seen = {0: [p.detach().clone() for p in pol.parameters() if p.requires_grad]}

    def on_step(k, *_):
        seen[k + 1] = [p.detach().clone() for p in pol.parameters() if p.requires_grad]

    cfg = PolicyOptConfig(max_steps=10, monitor_patience=100, snapshot_every=4)
    res = optimize_policy(StalledLoss(pol), pol, cfg, on_step=on_step)
    assert [step for step, _ in res.snapshots] == [0, 4, 8, 10]
    for step, values in res.snapshots:
        for v, w in zip(values, seen[step], strict=True):
            torch.testing.assert_close(v, w, rtol=0, atol=0)
    first, last = res.snapshots[0][1], res.snapshots[-1][1]
    assert any(not torch.equal(v, w) for v, w in zip(first, last, strict=True))
    only_final = optimize_policy(
        StalledLoss(pol), pol, PolicyOptConfig(max_steps=3, snapshot_every=0)
    )
    assert [step for step, _ in only_final.snapshots] == [3]
    with pytest.raises(ValueError, match="snapshot_every must be an integer"):
        PolicyOptConfig(snapshot_every=-1)


@pytest.mark.parametrize(("steps", "every"), [(1000, 100), (500, 50), (25, 3), (7, 1)])
def test_derived_snapshot_interval_keeps_about_ten_copies(steps, every):
    """``snapshot_every`` None: ``S = ceil(N_opt / 10)``, so the copies kept are the start,
    ``floor(N_opt / S)`` iterates and the final ones (counted on a run of ``N_opt`` steps)."""
    cfg = PolicyOptConfig(max_steps=steps, monitor_patience=10_000)
    assert cfg.snapshot_every is None and snapshot_interval(cfg) == every
    assert snapshot_interval(PolicyOptConfig(snapshot_every=7), 1000) == 7
    if steps <= 30:
        pol = SquashedRBFPolicy(LAYOUT, num_basis=5, seed=0)
        res = optimize_policy(StalledLoss(pol), pol, cfg)
        expected = [0, *range(every, steps + 1, every)]
        expected += [] if expected[-1] == steps else [steps]
        assert [step for step, _ in res.snapshots] == expected and res.snapshot_every == every


class ToyPopulation(nn.Module):
    """K candidate points ``w`` (K, 2) with the policy interface :func:`choose_policy` and
    :func:`optimize_policy` use; ``copy_to`` writes a candidate into a ``ToyPolicy``."""

    def __init__(self, w: torch.Tensor) -> None:
        super().__init__()
        self.w = nn.Parameter(w.clone())

    def copy_to(self, k: int, policy: nn.Module) -> None:
        with torch.no_grad():
            policy.w.copy_(self.w[k])

    def reset_parameters(self, seed: int | None = None) -> None:
        raise AssertionError("no restart expected")


class ToyCost(nn.Module):
    """``J(w) = |w - w*|^2`` per candidate, the known minimum ``w*``. While the population
    trains, a random tilt ``noise eps^T w`` (``eps ~ N(0, I)`` per call) makes the gradient
    noisy, as dropout does; in evaluation mode only a draw shared by every candidate is
    added (a Monte Carlo estimate's noise), which common random numbers cancel between
    snapshots."""

    def __init__(self, pop: ToyPopulation, target: torch.Tensor, noise: float) -> None:
        super().__init__()
        self.pop, self.target, self.noise = pop, target, noise

    def forward(self):
        w = self.pop.w
        per = ((w - self.target) ** 2).sum(1)
        if self.pop.training:
            per = per + self.noise * (torch.randn(w.shape[1]) * w).sum(1)
        else:
            per = per + self.noise * torch.randn(())
        return {"loss_cost": per.sum(), "cost_std": torch.tensor(0.0), "candidate_costs": per}


def _apply_best(start: torch.Tensor, target: torch.Tensor, lr: float, steps: int):
    """Adam from ``start`` on the noisy toy cost, snapshots every step, then choose_policy:
    (chosen point, snapshot points, result)."""
    torch.manual_seed(0)
    pop = ToyPopulation(start)
    cost = ToyCost(pop, target, noise=0.5)
    cfg = PolicyOptConfig(max_steps=steps, lr=lr, monitor_patience=10_000, snapshot_every=1)
    res = optimize_policy(cost, pop, cfg)
    applied = nn.Module()
    applied.w = nn.Parameter(torch.zeros(2))
    table, s = choose_policy(cost, pop, applied, res.snapshots)
    return applied.w.detach(), [v[0][0] for _, v in res.snapshots], res, table, s


def test_choose_policy_applies_the_iterate_nearest_the_known_minimum():
    """Adam with a large step overshoots and oscillates around ``w*``: the last iterate is
    not the best one. The applied point is the snapshot nearest ``w*`` (the analytic cost,
    not the noisy estimate the optimiser saw), strictly better than the last iterate."""
    target = torch.tensor([1.0, -2.0])
    chosen, points, res, table, s = _apply_best(torch.zeros(1, 2), target, lr=0.8, steps=40)
    true = [float(((p - target) ** 2).sum()) for p in points]
    best = min(range(len(true)), key=true.__getitem__)
    assert s == best and true[best] < true[-1]
    torch.testing.assert_close(chosen, points[best])
    torch.testing.assert_close(table[:, 0] - table[best, 0], torch.tensor(true) - true[best])


def test_choose_policy_keeps_the_starting_policy_when_it_is_the_best():
    """Started at the minimum (the previous trial's policy already optimal), noisy Adam
    steps only move away: the step-0 snapshot, the starting point, is applied unchanged."""
    target = torch.tensor([0.5, 0.25])
    chosen, points, res, _, s = _apply_best(target[None].clone(), target, lr=0.3, steps=20)
    assert res.snapshots[0][0] == 0 and s == 0
    assert float(((points[-1] - target) ** 2).sum()) > 1e-3  # the optimiser did move away
    torch.testing.assert_close(chosen, target, rtol=0, atol=0)


def test_unwrapped_cost_penalises_full_rotations():
    cost = swingup_cost(l_x=1.0, l_theta=3.0, wrap=False)
    up_once = torch.tensor([0.0, 0.0, math.pi, 0.0])
    up_after_spin = torch.tensor([0.0, 0.0, 3 * math.pi, 0.0])
    assert float(cost(up_once)) == pytest.approx(0.0, abs=1e-12)
    expected = 1 - math.exp(-((2 * math.pi) ** 2) / 9.0)  # |theta| - pi = 2 pi
    assert float(cost(up_after_spin)) == pytest.approx(expected, rel=1e-6)
    assert float(swingup_cost(wrap=True)(up_after_spin)) == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("p", [0.25, 0.125, 0.5])
def test_dropout_mask_is_bernoulli_with_unit_mean(p):
    torch.manual_seed(0)
    d = dropout_mask((400, 250), p, torch.float64)
    keep = 1.0 - p
    assert set(torch.unique(d).tolist()) == {0.0, 1.0 / keep}
    n = d.numel()
    frac = float((d == 0).double().mean())
    assert abs(frac - p) < 4 * math.sqrt(p * keep / n)  # binomial 4-sigma band
    assert abs(float(d.mean()) - 1.0) < 4 * math.sqrt(p / keep / n)
    # independent entries: neighbouring bytes of the same 64-bit word are uncorrelated
    flat = (d.flatten() == 0).double()
    corr = float(((flat[:-1] - p) * (flat[1:] - p)).mean() / (p * keep))
    assert abs(corr) < 4 / math.sqrt(n)
    assert torch.equal(dropout_mask((3, 4), 0.0, torch.float32), torch.ones(3, 4))
    with pytest.raises(ValueError, match="dropout"):
        dropout_mask((3,), 1.0, torch.float32)

"""Candidate policies optimised side by side (``PolicyPopulation``) against independent truth:
each candidate on its own, with the same initial states and noise (common random numbers)."""

from __future__ import annotations

import dataclasses

import pytest
import torch
from torch import nn

from mcpilco.agents.common.checkpoint import load_checkpoint
from mcpilco.agents.mc_pilco import (
    MCPilcoLoss,
    PolicyPopulation,
    SaturatingCost,
    SpeedIntegrationDynamics,
    SquashedRBFPolicy,
    StateLayout,
    TaskSpec,
    make_policy_module,
    run_mcpilco,
)
from mcpilco.agents.mc_pilco.optimize import choose_policy

f64 = torch.float64
TASK = TaskSpec.for_env("mcpilco/CartpoleSwingUp-v0")
LAYOUT = StateLayout.from_task(TASK)
MU0 = TASK.init_mean


class LinearDelta(nn.Module):
    """A known smooth stand-in for the GP: mean and variance of Delta from the GP input."""

    def forward(self, z):
        return 0.3 * torch.tanh(z[..., :2] - z[..., 5:6]), 0.01 + 0.01 * z[..., 3:5] ** 2


def _candidates(k: int) -> list[SquashedRBFPolicy]:
    return [
        SquashedRBFPolicy(LAYOUT, num_basis=20, weight_scale=0.8, seed=s).to(f64) for s in range(k)
    ]


def test_population_rows_use_their_own_candidate():
    cands = _candidates(3)
    pop = PolicyPopulation(cands).to(f64).eval()
    obs = torch.randn(3 * 7, 4, dtype=f64)
    u = pop(obs)
    for k, p in enumerate(cands):
        p.eval()
        torch.testing.assert_close(u[7 * k : 7 * (k + 1)], p(obs[7 * k : 7 * (k + 1)]))
        c = pop.candidate(k).to(f64)
        torch.testing.assert_close(c.weights, p.weights)
    with pytest.raises(ValueError, match="K = 3"):
        pop(torch.randn(8, 4, dtype=f64))
    with pytest.raises(ValueError, match="same architecture"):
        PolicyPopulation(
            [SquashedRBFPolicy(LAYOUT, num_basis=5), SquashedRBFPolicy(LAYOUT, num_basis=6)]
        )
    with pytest.raises(ValueError, match="same architecture"):  # other action bounds
        PolicyPopulation(
            [
                SquashedRBFPolicy(LAYOUT, num_basis=5),
                SquashedRBFPolicy(LAYOUT, (-2.0,), (2.0,), num_basis=5),
            ]
        )


def test_population_loss_and_gradients_equal_each_candidate_alone():
    K, M, H = 3, 16, 10
    cands = _candidates(K)
    dyn = SpeedIntegrationDynamics(LinearDelta(), 0.05, LAYOUT)
    cost = SaturatingCost.from_task(TASK, {"x": 1.0, "theta": 3.0}, angle_mode="abs")
    pop = PolicyPopulation(cands).to(f64)
    pop.eval()  # no dropout: deterministic given the noise
    gen = torch.Generator().manual_seed(0)
    x0 = 0.1 * torch.randn(K * M, 4, generator=gen, dtype=f64)
    eps = torch.randn(H, K * M, 2, generator=gen, dtype=f64)
    loss = MCPilcoLoss(make_policy_module(pop), dyn, cost, H, M, MU0)
    from tensordict import TensorDict

    out = loss(TensorDict({"initial_state": x0, "noise": eps}, []))
    grads = torch.autograd.grad(out["loss_cost"], [pop.centers, pop.weights, pop.log_lengthscales])
    for k, p in enumerate(cands):
        p.eval()
        rows = slice(k * M, (k + 1) * M)
        single = MCPilcoLoss(make_policy_module(p), dyn, cost, H, M, MU0)
        o = single(TensorDict({"initial_state": x0[rows], "noise": eps[:, rows]}, []))
        torch.testing.assert_close(out["candidate_costs"][k], o["loss_cost"].detach())
        g = torch.autograd.grad(o["loss_cost"], [p.centers, p.weights, p.log_lengthscales])
        for g_pop, g_one in zip(grads, g, strict=True):
            torch.testing.assert_close(g_pop[k], g_one, atol=1e-12, rtol=1e-9)
    torch.testing.assert_close(out["loss_cost"].detach(), out["candidate_costs"].sum())


def _population_loss(K: int = 3, H: int = 20, M: int = 64):
    cands = [SquashedRBFPolicy(LAYOUT, num_basis=20, weight_scale=0.8, seed=s) for s in range(K)]
    with torch.no_grad():
        cands[1].weights.zero_()  # u = 0: the pole stays down, the highest cost
    dyn = SpeedIntegrationDynamics(LinearDelta(), 0.05, LAYOUT)
    pop = PolicyPopulation(cands)
    cost = SaturatingCost.from_task(TASK, angle_mode="abs")
    return pop, cands, MCPilcoLoss(make_policy_module(pop), dyn, cost, H, M, MU0)


def test_choose_policy_copies_the_lowest_expected_cost():
    K = 3  # float32, as in the loop
    pop, cands, loss = _population_loss(K)
    applied = SquashedRBFPolicy(LAYOUT, num_basis=20, weight_scale=0.8)
    costs, snap = choose_policy(loss, pop, applied)
    best = int(costs[0].argmin())
    assert costs.shape == (1, K) and snap == 0 and best != 1
    torch.testing.assert_close(applied.weights, cands[best].weights)


def test_choose_policy_over_snapshots_compares_them_on_the_same_draws():
    """Snapshots: the current parameters, the same again, and one where every candidate is
    the zero policy (pole stays down, the highest cost). The two equal snapshots get the
    same J^ to the last bit (same particles); the zero snapshot is never chosen; the
    population is left at the chosen snapshot."""
    pop, _, loss = _population_loss()
    params = [p for p in pop.parameters() if p.requires_grad]
    now = [p.detach().clone() for p in params]
    zero = [p.detach().clone() for p in params]
    zero[[i for i, p in enumerate(params) if p is pop.weights][0]].zero_()
    applied = SquashedRBFPolicy(LAYOUT, num_basis=20, weight_scale=0.8)
    torch.manual_seed(0)
    costs, snap = choose_policy(loss, pop, applied, [(10, zero), (20, now), (30, now)])
    assert costs.shape == (3, 3)
    torch.testing.assert_close(costs[1], costs[2], rtol=0, atol=0)
    assert bool((costs[0] > costs[1].min()).all()) and snap in (1, 2)
    for p, v in zip(params, now, strict=True):
        torch.testing.assert_close(p, v)
    k = int(costs[snap].argmin())
    torch.testing.assert_close(
        applied.weights, now[[i for i, p in enumerate(params) if p is pop.weights][0]][k]
    )


def test_loop_with_two_candidates_applies_the_chosen_one_and_resumes(tmp_path):
    from tests.agents.mc_pilco.test_trainer import SMOKE

    cfg = dataclasses.replace(SMOKE, num_candidates=2)
    summary = run_mcpilco(cfg, tmp_path, progress=False, log=None, write_rrd=False)
    rec = summary.records[1]
    assert len(rec["candidate_costs"]) == 2
    assert rec["chosen_candidate"] == int(torch.tensor(rec["candidate_costs"]).argmin())
    # derived snapshots: the previous policy (step 0), then every S steps, the final last
    every, steps = rec["opt_snapshot_every"], rec["snapshot_steps"]
    assert every >= 1 and steps[0] == 0 and steps[-1] == rec["opt_steps"]
    assert all(s % every == 0 for s in steps[1:-1]) and rec["chosen_step"] in steps
    assert rec["chosen_cost"] == min(rec["snapshot_costs"]) and rec["choose_s"] >= 0
    ckpt = load_checkpoint(summary.checkpoint)
    pop = ckpt["population"]
    torch.testing.assert_close(ckpt["policy"]["weights"], pop["weights"][rec["chosen_candidate"]])
    resumed = run_mcpilco(
        dataclasses.replace(cfg, num_trials=2),
        tmp_path,
        resume=True,
        progress=False,
        log=None,
        write_rrd=False,
    )
    assert [r["index"] for r in resumed.records] == [0, 1, 2]
    with pytest.raises(ValueError, match="num_candidates"):
        run_mcpilco(SMOKE, tmp_path, resume=True, progress=False, log=None, write_rrd=False)


def test_candidates_may_differ_only_in_initial_weight_scale(tmp_path):
    """Weights start as w ~ U(-s_k, s_k): candidate k's initial weights lie within its own s_k
    (and fill most of it); anything but the weight scale must still agree."""
    from tests.agents.mc_pilco.test_trainer import SMOKE

    scales = [0.01, 0.5]
    cfg = dataclasses.replace(SMOKE, num_trials=0, num_candidates=2, candidate_weight_scales=scales)
    summary = run_mcpilco(cfg, tmp_path, progress=False, log=None, write_rrd=False)
    w = load_checkpoint(summary.checkpoint)["population"]["weights"]  # after exploration only
    for k, s in enumerate(scales):
        assert float(w[k].abs().max()) <= s and float(w[k].abs().max()) > 0.8 * s
    with pytest.raises(ValueError, match="same architecture"):
        PolicyPopulation(
            [
                SquashedRBFPolicy(LAYOUT, num_basis=5, dropout=0.1),
                SquashedRBFPolicy(LAYOUT, num_basis=5),
            ]
        )
    with pytest.raises(ValueError, match="candidate_weight_scales"):
        dataclasses.replace(SMOKE, num_candidates=2, candidate_weight_scales=[0.1])
    with pytest.raises(ValueError, match="candidate_weight_scales"):
        dataclasses.replace(SMOKE, num_candidates=2, candidate_weight_scales=[0.1, 0.0])

"""The rollout's hand-written backward passes against independent truth.

The policy, GP inputs, reparameterised sampling + integration, cost and the fused GP posterior
each run as one ``torch.autograd.Function`` with an analytic backward. Checked here:

* each backward against finite differences (``gradcheck``, float64);
* a whole particle rollout (GP dynamics, dropout, simulated observation noise, clipping) and
  its policy gradient against a plain-autograd reference written from the formulas, with the
  GP posterior from the GP core's ``CachedPredictor`` (gpytorch kernel evaluation), float64.
"""

from __future__ import annotations

import math
import subprocess
import sys

import pytest
import torch
from tensordict import TensorDict
from torch import nn

from mcpilco.agents.mc_pilco import (
    GPDynamicsModel,
    MCPilcoLoss,
    PolicyPopulation,
    SaturatingCost,
    SpeedIntegrationDynamics,
    SquashedRBFPolicy,
    StateLayout,
    TaskSpec,
    gp_inputs,
    make_policy_module,
)
from mcpilco.agents.mc_pilco.fast import (
    FastRollout,
    ShardedRollout,
    TorchRollout,
    use_fast_rollout,
)
from mcpilco.agents.mc_pilco.policy import _SquashedRBF, dropout_mask
from mcpilco.models.gp.fused import FusedRBFMPKPredictor

f64 = torch.float64
DT = 0.05


def _use(loss: MCPilcoLoss, enable: bool = True, **kwargs) -> FastRollout:
    """``use_fast_rollout(loss, **kwargs)``, or the eager rollout when not ``enable``."""
    if not enable:
        loss.set_fast_rollout(None)
        return FastRollout()
    return use_fast_rollout(loss, **kwargs)


TASK = TaskSpec.for_env("mcpilco/CartpoleSwingUp-v0")
LAYOUT = StateLayout.from_task(TASK)  # [x, x_dot, theta, theta_dot], theta an angle
MU0 = TASK.init_mean  # (0, 0, 0, 0)


def swingup_cost(l_x: float = 1.5, l_theta: float = 1.0, wrap: bool = True) -> SaturatingCost:
    """The cart-pole's saturating cost on ``x`` (target 0) and ``theta`` (target pi), with the
    wrapped angle or ``|theta| - pi``."""
    return SaturatingCost.from_task(
        TASK, length_scales={"x": l_x, "theta": l_theta}, angle_mode="wrap" if wrap else "abs"
    )


def _gp_model(kernel: str, n: int = 40, seed: int = 0, mpk_degree: int = 2) -> GPDynamicsModel:
    gen = torch.Generator().manual_seed(seed)
    s = torch.randn(n, 4, generator=gen, dtype=f64) * torch.tensor([0.5, 1.0, 2.0, 2.0], dtype=f64)
    a = torch.rand(n, 1, generator=gen, dtype=f64) * 2 - 1
    s1 = s + 0.05 * torch.randn(n, 4, generator=gen, dtype=f64)
    model = GPDynamicsModel(
        TASK, kernel=kernel, adam_iters=10, lbfgs_iters=0, mpk_degree=mpk_degree
    )
    return model.fit(s, a, s1)


# ---------------------------------------------------------------- gradchecks, float64
@pytest.mark.parametrize(("kernel", "degree"), [("rbf+mpk", 2), ("rbf+mpk", 1), ("rbf", 2)])
def test_fused_posterior_backward_matches_finite_differences(kernel, degree):
    model = _gp_model(kernel, mpk_degree=degree)
    pred = FusedRBFMPKPredictor.from_cached(model.gp_.cached_predictor(dtype=f64))
    assert pred.p == (degree if kernel == "rbf+mpk" else 0)
    gen = torch.Generator().manual_seed(1)
    x = torch.randn(2, 3, 6, generator=gen, dtype=f64).requires_grad_(True)  # batch dims kept
    assert torch.autograd.gradcheck(lambda z: pred(z), (x,))


def test_policy_backward_matches_finite_differences():
    """Two policies batched (K = 2, different parameters), with and without a mask; two
    actions, one with symmetric and one with asymmetric bounds."""
    low, high = (-0.8, -0.3), (0.8, 1.0)
    pols = [SquashedRBFPolicy(LAYOUT, low, high, num_basis=6, seed=s).to(f64) for s in (0, 1)]
    bounds = (pols[0].u_mid, pols[0].u_half)
    assert bounds[0].dtype == f64 and bounds[0].tolist() == pytest.approx([0.0, 0.35])
    obs = torch.randn(2, 5, 4, dtype=f64).requires_grad_(True)
    c = torch.stack([p.centers.detach() for p in pols]).requires_grad_(True)
    log_l = torch.stack([p.log_lengthscales.detach() + 0.1 * i for i, p in enumerate(pols)])
    log_l.requires_grad_(True)
    w = torch.stack([3.0 * p.weights.detach() for p in pols]).requires_grad_(True)  # tanh curvature
    gen = torch.Generator().manual_seed(3)
    mask = (torch.rand(2, 5, 6, generator=gen) < 0.6).to(f64) / 0.6
    for m in (None, mask):  # without and with a dropout mask on the activations
        assert torch.autograd.gradcheck(
            lambda o, c_, l_, w_, m=m: _SquashedRBF.apply(o, c_, l_, w_, bounds, m, LAYOUT),
            (obs, c, log_l, w),
        )


def test_gp_inputs_and_cost_backward_match_finite_differences():
    gen = torch.Generator().manual_seed(2)
    state = (torch.randn(7, 4, generator=gen, dtype=f64) * 2).requires_grad_(True)
    action = torch.randn(7, 1, generator=gen, dtype=f64).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda s, a: gp_inputs(s, a, LAYOUT), (state, action))
    for wrap in (True, False):
        cost = swingup_cost(l_x=1.2, l_theta=2.5, wrap=wrap)
        assert torch.autograd.gradcheck(cost, (state,))


def test_sample_clip_integrate_backward_matches_finite_differences():
    class Stub(nn.Module):  # mean and variance as smooth functions of the GP input
        def forward(self, z):
            return torch.tanh(z[..., :2] + z[..., 4:6]), 0.01 + z[..., 2:4] ** 2

    bound = torch.tensor([0.5, 0.8], dtype=f64)
    dyn = SpeedIntegrationDynamics(Stub(), DT, LAYOUT, delta_bound=bound)
    gen = torch.Generator().manual_seed(3)
    state = torch.randn(9, 4, generator=gen, dtype=f64).requires_grad_(True)
    action = torch.randn(9, 1, generator=gen, dtype=f64).requires_grad_(True)
    eps = torch.randn(9, 2, generator=gen, dtype=f64)
    delta = (dyn(state, action, eps) - state @ torch.eye(4, dtype=f64))[:, [1, 3]].detach()
    clipped = delta.abs() >= bound - 1e-9
    assert clipped.any() and not clipped.all()  # both branches of the clip are exercised
    assert torch.autograd.gradcheck(lambda s, a: dyn(s, a, eps), (state, action))
    assert torch.autograd.gradcheck(lambda s, a: dyn(s, a, None), (state, action))


# ------------------------------------------------- whole rollout vs plain autograd, f64
def _reference_rollout(pol, pred, bound, cost_l, x0, noise, obs_noise_std, seed):
    """Rollout + expected cost from the formulas with plain autograd ops (no custom
    backward anywhere); the GP posterior is the GP core's gpytorch-based predictor."""
    torch.manual_seed(seed)
    H, M = noise.shape[:2]
    obs_noise = obs_noise_std * torch.randn(H, M, 4, dtype=f64)
    l_x, l_theta = cost_l
    x = x0
    states, costs = [x], []
    for t in range(H):
        o = x + obs_noise[t]
        feats = torch.stack(
            [o[:, 0], o[:, 1], o[:, 3], torch.sin(o[:, 2]), torch.cos(o[:, 2])], dim=-1
        )
        ell = pol.log_lengthscales.exp()
        phi = torch.exp(-0.5 * (((feats[:, None, :] - pol.centers) / ell) ** 2).sum(-1))
        d = dropout_mask((M, pol.num_basis), pol.dropout, f64)  # per particle and basis
        u = pol.u_max * torch.tanh((d * phi) @ pol.weights / pol.u_max)
        gp_in = torch.cat(
            [x[:, 0:1], x[:, 1:2], x[:, 3:4], torch.sin(x[:, 2:3]), torch.cos(x[:, 2:3]), u], -1
        )
        mean, var = pred(gp_in)
        delta = mean + torch.sqrt(var.clamp_min(1e-12)) * noise[t]
        delta = torch.maximum(torch.minimum(delta, bound), -bound)
        q, qd = x[:, [0, 2]], x[:, [1, 3]]
        q1 = q + DT * qd + 0.5 * DT * delta
        qd1 = qd + delta
        x = torch.stack([q1[:, 0], qd1[:, 0], q1[:, 1], qd1[:, 1]], dim=-1)
        d_theta = x[:, 2].abs() - math.pi
        costs.append(1.0 - torch.exp(-((d_theta / l_theta) ** 2) - (x[:, 0] / l_x) ** 2))
        states.append(x)
    return torch.stack(states, 1), torch.stack(costs, 1)


@pytest.mark.parametrize("kernel", ["rbf+mpk", "rbf"])
def test_rollout_and_policy_gradient_match_plain_autograd_reference(kernel):
    model = _gp_model(kernel, n=60, seed=4)
    H, M, seed = 12, 16, 7
    cost_l = (1.0, 3.0)
    gen = torch.Generator().manual_seed(5)
    x0 = 0.3 * torch.randn(M, 4, generator=gen, dtype=f64)
    noise = torch.randn(H, M, 2, generator=gen, dtype=f64)

    pol = SquashedRBFPolicy(LAYOUT, num_basis=30, weight_scale=1.0, dropout=0.25, seed=0).to(f64)
    pol.train()
    dyn = model.particle_dynamics(f64)
    assert isinstance(dyn.delta_model, FusedRBFMPKPredictor)
    cost = swingup_cost(*cost_l, wrap=False)
    loss = MCPilcoLoss(make_policy_module(pol), dyn, cost, H, M, MU0, obs_noise_std=0.05)
    with torch.no_grad():  # bound |Delta x_dot| at its 70th percentile: the clip acts sometimes
        pre = loss.rollout(initial_state=x0, noise=noise).states[:, :, 1]
    bound = dyn.delta_bound.clone()
    bound[0] = (pre[:, 1:] - pre[:, :-1]).abs().quantile(0.7)
    dyn.delta_bound = bound
    torch.manual_seed(seed)
    ro = loss.rollout(initial_state=x0, noise=noise)
    J = ro.costs.sum(1).mean()
    grads = torch.autograd.grad(J, list(pol.parameters()))

    ref_pred = model.gp_.cached_predictor(dtype=f64)  # dense gpytorch kernel evaluation
    states, costs = _reference_rollout(pol, ref_pred, bound, cost_l, x0, noise, 0.05, seed)
    J_ref = costs.sum(1).mean()
    grads_ref = torch.autograd.grad(J_ref, list(pol.parameters()))

    dv = (ro.states[:, 1:, 1] - ro.states[:, :-1, 1]).detach().abs()
    hits = dv >= bound[0] * (1 - 1e-9)
    assert hits.any() and not hits.all()  # the clip is active on some particles only
    torch.testing.assert_close(ro.states, states, atol=1e-10, rtol=0)
    torch.testing.assert_close(ro.costs, costs, atol=1e-10, rtol=0)
    for g, g_ref in zip(grads, grads_ref, strict=True):
        torch.testing.assert_close(g, g_ref, atol=1e-10 * g_ref.abs().max(), rtol=0)


def test_float32_rollout_matches_the_float64_gp_posterior():
    """The default rollout evaluates the GP posterior in float32; with the same particles,
    noise and policy, a float64 posterior (``rollout_dtype="float64"``) must give the same
    expected cost and policy gradient to float32 accuracy over a whole horizon."""
    model = _gp_model("rbf+mpk", n=60, seed=4)
    pol = SquashedRBFPolicy(LAYOUT, num_basis=30, weight_scale=1.0, seed=0)  # float32 parameters
    pol.eval()
    out = {}
    for dtype in (torch.float32, torch.float64):
        dyn = model.particle_dynamics(dtype)
        assert dyn.delta_model.dtype == dtype
        loss = MCPilcoLoss(
            make_policy_module(pol), dyn, swingup_cost(), 30, 64, MU0, obs_noise_std=0.01
        )
        torch.manual_seed(0)
        J = loss()["loss_cost"]
        assert J.dtype == torch.float32  # particles stay float32 either way
        out[dtype] = (J, torch.autograd.grad(J, list(pol.parameters())))
    (J32, g32), (J64, g64) = out[torch.float32], out[torch.float64]
    torch.testing.assert_close(J32, J64, rtol=1e-5, atol=0)
    for a, b in zip(g32, g64, strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-4 * b.abs().max().item())


@pytest.mark.parametrize("backend", ["dynamo", "torch", "native"])
def test_fast_rollout_is_one_graph_and_matches_the_eager_rollout(backend):
    """``use_fast_rollout``: dynamo compiles a time step (policy with its dropout mask, GP
    inputs, fused posterior, sampling + integration, cost) as one graph (``fullgraph=True``
    fails on a graph break); every backend's rollout gives the eager expected cost and policy
    gradient from the same seed (the masks are drawn outside the fast code, from torch's
    generator). A wide cost (l_theta = 3) gives a gradient far from zero, so that a backend
    returning zero gradients fails here."""
    model = _gp_model("rbf+mpk", n=40, seed=2)
    pol = SquashedRBFPolicy(LAYOUT, num_basis=20, weight_scale=1.0, seed=0, dropout=0.25)
    pol.train()
    loss = MCPilcoLoss(
        make_policy_module(pol), model.particle_dynamics(), swingup_cost(l_theta=3.0), 8, 16,
        MU0, obs_noise_std=0.01,
    )  # fmt: skip
    x0 = loss.sample_initial_state()
    mask = pol.draw_dropout_mask(x0)
    assert mask is not None and (mask == 0).any()
    torch.compiler.reset()
    whole = torch.compile(loss.step, fullgraph=True, dynamic=False)
    whole(x0, torch.zeros(16, 2), torch.zeros(16, 4), mask)  # raises on a graph break
    out = []
    for fast in (False, True):
        # passes its own check
        used = _use(loss, fast, backend=backend, dynamic=False)
        assert used.in_use is fast and used.backend == (backend if fast else None)
        torch.manual_seed(5)
        J = loss()["loss_cost"]
        out.append((J, torch.autograd.grad(J, list(pol.parameters())), torch.rand(2)))
    loss.set_fast_rollout(None)
    (J_eager, g_eager, after_eager), (J_comp, g_comp, after_comp) = out
    torch.testing.assert_close(after_comp, after_eager, rtol=0, atol=0)  # same draws
    torch.testing.assert_close(J_comp, J_eager, rtol=1e-5, atol=0)
    for a, b in zip(g_comp, g_eager, strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-4 * b.abs().max().item())
    assert max(g.abs().max().item() for g in g_eager) > 1e-4  # not a vanishing gradient


def _broken_compile(kind: str):
    """A stand-in for ``torch.compile`` whose step keeps ``J^`` but breaks the gradient:
    ``"zero"`` cuts it everywhere (what torch 2.11's inductor did to this step), ``"short"``
    only through time (each step differentiates its own action alone)."""

    def compile_(fn, **_):
        def step(x, eps, nu, mask):
            x1, u, c = fn(x.detach() if kind == "short" else x, eps, nu, mask)
            return (x1, u, c) if kind == "short" else (x1.detach(), u.detach(), c.detach())

        return step

    return compile_


def _broken_step_backward(kind: str):
    """The same two faults in the torch backend's ``step_backward``: zero parameter gradients
    (``"zero"``) or no gradient passed back to the previous time step (``"short"``)."""
    right = TorchRollout.step_backward

    def step_backward(self, ctx, g_x_next, g_c_next, grads):
        g_prev, new = right(self, ctx, g_x_next, g_c_next, grads)
        if kind == "short":
            return torch.zeros_like(g_prev), new
        return g_prev, tuple(G + 0 * (g - G) for G, g in zip(grads, new, strict=True))

    return step_backward


@pytest.mark.parametrize("backend", ["dynamo", "torch"])
@pytest.mark.parametrize("kind", ["zero", "short"])
def test_a_fast_rollout_with_a_wrong_gradient_is_dropped_for_the_eager_one(
    monkeypatch, kind, backend
):
    """``use_fast_rollout`` checks the fast rollout against the eager one; a wrong gradient
    (same ``J^``) makes it warn, keep the eager rollout, and leave torch's random stream where
    it was; the loss then equals the eager loss."""
    model = _gp_model("rbf+mpk", n=40, seed=2)
    pol = SquashedRBFPolicy(LAYOUT, num_basis=20, weight_scale=1.0, seed=0)
    loss = MCPilcoLoss(
        make_policy_module(pol), model.particle_dynamics(), swingup_cost(l_theta=3.0), 8, 16, MU0
    )
    params = list(pol.parameters())
    pol.eval()  # the check runs it in training mode, then restores this
    torch.manual_seed(3)
    J_eager = loss()["loss_cost"]
    g_eager = torch.autograd.grad(J_eager, params)
    if backend == "dynamo":
        monkeypatch.setattr(torch, "compile", _broken_compile(kind))
    else:
        monkeypatch.setattr(TorchRollout, "step_backward", _broken_step_backward(kind))
    torch.manual_seed(3)
    with pytest.warns(RuntimeWarning, match="disagrees with the eager one"):
        used = use_fast_rollout(loss, backend=backend)
    assert used.backend is None and loss.fast_rollout == (None, None)
    assert used.check["J_rel"] < 1e-6 and used.check["grad_rel"] > 0.5
    assert loss.horizon == 8 and not pol.training  # the check's horizon and mode are undone
    J = loss()["loss_cost"]  # the stream continues from the seed: the check drew nothing
    torch.testing.assert_close(J, J_eager, rtol=0, atol=0)
    for a, b in zip(torch.autograd.grad(J, params), g_eager, strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)


@pytest.mark.parametrize("backend", ["dynamo", "torch"])
def test_a_build_that_raises_leaves_the_eager_step(monkeypatch, backend):
    """A build or compiler failure (here a stand-in step that raises as inductor does without
    a working C++ toolchain) is caught by ``use_fast_rollout``: a warning naming the error,
    the eager rollout, and the error's first line in ``error``; the trial line says so."""
    from mcpilco.agents.common.records import TrialRecord, record_line

    model = _gp_model("rbf", n=30, seed=1)
    pol = SquashedRBFPolicy(LAYOUT, num_basis=10, seed=0)
    loss = MCPilcoLoss(
        make_policy_module(pol), model.particle_dynamics(), swingup_cost(), 4, 8, MU0
    )

    def failing_compile(fn, *_, **__):
        def step(*args):
            raise RuntimeError("C++ compile error\ncc1plus: fatal error: Python.h")

        return step

    def failing_forward(self, *args):
        raise RuntimeError("C++ compile error\ncc1plus: fatal error: Python.h")

    monkeypatch.setattr(torch, "compile", failing_compile)
    monkeypatch.setattr(TorchRollout, "step_forward", failing_forward)
    with pytest.warns(RuntimeWarning, match=f"building the {backend} rollout failed"):
        used = use_fast_rollout(loss, backend=backend)
    assert not used.in_use and used.error == "RuntimeError: C++ compile error"
    assert used.check is None
    assert torch.isfinite(loss()["loss_cost"])  # the eager step runs
    rec = {
        "index": 1, "kind": "policy", "experience_s": 6.0, "cost": 50.0, "success": False,
        "time_in_goal": 0.0, "steps": 60, "wall_s": 10.0, "gp_fit_s": 1.0,
        "gp_points": 60, "opt_steps": 10, "s_per_opt_step": 0.1, "cpu_s_per_opt_step": 0.1,
        "opt_final_cost": 40.0, "compiled_step": False, "compile_error": used.error,
    }  # fmt: skip
    assert "compiling the step failed (RuntimeError: C++ compile error): ran eagerly" in (
        record_line(TrialRecord.from_dict(rec))
    )


def test_chained_backends_with_a_population_match_the_eager_rollout_and_know_their_limits(
    monkeypatch,
):
    """The torch and native backends with ``K = 2`` candidates, each with its own ``J^_k`` and
    gradient,
    equals the eager rollout from the same seed (dropout masks on), run in one thread and
    split over two threads by particles (each with one intra-op thread; meanwhile the
    caller's own ops, e.g. the splits, run on one thread too, and its count is restored
    after the forward and after the backward). A rollout of
    another particle count runs eagerly (a chained rollout is built for one count); a
    rollout it cannot chain by hand (here a GP posterior behind a module it does not know)
    makes ``backend="auto"`` pick dynamo, and ``backend="torch"`` refuse with the reason."""
    model = _gp_model("rbf+mpk", n=40, seed=2)
    pop = PolicyPopulation(
        [SquashedRBFPolicy(LAYOUT, num_basis=20, weight_scale=1.0, seed=s) for s in (0, 1)]
    )
    pop.train()
    loss = MCPilcoLoss(
        make_policy_module(pop), model.particle_dynamics(), swingup_cost(l_theta=3.0), 8, 16, MU0
    )
    params = list(pop.parameters())
    out = []
    threads_before, threads = torch.get_num_threads(), 2
    torch.set_num_threads(threads)
    split, caller_threads = ShardedRollout.split, []

    def recording_split(runner, t, dim):  # called by the caller, in forward and backward
        caller_threads.append(torch.get_num_threads())
        return split(runner, t, dim)

    monkeypatch.setattr(ShardedRollout, "split", recording_split)
    runs = ((None, 1), ("torch", 1), ("torch", 2), ("native", 1), ("native", 2))
    for backend, shards in runs:
        enable = backend is not None
        assert _use(loss, enable, backend=backend or "auto", shards=shards).in_use is enable
        assert loss.rollout_shards == shards
        assert torch.get_num_threads() == threads  # the workers' one thread does not leak
        torch.manual_seed(4)
        caller_threads.clear()
        td = loss()
        assert torch.get_num_threads() == threads
        out.append((td["candidate_costs"], torch.autograd.grad(td["loss_cost"], params)))
        assert torch.get_num_threads() == threads
        # forward: x, eps, nu; backward: the costs' gradient (none for the eager rollout)
        assert caller_threads == ([] if not enable else [1 if shards > 1 else threads] * 4)
        if shards > 1:  # after compiled rollouts, each shard's task still runs one thread
            seen = loss.fast_rollout[0].map_shards(lambda _i: torch.get_num_threads(), [0, 1])
            assert seen == [1, 1]
    torch.set_num_threads(threads_before)
    (J_e, g_e), *compiled = out
    for J_d, g_d in compiled:  # one thread, and two threads of 8 particles per candidate
        torch.testing.assert_close(J_d, J_e, rtol=1e-5, atol=0)
        for a, b in zip(g_d, g_e, strict=True):
            torch.testing.assert_close(a, b, rtol=0, atol=1e-4 * b.abs().max().item())
    # another particle count runs eagerly: the eager loss exactly (eval mode: no masks)
    x0 = torch.zeros(2 * 5, 4)
    noise = torch.randn(8, 10, 2)
    pop.eval()
    use_fast_rollout(loss, backend="torch")
    J_other = loss(TensorDict({"initial_state": x0, "noise": noise}, []))["loss_cost"]
    loss.set_fast_rollout(None)
    J_ref = loss(TensorDict({"initial_state": x0, "noise": noise}, []))["loss_cost"]
    torch.testing.assert_close(J_other, J_ref, rtol=0, atol=0)

    class Plain(nn.Module):  # a posterior the chained backends do not know
        def __init__(self, pred):
            super().__init__()
            self.pred = pred

        def forward(self, x):
            return self.pred(x)

    dyn = model.particle_dynamics()
    dyn.delta_model = Plain(dyn.delta_model)
    other = MCPilcoLoss(make_policy_module(pop), dyn, swingup_cost(), 4, 8, MU0)
    assert use_fast_rollout(other, verify=False).backend == "dynamo"
    with pytest.raises(ValueError, match="torch backend cannot run.*not fused"):
        use_fast_rollout(other, backend="torch")
    with pytest.raises(ValueError, match="backend must be"):
        use_fast_rollout(other, backend="inductor")
    with pytest.raises(ValueError, match="shards > 1 needs the native or torch backend"):
        use_fast_rollout(other, shards=2)  # auto picks dynamo here
    with pytest.raises(ValueError, match="positive divisor of the 16 particles, got 3"):
        use_fast_rollout(loss, backend="torch", shards=3)


def test_chained_backend_falls_back_to_the_eager_rollout_without_extra_draws():
    """A rollout of another particle count under the torch backend is the eager rollout,
    random draws included: with simulated observation noise it gives the eager loss and
    leaves torch's random stream where the eager loss leaves it."""
    model = _gp_model("rbf", n=30, seed=1)
    pol = SquashedRBFPolicy(LAYOUT, num_basis=10, seed=0)
    loss = MCPilcoLoss(
        make_policy_module(pol), model.particle_dynamics(), swingup_cost(), 4, 8, MU0,
        obs_noise_std=0.01,
    )  # fmt: skip
    td = {"initial_state": torch.zeros(5, 4)}
    out = []
    for backend in (None, "torch"):
        assert _use(loss, backend is not None, backend=backend or "auto").in_use is bool(backend)
        torch.manual_seed(2)
        out.append((loss(TensorDict(td, []))["loss_cost"], torch.rand(3)))
    (J_e, after_e), (J_d, after_d) = out
    torch.testing.assert_close(J_d, J_e, rtol=0, atol=0)
    torch.testing.assert_close(after_d, after_e, rtol=0, atol=0)


def test_shards_hold_each_candidates_particles_in_order():
    """``split`` gives shard ``s`` particles ``s M/S .. (s+1) M/S - 1`` of every candidate
    (rows candidate-major), along any dimension; ``join`` undoes it; a shard count that does
    not divide the particles is refused."""

    model = _gp_model("rbf", n=30, seed=1)
    pop = PolicyPopulation([SquashedRBFPolicy(LAYOUT, num_basis=4, seed=s) for s in (0, 1)])
    dyn, cost = model.particle_dynamics(), swingup_cost()
    runner = TorchRollout(pop, dyn, cost, rows=2 * 6, shards=3)
    rows = torch.arange(12.0)  # candidate 0: particles 0..5, candidate 1: 6..11
    parts = runner.split(rows.repeat(2, 1), 1)
    expected = [[0.0, 1.0, 6.0, 7.0], [2.0, 3.0, 8.0, 9.0], [4.0, 5.0, 10.0, 11.0]]
    assert [p[1].tolist() for p in parts] == expected
    assert all(p.is_contiguous() for p in parts)
    torch.testing.assert_close(runner.join(parts, 1), rows.repeat(2, 1), rtol=0, atol=0)
    bits, keep = runner.no_dropout()
    assert bits.shape == (2, 2, 4) and bits.dtype == torch.uint8 and keep.tolist() == [256, 1]
    with pytest.raises(ValueError, match="shards must be >= 1 and divide the 6 particles"):
        TorchRollout(pop, dyn, cost, rows=12, shards=4)


# ------------------------------------------------------------------ native (C++) rollout
@pytest.mark.parametrize(
    ("kernel", "n", "sample_noise", "clip", "wrap"),
    [("rbf+mpk", 37, False, 3.0, True), ("rbf", 53, True, None, False)],
)
def test_native_rollout_matches_the_eager_rollout(kernel, n, sample_noise, clip, wrap):
    """The C++ rollout (``backend="native"``) against the eager one, the second
    implementation, from the same seed over the whole horizon: dropout masks, simulated
    observation noise, both kernels (MPK features or none), ``N`` not a multiple of the
    kernel's row blocks, 20 particles per shard (one full tile of 16 and one of 4 padded
    ones), sampling noise on or off, clipping on or off, a wrapped or unwrapped angle in
    the cost. It is not a vanishing gradient (a wide cost)."""
    model = GPDynamicsModel(
        TASK, kernel=kernel, adam_iters=10, lbfgs_iters=0, sample_noise=sample_noise,
        delta_clip_factor=clip,
    )  # fmt: skip
    gen = torch.Generator().manual_seed(3)
    s = torch.randn(n, 4, generator=gen, dtype=f64) * torch.tensor([0.5, 1.0, 2.0, 2.0], dtype=f64)
    a = torch.rand(n, 1, generator=gen, dtype=f64) * 2 - 1
    model.fit(s, a, s + 0.05 * torch.randn(n, 4, generator=gen, dtype=f64))
    pol = SquashedRBFPolicy(LAYOUT, num_basis=27, weight_scale=1.0, seed=0, dropout=0.25)
    pol.train()
    loss = MCPilcoLoss(
        make_policy_module(pol), model.particle_dynamics(),
        swingup_cost(l_theta=3.0, wrap=wrap), 25, 40, MU0, obs_noise_std=0.01,
    )  # fmt: skip
    assert isinstance(loss.dynamics.delta_model, FusedRBFMPKPredictor)
    assert loss.dynamics.delta_model.p == (2 if kernel == "rbf+mpk" else 0)
    out = []
    threads_before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        for backend, shards in ((None, 1), ("native", 1), ("native", 2)):
            enable = backend is not None
            used = _use(loss, enable, backend=backend or "auto", shards=shards)
            assert used.in_use is enable and used.backend == backend
            torch.manual_seed(7)
            J = loss()["loss_cost"]
            out.append((J, torch.autograd.grad(J, list(pol.parameters())), torch.rand(2)))
    finally:
        torch.set_num_threads(threads_before)
    (J_e, g_e, after_e), *native = out
    assert max(g.abs().max().item() for g in g_e) > 1e-3
    for J_n, g_n, after_n in native:
        torch.testing.assert_close(after_n, after_e, rtol=0, atol=0)  # the same draws
        torch.testing.assert_close(J_n, J_e, rtol=1e-4, atol=0)
        for a_, b_ in zip(g_n, g_e, strict=True):
            torch.testing.assert_close(a_, b_, rtol=0, atol=1e-3 * b_.abs().max().item())


def test_native_backend_knows_its_limits_and_drops_a_wrong_gradient(monkeypatch):
    """``backend="native"`` refuses what it cannot run, with the reason (float64 parts:
    ``"auto"`` then picks dynamo), runs asymmetric bounds and any cost terms, and
    a native rollout whose gradient disagrees with the eager one is dropped for the eager
    step, with a warning."""
    from mcpilco.agents.mc_pilco.fast import native as native_rollout

    model = _gp_model("rbf+mpk", n=30, seed=1)
    pol = SquashedRBFPolicy(LAYOUT, num_basis=16, weight_scale=1.0, seed=0)
    loss = MCPilcoLoss(
        make_policy_module(pol), model.particle_dynamics(), swingup_cost(l_theta=3.0), 6, 16, MU0
    )
    assert use_fast_rollout(loss, verify=False).backend == "native"
    wide = MCPilcoLoss(
        make_policy_module(SquashedRBFPolicy(LAYOUT, num_basis=16, seed=0).double()),
        model.particle_dynamics(dtype=f64), swingup_cost(), 6, 16, MU0,
    )  # fmt: skip
    with pytest.raises(ValueError, match="native backend cannot run.*float32 only"):
        use_fast_rollout(wide, backend="native")
    assert use_fast_rollout(wide, verify=False).backend == "dynamo"
    # asymmetric action bounds and a cost on x alone run natively, as the eager rollout does
    lopsided = MCPilcoLoss(
        make_policy_module(SquashedRBFPolicy(LAYOUT, (-0.5,), (1.0,), num_basis=16, seed=0)),
        model.particle_dynamics(), swingup_cost(), 6, 16, MU0,
    )  # fmt: skip
    x_only = SaturatingCost(4, idx=(0,), targets=(0.0,), length_scales=(1.0,), modes=(0,))
    no_theta = MCPilcoLoss(make_policy_module(pol), model.particle_dynamics(), x_only, 6, 16, MU0)
    for other in (lopsided, no_theta):
        used = use_fast_rollout(other, backend="native")
        assert used.backend == "native"
        assert used.check["J_rel"] < 1e-4 and used.check["grad_rel"] < 1e-3

    backward = native_rollout.NativeRollout.backward_shard

    def doubled(self, state, g_costs, grads):
        before = [g.clone() for g in grads]
        new = backward(self, state, g_costs, grads)
        return [2 * g - b for g, b in zip(new, before, strict=True)]

    monkeypatch.setattr(native_rollout.NativeRollout, "backward_shard", doubled)
    with pytest.warns(RuntimeWarning, match=r"native rollout disagrees with the eager one"):
        assert use_fast_rollout(loss, backend="native").backend is None
    assert loss.fast_rollout == (None, None)
    monkeypatch.undo()

    def no_compiler():
        raise RuntimeError("no C++ compiler found (set CXX)")

    monkeypatch.setattr(native_rollout, "load_library", no_compiler)
    with pytest.raises(ValueError, match="native library is not available.*no C\\+\\+ compiler"):
        use_fast_rollout(loss, backend="native")
    assert use_fast_rollout(loss, verify=False).backend == "dynamo"
    monkeypatch.undo()
    # a compiler that fails to build the library: "auto" says so, then runs dynamo
    monkeypatch.setattr(native_rollout, "_LIBS", {})
    monkeypatch.setattr(native_rollout, "_LIB_ERRORS", {"native": "g++ ... failed: error: oops"})
    with pytest.warns(RuntimeWarning, match="native rollout was not used.*failed: error: oops"):
        assert use_fast_rollout(loss, verify=False).backend == "dynamo"


def test_native_library_builds_once_and_its_failures_are_clear_errors(tmp_path, monkeypatch):
    """The extension builds into its folder under the cache on first use and loads from
    there after, in this process and in a new one (nothing rebuilt); a compiler that fails
    gives its message, an unwritable cache folder an error, both remembered for the process
    (no rebuild at every trial)."""
    from mcpilco.agents.mc_pilco.fast import native as nr

    lib = nr.load_library()
    assert nr.load_library() is lib and lib.tile() == 16 and lib.row_block() == 6
    folder = nr.cache_dir() / nr.extension_name(nr.cpp_compiler())
    (built,) = folder.glob("mcpilco_native_rollout_*.so")
    mtime = built.stat().st_mtime_ns
    code = (
        "from mcpilco.agents.mc_pilco.fast import native as nr;"
        "assert nr.load_library().tile() == 16"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=300)
    assert built.stat().st_mtime_ns == mtime  # a new process loads the built extension

    def fresh(cache):
        monkeypatch.setattr(nr, "_LIBS", {})
        monkeypatch.setattr(nr, "_LIB_ERRORS", {})
        monkeypatch.setenv("MCPILCO_NATIVE_CACHE", str(cache))

    fake = tmp_path / "fake-c++"
    fake.write_text("#!/bin/sh\necho 'error: no such header' >&2\nexit 1\n")
    fake.chmod(0o755)
    fresh(tmp_path / "cache2")
    monkeypatch.setenv("CXX", str(fake))
    for _ in range(2):  # remembered
        with pytest.raises(RuntimeError, match="fake-c\\+\\+.*error: no such header"):
            nr.load_library()
    assert not list((tmp_path / "cache2").glob("*/*.so"))  # no library left
    monkeypatch.delenv("CXX")

    blocker = tmp_path / "a-file"
    blocker.write_text("")
    fresh(blocker / "cache")  # a folder below a file cannot be made
    with pytest.raises(RuntimeError, match="NotADirectoryError|FileExistsError"):
        nr.load_library()
    assert nr.build_error() is not None


def test_build_lock_removes_a_killed_builds_lock_and_excludes_other_processes(tmp_path):
    """A ``lock`` file left by a build that was killed (PyTorch's baton) is removed under the
    flock, and while one process holds the flock another cannot take it (it would wait)."""
    import fcntl
    import os
    import subprocess
    import sys

    from mcpilco.agents.mc_pilco.fast.native import BUILD_LOCK_NAME, TORCH_LOCK_NAME, build_lock

    (tmp_path / TORCH_LOCK_NAME).write_text("")  # what a killed build leaves
    probe = (
        "import fcntl, os, sys; fd = os.open(sys.argv[1], os.O_RDWR)\n"
        "try:\n    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)\nexcept BlockingIOError:\n"
        "    sys.exit(3)\nsys.exit(0)"
    )
    lock = str(tmp_path / BUILD_LOCK_NAME)
    with build_lock(tmp_path):
        assert not (tmp_path / TORCH_LOCK_NAME).exists()
        assert subprocess.run([sys.executable, "-c", probe, lock]).returncode == 3
    assert subprocess.run([sys.executable, "-c", probe, lock]).returncode == 0
    fd = os.open(lock, os.O_RDWR)  # released: this process can take it at once
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    os.close(fd)


def test_native_rollout_of_a_wide_arm_spec_in_groups_of_tiles():
    """The UR10 tracking spec (24 states, more policy features than the unrolled kernels
    take, 12 GP outputs, degree-1 MPK, known oscillators) against the eager rollout; its 40
    particles (three tiles) run in groups of 1, 2 (a full and a partial group) and 3 tiles
    give the same floats: each tile's arithmetic does not depend on the group. 45 basis
    functions: a block of 32, one of 8 and 5 single ones in the policy's loops."""
    from mcpilco.agents.mc_pilco.fast import native as native_rollout

    task = TaskSpec.for_env("mcpilco/UR10-v0")
    layout = StateLayout.from_task(task)
    model = GPDynamicsModel(task, kernel="rbf+mpk", mpk_degree=1, adam_iters=5, lbfgs_iters=0)
    gen = torch.Generator().manual_seed(5)
    mu = torch.tensor(task.init_mean, dtype=f64)
    s = mu + 0.05 * torch.randn(40, task.state_dim, generator=gen, dtype=f64)
    a = torch.rand(40, task.action_dim, generator=gen, dtype=f64) * 2 - 1
    model.fit(s, a, s + 0.01 * torch.randn(40, task.state_dim, generator=gen, dtype=f64))
    pol = SquashedRBFPolicy(layout, task.action_low, task.action_high, num_basis=45, seed=0)
    pol.train()
    dyn = model.particle_dynamics()
    cost = SaturatingCost.from_task(task)
    loss = MCPilcoLoss(make_policy_module(pol), dyn, cost, 12, 40, task.init_mean)
    assert layout.feature_dim > 16 and dyn.delta_model.p == 1 and layout.oscillators
    torch.manual_seed(7)
    J_e = loss()["loss_cost"]
    g_e = torch.autograd.grad(J_e, list(pol.parameters()))
    used = _use(loss, backend="native", shards=1)
    assert used.backend == "native"
    engine = loss.fast_rollout[0]
    out = []
    for group in (1, 2, 3):
        engine.model.set_group(group)
        native_rollout.stage_seconds(reset=True)
        torch.manual_seed(7)
        J = loss()["loss_cost"]
        out.append((J, torch.autograd.grad(J, list(pol.parameters()))))
        assert all(sec > 0 for sec in native_rollout.stage_seconds().values())
    for J, g in out:
        torch.testing.assert_close(J, out[0][0], rtol=0, atol=0)
        for a_, b_ in zip(g, out[0][1], strict=True):
            torch.testing.assert_close(a_, b_, rtol=0, atol=0)
    torch.testing.assert_close(out[0][0], J_e, rtol=1e-4, atol=0)
    for a_, b_ in zip(out[0][1], g_e, strict=True):
        torch.testing.assert_close(a_, b_, rtol=0, atol=1e-3 * b_.abs().max().item())
    with pytest.raises(RuntimeError, match="group must be >= 1"):
        engine.model.set_group(0)


def test_native_rollout_leaves_out_vanishing_kernel_rows_and_matches_the_eager_rollout():
    """A GP with short RBF lengthscales (a fifth of the fitted ones), so that most training
    points are so far from every particle of a tile that their kernel values are below
    ``exp(-69)``: the native loops leave those rows out of the products, forward and backward
    (:func:`~mcpilco.agents.mc_pilco.fast.native.kernel_rows` counts them), and still give
    the eager rollout's ``J^`` and policy gradient, which takes every row."""
    from gpytorch.kernels import RBFKernel

    from mcpilco.agents.mc_pilco.fast import native as native_rollout

    model = GPDynamicsModel(TASK, kernel="rbf+mpk", adam_iters=10, lbfgs_iters=0)
    gen = torch.Generator().manual_seed(4)
    s = torch.randn(61, 4, generator=gen, dtype=f64) * torch.tensor([0.5, 1.0, 2.0, 2.0], dtype=f64)
    a = torch.rand(61, 1, generator=gen, dtype=f64) * 2 - 1
    model.fit(s, a, s + 0.05 * torch.randn(61, 4, generator=gen, dtype=f64))
    (rbf,) = [k for k in model.gp_.model_.covar_module.modules() if isinstance(k, RBFKernel)]
    with torch.no_grad():
        rbf.lengthscale = rbf.lengthscale / 5
    pol = SquashedRBFPolicy(LAYOUT, num_basis=27, weight_scale=1.0, seed=0, dropout=0.25)
    pol.train()
    loss = MCPilcoLoss(
        make_policy_module(pol), model.particle_dynamics(), swingup_cost(l_theta=3.0), 25, 40,
        MU0, obs_noise_std=0.01,
    )  # fmt: skip
    out = []
    for backend, shards in ((None, 1), ("native", 1), ("native", 2)):
        enable = backend is not None
        assert _use(loss, enable, backend=backend or "auto", shards=shards).in_use is enable
        native_rollout.kernel_rows(reset=True)
        torch.manual_seed(7)
        J = loss()["loss_cost"]
        out.append((J, torch.autograd.grad(J, list(pol.parameters()))))
        if enable:
            taken, total = native_rollout.kernel_rows()
            # 25 steps, 40 particles in 3 or 4 tiles (1 or 2 shards), 2 outputs, 61 points
            assert total == 25 * (3 if shards == 1 else 4) * 2 * 61
            assert 0 < taken < total / 2  # most rows left out, some taken
    (J_e, g_e), *native = out
    assert max(g.abs().max().item() for g in g_e) > 1e-3
    for J_n, g_n in native:
        torch.testing.assert_close(J_n, J_e, rtol=1e-4, atol=0)
        for a_, b_ in zip(g_n, g_e, strict=True):
            torch.testing.assert_close(a_, b_, rtol=0, atol=1e-3 * b_.abs().max().item())

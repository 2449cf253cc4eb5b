"""The ``device`` option: clear errors on every machine, and (where a GPU exists) the CUDA
rollout and GP posterior against the CPU ones.

The CUDA tests need a GPU and are skipped without one (CI has none); they ran on an H100
(`docs/mcpilco.md`, "On a GPU"). The CPU computation is the independent reference: same
inputs, same random numbers (passed in), other kernels.
"""

from __future__ import annotations

import json
import math

import pytest
import torch
from tensordict import TensorDict

from mcpilco.agents.common.checkpoint import load_checkpoint
from mcpilco.agents.mc_pilco import (
    GPDynamicsModel,
    MCPilcoConfig,
    MCPilcoLoss,
    SaturatingCost,
    SquashedRBFPolicy,
    StateLayout,
    TaskSpec,
    make_policy_module,
    run_mcpilco,
)
from mcpilco.agents.mc_pilco.optimize import PolicyOptConfig, loss_and_grad_fn, optimize_policy
from mcpilco.models.device import check_device_name, resolve_device

f64 = torch.float64
TASK = TaskSpec.for_env("mcpilco/CartpoleSwingUp-v0")
LAYOUT = StateLayout.from_task(TASK)
needs_cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")


# ------------------------------------------------------------------- every machine
@pytest.mark.parametrize("bad", ["gpu", "mps", "xla", "cuda:x", ""])
def test_device_names_other_than_cpu_and_cuda_are_refused(bad):
    with pytest.raises(ValueError, match="device must be 'cpu', 'cuda'"):
        check_device_name(bad)
    with pytest.raises(ValueError, match="device must be"):
        MCPilcoConfig(device=bad)


def test_a_cuda_config_loads_on_a_machine_without_cuda(monkeypatch):
    """Only the syntax is checked at construction: a config saved on a GPU machine can be read
    (bench collection, resume checks) on a CPU one; the run itself refuses to start."""
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    cfg = MCPilcoConfig.from_dict(MCPilcoConfig(device="cuda:0").to_dict())
    assert cfg.device == "cuda:0"
    with pytest.raises(ValueError, match="sees no CUDA device.*use device 'cpu'"):
        resolve_device(cfg.device)
    assert resolve_device("cpu") == torch.device("cpu")


def test_train_script_refuses_cuda_without_a_gpu_before_any_work(
    monkeypatch, tmp_path, capsys, command
):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    out = tmp_path / "run"
    code = command("mcpilco-train", ["--device", "cuda", "--trials", "1", "--out", str(out)])
    assert code == 2
    assert "sees no CUDA device" in capsys.readouterr().err
    assert not out.exists()


# ------------------------------------------------------------------------ GPU only
def _gp_model(kernel: str = "rbf+mpk", n: int = 60, seed: int = 0) -> GPDynamicsModel:
    gen = torch.Generator().manual_seed(seed)
    s = torch.randn(n, 4, generator=gen, dtype=f64) * torch.tensor([0.5, 1.0, 2.0, 2.0], dtype=f64)
    a = torch.rand(n, 1, generator=gen, dtype=f64) * 2 - 1
    s1 = s + 0.05 * torch.randn(n, 4, generator=gen, dtype=f64)
    return GPDynamicsModel(TASK, kernel=kernel, adam_iters=20, lbfgs_iters=5).fit(s, a, s1)


@needs_cuda
@pytest.mark.parametrize("fused", [True, False])
def test_gp_posterior_on_cuda_equals_cpu_float64(fused):
    dyn = _gp_model().particle_dynamics(f64, fused=fused)
    pred_cpu = dyn.delta_model
    pred_gpu = _gp_model().particle_dynamics(f64, fused=fused).delta_model.to("cuda")
    x = torch.randn(300, 6, dtype=f64, generator=torch.Generator().manual_seed(3))
    m0, v0 = pred_cpu(x)
    m1, v1 = pred_gpu(x.cuda())
    assert m1.device.type == "cuda"
    torch.testing.assert_close(m1.cpu(), m0, rtol=0, atol=1e-10)
    torch.testing.assert_close(v1.cpu(), v0, rtol=0, atol=1e-10)


@needs_cuda
def test_rollout_and_policy_gradient_on_cuda_equal_cpu():
    """Same GP, policy, initial particles and noise (float64 posterior): the expected cost
    (with a barrier at limits of x that the particles reach) and its gradient w.r.t. every
    policy parameter agree between CPU and CUDA."""
    model = _gp_model()
    task = TASK.replace(limits={"x": (-0.3, 0.3)})
    results = []
    for dev in ("cpu", "cuda"):
        policy = SquashedRBFPolicy(LAYOUT, num_basis=50, weight_scale=0.5, seed=1).to(dev)
        loss = MCPilcoLoss(
            make_policy_module(policy),
            model.particle_dynamics(f64).to(dev),
            SaturatingCost.from_task(task, limit_widths={"x": 0.1}),
            horizon=30,
            num_particles=200,
            init_mean=TASK.init_mean,
        ).to(dev)
        gen = torch.Generator().manual_seed(7)
        x0 = 0.1 * torch.randn(200, 4, generator=gen)
        eps = torch.randn(30, 200, 2, generator=gen)
        policy.eval()  # no dropout: the masks would come from different generators
        out = loss(TensorDict({"initial_state": x0.to(dev), "noise": eps.to(dev)}, []))
        out["loss_cost"].backward()
        grads = [p.grad.detach().cpu() for p in policy.parameters()]
        results.append((float(out["loss_cost"]), grads))
    (j_cpu, g_cpu), (j_gpu, g_gpu) = results
    assert j_gpu == pytest.approx(j_cpu, rel=1e-4)
    for a, b in zip(g_gpu, g_cpu, strict=True):
        torch.testing.assert_close(a, b, rtol=2e-3, atol=2e-3 * float(b.abs().max()))


@needs_cuda
def test_run_on_cuda_checkpoints_loadable_on_cpu_and_resumes(tmp_path):
    cfg = MCPilcoConfig(
        num_trials=1,
        num_particles=20,
        num_basis=20,
        max_points=60,
        gp_adam_iters=10,
        gp_lbfgs_iters=0,
        opt=PolicyOptConfig(max_steps=5, min_steps=1),
        log_particles=5,
        device="cuda",
    )
    summary = run_mcpilco(cfg, tmp_path, progress=False, log=None, write_rrd=False)
    assert [r["kind"] for r in summary.records] == ["exploration", "policy"]
    ckpt = load_checkpoint(summary.checkpoint)  # mapped to the CPU
    assert all(t.device.type == "cpu" for t in ckpt["policy"].values())
    assert "cuda" in ckpt["rng"]
    more = run_mcpilco(
        cfg.with_overrides(num_trials=2),
        tmp_path,
        resume=True,
        progress=False,
        log=None,
        write_rrd=False,
    )
    assert more.resumed_from_trial == 2 and len(more.records) == 3
    saved = json.loads((tmp_path / "records.json").read_text())
    assert saved["config"]["device"] == "cuda"


# ------------------------------------------------------------ CUDA graph of a step
def _loss_and_policy(dev: str, fixed: bool, particles: int = 200):
    """A loss on ``dev``; ``fixed``: initial particles and noise passed in (no sampling)."""
    policy = SquashedRBFPolicy(LAYOUT, num_basis=50, weight_scale=0.5, seed=1).to(dev)
    loss = MCPilcoLoss(
        make_policy_module(policy),
        _gp_model().particle_dynamics().to(dev),
        SaturatingCost.from_task(TASK),
        horizon=30,
        num_particles=particles,
        init_mean=TASK.init_mean,
        obs_noise_std=0.0 if fixed else 0.01,
    ).to(dev)
    if not fixed:
        return loss, policy
    gen = torch.Generator().manual_seed(7)
    td = TensorDict(
        {
            "initial_state": (0.1 * torch.randn(particles, 4, generator=gen)).to(dev),
            "noise": torch.randn(30, particles, 2, generator=gen).to(dev),
        },
        [],
    )
    policy.eval()  # no dropout masks
    return (lambda: loss(td)), policy


def test_loss_and_grad_fn_on_the_cpu_is_plain_autograd():
    """``cuda_graph=True`` has no effect on CPU parameters: J^ and the gradients equal
    ``torch.autograd.grad`` of the same loss."""
    loss, policy = _loss_and_policy("cpu", fixed=True)
    params = list(policy.parameters())
    ref_j = loss()["loss_cost"]
    ref_g = torch.autograd.grad(ref_j, params)
    j, _ = loss_and_grad_fn(loss, params, cuda_graph=True)()
    assert float(j) == float(ref_j.detach())
    for p, g in zip(params, ref_g, strict=True):
        torch.testing.assert_close(p.grad, g, rtol=0, atol=0)


@needs_cuda
def test_cuda_graph_step_equals_the_eager_step_and_follows_parameter_updates():
    loss, policy = _loss_and_policy("cuda", fixed=True)
    params = list(policy.parameters())
    graphed = loss_and_grad_fn(loss, params, cuda_graph=True)
    eager = loss_and_grad_fn(loss, params, cuda_graph=False)
    opt = torch.optim.Adam(params, lr=0.05)
    for _ in range(3):  # the replay reads the parameters Adam updates in place
        j_g, _ = graphed()
        g_g = [p.grad.clone() for p in params]
        j_e, _ = eager()
        assert float(j_g) == pytest.approx(float(j_e), rel=1e-6)
        for a, p in zip(g_g, params, strict=True):
            torch.testing.assert_close(a, p.grad, rtol=1e-4, atol=1e-6 * float(p.grad.abs().max()))
        graphed()  # gradients back in the graph's tensors for the step
        opt.step()


@needs_cuda
def test_cuda_graph_replays_draw_fresh_particles():
    """Replays are not common random numbers: J^ varies between replays like between eager
    calls, around the same mean."""
    loss, policy = _loss_and_policy("cuda", fixed=False)
    params = list(policy.parameters())
    policy.train()
    graphed = loss_and_grad_fn(loss, params, cuda_graph=True)
    eager = loss_and_grad_fn(loss, params, cuda_graph=False)
    jg = torch.tensor([float(graphed()[0]) for _ in range(30)])
    je = torch.tensor([float(eager()[0]) for _ in range(30)])
    assert jg.unique().numel() == 30
    se = (jg.var() / 30 + je.var() / 30).sqrt()
    assert abs(float(jg.mean() - je.mean())) < 4 * float(se)


@needs_cuda
def test_optimize_policy_recaptures_when_dropout_changes():
    """A monitor that stalls every 2 steps halves the rate and lowers the dropout (0.25 ->
    0.125 -> 0): each change rebuilds the graph; the costs stay finite."""
    loss, policy = _loss_and_policy("cuda", fixed=False)
    cfg = PolicyOptConfig(
        max_steps=60, min_steps=0, monitor_patience=2, monitor_threshold=1e9, lr=0.02
    )
    res = optimize_policy(loss, policy, cfg)
    assert res.stop_reason == "lr_min" and res.num_lr_reductions == 3
    assert sorted(set(res.dropouts), reverse=True) == [0.25, 0.125, 0.0]
    assert all(math.isfinite(c) for c in res.costs)
    assert all(p.grad is None for p in policy.parameters())

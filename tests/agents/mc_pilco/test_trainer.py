"""Smoke test of the whole MC-PILCO loop: 1 exploration + 1 policy trial, then a resume."""

from __future__ import annotations

import dataclasses
import json

import pytest
import torch

from mcpilco.agents.common.checkpoint import load_checkpoint
from mcpilco.agents.mc_pilco import (
    DEFAULT_ENV_ID,
    MCPilcoConfig,
    SquashedRBFPolicy,
    TaskSpec,
    load_config,
    make_env,
    parse_set,
    run_mcpilco,
)

TASK = TaskSpec.for_env(DEFAULT_ENV_ID)
# the cart-pole's config file (MC-PILCO's cost l_x = 1, l_theta = 3 on |theta| - pi, actions
# held 2 steps in exploration) with a tiny budget
SMOKE = load_config(
    DEFAULT_ENV_ID,
    overrides={
        "num_trials": 1,
        "num_particles": 20,
        "max_points": 100,
        "gp_adam_iters": 20,
        "gp_lbfgs_iters": 5,
        "num_basis": 50,
        "opt": {"max_steps": 30, "monitor_patience": 10},
        "log_particles": 20,
        "seed": 3,
        "torch_threads": 1,
    },
)


@pytest.fixture(scope="module")
def smoke_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("mcpilco_smoke")
    summary = run_mcpilco(SMOKE, out, progress=False, log=None)
    return out, summary


def test_smoke_run_writes_checkpoint_png_and_rrd(smoke_run):
    out, summary = smoke_run
    assert [r["kind"] for r in summary.records] == ["exploration", "policy"]
    rec = summary.records[1]
    assert 1 <= rec["opt_steps"] <= 30
    assert isinstance(rec["success"], bool)
    assert rec["gp_points"] == 60 and len(rec["gp_rmse"]) == 2
    for k, r in enumerate(summary.records):  # the cart-pole's episodes run all 60 steps
        assert r["steps"] == 60 and r["experience_s"] == pytest.approx(3.0 * (k + 1))
        assert 0.0 <= r["time_in_goal"] <= 3.0
    ckpt = load_checkpoint(summary.checkpoint)
    assert ckpt["next_trial"] == 2
    assert len(ckpt["episodes"]) == 2
    assert ckpt["episodes"][0]["obs"].shape == (61, 4)
    # the saved settings rebuild the applied policy
    policy = SquashedRBFPolicy(**ckpt["policy_settings"])
    policy.load_state_dict(ckpt["policy"])
    policy.eval()
    assert policy.num_basis == 50 and policy.u_max == 1.0
    x = torch.tensor([[0.1, -0.2, 3.0, 0.5]])
    with torch.no_grad():
        u = policy(x)
    assert u.shape == (1, 1) and torch.isfinite(u).all() and u.abs().max() <= 1.0
    assert (out / ckpt["gp_file"]).is_file()
    png = out / "trial_01_particles.png"
    assert png.is_file() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (out / "optimisation.png").is_file()
    records = json.loads((out / "records.json").read_text())["records"]
    assert len(records) == 2
    assert not list(out.glob("*.tmp"))


def test_rrd_is_readable_by_rerun(smoke_run):
    _, summary = smoke_run
    assert summary.rrd.is_file() and summary.rrd.stat().st_size > 1000
    from rerun.chunk import RrdReader

    reader = RrdReader(summary.rrd)
    assert len(reader.recordings()) == 1
    assert len(reader.blueprints()) == 1  # the blueprint built in code travels with the file
    text = reader.store().summary()
    for entity in (
        "/particles/x/model",
        "/particles/theta/real",
        "/particles/theta_dot/model",  # one plot per state coordinate
        "/optimisation/expected_cost",
        "/gp/one_step_rmse/delta_theta_dot",
    ):
        assert entity in text


def test_resume_continues_without_redoing_finished_trials(smoke_run, tmp_path):
    out, summary = smoke_run
    # copy the finished run, then resume it asking for one more trial
    import shutil

    run2 = tmp_path / "run"
    shutil.copytree(out, run2)
    lines = []
    cfg = dataclasses.replace(SMOKE, num_trials=2)
    resumed = run_mcpilco(cfg, run2, resume=True, progress=False, log=lines.append)
    assert resumed.resumed_from_trial == 2
    assert [r["index"] for r in resumed.records] == [0, 1, 2]
    assert resumed.records[:2] == summary.records  # finished trials kept as they were
    assert "resumed" in lines[0] and len(lines) == 2  # one new trial line only
    ckpt = load_checkpoint(resumed.checkpoint)
    assert ckpt["next_trial"] == 3 and len(ckpt["episodes"]) == 3
    assert resumed.records[2]["n_data"] == 120
    # a resume with a different seed is refused with a clear message
    with pytest.raises(ValueError, match="cannot resume: seed"):
        run_mcpilco(dataclasses.replace(cfg, seed=4), run2, resume=True, progress=False, log=None)


def test_resume_without_checkpoint_is_a_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="no checkpoint"):
        run_mcpilco(SMOKE, tmp_path, resume=True, progress=False, log=None)


def test_compile_rollout_without_a_cpp_compiler_fails_before_any_trial(tmp_path, monkeypatch):
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    monkeypatch.delenv("CXX", raising=False)
    config = dataclasses.replace(SMOKE, compile_rollout=True)
    with pytest.raises(ValueError, match=r"needs a C\+\+ compiler \(g\+\+ or clang\+\+"):
        run_mcpilco(config, tmp_path / "run", progress=False, log=None)
    assert not (tmp_path / "run" / "checkpoint.pt").exists()
    monkeypatch.setenv("CXX", "no-such-c++")
    with pytest.raises(ValueError, match="no-such-c\\+\\+ not found"):
        run_mcpilco(config, tmp_path / "run", progress=False, log=None)
    # the torch backend needs no compiler: the run goes on with the chained PyTorch rollout
    torch_config = dataclasses.replace(config, rollout_backend="torch")
    summary = run_mcpilco(torch_config, tmp_path / "torch", progress=False, log=None)
    policy = [r for r in summary.records if r["kind"] == "policy"]
    assert policy and all(r["compile_backend"] == "torch" for r in policy)
    assert all(r["compile_check"]["grad_rel"] < 1e-3 for r in policy)


def test_bad_arguments_give_clear_errors():
    with pytest.raises(ValueError, match="registered mcpilco ids: .*mcpilco/CartpoleSwingUp-v0"):
        make_env("mcpilco/NoSuchEnv-v0", 60)
    with pytest.raises(ValueError, match="horizon mismatch"):
        make_env("mcpilco/CartpoleSwingUp-v0", 50, TASK)
    with pytest.raises(ValueError, match="num_particles"):
        MCPilcoConfig(num_particles=0)
    with pytest.raises(ValueError, match="kernel"):
        MCPilcoConfig(kernel="linear")
    with pytest.raises(ValueError, match="rollout_dtype must be one of"):
        MCPilcoConfig(rollout_dtype="float16")
    with pytest.raises(ValueError, match="rollout_backend must be one of"):
        MCPilcoConfig(rollout_backend="inductor")


def test_fused_predictor_matches_gp_cached_predictor():
    from mcpilco.agents.mc_pilco.dynamics import GPDynamicsModel
    from mcpilco.models.gp.fused import FusedRBFMPKPredictor

    gen = torch.Generator().manual_seed(0)
    s = torch.randn(50, 4, generator=gen, dtype=torch.float64)
    a = torch.rand(50, 1, generator=gen, dtype=torch.float64) * 2 - 1
    s1 = s + 0.05 * torch.randn(50, 4, generator=gen, dtype=torch.float64)
    for kernel in ("rbf+mpk", "rbf"):
        model = GPDynamicsModel(TASK, kernel=kernel, adam_iters=10, lbfgs_iters=0).fit(s, a, s1)
        pred = model.gp_.cached_predictor(dtype=torch.float64)
        fused = FusedRBFMPKPredictor.from_cached(pred)
        assert fused is not None
        z = torch.randn(30, 6, generator=gen, dtype=torch.float64).requires_grad_(True)
        m1, v1 = pred(z)
        m2, v2 = fused(z)
        torch.testing.assert_close(m2, m1, atol=1e-9, rtol=1e-9)
        torch.testing.assert_close(v2, v1, atol=1e-9, rtol=1e-9)
        g1 = torch.autograd.grad((m1 + v1).sum(), z)[0]
        g2 = torch.autograd.grad((m2 + v2).sum(), z)[0]
        torch.testing.assert_close(g2, g1, atol=1e-8, rtol=1e-8)


def test_fused_predictor_stays_finite_when_the_rbf_is_switched_off():
    """A fit where marginal likelihood switches the RBF off (lambda^2 underflows to 0) and one
    of its then-irrelevant lengthscales collapses to 0 (seen on the dm-control cartpole):
    the fused float32 predictor must give the float64 GP posterior, not NaN."""
    from mcpilco.agents.mc_pilco.dynamics import GPDynamicsModel
    from mcpilco.models.gp.fused import FusedRBFMPKPredictor

    gen = torch.Generator().manual_seed(1)
    s = torch.randn(40, 4, generator=gen, dtype=torch.float64)
    a = torch.rand(40, 1, generator=gen, dtype=torch.float64) * 2 - 1
    s1 = s + 0.05 * torch.randn(40, 4, generator=gen, dtype=torch.float64)
    model = GPDynamicsModel(TASK, kernel="rbf+mpk", adam_iters=5, lbfgs_iters=0).fit(s, a, s1)
    rbf = model.gp_.model_.covar_module.kernels[0]
    with torch.no_grad():
        rbf.raw_outputscale.fill_(-900.0)  # softplus -> exactly 0 in float64
        rbf.base_kernel.raw_lengthscale[..., 2] = -60.0  # lengthscale ~ 1e-26
    pred = model.gp_.cached_predictor(dtype=torch.float64)
    fused = FusedRBFMPKPredictor.from_cached(model.gp_.cached_predictor(dtype=torch.float32))
    z = torch.randn(30, 6, generator=gen, dtype=torch.float64)
    m1, v1 = pred(z)
    m2, v2 = fused(z.float())
    assert torch.isfinite(m2).all() and torch.isfinite(v2).all()
    torch.testing.assert_close(m2.double(), m1, atol=1e-4, rtol=1e-3)
    torch.testing.assert_close(v2.double(), v1, atol=1e-4, rtol=1e-3)


def test_config_overrides_keep_unset_fields_and_cap_the_first_trial_steps():
    BENCH_CONFIG = load_config(DEFAULT_ENV_ID, preset="bench")

    cfg = BENCH_CONFIG.with_overrides(num_trials=None, kernel="rbf", opt_steps=300)
    assert cfg.num_trials == BENCH_CONFIG.num_trials and cfg.kernel == "rbf"
    assert cfg.opt.max_steps == 300 and cfg.opt_steps_first == 300  # 500 capped at 300
    assert BENCH_CONFIG.with_overrides(opt_steps=2000).opt_steps_first == 500
    with pytest.raises(ValueError, match="num_particles"):
        BENCH_CONFIG.with_overrides(num_particles=0)


def test_config_from_dict_round_trips_and_names_unknown_fields():
    """A saved config reads back as it was; a config saved with the cart-pole's cost fields
    (``l_x``, ``l_theta``, ``cost_wrap_angle``) reads as the same cost; a field no config
    has is an error that names it."""
    saved = SMOKE.to_dict()
    assert MCPilcoConfig.from_dict(saved) == SMOKE
    old = {k: v for k, v in saved.items() if k not in ("cost_length_scales", "cost_angle_mode")}
    old.update(l_x=1.5, l_theta=2.0, cost_wrap_angle=True)
    cfg = MCPilcoConfig.from_dict(old)
    assert cfg.cost_length_scales == {"x": 1.5, "theta": 2.0}
    assert cfg.cost_angle_mode == "wrap"
    with pytest.raises(ValueError, match=r"unknown MC-PILCO config fields \['colour'\]"):
        MCPilcoConfig.from_dict({**saved, "colour": "red"})


DMC_ID = "mcpilco/DMCCartpoleSwingUp-v0"


def test_explore_hold_comes_from_the_envs_config_file():
    """Held exploration on our cartpole, i.i.d. on the dm-control adapter (whose held pushes
    hit the rail's end stop), in every preset; an explicit value always wins."""
    from mcpilco.agents.common.checkpoint import check_resume

    assert MCPilcoConfig().explore_hold == 1  # no file: i.i.d.
    assert load_config(DEFAULT_ENV_ID).explore_hold == 2
    assert load_config(DMC_ID).explore_hold == 1
    for preset in ("bench", "demo", "small"):
        assert load_config(DEFAULT_ENV_ID, preset=preset).explore_hold == 2
        assert load_config(DMC_ID, preset=preset).explore_hold == 1
        told = load_config(DMC_ID, preset=preset, overrides={"explore_hold": 2})
        assert told.explore_hold == 2
    # saved configs carry the value, so a resume compares like with like
    saved = load_config(DMC_ID).to_dict()
    assert saved["explore_hold"] == 1 and MCPilcoConfig.from_dict(saved).explore_hold == 1
    check_resume(saved, load_config(DMC_ID), ("explore_hold",))
    with pytest.raises(ValueError, match="cannot resume: explore_hold=2 differs .* 1"):
        check_resume(saved, load_config(DEFAULT_ENV_ID), ("explore_hold",))


def test_load_config_reads_the_file_then_the_preset_then_the_overrides():
    """The cart-pole's file holds MC-PILCO's optimised cost (Amadio et al. 2022), its presets
    the bench / demo / small budgets; overrides (``parse_set``) come last, nested fields
    merged; an unknown preset or field is a clear error."""
    base = load_config(DEFAULT_ENV_ID)
    assert base.cost_length_scales == {"x": 1.0, "theta": 3.0}
    assert base.cost_angle_mode == "abs" and base.horizon is None
    assert base.task_spec().horizon == 60 and base.task_spec() == TASK
    bench = load_config(DEFAULT_ENV_ID, preset="bench")
    assert (bench.num_trials, bench.max_points, bench.opt_steps_first) == (4, 250, 500)
    assert (bench.opt.max_steps, bench.opt.monitor_patience) == (1000, 100)
    assert load_config(DEFAULT_ENV_ID, preset="demo").num_trials == 3
    small = load_config(DEFAULT_ENV_ID, preset="small")
    assert (small.num_particles, small.num_candidates) == (100, 2)
    over = parse_set(["opt.max_steps=5", "num_particles=7", "cost_length_scales={x: 2}"])
    assert over == {"opt": {"max_steps": 5}, "num_particles": 7, "cost_length_scales": {"x": 2}}
    cfg = load_config(DEFAULT_ENV_ID, preset="bench", overrides=over)
    assert (cfg.opt.max_steps, cfg.opt.monitor_patience) == (5, 100)  # merged, not replaced
    assert cfg.num_particles == 7
    assert cfg.cost_length_scales == {"x": 2.0, "theta": 3.0}  # a mapping is merged too
    assert cfg.max_points == 250  # the preset's
    with pytest.raises(ValueError, match="unknown preset 'fast'.*bench"):
        load_config(DEFAULT_ENV_ID, preset="fast")
    with pytest.raises(ValueError, match=r"unknown MC-PILCO config fields \['particles'\]"):
        load_config(DEFAULT_ENV_ID, overrides={"particles": 3})
    with pytest.raises(ValueError, match="--set takes key=value"):
        parse_set(["num_particles"])

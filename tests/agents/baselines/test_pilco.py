"""PILCO from TorchRL's parts: the cost it optimises, the outer loop it shares with MC-PILCO.

Truth used: the env's own swing-up cost (:func:`mcpilco.envs.cartpole_task.cartpole_cost`),
a Monte Carlo estimate of the expected cost, botorch's own GP posterior, and MC-PILCO's
exploration trial.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
import torch
from tensordict import TensorDict

from mcpilco.agents.baselines.compare import run_method
from mcpilco.agents.baselines.pilco import (
    ImaginedCost,
    PilcoConfig,
    _torchrl_env,
    controller_act,
    env_settings,
    fit_world_model,
    make_controller,
    make_cost,
    optimize_controller,
    pilco_config,
    run_pilco,
)
from mcpilco.agents.mc_pilco import TaskSpec, load_config, run_mcpilco
from mcpilco.envs.cartpole_task import cartpole_cost

ENV = "mcpilco/CartpoleSwingUp-v0"
TASK = TaskSpec.for_env(ENV)
needs_cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")


def _expected_cost(cost, mean, cov) -> np.ndarray:
    td = TensorDict(
        {
            ("observation", "mean"): torch.as_tensor(mean, dtype=torch.float64),
            ("observation", "var"): torch.as_tensor(cov, dtype=torch.float64),
        },
        batch_size=[len(mean)],
    )
    return cost(td)["loss_cost"].numpy()


@pytest.mark.parametrize(("l_x", "l_theta"), [(1.5, 1.0), (1.0, 3.0)])
def test_cost_on_a_point_state_is_the_env_cost(l_x, l_theta):
    rng = np.random.default_rng(0)
    states = np.column_stack(
        [
            rng.uniform(-2, 2, 50),
            rng.normal(size=50),
            rng.uniform(0, np.pi, 50),
            rng.normal(size=50),
        ]
    )
    got = _expected_cost(
        make_cost(TASK, {"x": l_x, "theta": l_theta}), states, np.zeros((50, 4, 4))
    )
    # ExponentialQuadraticCost adds a 1e-5 jitter to its covariance term
    np.testing.assert_allclose(got, cartpole_cost(states, l_theta, l_x), atol=1e-4)
    if (l_x, l_theta) == (1.5, 1.0):  # the task's own length scales: its evaluation cost
        own = _expected_cost(make_cost(TASK), states, np.zeros((50, 4, 4)))
        np.testing.assert_allclose(own, got, rtol=0, atol=0)


def test_cost_on_states_without_a_task_term_is_torchrls_default():
    """Length scales sqrt(2) on every state of InvertedPendulum-v5 (whose task has cost terms
    on x and theta only) give ExponentialQuadraticCost's defaults, target 0 and W = I:
    ``c(x) = 1 - exp(-|x|^2 / 2)`` on a point state."""
    task = TaskSpec.for_env("InvertedPendulum-v5")
    states = np.random.default_rng(1).normal(scale=0.7, size=(40, 4))
    cost = make_cost(task, dict.fromkeys(task.state_names, math.sqrt(2.0)))
    got = _expected_cost(cost, states, np.zeros((40, 4, 4)))
    np.testing.assert_allclose(got, 1 - np.exp(-0.5 * (states**2).sum(1)), atol=1e-4)
    with pytest.raises(ValueError, match="cost_length_scales: unknown state.*theta_ddot"):
        make_cost(task, {"theta_ddot": 1.0})


def test_settings_by_env_id(tmp_path):
    """InvertedPendulum-v5 takes TorchRL's example (sota-implementations/pilco/config.yaml);
    an env without an entry takes MC-PILCO's exploration hold and cost; overrides win."""
    ip = pilco_config("InvertedPendulum-v5")
    assert (ip.num_basis, ip.optimizer, ip.lr, ip.opt_steps) == (10, "adam", 5e-3, 100)
    assert (ip.imagined_horizon, ip.max_points, ip.explore_steps) == (40, 350, 200)
    assert ip.init_std**2 == pytest.approx(1e-3)
    assert ip.cost_length_scales == dict.fromkeys(["x", "theta", "x_dot", "theta_dot"], 2**0.5)
    cart = pilco_config(ENV, {"num_basis": 7})
    assert (cart.explore_hold, cart.cost_length_scales) == (2, {"x": 1.0, "theta": 3.0})
    assert (cart.num_basis, cart.imagined_horizon, cart.explore_steps) == (7, None, None)
    bad = tmp_path / "pilco.yaml"
    bad.write_text("envs:\n  InvertedPendulum-v5: {basis: 3}\n")
    with pytest.raises(ValueError, match="unknown PILCO field\\(s\\) basis"):
        env_settings("InvertedPendulum-v5", bad)
    assert env_settings("mcpilco/UR10-v0", bad) == {}


def test_inverted_pendulum_run_counts_every_exploration_step(tmp_path):
    """TorchRL's example on InvertedPendulum-v5 through the compare entry point (a shorter
    random rollout and 2 Adam steps): the random rollout resets after every fall and takes
    exactly ``explore_steps`` steps, all of them experience (0.04 s each) and GP data."""
    opts = {
        "trials": 1,
        "pilco": {"explore_steps": 60, "opt_steps": 2, "max_points": 60},
        "threads": 1,
        "log": False,
    }
    curve = run_method("pilco", "InvertedPendulum-v5", 0, tmp_path, opts)
    saved = json.loads((tmp_path / "records.json").read_text())
    explore, policy = saved["records"]
    assert explore["steps"] == 60 and explore["episodes"] > 1
    assert explore["experience_s"] == pytest.approx(60 * 0.04)
    assert policy["gp_points"] == 60 and policy["opt_steps"] == 2
    assert 1 <= policy["steps"] <= 50
    assert policy["experience_s"] == pytest.approx((60 + policy["steps"]) * 0.04)
    assert [p["steps"] for p in curve["points"]] == [60, 60 + policy["steps"]]
    assert policy["success"] == (policy["steps"] == 50)
    cfg = saved["config"]
    assert (cfg["num_basis"], cfg["imagined_horizon"], cfg["optimizer"]) == (10, 40, "adam")


def test_expected_cost_matches_monte_carlo():
    rng = np.random.default_rng(1)
    mean = np.array([0.3, 0.1, 2.2, -0.2])
    a = rng.normal(size=(4, 4)) * 0.05
    cov = a @ a.T + 0.01 * np.eye(4)
    closed = _expected_cost(make_cost(TASK, {"x": 1.0, "theta": 3.0}), mean[None], cov[None])[0]
    samples = rng.multivariate_normal(mean, cov, size=200_000)
    assert np.all(samples[:, 2] < np.pi)  # the quadratic and the wrapped cost agree there
    mc = cartpole_cost(samples, 3.0, 1.0).mean()
    assert closed == pytest.approx(mc, abs=1e-3)


def test_moment_matching_at_a_point_belief_is_the_gp_posterior_in_target_units():
    """As ``Sigma_x -> 0`` PILCO's moment matching must return botorch's predictive variance.

    The targets differ in scale by 600x, so a variance left in botorch's standardised units
    (TorchRL 0.14's ``GPWorldModel.fit`` alone) is off by ``s_a^2`` (down to 1/400).
    """
    rng = np.random.default_rng(3)
    n, scales = 60, np.array([0.05, 1.0, 30.0, 0.3])
    obs = rng.uniform(-1.5, 1.5, size=(n, 4))
    act = rng.uniform(-1, 1, size=(n, 1))
    clean = np.column_stack(
        [
            np.sin(obs[:, 0] + act[:, 0]),
            obs[:, 1] * act[:, 0],
            np.cos(obs[:, 2]),
            obs[:, 3] ** 2 - 0.5,
        ]
    )
    delta = scales * (clean + 0.05 * rng.normal(size=(n, 4)))
    model = fit_world_model(obs, act, obs + delta)
    x = torch.as_tensor(rng.uniform(-1, 1, size=(5, 4)))
    u = torch.as_tensor(rng.uniform(-0.5, 0.5, size=(5, 1)))
    td = TensorDict(
        {
            ("observation", "mean"): x,
            ("observation", "var"): 1e-10 * torch.eye(4, dtype=torch.float64).expand(5, 4, 4),
            ("action", "mean"): u,
            ("action", "var"): torch.zeros(5, 1, 1, dtype=torch.float64),
            ("action", "cross_covariance"): torch.zeros(5, 4, 1, dtype=torch.float64),
        },
        batch_size=[5],
    )
    with torch.no_grad():
        out = model.uncertain_forward(td)
        var_mm = torch.diagonal(out["next", "observation", "var"], dim1=-2, dim2=-1)
        var_gp = torch.stack(
            [
                gp.posterior(torch.cat([x, u], -1), observation_noise=True).variance[:, 0]
                for gp in model.model_list.models
            ],
            -1,
        )
    # atol: the jitter TorchRL adds to K_a + sigma_eps_a^2 I (1e-6 s_a^2 in target units)
    np.testing.assert_allclose(var_mm.numpy(), var_gp.numpy(), rtol=0.02, atol=1e-6)


def test_controller_action_is_bounded_and_deterministic():
    controller, _ = make_controller(4, 1, num_basis=10, seed=0)
    with torch.no_grad():
        controller.weights.mul_(100.0)  # saturate: |u| must still be <= u_max = 1
    act = controller_act(controller)
    obs = np.random.default_rng(2).normal(size=(20, 4))
    u = np.array([act(o) for o in obs])
    assert u.shape == (20, 1) and np.all(np.abs(u) <= 1.0) and np.abs(u).max() > 0.5
    np.testing.assert_array_equal(u, np.array([act(o) for o in obs]))


def test_config_round_trips_through_to_dict_and_from_dict():
    """A saved PILCO config reads back as it was (also through JSON, as records.json holds
    it); one saved before ``explore_hold`` existed reads with 1; an unknown field is named."""
    for cfg in (PilcoConfig(), PilcoConfig(env_id="InvertedPendulum-v5", optimizer="adam")):
        assert PilcoConfig.from_dict(cfg.to_dict()) == cfg
        assert PilcoConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg
    old = PilcoConfig(explore_hold=3).to_dict()
    del old["explore_hold"]
    assert PilcoConfig.from_dict(old).explore_hold == 1
    with pytest.raises(ValueError, match=r"unknown PILCO config fields \['colour'\]"):
        PilcoConfig.from_dict({**old, "colour": "red"})


def test_config_validation():
    with pytest.raises(ValueError, match="init_std must be >= 1e-3"):
        PilcoConfig(init_std=1e-5)
    with pytest.raises(ValueError, match="max_points must be an integer >= 10"):
        PilcoConfig(max_points=3)
    with pytest.raises(ValueError, match="num_trials must be an integer >= 0"):
        PilcoConfig(num_trials=-1)
    with pytest.raises(ValueError, match="optimizer must be one of"):
        PilcoConfig(optimizer="bfgs")
    with pytest.raises(ValueError, match="cost length scales must be > 0"):
        PilcoConfig(cost_length_scales={"x": 1.0, "theta": 0.0})
    with pytest.raises(ValueError, match="device must be 'cpu', 'cuda'"):
        PilcoConfig(device="gpu")


def test_a_cuda_run_is_refused_before_any_work_without_a_gpu(monkeypatch, tmp_path):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(ValueError, match="sees no CUDA device"):
        run_pilco(PilcoConfig(env_id="InvertedPendulum-v5", device="cuda"), tmp_path / "run")
    assert not (tmp_path / "run").exists()


def _pendulum_objective(device: str):
    """``J`` of a 10-step imagined rollout on InvertedPendulum-v5 under a world model fitted
    on the host from fixed random transitions, with the model, controller and cost on
    ``device``; returns ``J`` and the controller."""
    task = TaskSpec.for_env("InvertedPendulum-v5")
    rng = np.random.default_rng(4)
    obs = rng.normal(scale=0.1, size=(40, 4))
    act = rng.uniform(-3.0, 3.0, size=(40, 1))
    nxt = obs + 0.04 * np.column_stack([obs[:, 2], obs[:, 3], act[:, 0], -act[:, 0]])
    model = fit_world_model(obs, act, nxt).to(device)
    controller, module = make_controller(4, 1, 10, seed=0, max_action=3.0, device=device)
    cost = make_cost(task).to(device)
    objective = ImaginedCost(
        model, _torchrl_env("InvertedPendulum-v5", device), module, cost, 10, 0.03
    )
    return objective(), controller


@needs_cuda
def test_imagined_cost_and_gradient_on_cuda_match_the_cpu():
    """Same fitted world model and controller initialisation: the moment-matching rollout on
    the GPU gives the CPU's ``J`` and policy gradient (float64, other kernels)."""
    j_cpu, c_cpu = _pendulum_objective("cpu")
    j_gpu, c_gpu = _pendulum_objective("cuda")
    assert j_gpu.device.type == "cuda"
    j_cpu.backward(), j_gpu.backward()
    assert float(j_gpu) == pytest.approx(float(j_cpu), rel=1e-9)
    for p_cpu, p_gpu in zip(c_cpu.parameters(), c_gpu.parameters(), strict=True):
        torch.testing.assert_close(p_gpu.grad.cpu(), p_cpu.grad, rtol=1e-7, atol=1e-12)


@needs_cuda
def test_a_cuda_run_trains_checkpoints_and_resumes(tmp_path):
    cfg = PilcoConfig(
        env_id="InvertedPendulum-v5",
        num_trials=1,
        opt_steps=2,
        num_basis=5,
        max_points=40,
        explore_steps=40,
        optimizer="adam",
        device="cuda",
    )
    first = run_pilco(cfg, tmp_path)
    assert [r["kind"] for r in first.records] == ["exploration", "policy"]
    assert first.records[1]["opt_steps"] == 2
    more = run_pilco(dataclasses.replace(cfg, num_trials=2), tmp_path, resume=True)
    assert more.resumed_from_trial == 2 and len(more.records) == 3


TINY = {"max_points": 30, "opt_steps": 2, "num_basis": 5}


@pytest.fixture(scope="module")
def pilco_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("pilco")
    opts = {"trials": 1, "pilco": TINY, "threads": 1, "log": False}
    curve = run_method("pilco", ENV, 2, out, opts)
    return out, opts, curve


def test_smoke_run_through_the_compare_entry_point(pilco_run):
    out, _, curve = pilco_run
    saved = json.loads((out / "records.json").read_text())
    recs = saved["records"]
    assert [r["kind"] for r in recs] == ["exploration", "policy"]
    # MC-PILCO's exploration hold and optimisation cost (its bench config) reach PILCO
    mc = load_config(ENV, preset="bench")
    assert saved["config"]["explore_hold"] == mc.explore_hold == 2
    assert (
        saved["config"]["cost_length_scales"] == mc.cost_length_scales == {"x": 1.0, "theta": 3.0}
    )
    # L-BFGS stops after the iteration that reaches opt_steps evaluations (its line search
    # may add up to 25)
    assert 2 <= recs[1]["opt_steps"] <= 2 + 25 and recs[1]["gp_points"] == 30
    assert math.isfinite(recs[1]["opt_final_cost"]) and 0 <= recs[1]["opt_final_cost"] <= 60
    assert [(p["steps"], p["experience_s"]) for p in curve["points"]] == [(60, 3.0), (120, 6.0)]
    assert (out / "checkpoint.pt").is_file() and (out / "optimisation.png").is_file()


def test_exploration_trial_is_mc_pilcos(pilco_run, tmp_path):
    out, _, _ = pilco_run
    pilco0 = json.loads((out / "records.json").read_text())["records"][0]
    # MC-PILCO's bench config, as the compare entry point gives PILCO its exploration hold
    config = load_config(
        ENV, preset="bench", overrides={"num_trials": 0, "seed": 2, "torch_threads": 1}
    )
    mc = run_mcpilco(
        config,
        tmp_path,
        progress=False,
        log=None,
        write_rrd=False,
    )
    mc0 = mc.records[0]
    for key in ("cost", "success", "time_in_goal", "steps", "experience_s"):
        assert pilco0[key] == mc0[key], key


def test_resume_adds_a_trial_and_keeps_the_old_ones(pilco_run):
    out, opts, curve = pilco_run
    more = run_method("pilco", ENV, 2, out, {**opts, "trials": 2})
    assert more["points"][:2] == curve["points"]
    assert [p["steps"] for p in more["points"]] == [60, 120, 180]
    with pytest.raises(ValueError, match="cannot resume: num_basis"):
        run_method("pilco", ENV, 2, out, {**opts, "pilco": {**TINY, "num_basis": 6}})


class _Quadratic(torch.nn.Module):
    """``J(w) = sum_i c_i (w_i - w*_i)^2``: minimum 0 at ``w*`` (closed form)."""

    def __init__(self) -> None:
        super().__init__()
        self.w = torch.nn.Parameter(torch.zeros(5, dtype=torch.float64))
        self.target = torch.linspace(-2.0, 3.0, 5, dtype=torch.float64)
        self.curv = torch.logspace(-1, 2, 5, dtype=torch.float64)

    def __call__(self) -> torch.Tensor:
        return (self.curv * (self.w - self.target) ** 2).sum()


def test_lbfgs_reaches_the_minimum_of_a_quadratic_and_keeps_the_best_on_nan():
    q = _Quadratic()
    res = optimize_controller(q, q, steps=40, lr=1.0, optimizer="lbfgs")
    np.testing.assert_allclose(q.w.detach().numpy(), q.target.numpy(), atol=1e-6)
    assert res["best"] < 1e-10 and len(res["costs"]) <= 40 + 25
    # Adam with the same budget is far from it on this ill-conditioned quadratic
    q2 = _Quadratic()
    assert optimize_controller(q2, q2, steps=40, lr=0.02, optimizer="adam")["best"] > 1.0

    q3, calls = _Quadratic(), []

    def nan_after_three() -> torch.Tensor:
        calls.append(1)
        return q3() * (math.nan if len(calls) > 3 else 1.0)

    res = optimize_controller(nan_after_three, q3, steps=40, lr=1.0, optimizer="lbfgs")
    assert len(res["costs"]) == 4 and res["skipped"] == 1
    assert res["best"] == min(res["costs"][:3])
    assert float(q3().detach()) == pytest.approx(res["best"])  # the best parameters were restored
    with pytest.raises(ValueError, match="optimizer must be one of"):
        optimize_controller(q3, q3, steps=1, lr=1.0, optimizer="sgd")

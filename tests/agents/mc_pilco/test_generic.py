"""MC-PILCO over tasks other than the cart-pole: a toy env trained through the same entry
point, the hand-chained rollout against autograd on random task layouts, resume after a
kill on a non-cart-pole task."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from mcpilco.agents.common.checkpoint import load_checkpoint
from mcpilco.agents.common.trials import make_env, run_episode
from mcpilco.agents.mc_pilco import (
    GPDynamicsModel,
    MCPilcoConfig,
    MCPilcoLoss,
    PolicyOptConfig,
    PolicyPopulation,
    SaturatingCost,
    SquashedRBFPolicy,
    StateLayout,
    TaskSpec,
    make_policy_module,
    run_mcpilco,
)
from mcpilco.agents.mc_pilco.fast import check_against_eager, use_fast_rollout
from tests.agents.mc_pilco.toy_env import ENV_ID, TASK

ROOT = Path(__file__).resolve().parents[3]


def toy_config(**over) -> MCPilcoConfig:
    base = dict(
        env_id=ENV_ID,
        task=TASK,
        num_trials=1,
        num_particles=50,
        max_points=100,
        gp_adam_iters=60,
        gp_lbfgs_iters=20,
        num_basis=50,
        sim_obs_noise_std=0.0,
        torch_threads=1,
        opt=PolicyOptConfig(max_steps=150, min_steps=50, monitor_patience=50),
    )
    base.update(over)
    return MCPilcoConfig(**base)


def test_toy_env_reaches_its_goal(tmp_path):
    """A 4-state, 2-action point mass: after 3 s of random exploration and two policy
    trials it is brought from (-1, 0.5) to the origin and kept there (the task's success
    test), with a far lower cost than the exploration trial."""
    cfg = toy_config(num_trials=2)
    summary = run_mcpilco(cfg, tmp_path, progress=False, log=None, write_rrd=False)
    explore, _, policy = summary.records
    assert policy["success"], policy
    assert policy["cost"] < 0.6 * explore["cost"]
    # the particles predicted the real trajectory: final positions within 0.15 of it
    arr = load_checkpoint(tmp_path / "checkpoint.pt")["arrays"][-1]
    pred_end = np.asarray(arr["particles"])[:, -1].mean(0)
    real_end = np.asarray(arr["real"])[-1]
    assert np.abs(pred_end[[0, 2]] - real_end[[0, 2]]).max() < 0.15


def random_task(rng: np.random.Generator) -> TaskSpec:
    """A task of 2-6 states with angles anywhere, 0-2 speed-integration pairs, 1-3 actions and
    limits on some plain states, within about 1 of their initial mean."""
    n = int(rng.integers(2, 7))
    names = [f"s{i}" for i in range(n)]
    order = rng.permutation(n)
    n_pairs = int(rng.integers(0, min(2, n // 2) + 1))
    pairs = [[names[order[2 * k]], names[order[2 * k + 1]]] for k in range(n_pairs)]
    velocities = {v for _, v in pairs}
    angles = [s for s in names if s not in velocities and rng.random() < 0.4]
    a = int(rng.integers(1, 4))
    terms = [
        {"state": s, "target": float(rng.normal()), "length_scale": float(rng.uniform(0.5, 2))}
        for s in names
        if rng.random() < 0.6
    ] or [{"state": names[0], "target": 0.3, "length_scale": 1.0}]
    init_mean = rng.normal(size=n)
    limits = {
        s: [float(init_mean[i] - rng.uniform(0.2, 1)), float(init_mean[i] + rng.uniform(0.2, 1))]
        for i, s in enumerate(names)
        if s not in angles and rng.random() < 0.5
    }
    return TaskSpec.from_dict(
        {
            "env_id": "any",
            "state_names": names,
            "angles": angles,
            "pairs": pairs,
            "action_low": [-2.0] * a,
            "action_high": [1.0] * a,
            "dt": 0.05,
            "horizon": 8,
            "init_mean": init_mean.tolist(),
            "init_std": 0.1,
            "cost": {"terms": terms},
            "limits": limits,
            "success": {"bounds": {names[0]: {"target": 0.0, "tol": 0.1}}},
        }
    )


def kernel_args(label: str) -> dict:
    """GPDynamicsModel's kernel arguments for a test label: ``"rbf+mpk1"`` is RBF + the
    degree-1 MPK, any other label a kernel name (``"rbf+mpk"``: degree 2)."""
    return {"kernel": "rbf+mpk", "mpk_degree": 1} if label == "rbf+mpk1" else {"kernel": label}


def fitted_loss(
    task: TaskSpec,
    rng: np.random.Generator,
    kernel: str,
    particles: int = 12,
    candidates: int = 1,
    angle_mode: str | None = None,
):
    """An MCPilcoLoss over a GP fitted (briefly) on smooth random transitions of ``task``;
    ``candidates > 1``: a :class:`PolicyPopulation` of that many (returned as the policy).
    The cost has a barrier of width 0.3 at each of the task's limits."""
    n, a = task.state_dim, task.action_dim
    s = rng.normal(size=(40, n))
    u = rng.uniform(-2, 1, size=(40, a))
    s1 = s + 0.1 * np.tanh(s @ rng.normal(size=(n, n)) + u @ rng.normal(size=(a, n)))
    model = GPDynamicsModel(
        task, **kernel_args(kernel), adam_iters=5, lbfgs_iters=0, max_points=None
    )
    model.fit(s, u, s1)
    layout = StateLayout.from_task(task)
    policies = [
        SquashedRBFPolicy(
            layout, task.action_low, task.action_high, num_basis=7, seed=1 + k, weight_scale=0.5
        )
        for k in range(candidates)
    ]
    policy = policies[0] if candidates == 1 else PolicyPopulation(policies)
    mode = angle_mode or str(rng.choice(["wrap", "abs"]))
    cost = SaturatingCost.from_task(
        task, angle_mode=mode, limit_widths={k: 0.3 for k in task.limits}
    )
    loss = MCPilcoLoss(
        make_policy_module(policy),
        model.particle_dynamics(torch.float32),
        cost,
        task.horizon,
        particles,
        task.init_mean,
        init_std=task.init_std,
        obs_noise_std=0.01,
    )
    return loss, policy


KERNEL_LABELS = ("rbf+mpk", "rbf", "rbf+mpk1")  # the fused posterior's kernels (kernel_args)


@pytest.mark.parametrize("seed", range(6))
def test_hand_chained_rollout_matches_autograd_on_random_tasks(seed):
    """The torch backend's forward and hand-chained backward through time against the
    autograd rollout: same random numbers, J^ and every policy-parameter gradient, on random
    layouts, action counts and the kernels (RBF, RBF + MPK of degree 2 or 1)."""
    rng = np.random.default_rng(seed)
    task = random_task(rng)
    loss, policy = fitted_loss(task, rng, KERNEL_LABELS[seed % 3])
    policy.train()
    assert use_fast_rollout(loss, backend="torch", verify=False).backend == "torch"
    check = check_against_eager(loss, seed=seed, horizon=None)
    assert check["J_rel"] < 1e-5, (task, check)
    assert check["grad_rel"] < 1e-4, (task, check)


def six_state_task(pairs: bool) -> TaskSpec:
    """Six states with angles at indices 0 and 2 (one of them a pair's position), three
    actions, a cost on an angle, a plain state and an unpaired one, limits on the plain one
    and the unpaired one; ``pairs=False``: every coordinate predicted as its own change (no
    speed integration)."""
    names = ["a0", "p", "a1", "v_a0", "v", "o"]
    return TaskSpec.from_dict(
        {
            "env_id": "any",
            "state_names": names,
            "angles": ["a0", "a1"],
            "pairs": [["a0", "v_a0"], ["p", "v"]] if pairs else [],
            "action_low": [-1.0, -2.0, -0.5],
            "action_high": [1.0, 1.0, 1.5],
            "dt": 0.05,
            "horizon": 8,
            "init_mean": [0.5, 0.1, -2.5, 0.0, 0.2, 0.3],
            "init_std": 0.2,
            "cost": {
                "terms": [
                    {"state": "a0", "target": 3.14159, "length_scale": 3.0},
                    {"state": "p", "target": 0.2, "length_scale": 1.0},
                    {"state": "o", "target": -0.3, "length_scale": 0.8},
                ]
            },
            "success": {"bounds": {"p": {"target": 0.0, "tol": 0.1}}},
            "limits": {"p": [-0.3, 0.4], "o": [0.0, 0.9]},
        }
    )


NATIVE_CASES = [
    # (task, kernel, candidates, shards, angle mode)
    ("pairs", "rbf+mpk", 2, 2, "wrap"),
    ("pairs", "rbf", 1, 1, "abs"),
    ("pairs", "rbf+mpk1", 1, 2, "wrap"),
    ("deltas", "rbf+mpk", 1, 2, "abs"),
    ("deltas", "rbf", 2, 1, "wrap"),
    ("deltas", "rbf+mpk1", 2, 1, "abs"),
    *((f"random{seed}", KERNEL_LABELS[seed % 3], 2, 1 + seed % 2, None) for seed in range(6)),
]


@pytest.mark.parametrize(("name", "kernel", "candidates", "shards", "mode"), NATIVE_CASES)
def test_native_rollout_matches_autograd_on_task_layouts(name, kernel, candidates, shards, mode):
    """The C++ rollout (``backend="native"``) against the autograd rollout, from the same
    random numbers over the whole horizon (dropout masks and observation noise on): J^ and
    every policy-parameter gradient, on the six-state task with and without speed
    integration (4 or 6 GP outputs, 3 actions, angles at indices 0 and 2) and on random
    layouts, RBF and RBF + MPK of degree 2 or 1, 1 or 2 candidates, 1 or 2 shards (20
    particles per candidate: a
    full tile and a part-filled one, or two part-filled ones)."""
    from mcpilco.agents.mc_pilco.fast import build_error

    if name.startswith("random"):
        rng = np.random.default_rng(100 + int(name[6:]))
        task = random_task(rng)
    else:
        rng = np.random.default_rng(7)
        task = six_state_task(pairs=name == "pairs")
    loss, policy = fitted_loss(task, rng, kernel, 20, candidates, mode)
    fast = use_fast_rollout(loss, backend="native", shards=shards, verify=False)
    assert fast.backend == "native" and loss.rollout_shards == shards, build_error()
    check = check_against_eager(loss, seed=3, horizon=None)
    assert check["J_rel"] < 1e-4, (task, check)
    assert check["grad_rel"] < 1e-3, (task, check)
    # "auto" picks the native rollout for every layout
    assert use_fast_rollout(loss, verify=False).backend == "native"


@pytest.mark.slow
def test_compiled_dynamo_rollout_on_a_non_cartpole_task():
    """``torch.compile`` of the time step on a 3-state, 2-action task with an angle at
    index 0 agrees with the eager rollout (use_fast_rollout's own check)."""
    rng = np.random.default_rng(11)
    task = TaskSpec.from_dict(
        {
            "env_id": "any",
            "state_names": ["a", "p", "v"],
            "angles": ["a"],
            "pairs": [["p", "v"]],
            "action_low": [-1.0, -1.0],
            "action_high": [1.0, 1.0],
            "dt": 0.1,
            "horizon": 6,
            "cost": {"terms": [{"state": "a", "target": 1.0}, {"state": "p"}]},
            "success": {"bounds": {"p": {"target": 0.0, "tol": 0.1}}},
        }
    )
    loss, _ = fitted_loss(task, rng, "rbf+mpk", particles=16)
    fast = use_fast_rollout(loss, backend="dynamo", dynamic=False)
    assert fast.backend == "dynamo"
    assert fast.check["grad_rel"] < 1e-3


def _records(path: Path) -> list[dict]:
    try:
        return json.loads((path / "records.json").read_text())["records"]
    except (OSError, ValueError):
        return []


def test_resume_after_kill_on_toy_task(tmp_path):
    """kill -9 during the policy trial of a non-cart-pole run, then resume: the records
    equal those of an uninterrupted run (same seed, bit-identical costs)."""
    cfg = toy_config(num_trials=1, opt=PolicyOptConfig(max_steps=60, min_steps=50))
    code = (
        "import sys; sys.path.insert(0, sys.argv[1]);"
        "from tests.agents.mc_pilco.toy_env import TASK;"
        "from tests.agents.mc_pilco.test_generic import toy_config;"
        "from mcpilco.agents.mc_pilco import run_mcpilco;"
        "from mcpilco.agents.mc_pilco import PolicyOptConfig;"
        "cfg = toy_config(num_trials=1, opt=PolicyOptConfig(max_steps=60, min_steps=50));"
        "run_mcpilco(cfg, sys.argv[2], progress=False, log=None,"
        " write_rrd=False)"
    )
    killed = tmp_path / "killed"
    proc = subprocess.Popen(
        [sys.executable, "-c", code, str(ROOT), str(killed)],
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    try:
        deadline = time.time() + 120
        while len(_records(killed)) < 1 and time.time() < deadline and proc.poll() is None:
            time.sleep(0.2)
        assert len(_records(killed)) == 1, "the exploration trial never finished"
        time.sleep(1.0)  # inside the policy trial
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait()
    assert len(_records(killed)) == 1  # the kill hit the policy trial
    resumed = run_mcpilco(cfg, killed, resume=True, progress=False, log=None, write_rrd=False)
    straight = run_mcpilco(cfg, tmp_path / "straight", progress=False, log=None, write_rrd=False)
    assert resumed.resumed_from_trial == 1
    assert [r["cost"] for r in resumed.records] == [r["cost"] for r in straight.records]


def test_exploration_trial_length_and_bad_values(tmp_path):
    """``explore_steps`` shortens the random trial only; the policy trials keep the horizon."""
    cfg = toy_config(num_trials=1, explore_steps=12, opt=PolicyOptConfig(max_steps=5, min_steps=1))
    summary = run_mcpilco(cfg, tmp_path, progress=False, log=None, write_rrd=False)
    assert [r["steps"] for r in summary.records] == [12, TASK["horizon"]]
    with pytest.raises(ValueError, match="explore_steps"):
        toy_config(explore_steps=0)
    with pytest.raises(ValueError, match=r"explore_steps \(31\) exceeds the horizon"):
        run_mcpilco(toy_config(explore_steps=31), tmp_path / "b", progress=False, log=None)
    with pytest.raises(ValueError, match="env_kwargs must be a mapping"):
        toy_config(env_kwargs=[1])


def test_env_kwargs_reach_gym_make():
    """The dm-control adapter's own episode length follows ``env_kwargs``: with
    ``episode_steps=80`` an 80-step horizon runs 80 steps; without it the adapter truncates at
    its default 60 steps, which is an error naming the fix, not a shorter trial."""
    task = TaskSpec.for_env("mcpilco/DMCCartpoleSwingUp-v0").replace(horizon=80)
    env = make_env(task.env_id, 80, task, {"episode_steps": 80})
    try:
        ep = run_episode(env, lambda _s: np.zeros(1), 0, 80, task)
    finally:
        env.close()
    assert ep["steps"] == 80
    env = make_env(task.env_id, 80, task)
    try:
        with pytest.raises(RuntimeError, match="after 60 of the horizon's 80 .*env_kwargs"):
            run_episode(env, lambda _s: np.zeros(1), 0, 80, task)
    finally:
        env.close()


def test_transitions_at_declared_limits_stay_out_of_the_model_data(tmp_path):
    """A lower limit on ``py`` 0.2 below the start: the random trial (unbraked,
    ``explore_limits: none``) crosses it, and the first policy trial's GP is fitted on the
    other transitions only (counted here from the episode's states); the barrier on that
    limit runs in the optimised cost. Widths on a state without limits, bad widths, and
    widths beside a cost function are refused."""
    lo = TASK["init_mean"][2] - 0.2
    task = {**TASK, "limits": {"py": [lo, 5.0]}}
    cfg = toy_config(
        task=task,
        num_trials=1,
        explore_limits="none",
        cost_limit_widths={"py": 0.02},
        opt=PolicyOptConfig(max_steps=5, min_steps=1),
    )
    summary = run_mcpilco(cfg, tmp_path, progress=False, log=None, write_rrd=False)
    obs = np.asarray(load_checkpoint(tmp_path / "checkpoint.pt")["episodes"][0]["obs"])
    py, vy = obs[:, 2], obs[:, 3]
    hit = (py[:-1] < lo) | (py[1:] < lo) | (py[:-1] + TASK["dt"] * vy[:-1] < lo)
    policy = summary.records[1]
    assert 0 < hit.sum() < len(hit)  # the random trial crossed the limit, not only
    assert policy["n_at_limits"] == hit.sum() and policy["n_data"] == len(hit) - hit.sum()
    assert policy["gp_points"] == policy["n_data"]
    # the plots mark the same transitions as left out
    excluded = load_checkpoint(tmp_path / "checkpoint.pt")["arrays"][0]["excluded"]
    np.testing.assert_array_equal(excluded, hit)
    with pytest.raises(ValueError, match=r"no limits in the task"):
        run_mcpilco(toy_config(task=task, cost_limit_widths={"px": 0.1}), tmp_path / "b", log=None)
    with pytest.raises(ValueError, match="cost_limit_widths"):
        toy_config(cost_limit_widths={"py": 0})
    own_cost = TaskSpec.from_dict(task).replace(cost_fn=lambda x: x[..., 0] ** 2)
    with pytest.raises(ValueError, match="has a cost function instead"):
        cfg = toy_config(task=task, cost_limit_widths={"py": 0.1})
        run_mcpilco(cfg, tmp_path / "c", log=None, task=own_cost)


def test_gp_noise_floor_is_a_fraction_of_each_outputs_variance():
    """Noise-free transitions of the toy's exact linear dynamics: the marginal likelihood
    drives each GP's noise variance down to its floor; ``noise_min`` (a fraction of the
    output's variance) is that floor. A negative floor is refused by the config."""
    from tests.agents.mc_pilco.toy_env import PointMass2D

    env, rng = PointMass2D(), np.random.default_rng(0)
    s = rng.normal(size=(60, 4))
    a = rng.uniform(-1, 1, size=(60, 2))
    s1 = np.empty_like(s)
    for i in range(60):  # one exact zero-order-hold step of the toy from s[i]
        env._x = s[i].copy()
        s1[i] = env.step(a[i])[0]
    task = toy_config().task_spec()
    fractions = {}
    for floor in (1e-8, 1e-3):
        model = GPDynamicsModel(
            task, adam_iters=100, lbfgs_iters=30, max_points=None, noise_min=floor
        )
        model.fit(s, a, s1)
        gp = model.gp_
        fractions[floor] = (gp.noise_variance / gp.y_scale_**2).numpy()
    assert np.all(fractions[1e-3] >= 1e-3 * (1 - 1e-6)) and np.all(fractions[1e-3] < 2e-3)
    assert np.all(fractions[1e-8] < 1e-4)
    with pytest.raises(ValueError, match="gp_noise_min"):
        toy_config(gp_noise_min=-1.0)


def test_data_init_keeps_the_basis_functions_alive_in_many_dimensions():
    """24 features of very different spreads: with the box initialisation every activation
    underflows (no gradient reaches the policy); with :func:`data_init` the mean
    log-activation at fresh states is ``-1`` (``E ||(x~ - c)/l||^2 = 2`` for Gaussian data,
    analytic) and the policy gradient is non-zero."""
    from mcpilco.agents.mc_pilco.policy import data_init

    rng = np.random.default_rng(0)
    F = 24
    scale = np.exp(rng.uniform(-3, 1, F))
    centre = rng.normal(size=F) * 2
    data = centre + scale * rng.normal(size=(4000, F))
    layout = StateLayout(n=F, plain_idx=tuple(range(F)), angle_idx=(), delta_idx=tuple(range(F)))
    init = data_init(torch.as_tensor(data[:2000]))
    np.testing.assert_allclose(init["center_std"], scale, rtol=0.1)
    np.testing.assert_allclose(
        init["lengthscale_init"], np.sqrt(F) * np.asarray(init["center_std"])
    )
    fresh = torch.as_tensor(data[2000:], dtype=torch.float32)
    box = SquashedRBFPolicy(layout, [-1.0], [1.0], num_basis=50, seed=0)
    assert box.basis(fresh).max() < 1e-10
    fitted = SquashedRBFPolicy(layout, [-1.0], [1.0], num_basis=50, seed=0, **init)
    log_phi = fitted.basis(fresh).detach().log()
    assert abs(float(log_phi.mean()) + 1.0) < 0.1
    fitted.eval()
    fitted(fresh).sum().backward()
    assert fitted.weights.grad.abs().min() > 0
    with pytest.raises(ValueError, match="N >= 2"):
        data_init(torch.zeros(1, F))
    # a population re-draws from the data spread (its re-initialisation after a non-finite
    # cost as well)
    pop = PolicyPopulation([box, SquashedRBFPolicy(layout, [-1.0], [1.0], num_basis=50, seed=1)])
    pop.use_data_init(init)
    pop.reset_parameters(3)
    assert pop.candidate(1).basis(fresh).detach().log().mean() > -1.5


def test_data_init_runs_resume_where_they_stopped(tmp_path):
    """``policy_init: data`` through run_mcpilco: the policy is re-drawn from the exploration
    trial's spread before the first optimisation, reaches the toy goal, and a run extended
    from one to two policy trials by ``resume`` (the data initialisation restored, not
    redrawn) repeats the two-trial run bit for bit."""
    cfg = toy_config(
        num_trials=2, policy_init="data", opt=PolicyOptConfig(max_steps=40, min_steps=20)
    )
    straight = run_mcpilco(cfg, tmp_path / "straight", progress=False, log=None, write_rrd=False)
    short = dataclasses.replace(cfg, num_trials=1)
    run_mcpilco(short, tmp_path / "grown", progress=False, log=None, write_rrd=False)
    grown = run_mcpilco(
        cfg, tmp_path / "grown", resume=True, progress=False, log=None, write_rrd=False
    )
    assert grown.resumed_from_trial == 2
    assert [r["cost"] for r in grown.records] == [r["cost"] for r in straight.records]
    ckpt = load_checkpoint(tmp_path / "straight" / "checkpoint.pt")
    assert ckpt["policy_settings"]["center_mean"] is not None
    with pytest.raises(ValueError, match="policy_init must be one of"):
        toy_config(policy_init="grid")


def test_min_lengthscale_bounds_the_fitted_rbf_lengthscales():
    """Noise-free data of ``sin(8 x_1)``, a wiggle of about 0.12 input standard deviations:
    unbounded, the fit takes a lengthscale below 0.5 (0.23); with ``min_lengthscale = 0.5``
    every fitted RBF lengthscale (standardised inputs) is at least 0.5; a bad bound is
    refused by the model and the config."""
    task = TaskSpec.from_dict(TASK)
    rng = np.random.default_rng(0)
    n, a = task.state_dim, task.action_dim
    s = rng.normal(size=(60, n))
    u = rng.uniform(-1, 1, size=(60, a))
    s1 = s + 0.1 * np.sin(8 * s[:, :1])
    low = {}
    for bound in (None, 0.5):
        model = GPDynamicsModel(task, adam_iters=30, lbfgs_iters=10, min_lengthscale=bound)
        model.fit(s, u, s1)
        ls = model.gp_.model_.covar_module.kernels[0].base_kernel.lengthscale
        low[bound] = float(ls.detach().min())
    assert low[None] < 0.5 <= low[0.5] + 1e-9, low
    with pytest.raises(ValueError, match="min_lengthscale must be > 0"):
        GPDynamicsModel(task, min_lengthscale=0.0)
    with pytest.raises(ValueError, match="gp_min_lengthscale must be a finite number"):
        toy_config(gp_min_lengthscale=-1.0)


def test_degree_one_mpk_extrapolates_an_affine_velocity_change():
    """The toy point mass is linear: its velocity change over one period,
    ``dt (u - b v)``, is affine in the GP inputs (state and action). Fitted on 60 noise-free
    transitions inside ``[-1, 1]``, RBF + the degree-1 MPK predicts transitions at three
    times that range to 1e-6 of the largest change there (it spans the affine functions
    exactly), the RBF alone, whose long lengthscales only approximate a plane, to no better
    than 1e-4 (measured: 1e-3). The fused
    posterior carries ``d + 1`` MPK features for degree 1 and ``(d + 1)(d + 2) / 2`` for
    degree 2; a degree below 1 is refused by the model and the config."""
    from mcpilco.models.gp.fused import FusedRBFMPKPredictor
    from tests.agents.mc_pilco.toy_env import FRICTION

    task = TaskSpec.from_dict(TASK)
    rng = np.random.default_rng(0)

    def transitions_at(scale: float, n: int):
        s = rng.uniform(-scale, scale, size=(n, 4))
        u = rng.uniform(-scale, scale, size=(n, 2))
        dv = task.dt * (u - FRICTION * s[:, [1, 3]])
        s1 = s.copy()
        s1[:, [1, 3]] += dv
        s1[:, [0, 2]] += task.dt * (s[:, [1, 3]] + dv / 2)  # the layout's trapezoid rule
        return s, u, s1, np.abs(dv).max()

    train, (*far, dv_max) = transitions_at(1.0, 60)[:3], transitions_at(3.0, 100)
    err, features = {}, {}
    for label, args in (("rbf", {"kernel": "rbf"}), ("mpk1", {"mpk_degree": 1}), ("mpk2", {})):
        model = GPDynamicsModel(task, **args, adam_iters=100, lbfgs_iters=20).fit(*train)
        err[label] = float(model.one_step_rmse(*far).max()) / dv_max
        pred = FusedRBFMPKPredictor.from_cached(model.gp_.cached_predictor())
        features[label] = pred.row_blocks.features
    assert err["mpk1"] < 1e-6 and err["mpk2"] < 1e-6 and err["rbf"] > 1e-4, err
    d = 6  # GP inputs: 4 states, 2 actions
    assert features == {"rbf": 0, "mpk1": d + 1, "mpk2": (d + 1) * (d + 2) // 2}
    with pytest.raises(ValueError, match="mpk_degree must be an integer >= 1"):
        GPDynamicsModel(task, mpk_degree=0)
    with pytest.raises(ValueError, match="mpk_degree must be an integer >= 1"):
        toy_config(mpk_degree=1.5)

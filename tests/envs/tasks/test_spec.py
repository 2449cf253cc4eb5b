"""Task specifications: the shipped task files, field-naming errors on bad specs, and the
cost and features against independent formulas."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
import torch

import mcpilco.envs  # noqa: F401  (registers the ids)
from mcpilco.agents.common.trials import make_env, run_episode
from mcpilco.agents.mc_pilco import (
    MCPilcoConfig,
    SaturatingCost,
    StateLayout,
    TaskSpec,
    TaskSpecError,
    load_config,
    parse_set,
)
from mcpilco.agents.mc_pilco.config import config_files
from mcpilco.envs.cartpole_task import cartpole_cost
from mcpilco.envs.tasks import task_ids

GOOD = {
    "env_id": "any",
    "state_names": ["x", "x_dot", "theta", "theta_dot"],
    "angles": ["theta"],
    "pairs": [["x", "x_dot"], ["theta", "theta_dot"]],
    "action_low": [-1.0],
    "action_high": [1.0],
    "dt": 0.05,
    "horizon": 10,
    "cost": {"terms": [{"state": "theta", "target": math.pi}]},
    "success": {"bounds": {"theta": {"target": math.pi, "tol": 0.2}}},
}


@pytest.mark.parametrize("env_id", task_ids())
def test_shipped_tasks_fit_their_envs(env_id):
    task = TaskSpec.for_env(env_id)
    env = gym.make(env_id)
    try:
        task.check_env(env)
        obs, info = env.reset(seed=0)
        assert task.state_from_obs(obs).shape == (task.state_dim,)
    finally:
        env.close()
    if task.model == "dynamics":  # its hyperparameter file, or MCPilcoConfig's defaults
        config = load_config(env_id)
        if env_id not in config_files():
            assert config == load_config(env_id, conf_dir=None)


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"angles": ["theta", "theta"]}, "task.angles[1]"),
        ({"angles": ["phi"]}, "task.angles[0]"),
        ({"pairs": [["x_dot"]]}, "task.pairs[0]"),
        ({"pairs": [[None, "x_dot"]]}, "task.pairs[0]"),
        ({"pairs": [["x", "x_dot"], ["x", "theta_dot"]]}, "task.pairs[1]"),
        ({"pairs": [["x", "q"]]}, "task.pairs[0]"),
        ({"cost": {"terms": [{"state": "z"}]}}, "task.cost.terms[0].state"),
        ({"cost": {"terms": [{"state": "x", "length_scale": 0}]}}, "task.cost.terms[0]"),
        ({"cost": {"terms": [{"state": "x", "weight": 2}]}}, "task.cost.terms[0]"),
        ({"obs_indices": [0, 1, 2]}, "task.obs_indices"),
        ({"obs_indices": [0, 1, 2, -1]}, "task.obs_indices[3]"),
        ({"state_names": ["x", "x"]}, "task.state_names[1]"),
        ({"action_high": [-2.0]}, "task.action_low[0]"),
        ({"dt": 0}, "task.dt"),
        ({"model": "physics"}, "task.model"),
        ({"horizon": 0}, "task.horizon"),
        ({"init_mean": [0.0]}, "task.init_mean"),
        ({"success": {"bounds": {"q": {"tol": 1}}}}, "task.success.bounds.q"),
        ({"success": {"window": 99, "bounds": {"x": {"tol": 1}}}}, "task.success.window"),
        ({"colour": "red"}, "task.colour"),
        ({"limits": {"q": [-1, 1]}}, "task.limits.q"),
        ({"limits": {"theta": [-1, 1]}}, "task.limits.theta"),
        ({"limits": {"x": [1, -1]}}, "task.limits.x"),
        ({"limits": {"x": [-1]}}, "task.limits.x"),
        ({"limits": {"x": ["a", 1]}}, "task.limits.x"),
        ({"limits": [-1, 1]}, "task.limits"),
    ],
)
def test_bad_specs_name_the_field(change, field):
    with pytest.raises(TaskSpecError) as err:
        TaskSpec.from_dict({**GOOD, **change})
    assert str(err.value).startswith(field), str(err.value)


def test_missing_required_field_is_named():
    bad = dict(GOOD)
    del bad["dt"]
    with pytest.raises(TaskSpecError, match=r"^task\.dt: is required"):
        TaskSpec.from_dict(bad)


def test_spec_that_does_not_fit_the_env_is_refused():
    env = gym.make("mcpilco/CartpoleSwingUp-v0")
    try:
        with pytest.raises(TaskSpecError, match="obs_indices"):
            TaskSpec.from_dict({**GOOD, "obs_indices": [0, 1, 2, 9]}).check_env(env)
        with pytest.raises(TaskSpecError, match="2 actions"):
            TaskSpec.from_dict({**GOOD, "action_low": [-1, -1], "action_high": [1, 1]}).check_env(
                env
            )
    finally:
        env.close()


def test_cartpole_task_cost_is_the_envs_cost():
    """The cart-pole task file's evaluation cost equals the env's own formula
    (thesis 5.5.1), in numpy and in torch."""
    task = TaskSpec.for_env("mcpilco/CartpoleSwingUp-v0")
    x = np.random.default_rng(0).normal(scale=4.0, size=(500, 4))
    truth = cartpole_cost(x)
    np.testing.assert_allclose(task.cost(x), truth, atol=1e-12)
    c = SaturatingCost.from_task(task)(torch.as_tensor(x))
    np.testing.assert_allclose(c.numpy(), truth, atol=1e-12)


def test_abs_mode_is_mcpilco_unwrapped_cost_and_gradients_match_autograd():
    """``abs`` mode: 1 - exp(-(|theta| - pi)^2 / l_t^2 - x^2 / l_x^2) written out here;
    the analytic backward against autograd of that expression."""
    task = TaskSpec.for_env("mcpilco/CartpoleSwingUp-v0")
    cost = SaturatingCost.from_task(task, {"x": 1.0, "theta": 3.0}, angle_mode="abs")
    assert_cost_is(
        cost,
        lambda x: 1 - torch.exp(-((x[:, 2].abs() - math.pi) ** 2) / 9.0 - x[:, 0] ** 2),
        torch.randn(64, 4, dtype=torch.float64) * 5,
    )


def assert_cost_is(cost, truth, x: torch.Tensor) -> None:
    """``cost(x)`` and its vector-Jacobian product against autograd of ``truth(x)``, an
    expression written out in the test."""
    x1 = x.clone().requires_grad_(True)
    x2 = x.clone().requires_grad_(True)
    mine, ref = cost(x1), truth(x2)
    torch.testing.assert_close(mine, ref)
    w = torch.randn(len(x), dtype=x.dtype)
    (g1,) = torch.autograd.grad((mine * w).sum(), x1)
    (g2,) = torch.autograd.grad((ref * w).sum(), x2)
    torch.testing.assert_close(g1, g2)


def test_limit_barrier_is_the_logistic_pair_and_its_gradient_matches_autograd():
    """``c = 1 - exp(-x^2 / l^2) + sigma((x - hi) / s) + sigma((lo - x) / s)`` written out
    here, with its known values: 1/2 at a limit, 0.047 at 3 s inside it."""
    task = TaskSpec.from_dict({**GOOD, "limits": {"x": [-1.8, 1.2]}})
    cost = SaturatingCost.from_task(task, {"theta": 1.0}, limit_widths={"x": 0.1})
    assert_cost_is(
        cost,
        lambda x: (
            1
            - torch.exp(-((torch.remainder(x[:, 2], 2 * math.pi) - math.pi) ** 2))
            + 1 / (1 + torch.exp(-(x[:, 0] - 1.2) / 0.1))
            + 1 / (1 + torch.exp(-(-1.8 - x[:, 0]) / 0.1))
        ),
        torch.randn(64, 4, dtype=torch.float64) * 2,
    )
    # upright at the upper limit, and 3 widths inside the lower one
    upright = torch.tensor(
        [[1.2, 0.0, math.pi, 0.0], [-1.5, 0.0, math.pi, 0.0]], dtype=torch.float64
    )
    c = cost(upright)
    assert abs(float(c[0]) - 0.5) < 1e-9 and abs(float(c[1]) - 1 / (1 + math.exp(3))) < 1e-9
    with pytest.raises(ValueError, match="no limits"):
        SaturatingCost.from_task(task, limit_widths={"x_dot": 0.1})


def test_transitions_that_touch_a_limit_are_found():
    """A cart against a stop at x = 1: before, during and after the impact, and a step whose
    free motion x + T_s xdot would have crossed the stop though both samples are inside."""
    task = TaskSpec.from_dict({**GOOD, "limits": {"x": [-1.0, 1.0]}})
    s = np.array([[0.0, 1.0, 0, 0], [0.9, 1.0, 0, 0], [0.99, 3.0, 0, 0], [1.02, 0.0, 0, 0]])
    s1 = np.array([[0.05, 1.0, 0, 0], [0.95, 1.0, 0, 0], [0.98, -0.5, 0, 0], [0.95, -1.0, 0, 0]])
    np.testing.assert_array_equal(task.touches_limit(s, s1), [False, False, True, True])
    assert not TaskSpec.from_dict(GOOD).touches_limit(s, s1).any()  # no limits declared


def test_features_and_their_backward_against_autograd():
    """Angles anywhere in the state: f(x) = [plain, sin, cos per angle] and its VJP."""
    layout = StateLayout(
        n=5, plain_idx=(1, 2, 4), angle_idx=(3, 0), position_idx=(), delta_idx=(0, 1, 2, 3, 4)
    )
    x = torch.randn(7, 5, dtype=torch.float64, requires_grad=True)
    f, s, c = layout.features(x)
    truth = torch.stack(
        [x[:, 1], x[:, 2], x[:, 4], x[:, 3].sin(), x[:, 3].cos(), x[:, 0].sin(), x[:, 0].cos()],
        dim=1,
    )
    torch.testing.assert_close(f, truth)
    g = torch.randn_like(f)
    (auto,) = torch.autograd.grad(truth, x, g)
    torch.testing.assert_close(layout.features_backward(g, s, c), auto)


def test_success_rules():
    task = TaskSpec.for_env("InvertedPendulum-v5")
    up = np.zeros((task.horizon, 4))
    assert task.is_success(up, {}, task.horizon)
    assert not task.is_success(up[:10], {}, 10)  # terminated early
    long = np.zeros((10 * task.horizon, 4))  # an evaluation episode of 10 horizons
    assert task.is_success(long, {}, len(long), planned=len(long))
    assert not task.is_success(long[:200], {}, 200, planned=len(long))  # fell after 4 horizons
    tipped = up.copy()
    tipped[5, 1] = 0.3
    assert not task.is_success(tipped, {}, task.horizon)
    cart = TaskSpec.for_env("mcpilco/CartpoleSwingUp-v0")
    assert cart.is_success(np.zeros((60, 4)), {"success": True}, 60)  # the env's flag wins


def test_inverted_pendulum_success_is_gymnasiums_balance():
    """Gymnasium's InvertedPendulum-v5 terminates when |theta| > 0.2 rad: an episode under a
    balancing PD law runs the task's whole horizon and succeeds; under zero force the pole
    falls, the env ends the episode at the first |theta| > 0.2 and the task says failure."""
    task = TaskSpec.for_env("InvertedPendulum-v5")
    env = make_env(task.env_id, task.horizon, task)
    gains = np.array([1.0, 10.0, 1.0, 2.0])  # u = K [x, theta, x_dot, theta_dot]
    for seed in range(3):
        ep = run_episode(env, lambda s: np.array([gains @ s]), seed, task.horizon, task)
        assert ep["steps"] == task.horizon and ep["success"]
        fell = run_episode(env, lambda s: np.zeros(1), seed, task.horizon, task)
        theta = np.abs(fell["states"][:, 1])
        assert fell["steps"] < task.horizon and not fell["success"]
        assert theta[-1] > 0.2 and np.all(theta[:-1] <= 0.2)
    env.close()


def test_config_files_and_overrides():
    cfg = load_config("mcpilco/CartpoleSwingUp-v0", preset="demo")
    assert (cfg.num_trials, cfg.explore_hold, cfg.cost_angle_mode) == (3, 2, "abs")
    over = parse_set(["num_particles=64", "opt.max_steps=7", "cost_length_scales={x: 2}"])
    cfg = load_config("mcpilco/CartpoleSwingUp-v0", preset="bench", overrides=over)
    assert (cfg.num_particles, cfg.opt.max_steps) == (64, 7)
    assert cfg.cost_length_scales == {"x": 2.0, "theta": 3.0}  # merged into the file's
    assert cfg.opt.monitor_patience == 100  # the preset's value kept beside the override
    with pytest.raises(ValueError, match="unknown preset 'nope'"):
        load_config("mcpilco/CartpoleSwingUp-v0", preset="nope")
    with pytest.raises(ValueError, match="unknown MC-PILCO config fields \\['particles'\\]"):
        load_config("mcpilco/CartpoleSwingUp-v0", overrides={"particles": 3})
    with pytest.raises(ValueError, match="key=value"):
        parse_set(["num_particles"])
    assert MCPilcoConfig(env_id="x", task=GOOD | {"env_id": "x"}).task_spec().state_dim == 4


@pytest.mark.parametrize("idx", [(), (2,), (1, 2, 3), (3, 0), (0, 2, 4), (4, 3, 2, 1, 0)])
def test_take_selects_like_advanced_indexing(idx):
    """``take`` (views, no index tensor) against torch's advanced indexing, values and
    gradients."""
    from mcpilco.agents.mc_pilco.features import take

    x = torch.randn(3, 7, 5, dtype=torch.float64, requires_grad=True)
    w = torch.randn(3, 7, len(idx), dtype=torch.float64)
    mine, ref = take(x, idx), x[..., list(idx)]
    torch.testing.assert_close(mine, ref, rtol=0, atol=0)
    (g1,) = torch.autograd.grad((mine * w).sum(), x)
    (g2,) = torch.autograd.grad((ref * w).sum(), x)
    torch.testing.assert_close(g1, g2, rtol=0, atol=0)


def test_declared_limits_are_the_simulators_joint_ranges():
    """The rail limits in the shipped task files are the slider ranges of the MuJoCo models
    the envs simulate (read from the compiled models, not from the files)."""
    for env_id, read in (
        ("mcpilco/DMCCartpoleSwingUp-v0", lambda e: e.unwrapped.physics.named.model.jnt_range),
        ("InvertedPendulum-v5", lambda e: _named_ranges(e.unwrapped.model)),
    ):
        env = gym.make(env_id)
        try:
            ranges = read(env)
            assert TaskSpec.for_env(env_id).limits == {"x": tuple(ranges["slider"])}, env_id
        finally:
            env.close()


def _named_ranges(model) -> dict[str, np.ndarray]:
    import mujoco

    return {
        mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j): model.jnt_range[j]
        for j in range(model.njnt)
    }


def test_the_spec_module_imports_without_torch():
    """The task contract is plain data: a fresh interpreter reads a shipped task, its cost
    and success test without importing torch."""
    import subprocess
    import sys

    code = (
        "import sys, numpy as np\n"
        "from mcpilco.envs.tasks.spec import TaskSpec\n"
        "t = TaskSpec.for_env('mcpilco/CartpoleSwingUp-v0')\n"
        "t.cost(np.zeros((3, 4))); t.in_goal(np.zeros((3, 4)))\n"
        "print('torch' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"

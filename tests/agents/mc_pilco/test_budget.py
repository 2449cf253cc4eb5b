"""Budgets derived from the task: the cost model by hand, the fit to the time budget, the
fields a config leaves unset, and the line mcpilco-train prints."""

from __future__ import annotations

import pytest

from mcpilco.agents.mc_pilco.budget import (
    C0_S,
    C1_S,
    DEFAULT_OPT_STEPS,
    DEFAULT_PARTICLES,
    MIN_OPT_STEPS,
    MIN_PARTICLES,
    OPT_TIME_BUDGET_S,
    derive_budget,
    run_seconds,
    step_seconds,
)
from mcpilco.agents.mc_pilco.config import budget_report, load_config
from mcpilco.envs.tasks.spec import TaskSpec


def test_step_seconds_is_the_cost_model_by_hand():
    """The cart-pole: E = 2 GP outputs, D = 5 features (x, x_dot, theta_dot, sin, cos) + 1
    action, H = 60."""
    task = TaskSpec.for_env("mcpilco/CartpoleSwingUp-v0")
    assert step_seconds(task, 400, 120) == pytest.approx(400 * 60 * 2 * (C0_S + C1_S * 120 * 6))
    # five trials of 60 steps: N = 60, 120, 180, 240, 300
    expected = sum(100 * step_seconds(task, 10, n) for n in (60, 120, 180, 240, 300))
    assert run_seconds(task, 10, 100, 300) == pytest.approx(expected)


@pytest.mark.parametrize(
    "env_id",
    ["mcpilco/CartpoleSwingUp-v0", "InvertedDoublePendulum-v5", "Pendulum-v1", "mcpilco/UR10-v0"],
)
def test_derived_budget_fits_the_time_budget(env_id):
    task = TaskSpec.for_env(env_id)
    b = derive_budget(task)
    assert b.predicted_s == pytest.approx(
        run_seconds(task, b.num_particles, b.opt_steps, b.max_points)
    )
    assert MIN_PARTICLES <= b.num_particles <= DEFAULT_PARTICLES
    assert MIN_OPT_STEPS <= b.opt_steps <= DEFAULT_OPT_STEPS
    at_floor = (b.num_particles, b.opt_steps) == (MIN_PARTICLES, MIN_OPT_STEPS)
    assert b.predicted_s <= OPT_TIME_BUDGET_S or (at_floor and b.max_points == 50)


def test_a_larger_task_gets_a_smaller_budget():
    small = derive_budget(TaskSpec.for_env("Pendulum-v1"))
    large = derive_budget(TaskSpec.for_env("InvertedDoublePendulum-v5"))
    assert large.num_particles < small.num_particles and large.opt_steps < small.opt_steps


def test_config_files_and_overrides_keep_their_values(tmp_path):
    derived = derive_budget(TaskSpec.for_env("InvertedDoublePendulum-v5"))
    cfg = load_config("InvertedDoublePendulum-v5")
    assert (cfg.num_particles, cfg.opt.max_steps, cfg.max_points) == (
        derived.num_particles, derived.opt_steps, derived.max_points,
    )  # fmt: skip
    cfg = load_config(
        "InvertedDoublePendulum-v5", overrides={"num_particles": 60, "opt": {"max_steps": 70}}
    )
    assert (cfg.num_particles, cfg.opt.max_steps, cfg.max_points) == (60, 70, derived.max_points)
    line = budget_report(cfg)
    assert line.startswith(
        f"budget: {derived.num_particles} particles, {derived.opt_steps} opt steps, "
        f"N <= {derived.max_points} GP points (derived from 6 states, 1 action, 3 GP outputs, "
        "horizon 100"
    )
    assert line.endswith("; the config sets num_particles=60, opt.max_steps=70")
    shipped = load_config("mcpilco/CartpoleSwingUp-v0")  # its config file sets M = 400
    assert shipped.num_particles == 400 and "num_particles=400" in budget_report(shipped)

"""The numpy swing-up task functions against hand-computed values."""

import math
import subprocess
import sys

import numpy as np
import pytest

from mcpilco.envs.cartpole_task import (
    CARTPOLE_TASK,
    SwingUpScorer,
    cartpole_cost,
    is_upright,
    swingup_success,
    validate_action,
    wrap_angle,
)


def test_task_constants_match_thesis_and_brief():
    assert CARTPOLE_TASK["dt"] == 0.05
    assert CARTPOLE_TASK["horizon"] == 60  # 3 s
    assert CARTPOLE_TASK["u_max"] == 10.0
    assert (CARTPOLE_TASK["l_x"], CARTPOLE_TASK["l_theta"]) == (1.5, 1.0)  # thesis 5.5.1
    assert CARTPOLE_TASK["state_names"] == ("x", "x_dot", "theta", "theta_dot")


def test_wrap_angle_range():
    theta = np.array([0.0, np.pi, -np.pi, 3 * np.pi, 2 * np.pi + 0.1, -0.1])
    expected = np.array([0.0, -np.pi, -np.pi, -np.pi, 0.1, -0.1])
    np.testing.assert_allclose(wrap_angle(theta), expected, atol=1e-12)


@pytest.mark.parametrize("theta", [np.pi, -np.pi, 3 * np.pi, -5 * np.pi])
def test_cost_zero_upright_at_origin(theta):
    assert cartpole_cost([0.0, 1.0, theta, -2.0]) == pytest.approx(0.0, abs=1e-12)


def test_cost_hand_values():
    # hanging down at the origin: 1 - exp(-pi^2 / l_theta^2)
    assert cartpole_cost([0, 0, 0, 0], l_theta=1.0, l_x=1.5) == pytest.approx(
        1 - math.exp(-(math.pi**2))
    )
    # upright, cart at x = 1.5 = l_x: 1 - exp(-1)
    assert cartpole_cost([1.5, 0, np.pi, 0]) == pytest.approx(1 - math.exp(-1))
    # angle 0.5 rad off upright on either side, l_theta = 2: 1 - exp(-(0.5/2)^2)
    for theta in (np.pi - 0.5, -np.pi + 0.5, np.pi + 0.5):
        assert cartpole_cost([0, 0, theta, 0], l_theta=2.0, l_x=1.0) == pytest.approx(
            1 - math.exp(-0.0625)
        )
    batch = cartpole_cost(np.zeros((3, 5, 4)))
    assert batch.shape == (3, 5)


def test_cost_rejects_bad_input():
    with pytest.raises(ValueError, match="shape"):
        cartpole_cost(np.zeros(3))
    with pytest.raises(ValueError, match="> 0"):
        cartpole_cost(np.zeros(4), l_theta=0.0)


def test_upright_tolerance_10_degrees():
    d9, d11 = math.radians(9), math.radians(11)
    assert is_upright(np.pi - d9) and is_upright(-np.pi + d9) and is_upright(3 * np.pi + d9)
    assert not is_upright(np.pi - d11) and not is_upright(0.0)


def _episode(n, upright_from, x=0.0):
    states = np.zeros((n, 4))
    states[:, 0] = x
    states[upright_from:, 2] = np.pi
    return states


def test_success_needs_last_20_steps_upright_and_cart_near_origin():
    assert swingup_success(_episode(60, upright_from=40))  # exactly the last 20 steps
    assert not swingup_success(_episode(60, upright_from=41))  # only 19
    assert not swingup_success(_episode(60, upright_from=0, x=0.5))  # |x| must be < 0.5
    assert swingup_success(_episode(60, upright_from=0, x=-0.49))
    assert not swingup_success(_episode(10, upright_from=0))  # shorter than the window


def test_scorer_reports_success_only_at_the_last_step():
    scorer = SwingUpScorer(l_theta=1.0, l_x=1.5, episode_steps=30)
    states = _episode(30, upright_from=10)
    for t, s in enumerate(states, start=1):
        cost, truncated, info = scorer.step(s)
        assert truncated == (t == 30)
        assert ("success" in info) == (t == 30)
    assert info["success"] is True and info["upright"] is True and cost == 0.0


def test_validate_action():
    np.testing.assert_array_equal(validate_action(0.5, 1), [0.5])
    with pytest.raises(ValueError, match=r"shape \(2,\)"):
        validate_action([0.1, 0.2], 1)
    with pytest.raises(ValueError, match="NaN"):
        validate_action([np.nan], 1)
    with pytest.raises(ValueError, match="numeric"):
        validate_action("left", 1)


def test_importing_envs_is_light():
    """Registration imports neither torch, agents/models, MuJoCo nor dm-control."""
    code = (
        "import sys, mcpilco.envs, mcpilco.envs.cartpole_task; "
        "bad = [m for m in ('torch', 'mujoco', 'dm_control', 'mcpilco.agents', "
        "'mcpilco.models') if m in sys.modules]; print(bad); assert not bad"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)


@pytest.mark.parametrize("env_id", ["mcpilco/CartpoleSwingUp-v0", "mcpilco/DMCCartpoleSwingUp-v0"])
def test_shipped_task_files_state_this_task(env_id):
    """The cart-poles' task files (read by the agents) against the constants and functions
    here: same period, horizon, states, initial distribution, cost and success test."""
    from mcpilco.envs.tasks.spec import TaskSpec

    task = TaskSpec.for_env(env_id)
    assert (task.dt, task.horizon) == (CARTPOLE_TASK["dt"], CARTPOLE_TASK["horizon"])
    assert task.state_names == CARTPOLE_TASK["state_names"] and task.angles == ("theta",)
    assert task.init_mean == CARTPOLE_TASK["init_mean"]
    assert task.init_std == (CARTPOLE_TASK["init_std"],) * 4
    rng = np.random.default_rng(0)
    states = rng.normal(size=(400, 4)) * np.array([1.0, 1.0, 8.0, 1.0])
    np.testing.assert_allclose(task.cost(states), cartpole_cost(states), atol=1e-12)
    # success by the bounds (no info flag) on episodes near the bounds (about half succeed)
    # and hanging down
    outcomes = []
    for k in range(200):
        ep = rng.normal(size=(60, 4)) * np.array([0.22, 1.0, 0.07, 1.0])
        ep[:, 2] += np.pi * rng.choice([1.0, -1.0, 3.0]) if k % 4 else 0.0
        outcomes.append(swingup_success(ep))
        assert task.is_success(ep, {}, 60) == outcomes[-1], k
    assert 40 < sum(outcomes) < 160
    assert task.is_success(_episode(60, upright_from=40), {}, 60)
    assert not task.is_success(_episode(60, upright_from=41), {}, 60)
    if task.success.info_key:  # the env's own flag, where the task reads it, is the answer
        assert task.is_success(_episode(60, upright_from=0), {"success": False}, 60) is False
    else:  # the same test from the states, for any horizon
        assert task.is_success(_episode(80, upright_from=60), {"success": False}, 80)
        assert not task.is_success(_episode(80, upright_from=61), {}, 80)

"""The gated linear feedback term (a catch) of fully actuated swing-ups: its gate, its
widths from the LQR, the tasks that get it, and an LQR catch of a known pendulum."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from mcpilco.agents.mc_pilco import MCPilcoConfig, PolicyPopulation, SquashedRBFPolicy
from mcpilco.agents.mc_pilco.features import StateLayout
from mcpilco.agents.mc_pilco.regulator import GATE_REACH, catch_gate, feature_gains, lqr_gain
from mcpilco.agents.mc_pilco.trainer import catch_point, policy_candidates, regulation_point
from mcpilco.envs.tasks.spec import TaskSpec

# a point-mass pendulum with a hinge motor (theta = 0 upright): m = 1 kg, l = 0.5 m, the
# torque limit 1 N m (the motor holds the pole within asin(1 / (m g l)) = 11.8 deg)
MASS, LENGTH, GRAVITY, U_MAX, DT = 1.0, 0.5, 9.81, 1.0, 0.01


def _pendulum_layout() -> StateLayout:
    return StateLayout.from_task(TaskSpec.for_env("dm_control/pendulum-swingup-v0"))


def _pendulum_step(x: np.ndarray, u: float) -> np.ndarray:
    """One semi-implicit Euler step of ``I th'' = m g l sin th + u``, ``I = m l^2``."""
    inertia = MASS * LENGTH**2
    acc = (MASS * GRAVITY * LENGTH * math.sin(x[0]) + u) / inertia
    w = x[1] + DT * acc
    return np.array([x[0] + DT * w, w])


def _linear_pendulum() -> tuple[np.ndarray, np.ndarray]:
    """``A, B`` of the same step linearised at upright (``sin th ~ th``)."""
    inertia = MASS * LENGTH**2
    a_c = MASS * GRAVITY * LENGTH / inertia
    a = np.array([[1.0 + DT * DT * a_c, DT], [DT * a_c, 1.0]])
    b = np.array([[DT * DT / inertia], [DT / inertia]])
    return a, b


def _catch_policy(k: np.ndarray, gate: np.ndarray | None) -> SquashedRBFPolicy:
    """A policy with no RBF part (weights 0) whose linear term is ``u = -K (x - x*)`` at
    ``x* = 0`` (features ``[theta_dot, sin, cos]``, reference ``[0, 0, 1]``)."""
    layout = _pendulum_layout()
    scale = np.array([2.0, 0.7, 0.4])  # the term's feature scales (any > 0)
    g = feature_gains(k, layout, np.zeros(2), scale, np.array([U_MAX]))
    return SquashedRBFPolicy(
        layout, [-U_MAX], [U_MAX], num_basis=5, weight_scale=0.0, linear_ref=[0.0, 0.0, 1.0],
        linear_scale=scale, gains_init=g, linear_gate=gate,
    ).eval()  # fmt: skip


def test_the_gate_widths_are_reach_times_the_saturating_deviation():
    """``v_j = GATE_REACH min_a u_half_a / |K_aj|``; an angle's ``sin, cos`` both get its
    width; a state no action feeds back gets an infinite width."""
    layout = _pendulum_layout()  # states [theta, theta_dot]: features [theta_dot, sin, cos]
    v = catch_gate(np.array([[4.0, -0.5]]), layout, np.array([2.0]))
    assert v == pytest.approx([GATE_REACH * 2.0 / 0.5] + [GATE_REACH * 2.0 / 4.0] * 2)
    two = catch_gate(np.array([[4.0, 0.0], [1.0, 0.0]]), layout, np.array([2.0, 1.0]))
    assert two[1] == pytest.approx(GATE_REACH * min(2.0 / 4.0, 1.0 / 1.0))
    assert math.isinf(two[0])


def test_the_gated_term_is_the_lqr_at_the_goal_and_vanishes_far_from_it():
    k = np.array([[6.0, 1.2]])
    gate = catch_gate(k, _pendulum_layout(), np.array([U_MAX]))
    pol = _catch_policy(k, gate)
    d = np.array([1e-3, -2e-3])  # at the goal: the LQR, to first order
    u = pol(torch.tensor(d, dtype=torch.float32)[None])[0, 0].item()
    assert u == pytest.approx(-(k @ d)[0], rel=2e-3)
    # the gate: exp(-1/2 sum ((x~ - x~*) / v)^2) on the features (a second implementation)
    x = np.array([0.2, 0.5])
    feats = np.array([x[1], math.sin(x[0]), math.cos(x[0])])
    g = math.exp(-0.5 * np.sum(((feats - [0.0, 0.0, 1.0]) / gate) ** 2))
    ungated = _catch_policy(k, None)(torch.tensor(x, dtype=torch.float32)[None])[0, 0].item()
    pre = U_MAX * math.atanh(ungated / U_MAX)
    gated = pol(torch.tensor(x, dtype=torch.float32)[None])[0, 0].item()
    assert gated == pytest.approx(U_MAX * math.tanh(g * pre / U_MAX), rel=1e-4)
    # hanging, or spinning through upright: nothing (the RBF part alone, here 0)
    for far in ([math.pi, 0.0], [0.0, 10.0]):
        assert abs(pol(torch.tensor([far], dtype=torch.float32))[0, 0].item()) < 1e-3


def test_an_lqr_catch_holds_a_known_pendulum_and_the_ungated_one_too():
    """The LQR of the linearised pendulum (``Q = diag(2, 0)``, ``R = 2``, as the regulator
    takes them) in the gated term catches the nonlinear pendulum, torque-limited, from a
    slow arrival 6 deg from upright: it ends upright at rest."""
    a, b = _linear_pendulum()
    k = lqr_gain(a, b, np.diag([2.0, 0.0]), np.array([[2.0]]))
    assert k is not None
    gate = catch_gate(k, _pendulum_layout(), np.array([U_MAX]))
    for g in (gate, None):
        pol = _catch_policy(k, g)
        x = np.array([math.radians(6.0), -0.2])
        for _ in range(600):
            u = pol(torch.tensor(x, dtype=torch.float32)[None])[0, 0].item()
            assert abs(u) <= U_MAX
            x = _pendulum_step(x, u)
        assert abs(x[0]) < 1e-3 and abs(x[1]) < 1e-2
    # no catch without the term: the pole falls
    x = np.array([math.radians(6.0), -0.2])
    for _ in range(600):
        x = _pendulum_step(x, 0.0)
    assert abs(x[0]) > 1.0


def test_a_population_keeps_the_gate_and_resets_keep_it():
    layout = _pendulum_layout()
    gate = [1.0, 0.3, 0.3]
    cands = [
        SquashedRBFPolicy(layout, num_basis=4, seed=s, linear_ref=[0.0, 0.0, 1.0]) for s in (1, 2)
    ]
    pop = PolicyPopulation(cands)
    assert bool(torch.isinf(pop.linear_gate).all())  # no gate yet: g = 1
    pop.use_data_init({"linear_gate": gate})
    pop.reset_parameters(0)
    one = pop.candidate(1)
    assert one.linear_gate.tolist() == pytest.approx(gate)
    assert one.settings()["linear_gate"] == pytest.approx(gate)
    out = cands[0]
    pop.copy_to(0, out)
    assert out.linear_gate.tolist() == pytest.approx(gate)
    with pytest.raises(ValueError, match="linear_gate"):
        SquashedRBFPolicy(layout, num_basis=4, linear_gate=gate)  # no linear term
    with pytest.raises(ValueError, match="linear_gate"):
        SquashedRBFPolicy(
            layout, num_basis=4, linear_ref=[0.0, 0.0, 1.0], linear_gate=[1.0, 0.0, 1.0]
        )


@pytest.mark.parametrize(
    ("env_id", "catch"),
    [
        ("dm_control/pendulum-swingup-v0", True),  # a hinge motor: one action, one position
        ("Pendulum-v1", True),
        ("dm_control/cartpole-swingup-v0", False),  # one force, two positions
        ("mcpilco/CartpoleSwingUp-v0", False),  # and an env success flag
        ("InvertedDoublePendulum-v5", False),  # a balance: the ungated term
    ],
)
def test_fully_actuated_swing_ups_get_a_gated_catch_at_their_goal(env_id, catch):
    task = TaskSpec.for_env(env_id)
    point = catch_point(task)
    assert (point is not None) == catch
    cands = policy_candidates(
        MCPilcoConfig(env_id=env_id, num_basis=4), task, StateLayout.from_task(task)
    )
    assert all(c.linear == (catch or regulation_point(task) is not None) for c in cands)
    if catch:
        assert np.array_equal(point, np.zeros(2))  # the cost's target: upright at rest

"""The policy's linear feedback term and the regulation tasks that get it by default."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mcpilco.agents.mc_pilco import MCPilcoConfig, PolicyPopulation, SquashedRBFPolicy
from mcpilco.agents.mc_pilco.fast.base import unsupported_reason
from mcpilco.agents.mc_pilco.features import StateLayout
from mcpilco.agents.mc_pilco.trainer import policy_candidates, regulation_point
from mcpilco.envs.tasks.spec import TaskSpec


def _plain_policy(p: SquashedRBFPolicy, x: torch.Tensor) -> torch.Tensor:
    """``u_mid + u_half tanh((sum_i w_i phi_i + u_half G^T (x~ - x~*) / s) / u_half)`` written
    out with autograd ops (a second implementation of the module glossary's formula)."""
    ang, plain = list(p.layout.angle_idx), list(p.layout.plain_idx)
    feats = torch.cat(
        [x[:, plain], torch.stack([x[:, ang].sin(), x[:, ang].cos()], -1).reshape(len(x), -1)], 1
    )
    d = (feats[:, None, :] - p.centers[None]) / p.log_lengthscales.exp()
    phi = torch.exp(-0.5 * (d * d).sum(-1))
    pre = phi @ p.weights + p.u_half * (((feats - p.linear_ref) / p.linear_scale) @ p.gains)
    return p.u_mid + p.u_half * torch.tanh(pre / p.u_half)


def _layout() -> StateLayout:
    return StateLayout.from_task(TaskSpec.for_env("mcpilco/CartpoleSwingUp-v0"))


def test_linear_term_value_and_gradients_match_the_formula():
    layout = _layout()  # [x, x_dot, theta_dot] plain, theta an angle: features (sin, cos) too
    F = layout.feature_dim
    p = SquashedRBFPolicy(
        layout, [-2.0], [4.0], num_basis=7, weight_scale=0.5, seed=3,
        linear_ref=np.linspace(-0.5, 0.5, F), linear_scale=np.linspace(0.5, 2.0, F),
    )  # fmt: skip
    p.dropout = 0.0
    with torch.no_grad():
        p.gains.copy_(torch.randn(F, 1, generator=torch.Generator().manual_seed(1)))
    x = torch.randn(11, layout.n, dtype=torch.float32, generator=torch.Generator().manual_seed(2))
    x1, x2 = x.clone().requires_grad_(), x.clone().requires_grad_()
    u1 = p(x1)
    g1 = torch.autograd.grad((u1**2).sum(), [x1, *p.parameters()])
    u2 = _plain_policy(p, x2)
    g2 = torch.autograd.grad((u2**2).sum(), [x2, *p.parameters()])
    assert torch.allclose(u1, u2, atol=1e-6)
    for a, b in zip(g1, g2, strict=True):
        assert torch.allclose(a, b, atol=1e-5, rtol=1e-4)


def test_zero_gains_give_the_policy_without_the_term_and_a_population_keeps_them():
    layout = _layout()
    F = layout.feature_dim
    plain = SquashedRBFPolicy(layout, num_basis=9, weight_scale=0.3, seed=5)
    lin = SquashedRBFPolicy(layout, num_basis=9, weight_scale=0.3, seed=5, linear_ref=[0.0] * F)
    x = torch.randn(6, layout.n)
    assert torch.equal(plain.eval()(x), lin.eval()(x))  # G = 0 at initialisation
    assert "gains" not in plain.state_dict() and lin.linear and not plain.linear
    with torch.no_grad():
        lin.gains.fill_(0.3)
    other = SquashedRBFPolicy(layout, num_basis=9, seed=6, linear_ref=[0.0] * F)
    pop = PolicyPopulation([other, lin])
    assert torch.equal(pop.candidate(1).eval()(x), lin(x))
    pop.reset_parameters(0)
    assert float(pop.gains.detach().abs().max()) == 0.0


def test_regulation_tasks_are_the_balances_that_start_inside_their_set():
    """A balance from upright (starts inside the set it must stay in for the whole episode)
    regulates; a swing-up, judged at its end from hanging, does not."""
    idp = TaskSpec.for_env("InvertedDoublePendulum-v5")
    assert np.array_equal(regulation_point(idp), np.zeros(6))  # the cost's targets
    assert regulation_point(TaskSpec.for_env("InvertedPendulum-v5")) is not None
    assert regulation_point(TaskSpec.for_env("mcpilco/CartpoleSwingUp-v0")) is None
    away = idp.replace(init_mean=[0.0, 0.5, 0.0, 0.0, 0.0, 0.0])  # outside th1's box
    assert regulation_point(away) is None


@pytest.mark.parametrize(
    ("env_id", "setting", "linear"),
    [
        ("InvertedDoublePendulum-v5", None, True),  # derived: a balance
        ("InvertedDoublePendulum-v5", False, False),
        ("mcpilco/CartpoleSwingUp-v0", None, False),  # derived: a swing-up
        ("mcpilco/CartpoleSwingUp-v0", True, True),
    ],
)
def test_policy_linear_is_derived_from_the_task_unless_set(env_id, setting, linear):
    cfg = MCPilcoConfig(env_id=env_id, num_basis=4, policy_linear=setting)
    task = cfg.task_spec()
    cands = policy_candidates(cfg, task, StateLayout.from_task(task))
    assert all(c.linear == linear for c in cands)
    if linear:
        assert unsupported_reason(cands[0], None, None, torch.device("cpu")) is not None


def test_policy_linear_rejects_non_booleans():
    with pytest.raises(ValueError, match="policy_linear"):
        MCPilcoConfig(policy_linear="yes")


def test_the_loaded_config_derives_policy_linear_where_no_file_sets_it():
    """A config built from the shipped files leaves ``policy_linear`` to the task (None)
    unless a file sets it: ``InvertedPendulum-v5``'s sets false."""
    from mcpilco.agents.mc_pilco.config import load_config

    assert load_config("InvertedDoublePendulum-v5").policy_linear is None
    assert load_config("mcpilco/CartpoleSwingUp-v0").policy_linear is None
    assert load_config("InvertedPendulum-v5").policy_linear is False


def test_lqr_gain_solves_the_scalar_riccati_equation():
    """``x+ = a x + b u``: ``p = q + a^2 p - (a b p)^2 / (r + b^2 p)`` is the quadratic
    ``b^2 p^2 + (r - a^2 r - q b^2) p - q r = 0``; ``k = a b p / (r + b^2 p)``."""
    from mcpilco.agents.mc_pilco.regulator import Q_FLOOR, lqr_gain

    a, b, q, r = 1.2, 0.5, 3.0, 0.7
    qf = q + Q_FLOOR * q  # the floor lqr_gain adds (relative to the largest entry of Q)
    c1 = r - a * a * r - qf * b * b
    p = (-c1 + np.sqrt(c1 * c1 + 4 * b * b * qf * r)) / (2 * b * b)
    k = lqr_gain(np.array([[a]]), np.array([[b]]), np.array([[q]]), np.array([[r]]))
    assert k[0, 0] == pytest.approx(a * b * p / (r + b * b * p), rel=1e-9)
    assert abs(a - b * k[0, 0]) < 1.0
    # no control authority on an unstable mode: no stabilising solution
    assert lqr_gain(np.array([[1.5]]), np.array([[0.0]]), np.array([[1.0]]), np.eye(1)) is None


def test_model_jacobians_and_cost_hessian_of_known_parts():
    from mcpilco.agents.mc_pilco.cost import SaturatingCost
    from mcpilco.agents.mc_pilco.regulator import cost_hessian, model_jacobians

    A = np.array([[1.0, 0.1], [-0.3, 0.9]])
    B = np.array([[0.0], [0.2]])
    At, Bt = torch.tensor(A, dtype=torch.float32), torch.tensor(B, dtype=torch.float32)
    ja, jb = model_jacobians(lambda x, u: x @ At.T + u @ Bt.T, np.array([0.3, -1.0]), [0.5])
    assert np.allclose(ja, A, atol=1e-6) and np.allclose(jb, B, atol=1e-6)
    cost = SaturatingCost(3, [0, 2], [0.5, -1.0], [0.3, 2.0], [0, 0])  # plain terms
    q = cost_hessian(cost, np.array([0.5, 7.0, -1.0]))  # at the targets: diag(2 / l^2)
    assert np.allclose(q, np.diag([2 / 0.3**2, 0.0, 2 / 2.0**2]), atol=1e-4)


def test_feature_gains_reproduce_the_state_feedback_to_first_order():
    """A policy whose RBF weights are 0 and whose gains are ``feature_gains(K)`` applies
    ``u = u_mid - K (x - x*)`` near ``x*``, an angle (features sin, cos) included."""
    from mcpilco.agents.mc_pilco.regulator import feature_gains

    layout = _layout()  # [x, x_dot, theta, theta_dot]; theta (index 2) an angle
    x_star = np.array([0.2, 0.0, 2.5, 0.0])
    k = np.array([[0.7, -1.3, 2.1, 0.4]])
    scale = np.linspace(0.3, 1.5, layout.feature_dim)
    g = feature_gains(k, layout, x_star, scale, np.array([3.0]))
    ref = [0.2, 0.0, 0.0, np.sin(2.5), np.cos(2.5)]  # [x, x_dot, theta_dot, sin, cos]
    p = SquashedRBFPolicy(
        layout, [-2.0], [4.0], num_basis=3, weight_scale=0.0, linear_ref=ref,
        linear_scale=scale, gains_init=g,
    )  # fmt: skip
    d = 1e-3 * np.array([1.0, -2.0, 1.5, 0.5])
    u = p.eval()(torch.as_tensor(x_star + d, dtype=torch.float32)[None])[0].detach().numpy()
    assert u - 1.0 == pytest.approx(-(k @ d), rel=2e-3)

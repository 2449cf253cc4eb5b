"""MC-PILCO through a kinematic model (:mod:`mcpilco.agents.mc_pilco.reaching`), on a planar
three-link arm whose forward kinematics are written here in closed form."""

import math

import numpy as np
import pytest
import torch

from mcpilco.agents.mc_pilco.optimize import PolicyOptConfig
from mcpilco.agents.mc_pilco.reaching import (
    IncrementDynamics,
    PoseErrorCost,
    ReachingConfig,
    joint_layout,
    optimise_reaching_policy,
    rollout_error,
)

LINKS = (0.5, 0.4, 0.3)  # link lengths of the planar arm [m]


class PlanarArm(torch.nn.Module):
    """A planar three-link arm: ``l = sum_i a_i [cos phi_i, sin phi_i, 0]``,
    ``R = Rz(phi_3)``, ``phi_i = q_1 + ... + q_i``."""

    def position_and_rotation(self, q):
        phi = torch.cumsum(q, -1)
        a = torch.tensor(LINKS, dtype=q.dtype)
        x = (a * torch.cos(phi)).sum(-1)
        y = (a * torch.sin(phi)).sum(-1)
        l = torch.stack([x, y, torch.zeros_like(x)], -1)  # noqa: E741
        c, s = torch.cos(phi[..., -1]), torch.sin(phi[..., -1])
        o, z = torch.ones_like(c), torch.zeros_like(c)
        R = torch.stack([c, -s, z, s, c, z, z, z, o], -1).reshape(*q.shape[:-1], 3, 3)
        return l, R


def _pose(q):
    with torch.no_grad():
        l, R = PlanarArm().position_and_rotation(torch.as_tensor(q, dtype=torch.float64))
    return l.numpy(), R.numpy()


def _rz(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_pose_error_cost_is_distance_plus_weighted_rotation_angle():
    q = np.array([0.3, -0.5, 0.8])
    l_star, R_star = _pose(q)
    qt = torch.as_tensor(q).reshape(1, 3)
    assert PoseErrorCost(PlanarArm(), l_star, R_star)(qt).item() < 1e-5
    # the target 0.1 m away along z and turned 0.4 rad about z: cost = 0.1 + w 0.4
    cost = PoseErrorCost(PlanarArm(), l_star + [0, 0, 0.1], R_star @ _rz(0.4), 0.2)
    assert cost(qt).item() == pytest.approx(0.1 + 0.2 * 0.4, abs=1e-5)
    pos, theta = cost.errors(qt)
    assert pos.item() == pytest.approx(0.1, abs=1e-6) and theta.item() == pytest.approx(
        0.4, abs=1e-6
    )
    # the optimised cost: eps log(1 + e / eps)
    log_cost = PoseErrorCost(PlanarArm(), l_star + [0, 0, 0.1], R_star @ _rz(0.4), 0.2, 0.01)
    assert log_cost(qt).item() == pytest.approx(0.01 * math.log1p(0.18 / 0.01), rel=1e-4)


def test_increment_dynamics_step_and_clip():
    dyn = IncrementDynamics([0.1, 0.2], q_limits=[[-1.0, 1.0], [-0.5, 0.5]])
    q = torch.tensor([[0.95, 0.0]], dtype=torch.float64)
    out = dyn(q, torch.tensor([[1.0, -0.5]], dtype=torch.float64))
    np.testing.assert_allclose(out.numpy(), [[1.0, -0.1]])


def test_policy_through_the_model_reaches_a_target_the_start_is_far_from():
    q0, q_star = np.array([0.2, 0.3, -0.2]), np.array([1.1, -0.6, 0.5])
    l_star, R_star = _pose(q_star)
    start_error = np.linalg.norm(_pose(q0)[0] - l_star)
    rng = np.random.default_rng(0)
    q_data = q0 + rng.uniform(-1.0, 1.0, (50, 3))
    inc = [0.15, 0.15, 0.15]
    policy, res = optimise_reaching_policy(
        PlanarArm(), "RRR", q0, l_star, R_star, inc, q_data, seed=0,
        config=ReachingConfig(horizon=15, particles=8),
    )  # fmt: skip
    q, c = rollout_error(policy, PlanarArm(), q0, l_star, R_star, inc, 15)
    l_end, R_end = _pose(q[-1])
    # the closed form of the final pose, not the cost the optimiser saw
    pos_err = np.linalg.norm(l_end - l_star)
    angle_err = abs(math.atan2(R_end[1, 0], R_end[0, 0]) - math.atan2(R_star[1, 0], R_star[0, 0]))
    assert start_error > 0.5
    assert pos_err < 0.01 and angle_err < 0.05, (pos_err, angle_err, res.stop_reason)
    assert c[-1] == pytest.approx(pos_err + 0.1 * angle_err, abs=1e-3)


def test_bad_inputs_are_refused_with_the_field_named():
    l_star, R_star = _pose([0.0, 0.0, 0.0])
    q_data = np.zeros((5, 3))
    with pytest.raises(ValueError, match="joint_types"):
        joint_layout("RX")
    with pytest.raises(ValueError, match="q0 must have 3"):
        optimise_reaching_policy(PlanarArm(), "RRR", [0.0, 0.0], l_star, R_star, [0.1] * 3, q_data)
    with pytest.raises(ValueError, match="increments must be > 0"):
        IncrementDynamics([0.1, 0.0])
    with pytest.raises(ValueError, match="target_position"):
        PoseErrorCost(PlanarArm(), [0.0, 0.0], R_star)
    with pytest.raises(ValueError, match="q_data must be"):
        optimise_reaching_policy(
            PlanarArm(), "RRR", [0.0] * 3, l_star, R_star, [0.1] * 3, q_data[:, :2]
        )
    with pytest.raises(ValueError, match="horizon, particles"):
        ReachingConfig(horizon=0, opt=PolicyOptConfig())

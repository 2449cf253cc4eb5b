"""Speed integration (eq. 5.9) against a learned position change, on a forced harmonic
oscillator whose exact discrete-time step is written here in closed form.

``qdd = -w^2 q + u`` with ``u`` held over ``T``: about ``q_e = u / w^2`` the state
``(q - q_e, qd / w)`` rotates by ``theta = w T`` per step. For ``q = A sin(w t)`` the true
displacement of a step is ``2 A cos(phi + theta/2) sin(theta/2)`` and eq. (5.9)'s
``T qd + T/2 Delta qd`` is ``A theta cos(phi + theta/2) cos(theta/2)``: the ratio
``(theta/2) / tan(theta/2)``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from mcpilco.agents.mc_pilco import StateLayout, TaskSpec, TaskSpecError
from mcpilco.agents.mc_pilco.dynamics import GPDynamicsModel, speed_integration
from mcpilco.envs.tasks.spec import CostTerm, SuccessSpec

OMEGA = 6.0  # [rad/s]
DT = 0.1  # [s]: theta = w T = 0.6 rad per step


def oscillator_task(speed_integration: bool) -> TaskSpec:
    return TaskSpec(
        env_id="oscillator",
        state_names=("q", "qd"),
        pairs=(("q", "qd"),),
        action_low=(-1.0,),
        action_high=(1.0,),
        dt=DT,
        horizon=20,
        cost_terms=(CostTerm("q"),),
        success=SuccessSpec(full_horizon=True),
        speed_integration=speed_integration,
    )


def exact_step(x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Closed-form step of ``qdd = -w^2 q + u`` over ``T`` with ``u`` held."""
    th = OMEGA * DT
    qe = u[..., 0] / OMEGA**2
    p, v = x[..., 0] - qe, x[..., 1] / OMEGA
    p1 = math.cos(th) * p + math.sin(th) * v
    v1 = -math.sin(th) * p + math.cos(th) * v
    return np.stack([p1 + qe, OMEGA * v1], axis=-1)


def test_layout_of_learned_positions():
    on, off = oscillator_task(True), oscillator_task(False)
    assert StateLayout.from_task(on).output_idx == (1,)
    assert StateLayout.from_task(off).output_idx == (0, 1)
    assert off.gp_output_names() == ["delta_q", "delta_qd"]
    assert off.pairs == (("q", "qd"),)  # the pairing itself is kept (joints, kernels)
    with pytest.raises(TaskSpecError, match="speed_integration"):
        TaskSpec.from_dict(
            {"env_id": "o", "state_names": ["q"], "action_low": [-1], "action_high": [1],
             "dt": 0.1, "horizon": 5, "cost": {"terms": [{"state": "q"}]},
             "success": {"full_horizon": True}, "speed_integration": "no"}
        )  # fmt: skip


def test_integration_step_against_the_closed_form():
    """With the exact velocity change, eq. (5.9) misses the displacement by the factor
    ``(theta/2)/tan(theta/2)``; predicting the position change too reproduces the step."""
    a, phi = 0.3, np.linspace(0.0, 2 * math.pi, 13)
    th = OMEGA * DT
    x = np.stack([a * np.sin(phi), a * OMEGA * np.cos(phi)], axis=-1)
    x1 = exact_step(x, np.zeros((len(phi), 1)))
    delta = torch.as_tensor(x1 - x)
    state = torch.as_tensor(x)
    on = speed_integration(state, delta[:, 1:], DT, StateLayout.from_task(oscillator_task(True)))
    off = speed_integration(state, delta, DT, StateLayout.from_task(oscillator_task(False)))
    np.testing.assert_allclose(off.numpy(), x1, atol=1e-12)
    np.testing.assert_allclose(on[:, 1].numpy(), x1[:, 1], atol=1e-12)
    ratio = (th / 2) / math.tan(th / 2)
    np.testing.assert_allclose(on[:, 0].numpy() - x[:, 0], ratio * (x1[:, 0] - x[:, 0]), atol=1e-12)
    assert abs(1 - ratio) > 0.02  # 3 % of each step's displacement


def test_learned_positions_predict_the_oscillator_over_a_horizon():
    """GPs fitted on the same 150 transitions: with speed integration the 20-step mean
    prediction drifts by the integration's bias; with learned position changes it follows
    the closed form."""
    rng = np.random.default_rng(0)
    x = np.stack([rng.uniform(-0.5, 0.5, 150), rng.uniform(-3.0, 3.0, 150)], axis=-1)
    u = rng.uniform(-1.0, 1.0, (150, 1))
    x1 = exact_step(x, u)
    t = np.arange(21) * DT
    true = np.stack([0.3 * np.sin(OMEGA * t), 0.3 * OMEGA * np.cos(OMEGA * t)], axis=-1)
    errors = {}
    for flag in (True, False):
        model = GPDynamicsModel(oscillator_task(flag), max_points=None, mpk_degree=1)
        dyn = model.fit(x, u, x1).particle_dynamics(dtype=torch.float64)
        s = torch.as_tensor(true[:1])
        pred = [s]
        with torch.no_grad():
            for _ in range(20):
                s = dyn(s, torch.zeros(1, 1))
                pred.append(s)
        errors[flag] = float(np.abs(torch.cat(pred).numpy()[:, 0] - true[:, 0]).max())
    assert errors[False] < 0.01, errors  # 3 % of the 0.3 rad amplitude
    assert errors[True] > 5 * errors[False], errors

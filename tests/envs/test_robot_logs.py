"""Synthetic robot logs: reproducibility, physics of the hidden effects, measurement model.

The independent truth is MuJoCo's inverse dynamics (``mj_inverse``) of the nominal model at
the exact states of the simulation: the residual ``tau - ID_nom`` must be the effect's torque.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from mcpilco.envs.arms import random_arm
from mcpilco.envs.robot_logs import HiddenEffect, SimulationDiverged, build_models, simulate_log

DURATION = 2.0
QUIET = dict(tau_noise=0.0, encoder_noise=0.0)


@pytest.fixture(scope="module")
def arm():
    return random_arm(3, seed=1, joint_types="RRR").rigid()


def inverse_dynamics(model, q, qd, qdd):
    data = mujoco.MjData(model)
    out = np.zeros_like(q)
    for k in range(q.shape[0]):
        data.qpos[:], data.qvel[:], data.qacc[:] = q[k], qd[k], qdd[k]
        mujoco.mj_inverse(model, data)
        out[k] = data.qfrc_inverse
    return out


def residual(arm, log):
    nominal, _, _ = build_models(arm)
    tr = log.truth
    return tr.tau - inverse_dynamics(nominal, tr.q, tr.qd, tr.qdd)


def test_columns_and_reproducibility(arm):
    a = simulate_log(arm, duration=DURATION, seed=4)
    b = simulate_log(arm, duration=DURATION, seed=4)
    c = simulate_log(arm, duration=DURATION, seed=5)
    assert list(a.table.columns) == ["t", "q1", "q2", "q3", "tau1", "tau2", "tau3"]
    assert a.table.equals(b.table)
    assert not a.table.equals(c.table)
    np.testing.assert_allclose(np.diff(a.table["t"]), 0.004, rtol=1e-9)
    ranges = arm.joint_ranges
    assert (a.truth.q > ranges[:, 0]).all() and (a.truth.q < ranges[:, 1]).all()


def test_without_effects_tau_is_the_nominal_inverse_dynamics(arm):
    log = simulate_log(arm, duration=DURATION, seed=0, **QUIET)
    np.testing.assert_array_equal(log.table[["tau1", "tau2", "tau3"]].to_numpy(), log.truth.tau)
    scale = np.abs(log.truth.tau).max()
    assert scale > 0.1
    np.testing.assert_allclose(residual(arm, log), 0.0, atol=1e-9 * scale)


def test_damping_residual_is_b_qd(arm):
    b = 0.7
    log = simulate_log(arm, [HiddenEffect("damping", 2, b)], duration=DURATION, seed=0, **QUIET)
    r = residual(arm, log)
    np.testing.assert_allclose(r[:, 1], b * log.truth.qd[:, 1], atol=1e-9)
    np.testing.assert_allclose(r[:, [0, 2]], 0.0, atol=1e-9)
    assert np.abs(r[:, 1]).max() > 0.05  # the joint moves: the effect is visible


def test_frictionloss_residual_is_the_friction_level_while_moving(arm):
    level = 0.5
    log = simulate_log(
        arm, [HiddenEffect("frictionloss", 1, level)], duration=DURATION, seed=0, **QUIET
    )
    r = residual(arm, log)[:, 0]
    moving = np.abs(log.truth.qd[:, 0]) > 0.02
    assert moving.mean() > 0.5
    np.testing.assert_allclose(np.abs(r[moving]), level, rtol=0.02)
    np.testing.assert_array_equal(np.sign(r[moving]), np.sign(log.truth.qd[moving, 0]))
    assert (np.abs(r) <= level * 1.02).all()


@pytest.mark.parametrize(
    "effect",
    [HiddenEffect("mass", 3, 1.5), HiddenEffect("payload", 0, 1.0, 0.05)],
    ids=["heavier_link", "payload"],
)
def test_inertial_residual_is_the_inverse_dynamics_difference(arm, effect):
    log = simulate_log(arm, [effect], duration=DURATION, seed=0, **QUIET)
    nominal, true, _ = build_models(arm, [effect])
    tr = log.truth
    diff = inverse_dynamics(true, tr.q, tr.qd, tr.qdd) - inverse_dynamics(
        nominal, tr.q, tr.qd, tr.qdd
    )
    assert np.abs(diff).max() > 0.1
    np.testing.assert_allclose(residual(arm, log), diff, atol=1e-8)


def test_position_dependent_friction_is_applied_as_documented(arm):
    level, freq = 0.3, 2.0
    effect = HiddenEffect("position_friction", 2, level, freq)
    log = simulate_log(arm, [effect], duration=DURATION, seed=0, **QUIET)
    q, qd = log.truth.q[:, 1], log.truth.qd[:, 1]
    expected = level * (1 + 0.5 * np.sin(freq * q)) * np.tanh(qd / 0.01)
    np.testing.assert_allclose(residual(arm, log)[:, 1], expected, atol=1e-9)


def test_cogging_is_applied_with_its_order_and_phase(arm):
    value, order, phase = 0.2, 7.3, 1.1
    effect = HiddenEffect("cogging", 2, value, order, phase=phase)
    log = simulate_log(arm, [effect], duration=DURATION, seed=0, **QUIET)
    # an applied force value sin(n q + phase): the actuator supplies its opposite
    expected = -value * np.sin(order * log.truth.q[:, 1] + phase)
    np.testing.assert_allclose(residual(arm, log)[:, 1], expected, atol=1e-9)
    np.testing.assert_allclose(residual(arm, log)[:, [0, 2]], 0.0, atol=1e-9)


def test_the_torque_columns_lag_by_the_measurement_delay(arm):
    log = simulate_log(arm, duration=DURATION, seed=0, tau_delay=[0.0, 0.008, 0.002], **QUIET)
    tau = log.table[["tau1", "tau2", "tau3"]].to_numpy()
    np.testing.assert_array_equal(tau[:, 0], log.truth.tau[:, 0])
    # 8 ms = 2 samples: the applied torque two rows earlier (the first rows repeat row 0)
    np.testing.assert_allclose(tau[2:, 1], log.truth.tau[:-2, 1], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(tau[:2, 1], log.truth.tau[0, 1], rtol=1e-12)
    # 2 ms lies between two rows: the torque of the physics step two before each row's,
    # read from the same simulation logged at every step
    fine = simulate_log(arm, duration=DURATION, seed=0, substeps=1, **QUIET)
    k = np.arange(1, tau.shape[0])
    np.testing.assert_allclose(tau[1:, 2], fine.truth.tau[4 * k - 2, 2], rtol=1e-9, atol=1e-12)
    assert np.abs(tau[1:, 2] - log.truth.tau[1:, 2]).max() > 1e-5  # not the same rows
    assert log.truth.settings["tau_delay"] == [0.0, 0.008, 0.002]


def test_stiffness_and_armature_residuals(arm):
    k, ref, ia = 3.0, 0.1, 0.2
    effects = [HiddenEffect("stiffness", 1, k, ref), HiddenEffect("armature", 3, ia)]
    log = simulate_log(arm, effects, duration=DURATION, seed=0, **QUIET)
    r = residual(arm, log)
    np.testing.assert_allclose(r[:, 0], k * (log.truth.q[:, 0] - ref), atol=1e-9)
    np.testing.assert_allclose(r[:, 2], ia * log.truth.qdd[:, 2], atol=1e-9)


def test_encoder_quantisation_and_torque_noise(arm):
    counts = 2**12
    step = 2 * math.pi / counts
    log = simulate_log(
        arm, duration=DURATION, seed=0, counts_per_rev=counts, encoder_noise=0.0, tau_noise=0.05
    )
    q = log.table[["q1", "q2", "q3"]].to_numpy()
    np.testing.assert_allclose(q / step, np.round(q / step), atol=1e-9)
    assert np.abs(q - log.truth.q).max() <= step / 2 * (1 + 1e-9)
    assert np.unique(q[:, 0]).size > 10
    noise = log.table[["tau1", "tau2", "tau3"]].to_numpy() - log.truth.tau
    np.testing.assert_allclose(noise.std(axis=0), 0.05, rtol=0.15)
    noisy = simulate_log(arm, duration=DURATION, seed=0, counts_per_rev=counts, encoder_noise=2)
    qn = noisy.table[["q1", "q2", "q3"]].to_numpy()
    np.testing.assert_allclose(qn / step, np.round(qn / step), atol=1e-9)
    # reading noise of 2 counts, then rounding: std sqrt(2^2 + 1/12) counts
    np.testing.assert_allclose((qn - noisy.truth.q).std(axis=0) / step, 2.02, rtol=0.1)


def test_bad_effects_are_refused(arm):
    with pytest.raises(ValueError, match="unknown effect kind"):
        HiddenEffect("magic", 1, 1.0)
    with pytest.raises(ValueError, match="joint 5 but the arm has 3"):
        simulate_log(arm, [HiddenEffect("damping", 5, 1.0)], duration=0.1)


def test_current_log_is_the_torque_over_the_torque_constant(arm):
    """``torque_constants``: the file holds ``i = tau / k_t`` plus noise of ``current_noise``
    amperes instead of torques; the motion is that of the torque log of the same seed."""
    k_t = [0.1, -2.0, 1.5]
    log = simulate_log(arm, duration=DURATION, seed=0, torque_constants=k_t, current_noise=0.02)
    torque = simulate_log(arm, duration=DURATION, seed=0)
    assert list(log.table.columns) == ["t", "q1", "q2", "q3", "i1", "i2", "i3"]
    np.testing.assert_array_equal(log.truth.torque_constants, k_t)
    assert log.truth.settings["torque_constants"] == k_t
    assert "tau_noise" not in log.truth.settings
    assert torque.truth.torque_constants is None
    q_cols = ["q1", "q2", "q3"]
    assert log.table[q_cols].equals(torque.table[q_cols])
    current = log.table[["i1", "i2", "i3"]].to_numpy()
    noise = current - log.truth.tau / np.array(k_t)
    np.testing.assert_allclose(noise.std(axis=0), 0.02, rtol=0.15)
    assert abs(noise.mean()) < 0.005


@pytest.mark.parametrize(
    "k_t, match",
    [
        ([1.0, 0.0, 1.0], "joint 2 has k_t = 0.0"),
        ([1.0, float("nan"), 1.0], "joint 2 has k_t = nan"),
        ([1.0, 2.0], "one value or 3"),
    ],
)
def test_bad_torque_constants_are_refused(arm, k_t, match):
    with pytest.raises(ValueError, match=match):
        simulate_log(arm, duration=0.1, torque_constants=k_t)


def test_a_spring_too_stiff_for_the_time_step_is_reported_as_diverged(arm):
    # explicit Euler on a spring of natural frequency w is unstable for w dt > 2
    nominal, _, _ = build_models(arm)
    data = mujoco.MjData(nominal)
    mujoco.mj_forward(nominal, data)
    mass = np.zeros((arm.n_joints, arm.n_joints))
    mujoco.mj_fullM(nominal, data, mass)
    dt = 1e-3
    k = 25.0 * (2.0 / dt) ** 2 * mass[2, 2]  # w dt = 10
    # the first joint past its tracking limit may be one the spring's joint shakes
    with pytest.raises(SimulationDiverged, match=r"'stiffness', 3, .* too stiff for the time step"):
        simulate_log(arm, [HiddenEffect("stiffness", 3, k)], duration=0.5, timestep=dt, seed=0)


def coaxial_masses(light: float, heavy: float, angles: np.ndarray) -> np.ndarray:
    """``M(q)`` of two joints whose axes line up at ``angle = 0``: joint 1 turns bodies 1 and
    2, joint 2 only body 2 (inertia ``heavy`` about both axes when aligned, less as the axes
    part), so that ``1 / (M^-1)_11`` falls to ``light`` at alignment."""
    c = np.cos(angles)
    m = np.zeros((angles.size, 2, 2))
    m[:, 0, 0] = light + heavy * (0.5 + 0.5 * c**2)
    m[:, 0, 1] = m[:, 1, 0] = heavy * c
    m[:, 1, 1] = heavy
    return m


def test_coupled_servo_cap_bounds_the_coupled_damping_step():
    from mcpilco.envs.robot_logs import coupled_servo_cap

    dt, light, heavy = 1e-3, 0.01, 1.0
    masses = coaxial_masses(light, heavy, np.linspace(-0.5, 0.5, 41))
    kd = np.array([0.4 * masses[0, 0, 0] / dt, 0.4 * heavy / dt])  # each at 0.4 on its own M_jj
    kp = (kd / 2) ** 2 / np.array([masses[0, 0, 0], heavy])  # critically damped on M_jj
    ki = 0.1 * kp

    def rho(kd_):  # the non-symmetric product's spectrum, computed directly
        return max(
            dt * np.abs(np.linalg.eigvals(np.linalg.inv(m) @ np.diag(kd_))).max() for m in masses
        )

    assert rho(kd) > 2.0  # the diagonal caps alone leave the aligned loop unstable
    kp2, kd2, ki2 = coupled_servo_cap(kp, kd, ki, masses, dt, limit=1.0)
    assert rho(kd2) <= 1.0 + 1e-9
    np.testing.assert_allclose(kd2**2 / kp2, kd**2 / kp)  # damping ratios kept
    np.testing.assert_allclose(ki2 / kp2**1.5, ki / kp**1.5)  # integral time in units of 1/w
    assert (kd2 <= kd).all() and (kd2 < kd).any()

    far = coaxial_masses(light, heavy, np.linspace(1.2, 1.5, 5))  # axes apart: M^-1 Kd small
    small = 0.1 * kd
    assert (
        max(dt * np.abs(np.linalg.eigvals(np.linalg.inv(m) @ np.diag(small))).max() for m in far)
        < 1.0
    )
    out = coupled_servo_cap(kp * 1e-2, small, ki, far, dt, limit=1.0)
    np.testing.assert_array_equal(out[1], small)  # within the cap: unchanged


def test_iiwa_log_through_aligned_axes_does_not_chatter():
    """A reference of the iiwa 14 that passes its first and third joints' axes through
    alignment: with the diagonal caps alone the servo chattered there at the physics rate
    (|qdd| ~ 6,000 rad/s^2, the first joint's torque at its limit for 0.4 s)."""
    from mcpilco.envs.arms import iiwa14

    arm = iiwa14().without_friction()
    log = simulate_log(arm, duration=5.0, seed=1234240068, **QUIET)
    limit = arm.joint_array("torque_limit")
    assert np.abs(log.truth.qdd).max() < 100.0
    assert (np.abs(log.truth.tau) < 0.999 * limit).all()

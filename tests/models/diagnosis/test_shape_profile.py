"""Continuous shape values fitted by profile log-evidence, with likelihood-ratio intervals.

Independent truth: analytic profiles (a quadratic log-likelihood, a Gaussian weight
posterior), and logs of :func:`mcpilco.envs.robot_logs.simulate_log` whose cogging force has a
known, non-integer order and a known phase, and whose torque column lags by a known delay
that is not a whole number of samples.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from mcpilco.envs.arm_builder import arm_to_xml
from mcpilco.envs.arms import random_arm
from mcpilco.envs.robot_logs import HiddenEffect, simulate_log, write_log
from mcpilco.models.diagnosis import DiagnosisModel, NominalStart, load_trajectories
from mcpilco.models.diagnosis.effects import Cogging, Delay, effect_from_spec
from mcpilco.models.diagnosis.profile import (
    CHI2_HALF_95,
    likelihood_interval,
    phase_interval,
)
from mcpilco.models.diagnosis.search import score_effect


def test_interval_of_a_quadratic_profile_is_mean_plus_minus_1_96_sd():
    mu, sd = 0.3, 0.05

    def f(u):
        return -0.5 * ((u - mu) / sd) ** 2

    lo, hi, limited = likelihood_interval(f, mu, 0.0, -5.0, 5.0)
    assert not limited
    assert math.isclose(lo, mu - 1.959964 * sd, abs_tol=2e-3)
    assert math.isclose(hi, mu + 1.959964 * sd, abs_tol=2e-3)
    assert math.isclose(2 * CHI2_HALF_95, 3.841459, rel_tol=1e-6)  # chi^2_1, 95%
    # a flat side is not pinned down: its end is the search limit
    lo, hi, limited = likelihood_interval(
        lambda u: min(f(u), 0.0) if u < mu else 0.0, mu, 0.0, -5, 1
    )
    assert limited and hi == 1 and math.isclose(lo, mu - 1.96 * sd, abs_tol=2e-3)


def test_phase_interval_of_a_gaussian_weight_posterior():
    """One order, w ~ N(A u(phi0), s^2 I) with A >> s: phi0 +- 1.96 s / A."""
    amp, s, phi0 = 1.0, 0.02, 3.12
    mean = amp * np.array([[math.cos(phi0), math.sin(phi0)]])
    phi, lo, hi, limited = phase_interval(np.zeros(1), mean, s**2 * np.eye(2)[None])
    assert not limited and math.isclose(phi, phi0, abs_tol=1e-12)
    assert math.isclose(hi - phi0, 1.96 * s / amp, rel_tol=0.02)
    assert math.isclose(phi0 - lo, 1.96 * s / amp, rel_tol=0.02)
    assert hi > math.pi  # an interval across +-pi is not wrapped
    # an amplitude the data cannot tell from zero leaves the phase open
    _, lo, hi, limited = phase_interval(np.zeros(1), 1e-3 * mean, s**2 * np.eye(2)[None])
    assert limited and math.isclose(hi - lo, 2 * math.pi)


@pytest.fixture(scope="module")
def arm():
    return random_arm(3, seed=1, joint_types="RRR").rigid()


def _model(arm, tmp, effects=(), **log):
    """A nominal-start model fitted on a 4 s position-only log (derivatives estimated)."""
    data = simulate_log(arm, effects, duration=4.0, seed=0, **log)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        train = load_trajectories([write_log(tmp / "log.csv", data)])
    return DiagnosisModel(NominalStart(arm_to_xml(arm, friction=False))).fit(train)


def test_cogging_order_and_phase_lie_in_their_intervals(arm, tmp_path):
    value, order, phase = 0.2, 9.1, -1.4
    model = _model(arm, tmp_path, [HiddenEffect("cogging", 2, value, order, phase=phase)])
    cand = score_effect(model, Cogging(joint=2), refine=True)
    est = {p.name: p for p in cand.estimates}
    n, phi, amp = est["n"], est["phi"], est["A"]
    assert not float(cand.effect.order).is_integer()  # refined off the scan's grid
    assert n.interval[0] <= order <= n.interval[1] and not n.limited, n
    assert n.interval[1] - n.interval[0] < 1.0  # finer than the scan's step
    # the actuator supplies the opposite of the applied force: phase + pi
    true_phi = phi.value + math.remainder(phase + math.pi - phi.value, 2 * math.pi)
    assert phi.interval[0] <= true_phi <= phi.interval[1] and not phi.limited, phi
    assert abs(amp.value - value) <= amp.ci95, amp
    # the intervals travel with the effect: into the model's parameters and its saved spec
    v1 = model.with_effect(cand.effect)
    params = {p["name"]: p for p in v1.parameters(shape=True)}
    assert params["n"]["interval"] == n.interval and params["phi"]["interval"] == phi.interval
    assert [p["name"] for p in v1.parameters()] == ["A", "phi"]  # the physical parameters
    assert effect_from_spec(cand.effect.spec()).profile == cand.effect.profile
    assert "95% LR interval" in cand.estimate_text()


def test_a_delay_between_samples_is_found_with_its_interval(arm, tmp_path):
    """10 ms at 4 ms sampling: 2.5 samples, between two scan values."""
    delay = 0.01
    model = _model(arm, tmp_path, tau_delay=[0.0, delay, 0.0], tau_noise=0.01)
    cand = score_effect(model, Delay(joint=2), refine=True)
    (d,) = [p for p in cand.estimates if p.name == "d"]
    assert d.interval[0] <= delay <= d.interval[1] and not d.limited, d
    assert d.interval[1] - d.interval[0] < model.train_.sample_time  # under one sample
    assert not float(cand.effect.samples).is_integer()

"""The residual's structure (whiteness, cross-correlation with the inputs) and identifiability.

Independent truth: series built with a known law (white noise; an AR(1) process, whose
lag-1 autocorrelation is its coefficient; a residual that is a known function of ``q``; a
coloured residual drawn independently of ``q``), and a model whose blocks are collinear by
construction (a spring's constant column is the offset's column).
"""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest
from scipy.signal import lfilter

from mcpilco.envs.arm_builder import arm_to_xml
from mcpilco.envs.arms import random_arm
from mcpilco.envs.robot_logs import HiddenEffect, simulate_log, write_log
from mcpilco.models.diagnosis import (
    CoulombFriction,
    DiagnosisModel,
    NominalStart,
    Spring,
    TorqueOffset,
    ViscousFriction,
    load_trajectories,
)
from mcpilco.models.diagnosis.analysis import cross_correlation_test, whiteness_test
from mcpilco.models.diagnosis.effects import FeatureContext, ParamEstimate
from mcpilco.models.diagnosis.identifiability import (
    IDENTIFIABLE_CORRELATION,
    judge_estimates,
    weight_names,
)
from mcpilco.models.gp.linear_gp import JointGP

N = 2000
DT = 0.004


def smooth_q(seed: int) -> np.ndarray:
    """A joint trajectory like a robot log's: a few slow sines with random phases [rad]."""
    rng = np.random.default_rng(seed)
    t = np.arange(N) * DT
    freqs, phases = (0.2, 0.45, 0.9), rng.uniform(0, 2 * np.pi, 3)
    return sum(0.4 * np.sin(2 * np.pi * f * t + p) for f, p in zip(freqs, phases, strict=True))


# ------------------------------------------------------------------------- whiteness
def test_whiteness_passes_white_noise_and_fails_an_ar1_sequence():
    e = np.random.default_rng(0).standard_normal(N)
    white = whiteness_test(e)
    assert white.passed, (white.peak, white.threshold)
    assert white.band == pytest.approx(2.5758 / np.sqrt(N), rel=1e-3)  # MATLAB's 99% band
    ar1 = whiteness_test(lfilter([1.0], [1.0, -0.5], e))
    assert not ar1.passed and ar1.peak_lag == 1
    assert ar1.peak == pytest.approx(0.5, abs=0.05)  # rho_1 of AR(1) is its coefficient


def test_whiteness_pools_segments_without_crossing_their_border():
    """Two white halves with different means are white as two segments (the step between
    them is not a correlation) but not as one series."""
    e = np.random.default_rng(1).standard_normal(N) + np.repeat([0.0, 3.0], N // 2)
    assert whiteness_test(e, [(0, N // 2), (N // 2, N)]).passed
    assert not whiteness_test(e).passed


# ------------------------------------------------------------------------- cross-correlation
def test_cross_correlation_flags_a_residual_that_is_a_function_of_q():
    q = smooth_q(0)
    noise = np.random.default_rng(2).standard_normal(N)
    e = 0.1 * np.tanh(3 * q) + 0.05 * noise
    test = cross_correlation_test(e, q)
    assert not test.passed
    r0 = test.r[test.lags == 0][0]
    assert r0 > test.threshold and abs(r0 - test.peak) < 0.05, (r0, test.peak)


def test_cross_correlation_keeps_an_independent_coloured_residual_inside_the_band():
    """An AR(0.9) residual drawn independently of a smooth q: MATLAB's 1/N band (which
    assumes a white residual) is too narrow; Bartlett's widened band is not crossed."""
    q = smooth_q(3)
    e = lfilter([1.0], [1.0, -0.9], np.random.default_rng(4).standard_normal(N))
    test = cross_correlation_test(e, q)
    assert test.inflation > 2.0  # both series are autocorrelated
    assert test.passed, (test.peak, test.threshold)
    assert abs(test.peak) > test.threshold / np.sqrt(test.inflation)  # the 1/N band: a false alarm
    assert cross_correlation_test(np.random.default_rng(5).standard_normal(N), q).passed


def test_correlation_tests_reject_bad_input():
    with pytest.raises(ValueError, match="e and u differ in length"):
        cross_correlation_test(np.zeros(10), np.zeros(11))
    with pytest.raises(ValueError, match="e has NaN"):
        whiteness_test(np.array([0.0, np.nan, 1.0]))
    with pytest.raises(ValueError, match="segments must lie inside e"):
        whiteness_test(np.zeros(10), [(0, 20)])


# ------------------------------------------------------------------------- identifiability
def test_a_weight_the_data_do_not_excite_is_not_identifiable():
    """A viscous term on a joint that never moves: its column is zero, the likelihood is
    flat along its weight, and the estimate says so instead of a number."""
    rng = np.random.default_rng(6)
    n = 400
    qd = np.zeros((n, 2))
    qd[:, 0] = np.sin(np.linspace(0, 6, n))
    ctx = FeatureContext(
        q=np.zeros((n, 2)), qd=qd, qdd=np.zeros((n, 2)), base=np.zeros((n, 2)), joint_types="RR"
    )
    moving, still = ViscousFriction(joint=1), ViscousFriction(joint=2)
    r = 0.7 * qd[:, 0] + 0.01 * rng.standard_normal(n)
    gp = JointGP(r, [moving.columns(ctx, 0), still.columns(ctx, 0)])
    theta, _ = gp.optimise(gp.default_theta())
    mean, cov = gp.weights(theta)
    names = weight_names([moving, still], gp.sizes)
    ok = judge_estimates(
        moving, moving.estimates(mean[:1], cov[:1, :1], ctx, 0), gp, theta, 0, names, ctx, 0
    )
    assert not ok[0].unidentified and ok[0].value == pytest.approx(0.7, abs=0.01)
    (flat,) = judge_estimates(
        still, still.estimates(mean[1:], cov[1:, 1:], ctx, 0), gp, theta, 1, names, ctx, 0
    )
    assert "do not excite it" in flat.unidentified
    assert flat.text().startswith("F_v: not identifiable from these data")


@pytest.fixture(scope="module")
def damping_logs(tmp_path_factory):
    out = tmp_path_factory.mktemp("ident")
    arm = random_arm(3, seed=1, joint_types="RRR").rigid()
    log = simulate_log(arm, [HiddenEffect("damping", 2, 0.5)], duration=4.0, seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        train = load_trajectories([write_log(out / "log.csv", log)])
    return arm, train


def test_collinear_effects_are_reported_as_not_identifiable(damping_logs):
    """A spring's constant column equals the offset's: the likelihood is flat along the
    difference of their weights, so neither constant is identifiable; the viscous friction
    the log holds (0.5 N m s/rad) stays a number with its interval."""
    arm, train = damping_logs
    effects = [ViscousFriction(joint=2), TorqueOffset(joint=2), Spring(joint=2)]
    model = DiagnosisModel(NominalStart(arm_to_xml(arm, friction=False)), effects).fit(train)
    rows = {(p["effect"], p["name"]): p for p in model.parameters()}
    fv = rows[("viscous:2", "F_v")]
    assert not fv["unidentified"] and abs(fv["value"] - 0.5) < fv["ci95"] + 0.01, fv
    for key, partner in [(("offset:2", "tau_0"), "spring:2 c"), (("spring:2", "c"), "offset:2")]:
        p = rows[key]
        assert "the likelihood is flat along it" in p["unidentified"], p
        assert partner in p["unidentified"], p
        assert p["text"].endswith(f"not identifiable from these data ({p['unidentified']})")


def test_parameter_estimates_keep_their_number_when_identifiable():
    est = ParamEstimate("F_v", 0.5, 0.01, "N·m·s/rad")
    assert est.text() == "F_v = 0.5 ± 0.01 N·m·s/rad"


def test_nearly_collinear_effects_are_reported_by_their_posterior_correlation():
    """Viscous friction and a Coulomb term whose smoothing is wider than the velocities
    (``tanh(qd / eps)`` bends little below ``|qd| = eps``): their columns are nearly
    proportional, not exactly, so the likelihood is not flat, but the posterior ties the two
    weights (correlation near -1) and neither is pinned down alone."""
    rng = np.random.default_rng(7)
    n = 400
    qd = np.zeros((n, 1))
    qd[:, 0] = 0.3 * np.sin(np.linspace(0, 12, n))
    ctx = FeatureContext(
        q=np.zeros((n, 1)), qd=qd, qdd=np.zeros((n, 1)), base=np.zeros((n, 1)), joint_types="R"
    )
    visc, coul = ViscousFriction(joint=1), CoulombFriction(joint=1, eps=0.5)
    r = 0.5 * qd[:, 0] + 0.01 * rng.standard_normal(n)
    gp = JointGP(r, [visc.columns(ctx, 0), coul.columns(ctx, 0)])
    theta = gp.default_theta(noise=1e-4)  # both blocks keep their prior variance
    mean, cov = gp.weights(theta)
    names = weight_names([visc, coul], gp.sizes)
    (fv,) = judge_estimates(
        visc, visc.estimates(mean[:1], cov[:1, :1], ctx, 0), gp, theta, 0, names, ctx, 0
    )
    (rho,) = re.findall(r"posterior correlation ([-+][0-9.]+) with", fv.unidentified)
    assert float(rho) <= -IDENTIFIABLE_CORRELATION and "flat" not in fv.unidentified
    assert "coulomb:1 (eps=0.5) F_c" in fv.unidentified

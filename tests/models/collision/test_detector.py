"""Collision detector pieces against hand-computed or analytic truth."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import norm

from mcpilco.models.collision import (
    CollisionDetector,
    alarm_flags,
    evaluate_detection,
    max_error_threshold,
    monitoring_signal,
    persistent,
    quantile_threshold,
    runs,
)


def test_runs_and_persistence_on_hand_made_sequences() -> None:
    f = np.array([0, 1, 1, 0, 1, 1, 1, 0, 0, 1], dtype=bool)
    assert runs(f) == [(1, 2), (4, 6), (9, 9)]
    np.testing.assert_array_equal(persistent(f, 1), f)
    np.testing.assert_array_equal(
        persistent(f, 2), np.array([0, 0, 1, 0, 0, 1, 1, 0, 0, 0], dtype=bool)
    )
    np.testing.assert_array_equal(
        persistent(f, 3), np.array([0, 0, 0, 0, 0, 0, 1, 0, 0, 0], dtype=bool)
    )
    with pytest.raises(ValueError, match="persistence"):
        persistent(f, 0)


def test_alarm_when_any_joint_reaches_its_threshold() -> None:
    s = np.array([[0.5, -0.1], [0.1, -0.95], [1.0, 0.0], [0.0, 0.0]])
    np.testing.assert_array_equal(alarm_flags(s, [1.0, 0.9]), [False, True, True, False])
    thr = np.array([[1.0, 1.0], [1.0, 1.0], [2.0, 2.0], [1e-3, 1.0]])  # input-dependent
    np.testing.assert_array_equal(alarm_flags(s, thr), [False, False, False, False])
    with pytest.raises(ValueError, match="shape"):
        alarm_flags(s, [1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="> 0"):
        alarm_flags(s, [1.0, 0.0])


def test_max_rule_and_gaussian_quantiles() -> None:
    rng = np.random.default_rng(0)
    z = rng.standard_normal((400_000, 2)) * np.array([1.0, 3.0])
    np.testing.assert_allclose(max_error_threshold(z), np.abs(z).max(0))
    np.testing.assert_allclose(quantile_threshold(z, 0.0), np.abs(z).max(0))
    for alpha in (0.05, 0.01, 1e-3):
        k = quantile_threshold(z, alpha)
        truth = norm.ppf(1 - alpha / 2) * np.array([1.0, 3.0])  # two-sided: P(|z| > k) = alpha
        np.testing.assert_allclose(k, truth, rtol=0.03)


def test_variance_rule_calibrates_a_per_sample_false_alarm_rate() -> None:
    # heteroscedastic residuals s = sigma(x) e with a known sigma(x): the k of the variance
    # rule is the Gaussian quantile, and fresh data exceed k sigma(x) at the rate alpha
    rng = np.random.default_rng(1)
    n = 300_000
    sigma = np.exp(rng.uniform(-1.5, 1.5, (n, 1)))
    s = sigma * rng.standard_normal((n, 1))
    alpha = 0.01
    k = quantile_threshold(s / sigma, alpha)
    np.testing.assert_allclose(k, norm.ppf(1 - alpha / 2), rtol=0.02)
    sigma2 = np.exp(rng.uniform(-1.5, 1.5, (n, 1)))
    s2 = sigma2 * rng.standard_normal((n, 1))
    rate = alarm_flags(s2, k * sigma2).mean()
    assert rate == pytest.approx(alpha, rel=0.1)
    # a constant threshold at the same overall rate flags the high-sigma samples far more
    c = quantile_threshold(s, alpha)
    hi = sigma2[:, 0] > np.exp(1.0)
    assert alarm_flags(s2[hi], c).mean() > 3 * alarm_flags(s2[hi], k * sigma2[hi]).mean()


def test_evaluate_detection_counts_by_hand() -> None:
    t = np.arange(100) * 0.01
    contact = np.zeros(100, dtype=int)
    contact[10:20] = 1  # push 1: 0.10-0.19 s
    contact[60:70] = 1  # push 2: 0.60-0.69 s (missed)
    alarm = np.zeros(100, dtype=bool)
    alarm[13:16] = True  # detects push 1, latency 0.03 s
    alarm[21] = True  # within the grace after push 1: not a false alarm
    alarm[40:42] = True  # false alarm 1
    alarm[90] = True  # false alarm 2
    ev = evaluate_detection(alarm, contact, t, grace=0.055)
    assert ev["n_pushes"] == 2
    assert [p["detected"] for p in ev["pushes"]] == [True, False]
    assert ev["pushes"][0]["latency"] == pytest.approx(0.03)
    assert ev["detection_rate"] == 0.5
    assert ev["median_latency"] == pytest.approx(0.03)
    assert ev["false_alarms"] == 2
    free = 100 - 15 - 15  # samples outside [start, end + grace] of both pushes
    assert ev["push_free_minutes"] == pytest.approx(free * 0.01 / 60)
    assert ev["false_alarms_per_minute"] == pytest.approx(2 / (free * 0.01 / 60))


class _KnownEstimator:
    """Stand-in estimator whose current estimate is exactly zero (so ``s = i``) with a
    known predictive std: isolates the detector logic from the GP."""

    name = "stub"
    n_joints_ = 2

    def __init__(self, noise_std: float) -> None:
        self.noise_variance_ = np.full(2, noise_std**2)

    def predict(self, X, return_var=True):
        x = np.asarray(X, dtype=float)
        return np.zeros((x.shape[0], 2)), (np.zeros((x.shape[0], 2)) if return_var else None)


def test_detector_finds_known_pushes_on_a_synthetic_signal() -> None:
    rng = np.random.default_rng(2)
    T, noise = 0.008, 0.1
    n = 20_000
    t = np.arange(n) * T
    calib = noise * rng.standard_normal((n, 2))  # collision-free residuals
    det = CollisionDetector(_KnownEstimator(noise), "max", 0.0, persistence=2)
    det.calibrate(np.zeros((n, 1)), calib)
    np.testing.assert_allclose(det.scale_, np.abs(calib).max(0))
    # test signal: noise + five 1 A steps on joint 2 of 0.3 s
    i = noise * rng.standard_normal((n, 2))
    contact = np.zeros(n, dtype=int)
    starts = [2000, 6000, 9000, 13000, 17000]
    for a in starts:
        i[a : a + 38, 1] += 1.0
        contact[a : a + 38] = 1
    res = det.detect(np.zeros((n, 1)), i)
    np.testing.assert_allclose(res.s, i)
    ev = evaluate_detection(res.alarm, contact, t)
    assert ev["detection_rate"] == 1.0
    # a 1 A step is ~10 sigma: the first sample already exceeds; persistence 2 adds one T
    assert ev["median_latency"] == pytest.approx(T)
    assert ev["false_alarms"] == 0  # two noise samples in a row above ~4.3 sigma: ~never
    intervals = res.intervals(t)
    assert len(intervals) == 5
    assert all(iv["joint"] == 2 for iv in intervals)
    for iv, a in zip(intervals, starts, strict=True):
        assert iv["start"] == pytest.approx(t[a + 1])
    # merging: the gaps between the alarm runs are 3964, 2964, 3964, 3964 samples
    assert len(res.intervals(t, merge_gap=2900 * T)) == 5
    merged = res.intervals(t, merge_gap=3000 * T)  # joins the runs at 6000 and 9000
    assert len(merged) == 4
    assert merged[1]["start"] == intervals[1]["start"] and merged[1]["end"] == intervals[2]["end"]
    assert len(res.intervals(t, merge_gap=4000 * T)) == 1


def test_monitoring_signal_validates_shapes() -> None:
    np.testing.assert_allclose(monitoring_signal([[1.0, 2.0]], [[0.5, 3.0]]), [[0.5, -1.0]])
    with pytest.raises(ValueError, match="same shape"):
        monitoring_signal(np.zeros((3, 2)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="NaN"):
        monitoring_signal([[np.nan, 0.0]], [[0.0, 0.0]])
    with pytest.raises(ValueError, match="rule"):
        CollisionDetector(_KnownEstimator(0.1), rule="median")

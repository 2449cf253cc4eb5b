"""Interval statistics (:mod:`mcpilco.models.stats`) against SciPy and analytic cases."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats as sps

from mcpilco.models.stats import Z95, bootstrap_interval, iqm, wilson_interval


@pytest.mark.parametrize("k,n", [(0, 10), (3, 10), (10, 10), (17, 20), (1, 1), (50, 200)])
def test_wilson_matches_scipy(k: int, n: int) -> None:
    """SciPy's Wilson interval uses z = 1.95996...; Z95 = 1.96 moves the ends by < 1e-4."""
    ref = sps.binomtest(k, n).proportion_ci(method="wilson")
    lo, hi = wilson_interval(k, n)
    assert lo == pytest.approx(ref.low, abs=1e-4) and hi == pytest.approx(ref.high, abs=1e-4)


def test_wilson_rejects_bad_counts() -> None:
    with pytest.raises(ValueError, match="trials"):
        wilson_interval(0, 0)
    with pytest.raises(ValueError, match="successes"):
        wilson_interval(4, 3)


@pytest.mark.parametrize("n", [4, 7, 10, 21])
def test_iqm_matches_scipy_trim_mean(n: int) -> None:
    x = np.random.default_rng(n).normal(size=n)
    assert iqm(x) == pytest.approx(sps.trim_mean(x, 0.25))


def test_bootstrap_of_the_mean_matches_the_normal_interval() -> None:
    """For the mean of n = 400 normal values the bootstrap interval is mean +- Z95 s / sqrt(n)."""
    x = np.random.default_rng(1).normal(3.0, 2.0, size=400)
    lo, hi = bootstrap_interval(x, "mean", resamples=4000)
    half = Z95 * x.std(ddof=1) / np.sqrt(x.size)
    assert lo == pytest.approx(x.mean() - half, abs=0.15 * half)
    assert hi == pytest.approx(x.mean() + half, abs=0.15 * half)


def test_bootstrap_median_brackets_and_drops_nan() -> None:
    x = [1.0, 2.0, np.nan, 3.0, 4.0, 100.0]
    lo, hi = bootstrap_interval(x, "median")
    assert 1.0 <= lo <= 3.0 <= hi <= 100.0
    assert bootstrap_interval([5.0], "iqm") == (5.0, 5.0)
    with pytest.raises(ValueError, match="statistic"):
        bootstrap_interval(x, "mode")

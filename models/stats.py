r"""The interval statistics every layer reports with: one 95 % quantile, Wilson intervals for
rates, percentile-bootstrap intervals over seeds for medians and interquartile means.

* :data:`Z95`: the two-sided 95 % quantile of the standard normal, :math:`z_{0.975}`, as the
  thesis writes it (1.96). A 95 % interval of a Gaussian estimate is
  :math:`\hat\theta \pm z_{0.975}\,\sigma`.
* :func:`wilson_interval`: the 95 % Wilson score interval of a rate :math:`k/n`,

  .. math::

     \frac{\hat p + z^2/2n \pm z\sqrt{\hat p(1-\hat p)/n + z^2/4n^2}}{1 + z^2/n},

  which stays inside :math:`[0, 1]` and is sensible at :math:`k = 0` or :math:`k = n` where the
  normal approximation collapses to a point.
* :func:`mad_std`: the standard deviation of a normal sample from its median absolute
  deviation, :math:`1.4826\,\mathrm{median}|x - \mathrm{median}\,x|`, which the rare
  outliers (jumps at file boundaries, impacts) do not move.
* :func:`bootstrap_interval`: the percentile bootstrap of a statistic (median, :func:`iqm`,
  mean) over independent units, the seeds (rliable's convention, Agarwal et al. 2021: a run is
  the unit, never a time step or an episode of the same run).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

# Two-sided 95 % standard-normal quantile z_0.975, rounded as the thesis writes it.
Z95 = 1.96

# Median absolute deviation of a normal variable over its standard deviation, inverted.
MAD_TO_STD = 1.4826

# Bootstrap resamples of bootstrap_interval (the percentile ends move by < 1 % of the
# interval's width between repeated draws at this count for 10-100 seeds).
BOOTSTRAP_RESAMPLES = 2000


def mad_std(x: np.ndarray, axis: int = 0) -> np.ndarray:
    """Robust standard deviation along ``axis``: :data:`MAD_TO_STD` times the median absolute
    deviation from the median (module docstring)."""
    x = np.asarray(x, dtype=np.float64)
    med = np.median(x, axis=axis, keepdims=True)
    return MAD_TO_STD * np.median(np.abs(x - med), axis=axis)


def wilson_interval(successes: int, trials: int, z: float = Z95) -> tuple[float, float]:
    """95 % Wilson score interval ``(low, high)`` of the rate ``successes / trials``.

    Raises ValueError when ``trials`` < 1 or ``successes`` is outside ``0..trials``.
    """
    if trials < 1:
        raise ValueError(f"wilson_interval: trials must be >= 1, got {trials}")
    if not 0 <= successes <= trials:
        raise ValueError(f"wilson_interval: successes must be in 0..{trials}, got {successes}")
    p = successes / trials
    z2 = z * z
    centre = p + z2 / (2 * trials)
    half = z * np.sqrt(p * (1 - p) / trials + z2 / (4 * trials * trials))
    denom = 1 + z2 / trials
    return float(max(0.0, (centre - half) / denom)), float(min(1.0, (centre + half) / denom))


def iqm(values: Sequence[float] | np.ndarray) -> float:
    """Interquartile mean: the mean of the middle 50 % of ``values`` (the lowest and highest
    25 % dropped, ``floor(n/4)`` values each side as ``scipy.stats.trim_mean(x, 0.25)``)."""
    x = np.sort(np.asarray(values, dtype=float))
    if x.size == 0:
        raise ValueError("iqm: no values")
    cut = x.size // 4
    return float(x[cut : x.size - cut].mean())


# The statistics bootstrap_interval accepts by name.
STATISTICS: dict[str, Callable[[np.ndarray], float]] = {
    "median": lambda x: float(np.median(x)),
    "iqm": iqm,
    "mean": lambda x: float(np.mean(x)),
}


def bootstrap_interval(
    values: Sequence[float] | np.ndarray,
    statistic: str | Callable[[np.ndarray], float] = "median",
    *,
    level: float = 0.95,
    resamples: int = BOOTSTRAP_RESAMPLES,
    seed: int = 0,
) -> tuple[float, float]:
    """Percentile-bootstrap ``level`` interval ``(low, high)`` of ``statistic`` over ``values``,
    one value per seed (the seeds are resampled with replacement, ``resamples`` times, from a
    generator seeded with ``seed`` so that a report is reproducible).

    ``statistic``: ``"median"``, ``"iqm"``, ``"mean"`` or a function of a 1-D array. NaN values
    (a seed without a result) are dropped; one value gives the point ``(v, v)``. Raises
    ValueError on no finite value or an unknown statistic name.
    """
    fn = STATISTICS.get(statistic) if isinstance(statistic, str) else statistic
    if fn is None:
        raise ValueError(f"bootstrap_interval: statistic must be one of {sorted(STATISTICS)}")
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        raise ValueError("bootstrap_interval: no finite value")
    if x.size == 1:
        return float(x[0]), float(x[0])
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, x.size, size=(resamples, x.size))
    stats = np.array([fn(x[row]) for row in idx])
    alpha = (1 - level) / 2
    return float(np.quantile(stats, alpha)), float(np.quantile(stats, 1 - alpha))

"""Compare a model with measurements and see where it fails: metrics and residual analysis.

Metrics per joint ``j`` (``y`` measured, ``y_hat`` predicted, ``N`` samples)
    ``nMSE = mean((y - y_hat)^2) / var(y)`` (thesis 3.4.1), ``RMSE = sqrt(mean((y -
    y_hat)^2))``, ``fit = 100 (1 - ||y - y_hat|| / ||y - mean(y)||)`` % (NRMSE fit, as in
    system-identification toolboxes).
Residual ``e = y - y_hat`` analysis
    * binned against ``qd_j``, ``q_j``, ``qdd_j`` (equal-count bins): mean ``+-`` 1.96
      ``sd / sqrt(count)`` (95% interval of the bin mean);
    * averaged around velocity reversals of joint ``j`` (sign changes of ``qd_j``), ``+-W``
      samples, separately for ``+ -> -`` and ``- -> +`` reversals;
    * autocorrelation ``rho_k`` up to lag ``L`` with the whiteness band ``+-1.96 / sqrt(N)``
      (a white residual stays inside for ~95% of the lags);
    * in words: the state region (bin) whose mean residual is largest relative to the noise
      std ``sigma_j`` of the model, and the worst time windows (rms of ``e`` over ``window``
      seconds), e.g. ``"joint 2, qd in [-0.05, 0.04] rad/s: mean residual 2.9 N·m, 14x
      noise"``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mcpilco.models.diagnosis.data import Trajectories

FloatArray = NDArray[np.float64]

__all__ = [
    "JointResiduals",
    "ResidualReport",
    "fit_metrics",
    "metrics_table",
    "noise_floor",
    "residual_report",
]


def noise_floor(traj: Trajectories, y_hat: FloatArray | None = None) -> FloatArray:
    """``(n,)`` measurement-noise std from first differences, independent of any model:
    ``sigma = 1.4826 MAD(diff(e)) / sqrt(2)`` per segment, pooled (``e = y - y_hat``, or
    ``y``). Smooth signals and model errors nearly cancel in ``diff``; white noise of std
    ``sigma`` gives ``diff`` std ``sqrt(2) sigma``; the MAD ignores the rare jumps."""
    e = traj.y if y_hat is None else traj.y - y_hat
    d = np.concatenate([np.diff(e[a:b], axis=0) for a, b in traj.segments if b - a > 2])
    mad = np.median(np.abs(d - np.median(d, axis=0)), axis=0)
    return 1.4826 * mad / np.sqrt(2.0)


STATE_UNITS = {"q": ("rad", "m"), "qd": ("rad/s", "m/s"), "qdd": ("rad/s²", "m/s²")}


def fit_metrics(y: FloatArray, y_hat: FloatArray) -> dict[str, FloatArray]:
    """``{"nmse", "rmse", "fit_pct"}`` per joint, each ``(n,)`` (module docstring)."""
    y = np.asarray(y, dtype=np.float64)
    y_hat = np.asarray(y_hat, dtype=np.float64)
    if y.shape != y_hat.shape:
        raise ValueError(f"shapes differ: measured {y.shape}, predicted {y_hat.shape}")
    err = y - y_hat
    mse = np.mean(err**2, axis=0)
    var = np.var(y, axis=0)
    var = np.where(var > 0, var, np.nan)
    dev = np.linalg.norm(y - y.mean(axis=0), axis=0)
    dev = np.where(dev > 0, dev, np.nan)
    return {
        "nmse": mse / var,
        "rmse": np.sqrt(mse),
        "fit_pct": 100.0 * (1.0 - np.linalg.norm(err, axis=0) / dev),
    }


@dataclass
class JointResiduals:
    """Residual analysis of one joint (arrays for plotting, module docstring)."""

    joint: int
    noise_std: float
    bins: dict[str, dict[str, FloatArray]] = field(default_factory=dict)
    reversal_lags: FloatArray = field(default_factory=lambda: np.zeros(0))
    reversal_up: FloatArray = field(default_factory=lambda: np.zeros(0))
    reversal_down: FloatArray = field(default_factory=lambda: np.zeros(0))
    n_reversals: tuple[int, int] = (0, 0)
    acf: FloatArray = field(default_factory=lambda: np.zeros(0))
    whiteness_band: float = 0.0
    outside_fraction: float = 0.0
    findings: list[tuple[float, str]] = field(default_factory=list)


@dataclass
class ResidualReport:
    """All joints' residual analyses plus the findings in words, worst first."""

    model_name: str
    joints: list[JointResiduals]
    windows: list[tuple[float, str]]

    def findings(self, top: int = 5) -> list[str]:
        items = sorted(
            [f for jr in self.joints for f in jr.findings] + self.windows, key=lambda x: -x[0]
        )
        return [text for _, text in items[:top]]

    def text(self, top: int = 5) -> str:
        lines = [f"where {self.model_name} fails (worst first):"]
        lines += [f"  - {t}" for t in self.findings(top)]
        lines.append("  residual whiteness (fraction of lags 1..L outside +-1.96/sqrt(N)):")
        lines.append(
            "    "
            + ", ".join(f"joint {jr.joint}: {100 * jr.outside_fraction:.0f}%" for jr in self.joints)
        )
        return "\n".join(lines)


def _bins(x: FloatArray, e: FloatArray, n_bins: int) -> dict[str, FloatArray]:
    edges = np.unique(np.quantile(x, np.linspace(0, 1, n_bins + 1)))
    if edges.size < 2:
        edges = np.array([x.min(), x.max() + 1e-12])
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, edges.size - 2)
    k = edges.size - 1
    count = np.bincount(idx, minlength=k).astype(float)
    s = np.bincount(idx, weights=e, minlength=k)
    s2 = np.bincount(idx, weights=e**2, minlength=k)
    c = np.maximum(count, 1)
    mean = s / c
    sd = np.sqrt(np.maximum(s2 / c - mean**2, 0.0))
    rms = np.sqrt(s2 / c)
    return {
        "lo": edges[:-1],
        "hi": edges[1:],
        "centre": 0.5 * (edges[:-1] + edges[1:]),
        "mean": mean,
        "ci95": 1.96 * sd / np.sqrt(c),
        "rms": rms,
        "count": count,
    }


def _acf(e: FloatArray, segments: list[tuple[int, int]], max_lag: int) -> FloatArray:
    num = np.zeros(max_lag + 1)
    den = 0.0
    for a, b in segments:
        x = e[a:b] - e[a:b].mean()
        den += float(x @ x)
        for k in range(min(max_lag, b - a - 1) + 1):
            num[k] += float(x[: b - a - k] @ x[k:])
    return num / den if den > 0 else num


def residual_report(
    traj: Trajectories,
    y_hat: FloatArray,
    noise_std: FloatArray | None,
    joint_types: str,
    *,
    model_name: str = "model",
    n_bins: int = 10,
    reversal_window: int = 30,
    max_lag: int = 50,
    window_s: float = 0.5,
    unit: str | None = None,
) -> ResidualReport:
    """Residual analysis of ``traj.y - y_hat`` (module docstring).

    Args:
        traj: measured trajectories.
        y_hat: ``(N, n)`` predicted output.
        noise_std: ``(n,)`` the "x noise" yardstick; ``None``: :func:`noise_floor` (the
            measurement noise, not the model's fitted noise, which absorbs model errors).
        joint_types: e.g. ``"RRPR"`` (units in the words).
    """
    e_all = traj.y - y_hat
    if noise_std is None:
        noise_std = noise_floor(traj, y_hat)
    segs = traj.segments
    dt = traj.sample_time
    out, windows = [], []
    for j in range(traj.n_joints):
        prism = joint_types[j] == "P"
        force = unit or ("N" if prism else "N·m")
        e = e_all[:, j]
        sigma = float(noise_std[j]) if noise_std[j] > 0 else float(np.std(e)) or 1.0
        jr = JointResiduals(joint=j + 1, noise_std=sigma)
        for name in ("qd", "q", "qdd"):
            x = getattr(traj, name)[:, j]
            b = _bins(x, e, n_bins)
            jr.bins[name] = b
            score = np.abs(b["mean"]) / sigma
            significant = np.abs(b["mean"]) > b["ci95"]
            if np.any(significant):
                k = int(np.argmax(np.where(significant, score, -1)))
                su = STATE_UNITS[name][int(prism)]
                jr.findings.append(
                    (
                        float(score[k]),
                        f"joint {j + 1}, {name}{j + 1} in [{b['lo'][k]:.3g}, {b['hi'][k]:.3g}] "
                        f"{su}: mean residual {b['mean'][k]:+.3g} {force} "
                        f"(rms {b['rms'][k]:.3g}), {score[k]:.1f}x noise",
                    )
                )
        # velocity reversals
        lags = np.arange(-reversal_window, reversal_window + 1)
        up, down = [], []
        for a, b in segs:
            s = np.sign(traj.qd[a:b, j])
            rev = np.flatnonzero((s[:-1] != 0) & (s[1:] != 0) & (s[:-1] != s[1:])) + a + 1
            for r in rev:
                if r - reversal_window < a or r + reversal_window >= b:
                    continue
                w = e[r + lags]
                (up if traj.qd[r, j] > 0 else down).append(w)
        jr.reversal_lags = lags * dt
        jr.reversal_up = np.mean(up, axis=0) if up else np.zeros(lags.size)
        jr.reversal_down = np.mean(down, axis=0) if down else np.zeros(lags.size)
        jr.n_reversals = (len(up), len(down))
        if up and down:
            jump = float(np.max(np.abs(jr.reversal_up - jr.reversal_down)))
            if jump > 3 * sigma:
                jr.findings.append(
                    (
                        jump / sigma,
                        f"joint {j + 1}, velocity reversals ({len(up) + len(down)}): residual "
                        f"differs by {jump:.3g} {force} between - to + and + to - reversals, "
                        f"{jump / sigma:.1f}x noise (friction-like)",
                    )
                )
        # whiteness
        jr.acf = _acf(e, segs, max_lag)
        jr.whiteness_band = 1.96 / np.sqrt(max(traj.n_samples, 1))
        jr.outside_fraction = float(np.mean(np.abs(jr.acf[1:]) > jr.whiteness_band))
        # worst time windows
        w = max(int(round(window_s / dt)), 1)
        best: list[tuple[float, int, int]] = []
        for s_idx, (a, b) in enumerate(segs):
            if b - a < w:
                continue
            c = np.concatenate([[0.0], np.cumsum(e[a:b] ** 2)])
            rms = np.sqrt((c[w:] - c[:-w]) / w)
            k = int(np.argmax(rms))
            best.append((float(rms[k]), a + k, s_idx))
        for rms, start, s_idx in sorted(best, reverse=True)[:1]:
            t0, t1 = traj.t[start], traj.t[min(start + w, traj.n_samples - 1)]
            windows.append(
                (
                    rms / sigma,
                    f"joint {j + 1}, t = {t0:.2f}-{t1:.2f} s of {traj.names[s_idx]}: residual rms "
                    f"{rms:.3g} {force}, {rms / sigma:.1f}x noise",
                )
            )
        out.append(jr)
    return ResidualReport(model_name, out, windows)


def metrics_table(rows: list[tuple[str, str, dict[str, Any]]], n_joints: int) -> str:
    """Fixed-width table of :func:`fit_metrics` rows ``(version, set, metrics)``."""
    head = f"{'model':<6} {'data':<9} {'joint':>5} {'nMSE':>9} {'RMSE':>10} {'fit %':>7}"
    lines = [head, "-" * len(head)]
    for version, which, m in rows:
        for j in range(n_joints):
            lines.append(
                f"{version:<6} {which:<9} {j + 1:>5} {m['nmse'][j]:>9.2e} {m['rmse'][j]:>10.3g} "
                f"{m['fit_pct'][j]:>7.2f}"
            )
    return "\n".join(lines)

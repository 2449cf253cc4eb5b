"""Figures (matplotlib, Agg, PNG) and the Rerun recording of the diagnosis loop.

* :func:`plot_time`: measured vs predicted output per joint with the GP ``+-2 sigma`` band
  (``sigma^2`` = latent variance + noise variance: where a new measurement should fall).
* :func:`plot_residuals`: per joint, the residual binned against ``qd``, ``q``, ``qdd``
  (95% intervals), around velocity reversals, its autocorrelation with the 99% whiteness
  band, and its cross-correlation with ``q``, ``qd`` and the predicted torque with their 99%
  bands (:mod:`.analysis`).
* :func:`plot_waterfall`: held-out RMSE per version and joint (bars) over the noise floor.
* :func:`write_rerun`: ``.rrd`` with ``/joint/j{k}/tau/{measured, v0, v1, ...}`` and
  ``/joint/j{k}/residual/{v0, v1, ...}``, and a blueprint with one time-series view per joint.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from mcpilco.models.diagnosis.analysis import ResidualReport
from mcpilco.models.robot_data import Trajectories

FloatArray = NDArray[np.float64]

__all__ = ["plot_residuals", "plot_time", "plot_waterfall", "write_rerun"]


def _plt():  # noqa: ANN202
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: str | Path, dpi: int) -> Path:  # noqa: ANN001
    """Write ``fig`` to ``path`` (parent folders created) and close it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    _plt().close(fig)
    return path


def plot_time(
    traj: Trajectories,
    mean: FloatArray,
    var: FloatArray,
    noise_std: FloatArray,
    path: str | Path,
    title: str = "",
    segment: int = 0,
) -> Path:
    """Measured vs predicted on one segment, ``+-2 sigma`` band; returns the PNG path."""
    plt = _plt()
    a, b = traj.segments[segment]
    n = traj.n_joints
    fig, axes = plt.subplots(n, 1, figsize=(10, 1.9 * n + 0.6), sharex=True, squeeze=False)
    t = traj.t[a:b]
    for j in range(n):
        ax = axes[j, 0]
        sd = np.sqrt(var[a:b, j] + noise_std[j] ** 2)
        ax.fill_between(
            t, mean[a:b, j] - 2 * sd, mean[a:b, j] + 2 * sd, color="C1", alpha=0.3, lw=0
        )
        ax.plot(t, traj.y[a:b, j], color="k", lw=0.8, label="measured")
        ax.plot(t, mean[a:b, j], color="C1", lw=1.0, label="predicted ±2σ")
        ax.set_ylabel(f"{traj.output}{j + 1}")
        if j == 0:
            ax.legend(loc="upper right", fontsize=8)
    axes[-1, 0].set_xlabel("t [s]")
    fig.suptitle(f"{title} ({traj.names[segment]})", fontsize=10)
    fig.tight_layout()
    return _save(fig, path, dpi=90)


def plot_residuals(report: ResidualReport, path: str | Path) -> Path:
    """Binned residuals, reversal averages, autocorrelation and cross-correlation with the
    inputs, one row per joint."""
    plt = _plt()
    n = len(report.joints)
    fig, axes = plt.subplots(n, 6, figsize=(19, 2.2 * n + 0.6), squeeze=False)
    for r, jr in enumerate(report.joints):
        for c, name in enumerate(("qd", "q", "qdd")):
            ax = axes[r, c]
            b = jr.bins[name]
            ax.errorbar(b["centre"], b["mean"], yerr=b["ci95"], fmt="o-", ms=3, lw=1)
            ax.axhline(0, color="k", lw=0.5)
            ax.axhspan(-jr.noise_std, jr.noise_std, color="0.85", lw=0)
            ax.set_xlabel(f"{name}{jr.joint}", fontsize=8)
            if c == 0:
                ax.set_ylabel(f"joint {jr.joint} residual")
        ax = axes[r, 3]
        ax.plot(jr.reversal_lags, jr.reversal_up, label=f"+→- ({jr.n_reversals[0]})")
        ax.plot(jr.reversal_lags, jr.reversal_down, label=f"-→+ ({jr.n_reversals[1]})")
        ax.axvline(0, color="k", lw=0.5)
        ax.set_xlabel("time from velocity reversal [s]", fontsize=8)
        ax.legend(fontsize=7)
        ax = axes[r, 4]
        lags = np.arange(jr.acf.size)
        ax.bar(lags[1:], jr.acf[1:], width=0.8)
        ax.axhline(jr.whiteness_band, color="r", ls="--", lw=0.8)
        ax.axhline(-jr.whiteness_band, color="r", ls="--", lw=0.8)
        ax.set_xlabel("lag [samples]", fontsize=8)
        ax.set_ylim(-1, 1)
        ax = axes[r, 5]
        for k, (name, test) in enumerate(jr.xcorr.items()):
            ax.plot(test.lags, test.r, color=f"C{k}", lw=1, label=f"{name}{jr.joint}")
            ax.axhline(test.band, color=f"C{k}", ls="--", lw=0.6)
            ax.axhline(-test.band, color=f"C{k}", ls="--", lw=0.6)
        ax.axvline(0, color="k", lw=0.5)
        ax.set_xlabel("lag [samples] (input leads >0)", fontsize=8)
        ax.set_ylim(-1, 1)
        if jr.xcorr:
            ax.legend(fontsize=7)
    fig.suptitle(f"residuals of {report.model_name}", fontsize=10)
    fig.tight_layout()
    return _save(fig, path, dpi=80)


def plot_waterfall(
    versions: Sequence[str],
    rmse: FloatArray,
    noise_std: FloatArray,
    path: str | Path,
    labels: Sequence[str] | None = None,
) -> Path:
    """Held-out RMSE ``(n_versions, n)`` as grouped bars per joint, relative to the noise
    floor ``noise_std`` (:func:`~.search.heldout_floor`), with the "at the floor" limit
    :data:`~.search.FLOOR_FACTOR`."""
    from mcpilco.models.diagnosis.search import FLOOR_FACTOR

    plt = _plt()
    rmse = np.asarray(rmse)
    k, n = rmse.shape
    fig, ax = plt.subplots(figsize=(2 + 1.3 * n, 3.6))
    width = 0.8 / k
    for v in range(k):
        ax.bar(
            np.arange(n) + (v - (k - 1) / 2) * width,
            rmse[v] / noise_std,
            width,
            label=labels[v] if labels else versions[v],
        )
    ax.axhline(1.0, color="k", ls="--", lw=0.8, label="noise floor")
    ax.axhline(FLOOR_FACTOR, color="r", ls=":", lw=0.8, label=f"{FLOOR_FACTOR:g}x floor")
    ax.set_yscale("log")
    ax.set_xticks(np.arange(n), [f"joint {j + 1}" for j in range(n)])
    ax.set_ylabel("held-out RMSE / noise floor")
    ax.legend(fontsize=7)
    ax.set_title("held-out error per model version")
    fig.tight_layout()
    return _save(fig, path, dpi=90)


def write_rerun(
    path: str | Path, traj: Trajectories, predictions: dict[str, FloatArray], segment: int = 0
) -> Path:
    """A Rerun ``.rrd``: measured and every version's prediction and residual per joint, on
    the timeline ``t`` (seconds) of one segment, with a blueprint (one view per joint)."""
    import rerun as rr
    import rerun.blueprint as rrb

    a, b = traj.segments[segment]
    t = traj.t[a:b]
    n = traj.n_joints
    rec = rr.RecordingStream("mcpilco_diagnosis")
    blueprint = rrb.Blueprint(
        rrb.Grid(
            *[
                rrb.TimeSeriesView(origin=f"/joint/j{j + 1}", name=f"joint {j + 1}")
                for j in range(n)
            ]
        ),
        collapse_panels=True,
    )
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rec.save(str(path), default_blueprint=blueprint)
    times = [rr.TimeColumn("t", duration=t)]
    for j in range(n):
        base = f"/joint/j{j + 1}"
        rec.send_columns(
            f"{base}/tau/measured",
            indexes=times,
            columns=rr.Scalars.columns(scalars=traj.y[a:b, j]),
        )
        for name, pred in predictions.items():
            rec.send_columns(
                f"{base}/tau/{name}",
                indexes=times,
                columns=rr.Scalars.columns(scalars=pred[a:b, j]),
            )
            rec.send_columns(
                f"{base}/residual/{name}",
                indexes=times,
                columns=rr.Scalars.columns(scalars=traj.y[a:b, j] - pred[a:b, j]),
            )
    rec.flush()
    rec.disconnect()
    return path

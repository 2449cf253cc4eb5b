"""Figure of a detection run on a log: currents, monitoring ratio, alarms, contacts."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mcpilco.models.collision.detector import Detection, runs
from mcpilco.models.robot_data import Trajectories


def plot_detection(ds: Trajectories, result: Detection, joint: int, path: Path) -> None:
    """Two panels over time, saved to ``path``: the measured current of ``joint`` (1-based)
    with its estimate, and ``|s_j| / sigma_CD,j`` of every joint against the threshold 1.
    Alarms are shaded red, logged ground-truth contacts grey."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = ds.t
    j = joint - 1
    fig, axes = plt.subplots(2, 1, figsize=(10, 5.5), sharex=True)
    axes[0].plot(t, ds.i[:, j], color="0.4", lw=0.6, label=f"i{joint} measured")
    axes[0].plot(t, result.i_hat[:, j], color="C0", lw=0.9, label=f"i{joint} estimate")
    axes[0].set_ylabel("[A]")
    ratio = np.abs(result.s) / result.thresholds
    for k in range(ratio.shape[1]):
        axes[1].plot(t, ratio[:, k], lw=0.6, label=f"joint {k + 1}")
    axes[1].axhline(1.0, color="C3", ls="--", lw=1, label="threshold")
    axes[1].set_ylabel("|s_j| / sigma_CD,j")
    for a, b in runs(result.alarm):
        for ax in axes:
            ax.axvspan(t[a], t[b], color="C3", alpha=0.25, lw=0)
    if ds.contact is not None:
        for a, b in runs(ds.contact.astype(bool)):
            axes[0].axvspan(t[a], t[b], color="0.8", zorder=0, lw=0)
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=7, ncol=4)
    axes[1].set_xlabel("t [s] (alarms red; ground-truth contact grey, if logged)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)

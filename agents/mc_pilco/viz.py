"""Plots (PNG, matplotlib Agg) and the Rerun recording (``run.rrd``) of an MC-PILCO run.

Per trial ``k`` the loop stores (see :mod:`mcpilco.agents.mc_pilco.loop`):

``particles (M, H+1, 4)``
    particle trajectories predicted by the GP model with the final policy of trial ``k``.
``real (H+1, 4)``
    the true trajectory measured when that policy ran on the env.
``opt_costs (K,)``
    expected cost ``J^`` at each optimisation step.
``gp_rmse (2,)``
    one-step RMSE of ``E[Delta q_dot]`` of the model fitted before trial ``k`` on the data
    of trial ``k`` (out of sample).

The Rerun file is rebuilt from these arrays after every trial (through a temporary file and
``os.replace``), so a resumed run has one consistent recording. Its blueprint (built in
code) opens with: x and theta particle plots (a ``trial`` timeline selects the trial), the
expected cost over optimisation steps, and the GP one-step error and trial metrics.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

STATE_LABELS = {0: ("x", "cart position x [m]"), 2: ("theta", "pole angle theta [rad]")}


def plot_trial_particles(
    path: str | os.PathLike,
    particles: np.ndarray,
    real: np.ndarray,
    dt: float,
    title: str = "",
) -> Path:
    """PNG like thesis Fig. 5.3: particles (lines) of x and theta vs the real trajectory (dots)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    t = np.arange(real.shape[0]) * dt
    fig, axes = plt.subplots(2, 1, figsize=(7, 5), sharex=True)
    for ax, (idx, (_, label)) in zip(axes, STATE_LABELS.items(), strict=True):
        ax.plot(t, particles[:, :, idx].T, color="tab:blue", alpha=0.15, linewidth=0.7)
        ax.plot(t, real[:, idx], "o", color="black", markersize=2.5, label="real")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[1].axhline(np.pi, color="gray", linestyle="--", linewidth=0.8)
    axes[1].axhline(-np.pi, color="gray", linestyle="--", linewidth=0.8)
    axes[0].legend(loc="upper left", fontsize=8)
    axes[1].set_xlabel("time [s]")
    axes[0].set_title(title or "particle rollout (lines) vs real trajectory (dots)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_optimisation(
    path: str | os.PathLike, opt_costs: Sequence[np.ndarray], labels: Sequence[str]
) -> Path:
    """PNG of the expected cost ``J^`` vs optimisation step, one line per trial."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    fig, ax = plt.subplots(figsize=(7, 3.5))
    for c, lab in zip(opt_costs, labels, strict=True):
        ax.plot(np.arange(len(c)), c, label=lab)
    ax.set_xlabel("optimisation step")
    ax.set_ylabel("expected cumulative cost J")
    ax.grid(alpha=0.3)
    if labels:
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _blueprint():
    import rerun.blueprint as rrb

    bounds = rrb.VisualBounds2D(x_range=[0.0, 3.0], y_range=[-4.0, 4.0])
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial2DView(
                    origin="/particles/x",
                    name="x [m] vs t [s]: particles / real",
                    visual_bounds=bounds,
                ),
                rrb.Spatial2DView(
                    origin="/particles/theta",
                    name="theta [rad] vs t [s]: particles / real",
                    visual_bounds=bounds,
                ),
            ),
            rrb.Vertical(
                rrb.TimeSeriesView(origin="/optimisation", name="expected cost vs opt. step"),
                rrb.TimeSeriesView(origin="/gp", name="GP one-step RMSE"),
                rrb.TimeSeriesView(origin="/trial", name="trial metrics"),
            ),
        ),
        rrb.TimePanel(state="collapsed"),
        collapse_panels=True,
    )


def write_rerun_recording(
    path: str | os.PathLike,
    trials: Sequence[dict[str, Any]],
    dt: float,
    application_id: str = "mcpilco",
    recording_id: str | None = None,
) -> Path:
    """Write ``run.rrd`` from the per-trial arrays (atomically).

    Args:
        path: output ``.rrd`` path.
        trials: per trial a dict with ``index``, ``particles`` (M, H+1, 4) or None,
            ``real`` (H+1, 4), ``opt_costs`` (K,) or None, ``gp_rmse`` (2,) or None and the
            scalar metrics ``cost``, ``time_upright``, ``success``.
        dt: control period [s] (time axis of the particle plots).
    """
    import rerun as rr

    path = Path(path)
    tmp = path.with_name(path.name + ".tmp.rrd")
    rec = rr.RecordingStream(application_id, recording_id=recording_id)
    rec.save(tmp, default_blueprint=_blueprint())
    step0 = 0
    for tr in trials:
        k = int(tr["index"])
        rec.set_time("trial", sequence=k)
        real = np.asarray(tr["real"], dtype=np.float64)
        t = np.arange(real.shape[0]) * dt
        parts = tr.get("particles")
        for idx, (name, _) in STATE_LABELS.items():
            if parts is not None:
                strips = np.stack([np.broadcast_to(t, parts.shape[:2]), parts[:, :, idx]], -1)
                rec.log(
                    f"particles/{name}/model",
                    rr.LineStrips2D(strips, colors=[70, 130, 230, 60], radii=0.004),
                )
            else:
                rec.log(f"particles/{name}/model", rr.Clear(recursive=False))
            pts = np.stack([t, real[:, idx]], -1)
            rec.log(
                f"particles/{name}/real",
                rr.Points2D(pts, colors=[0, 0, 0, 255], radii=0.02),
            )
        for key in ("cost", "time_upright", "mean_abs_x"):
            if tr.get(key) is not None:
                rec.log(f"trial/{key}", rr.Scalars([float(tr[key])]))
        if tr.get("success") is not None:
            rec.log("trial/success", rr.Scalars([float(bool(tr["success"]))]))
        if tr.get("gp_rmse") is not None:
            rmse = np.asarray(tr["gp_rmse"], dtype=np.float64)
            rec.log("gp/one_step_rmse/delta_x_dot", rr.Scalars([rmse[0]]))
            rec.log("gp/one_step_rmse/delta_theta_dot", rr.Scalars([rmse[1]]))
        costs = tr.get("opt_costs")
        if costs is not None and len(costs):
            steps = step0 + np.arange(len(costs))
            rec.send_columns(
                "optimisation/expected_cost",
                indexes=[rr.TimeColumn("opt_step", sequence=steps)],
                columns=rr.Scalars.columns(scalars=np.asarray(costs, dtype=np.float64)),
            )
            step0 += len(costs)
    rec.flush()
    rec.disconnect()
    os.replace(tmp, path)
    return path

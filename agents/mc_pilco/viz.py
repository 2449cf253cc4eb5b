"""Plots (PNG, matplotlib Agg) and the Rerun recording (``run.rrd``) of an MC-PILCO run.

Per trial ``k`` the loop stores (see :mod:`mcpilco.agents.mc_pilco.loop`):

``particles (M, H+1, n)``
    particle trajectories predicted by the GP model with the final policy of trial ``k``.
``real (H+1, n)``
    the true trajectory measured when that policy ran on the env.
``opt_costs (K,)``
    expected cost ``J^`` at each optimisation step.
``gp_rmse (m,)``
    one-step RMSE of ``E[Delta]`` of the model fitted before trial ``k`` on the data
    of trial ``k`` (out of sample), per GP output.
``excluded (H,)`` (optional)
    the transitions ``x_t -> x_{t+1}`` of the real trajectory left out of the dynamics data
    (they touch one of the task's declared limits, or a push filter marked them); drawn as
    red marks at ``x_t``.
``contact (H,)`` (optional)
    the transitions during which the env pushed the system (its own ground truth); drawn as
    an orange band.

A state that a cost term tracks against another state (``reference``) gets that state's
real trajectory drawn in its panel (green line): a tracking task's joint against its
reference.

The Rerun file is rebuilt from these arrays after every trial (through a temporary file and
``os.replace``), so a resumed run has one consistent recording. Its blueprint (built in
code) opens with one particle plot per state coordinate (a ``trial`` timeline selects the
trial), the expected cost over optimisation steps, and the GP one-step error and trial
metrics.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.models.safe_io import create_new


def plot_trial_particles(
    path: str | os.PathLike,
    particles: np.ndarray,
    real: np.ndarray,
    dt: float,
    state_names: Sequence[str],
    title: str = "",
    references: Mapping[str, str] | None = None,
    excluded: np.ndarray | None = None,
    contact: np.ndarray | None = None,
) -> Path:
    """PNG like thesis Fig. 5.3: particles (lines) of every state coordinate vs the real
    trajectory (dots), one panel per coordinate; ``references`` (state -> the state it
    tracks) adds the tracked state's real trajectory, ``excluded`` (H,) marks the real
    states whose transitions were left out of the dynamics data, ``contact`` (H,) shades
    the transitions during which the system was pushed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    n = real.shape[1]
    cols = 1 if n <= 4 else 2
    rows = -(-n // cols)
    t = np.arange(real.shape[0]) * dt
    tp = np.arange(particles.shape[1]) * dt  # the model's horizon (the real episode may end early)
    fig, axes = plt.subplots(rows, cols, figsize=(7 * cols, 1.9 * rows + 1), sharex=True)
    axes = np.atleast_1d(axes).reshape(-1)
    for idx in range(n):
        ax = axes[idx]
        ax.plot(tp, particles[:, :, idx].T, color="tab:blue", alpha=0.15, linewidth=0.7)
        ax.plot(t, real[:, idx], "o", color="black", markersize=2.5, label="real")
        ref = (references or {}).get(state_names[idx])
        if ref is not None:
            j = list(state_names).index(ref)
            ax.plot(t, real[:, j], color="tab:green", linewidth=1.2, label=f"reference ({ref})")
        if excluded is not None and np.any(excluded):
            at = np.flatnonzero(excluded)
            ax.plot(
                t[at], real[at, idx], "x", color="tab:red", markersize=5, label="not in GP data"
            )
        for k, (a, b) in enumerate(_runs(contact)):
            ax.axvspan(t[a], t[b], color="tab:orange", alpha=0.2, label=None if k else "push")
        ax.set_ylabel(state_names[idx])
        ax.grid(alpha=0.3)
    for ax in axes[n:]:
        ax.set_visible(False)
    axes[0].legend(loc="upper left", fontsize=8)
    axes[min(n, len(axes)) - 1].set_xlabel("time [s]")
    axes[0].set_title(title or "particle rollout (lines) vs real trajectory (dots)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _runs(mask: np.ndarray | None) -> list[tuple[int, int]]:
    """``(first, last + 1)`` of each run of true entries of a transition mask (H,): the
    state indices a run of transitions spans."""
    if mask is None:
        return []
    m = np.concatenate([[False], np.asarray(mask, dtype=bool), [False]])
    edges = np.flatnonzero(np.diff(m.astype(np.int8)))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


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


def _blueprint(state_names: Sequence[str], duration: float):
    import rerun.blueprint as rrb

    bounds = rrb.VisualBounds2D(x_range=[0.0, duration], y_range=[-4.0, 4.0])
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                *(
                    rrb.Spatial2DView(
                        origin=f"/particles/{name}",
                        name=f"{name} vs t [s]: particles / real",
                        visual_bounds=bounds,
                    )
                    for name in state_names
                )
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
    state_names: Sequence[str],
    output_names: Sequence[str],
    application_id: str = "mcpilco",
    recording_id: str | None = None,
    references: Mapping[str, str] | None = None,
) -> Path:
    """Write ``run.rrd`` from the per-trial arrays (atomically).

    Args:
        path: output ``.rrd`` path.
        trials: per trial a dict with ``index``, ``particles`` (M, H+1, n) or None,
            ``real`` (H+1, n), ``opt_costs`` (K,) or None, ``gp_rmse`` (m,) or None and the
            scalar metrics ``cost``, ``time_in_goal``, ``success``.
        dt: control period [s] (time axis of the particle plots).
        state_names: the task's state names (one plot each).
        output_names: the GP outputs' names (one error series each).
        references: state -> the state it tracks (its real trajectory is drawn in the
            state's plot, ``particles/<state>/reference``); the transitions of ``excluded``
            (a trial's optional (H,) mask) are drawn at ``particles/<state>/excluded``, the
            transitions of ``contact`` (pushes) at ``particles/<state>/push``.
    """
    import rerun as rr

    path = Path(path)
    tmp = path.with_name(path.name + ".tmp.rrd")
    os.close(create_new(tmp))  # a link at the temporary path is refused, never written through
    rec = rr.RecordingStream(application_id, recording_id=recording_id)
    longest = max((len(tr["real"]) for tr in trials), default=1)
    rec.save(tmp, default_blueprint=_blueprint(state_names, longest * dt))
    step0 = 0
    for tr in trials:
        k = int(tr["index"])
        rec.set_time("trial", sequence=k)
        real = np.asarray(tr["real"], dtype=np.float64)
        t = np.arange(real.shape[0]) * dt
        parts = tr.get("particles")
        for idx, name in enumerate(state_names):
            if parts is not None:
                tp = np.arange(parts.shape[1]) * dt
                strips = np.stack([np.broadcast_to(tp, parts.shape[:2]), parts[:, :, idx]], -1)
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
            ref = (references or {}).get(name)
            if ref is not None:
                line = np.stack([t, real[:, list(state_names).index(ref)]], -1)
                rec.log(
                    f"particles/{name}/reference",
                    rr.LineStrips2D([line], colors=[40, 160, 60, 255], radii=0.006),
                )
            excl = tr.get("excluded")
            if excl is not None and np.any(excl):
                rec.log(
                    f"particles/{name}/excluded",
                    rr.Points2D(pts[np.flatnonzero(excl)], colors=[220, 40, 40, 255], radii=0.04),
                )
            else:
                rec.log(f"particles/{name}/excluded", rr.Clear(recursive=False))
            spans = _runs(tr.get("contact"))
            if spans:
                rec.log(
                    f"particles/{name}/push",
                    rr.LineStrips2D(
                        [pts[a : b + 1] for a, b in spans], colors=[240, 140, 20, 255], radii=0.03
                    ),
                )
            else:
                rec.log(f"particles/{name}/push", rr.Clear(recursive=False))
        for key in ("cost", "time_in_goal"):
            if tr.get(key) is not None:
                rec.log(f"trial/{key}", rr.Scalars([float(tr[key])]))
        if tr.get("success") is not None:
            rec.log("trial/success", rr.Scalars([float(bool(tr["success"]))]))
        if tr.get("gp_rmse") is not None:
            rmse = np.asarray(tr["gp_rmse"], dtype=np.float64)
            for name, value in zip(output_names, rmse, strict=True):
                rec.log(f"gp/one_step_rmse/{name}", rr.Scalars([float(value)]))
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

"""Collision detection on logged files: read and check a log, train a detector on one.

A log follows the dataset schema of :mod:`mcpilco.models.robot_data` (CSV or Parquet;
columns ``t, q1..qn, qd1..qdn, qdd1..qddn, i1..in``; the FC estimator also needs
``e_q1..e_qn, e_qd1..e_qdn, i_cmd1..i_cmdn``; an optional ``contact`` column is ground
truth). The checks raise :class:`InputError` with a message that names the file and the
problem: a missing current group (or controller groups for FC), values the schema loader
rejects (NaN/inf, time not increasing, a joint count other than the detector's), and a
sampling time other than the detector's (median ``diff(t)`` off by more than a relative
tolerance) or a non-uniform grid.
"""

from __future__ import annotations

import csv
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.models.collision.detector import CollisionDetector
from mcpilco.models.collision.estimators import make_estimator
from mcpilco.models.collision.inputs import as_collision_inputs
from mcpilco.models.robot_data import Trajectories, load_dataset

INTERVAL_COLUMNS = ("start", "end", "duration", "joint", "peak_ratio")
"""Columns of the alarm-interval CSV (:func:`write_intervals`)."""


class InputError(ValueError):
    """A problem with the user's files or options (reported without a traceback)."""


def load_log(path: str | Path, n_joints: int | None = None, fc: bool = False) -> Trajectories:
    """Read and check a log (schema loader + current / controller groups)."""
    try:
        ds = load_dataset(path, n_joints=n_joints)
    except (ValueError, FileNotFoundError) as err:
        raise InputError(str(err)) from err
    n = ds.n_joints
    if ds.i is None:
        raise InputError(
            f"{path}: missing motor-current columns i1..i{n}: the detector compares measured "
            "currents with their estimate"
        )
    if fc:
        missing = [g for g in ("e_q", "e_qd", "i_cmd") if getattr(ds, g) is None]
        if missing:
            raise InputError(
                f"{path}: the FC estimator needs the controller columns "
                + ", ".join(f"{g}1..{g}{n}" for g in missing)
            )
    return ds


def check_sample_time(ds: Trajectories, expected: float | None, tolerance: float) -> float:
    """Median ``diff(t)``; raises when it is off ``expected`` or the grid is not uniform."""
    dt = np.diff(ds.t)
    median = float(np.median(dt))
    source = ds.metadata.get("source", "data")
    if expected is not None and abs(median - expected) > tolerance * expected:
        raise InputError(
            f"{source}: wrong sample rate: median time step {median * 1e3:.3f} ms but the "
            f"detector was made for {expected * 1e3:.3f} ms ({1 / expected:.1f} Hz); resample "
            "the log or train a detector at this rate"
        )
    if np.max(np.abs(dt - median)) > 0.5 * median:
        k = int(np.argmax(np.abs(dt - median)))
        raise InputError(
            f"{source}: non-uniform sampling: step {dt[k] * 1e3:.3f} ms at row {k + 1} (median "
            f"{median * 1e3:.3f} ms); the detector needs a uniform grid (no gaps)"
        )
    return median


def train_detector(
    train: str | Path,
    model: str,
    *,
    estimator: str = "FC",
    calibrate: str | Path | None = None,
    calibration_fraction: float = 0.2,
    gp_points: int = 2000,
    hyper_points: int = 400,
    adam_iters: int = 80,
    lbfgs_iters: int = 20,
    rule: str = "max",
    false_alarm_rate: float = 0.0,
    persistence: int = 1,
    rate_tolerance: float = 0.05,
    save: str | Path | None = None,
) -> CollisionDetector:
    """A detector trained on the collision-free log ``train`` with the nominal ``model``
    (MJCF/URDF path or MJCF text).

    The GP is conditioned on ``gp_points`` rows of the fitting part taken with a constant
    step. The thresholds are calibrated on the log ``calibrate`` (same robot and rate) or,
    without one, on the last ``calibration_fraction`` of ``train``, which the fit then does
    not see. ``save``: also write the detector there (:meth:`CollisionDetector.save`).
    """
    fc = estimator == "FC"
    ds = load_log(train, fc=fc)
    sample_time = check_sample_time(ds, None, rate_tolerance)
    inputs = as_collision_inputs(ds, require_controller=fc)
    n = inputs.n_samples
    if calibrate:
        cal = load_log(calibrate, n_joints=ds.n_joints, fc=fc)
        check_sample_time(cal, sample_time, rate_tolerance)
        fit_rows = np.arange(n)
        cal_inputs, cal_i = as_collision_inputs(cal, require_controller=fc), cal.i
    else:
        cut = int((1.0 - calibration_fraction) * n)
        if cut < 10 or n - cut < 10:
            raise InputError(f"{train}: too few rows ({n}) to split off a calibration part")
        fit_rows = np.arange(cut)
        cal_inputs, cal_i = inputs.rows(slice(cut, None)), ds.i[cut:]
    step = max(fit_rows.size // gp_points, 1)
    rows = fit_rows[::step][:gp_points]
    est = make_estimator(
        estimator,
        model,
        hyper_points=hyper_points,
        adam_iters=adam_iters,
        lbfgs_iters=lbfgs_iters,
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est.fit(inputs.rows(rows), ds.i[rows])
    det = CollisionDetector(est, rule, false_alarm_rate, persistence, sample_time)
    det.calibrate(cal_inputs, cal_i)
    if save:
        det.save(save)
    return det


def write_intervals(rows: Sequence[dict[str, Any]], path: Path) -> None:
    """The alarm intervals (``Detection.intervals``) as CSV, columns :data:`INTERVAL_COLUMNS`."""
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=INTERVAL_COLUMNS)
        w.writeheader()
        for r in rows:
            w.writerow({k: r[k] for k in INTERVAL_COLUMNS})

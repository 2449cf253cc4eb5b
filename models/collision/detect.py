"""Run a collision detector on a logged robot file; write the alarm intervals and a plot.

The detector is either loaded (a file written by ``CollisionDetector.save``, e.g. by
``mcpilco-bench-collision --save-detector FILE``) or trained on a collision-free log of the
same robot (:func:`mcpilco.models.collision.train_detector`) with a nominal model (MJCF/URDF
text or path; the console script defaults it to a nominal arm,
:func:`mcpilco.experiments.collision.nominal.nominal_model`). The log is
checked against the detector (:mod:`mcpilco.models.collision.files`: current groups,
controller groups for FC, joint count, sampling time).

Outputs: ``<stem>_collisions.csv`` (one row per alarm interval, alarms closer than
``merge_gap`` s merged: ``start, end, duration, joint, peak_ratio``, the last being the
largest ``|s_j| / sigma_CD,j``) and ``<stem>_collisions.png``
(:func:`~mcpilco.models.collision.plot_detection`); with a ``contact`` column in the log,
the detection is also scored against it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.models.collision import (
    CollisionDetector,
    InputError,
    as_collision_inputs,
    check_sample_time,
    evaluate_detection,
    load_log,
    plot_detection,
    train_detector,
    write_intervals,
)


def detect_collisions(
    data: str | Path,
    *,
    detector: str | Path | None = None,
    train: str | Path | None = None,
    estimator: str = "FC",
    model: str | None = None,
    calibrate: str | Path | None = None,
    calibration_fraction: float = 0.2,
    gp_points: int = 2000,
    hyper_points: int = 400,
    adam_iters: int = 80,
    lbfgs_iters: int = 20,
    rule: str = "max",
    false_alarm_rate: float = 0.0,
    persistence: int | None = None,
    save: str | Path | None = None,
    rate_tolerance: float = 0.05,
    merge_gap: float = 0.25,
    joint: int | None = None,
    out_dir: str | Path | None = None,
) -> dict[str, Any]:
    """Detect collisions in the log ``data`` and write its interval CSV and plot.

    Exactly one of ``detector`` (a saved detector; ``persistence`` overrides its own) and
    ``train`` (a collision-free log to train one on, see
    :func:`~mcpilco.models.collision.train_detector` for ``estimator`` ... ``save``;
    ``persistence`` defaults to 1) is given; ``model`` is the nominal robot (MJCF/URDF text or
    path), required with ``train``. ``joint``: the joint plotted (1-based; default the one
    with the largest monitoring ratio); ``out_dir``: default the folder of ``data``.

    Returns ``{"intervals", "csv", "png", "detector"}`` and, when the log has a ``contact``
    column, ``"score"`` (:func:`~mcpilco.models.collision.evaluate_detection` without the
    per-push list). Raises :class:`~mcpilco.models.collision.InputError` on a bad file or
    option.
    """
    if (detector is None) == (train is None):
        raise InputError("give either a detector file or a collision-free log to train one on")
    if train is not None:
        if not model:
            raise InputError("training a detector needs the nominal robot model (--model)")
        det = train_detector(
            train,
            model,
            estimator=estimator,
            calibrate=calibrate,
            calibration_fraction=calibration_fraction,
            gp_points=gp_points,
            hyper_points=hyper_points,
            adam_iters=adam_iters,
            lbfgs_iters=lbfgs_iters,
            rule=rule,
            false_alarm_rate=false_alarm_rate,
            persistence=1 if persistence is None else persistence,
            rate_tolerance=rate_tolerance,
            save=save,
        )
    else:
        try:
            det = CollisionDetector.load(detector)
        except (OSError, ValueError, RuntimeError) as err:
            raise InputError(f"cannot read the detector {detector}: {err}") from err
        if persistence is not None:
            det.persistence = persistence
    fc = det.estimator.requires_controller
    ds = load_log(data, n_joints=det.n_joints, fc=fc)
    check_sample_time(ds, det.sample_time, rate_tolerance)
    result = det.detect(as_collision_inputs(ds, det.n_joints, fc), ds.i)
    intervals = result.intervals(ds.t, merge_gap)
    path = Path(data)
    out = Path(out_dir) if out_dir else path.parent
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / f"{path.stem}_collisions.csv"
    png_path = out / f"{path.stem}_collisions.png"
    write_intervals(intervals, csv_path)
    ratio = np.abs(result.s) / result.thresholds
    joint = joint or int(np.argmax(ratio.max(axis=0))) + 1
    if not 1 <= joint <= det.n_joints:
        raise InputError(f"--joint must be in 1..{det.n_joints}, got {joint}")
    plot_detection(ds, result, joint, png_path)
    summary: dict[str, Any] = {
        "intervals": intervals,
        "csv": str(csv_path),
        "png": str(png_path),
        "detector": det.describe(),
    }
    if ds.contact is not None:
        ev = evaluate_detection(result.alarm, ds.contact, ds.t)
        summary["score"] = {k: v for k, v in ev.items() if k != "pushes"}
    return summary

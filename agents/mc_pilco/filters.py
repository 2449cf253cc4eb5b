"""Keep the samples of external pushes out of MC-PILCO's dynamics data (thesis chapter 4).

A push on a robot arm is not part of its dynamics: a GP of ``x_{t+1} - x_t`` fitted on
transitions during which someone pushed the arm learns a force that will not be there, and
the particles inherit it. :class:`CollisionFilter` runs a collision detector of
:mod:`mcpilco.models.collision` (a GP of the motor currents trained on collision-free data,
thresholds on the monitoring signal ``s = i - i_hat``) on every sample of an episode and
marks the control steps it alarms in; the loop leaves those transitions out of the GP data,
as it does those at a declared limit.

Glossary
--------
``R``
    the task's ``action_repeat``: env samples per control step (the detector runs at the
    env's sampling time ``T = T_s / R``).
alarm ``a_k``
    the detector's alarm at env sample ``k`` (after its persistence).
``e_t``
    transition ``t`` (from control step ``t`` to ``t + 1``, its ``R`` env samples) is
    excluded when an alarm falls on one of its samples, or on those of the ``margin``
    transitions before and after it: the detector raises its alarm some samples into a push
    (its latency: results/collision_5000/collision.md) and the push's ramp ends before the
    arm settles.

The env's ``info`` must carry the arm env's per-sample keys (:mod:`mcpilco.envs.arm_env`):
``q, qd, qdd, e_q, e_qd`` and the motor currents ``current`` (``i``) and ``current_cmd``
(``i_cmd``); ``contact``, when present, is the ground truth the records report against.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

FILTER_GROUPS = ("q", "qd", "qdd", "e_q", "e_qd", "i", "i_cmd")
"""Dataset groups the detector reads, from each env sample's ``info``
(:func:`mcpilco.envs.arm_data.log_from_infos`: ``i`` is ``current``, ``i_cmd`` is
``current_cmd``)."""

SAMPLE_TIME_TOLERANCE = 0.05  # relative difference allowed between the detector's and the env's T


class CollisionFilter:
    """Marks the transitions of an episode in which a collision detector alarms (module
    glossary).

    Args:
        detector: a :class:`~mcpilco.models.collision.CollisionDetector` or the path of one
            saved with ``CollisionDetector.save`` (e.g. ``mcpilco-detect-collisions --train
            free.parquet --save fc.pt``).
        n_joints: the task's joint count (the detector's must be the same).
        sample_time: the env's sampling time ``T`` [s] (the detector's must match within
            5 %).
        margin: transitions excluded before and after each alarmed one.

    Raises:
        FileNotFoundError: no detector file at the path.
        ValueError: another joint count or sampling time than the detector's.
    """

    def __init__(self, detector: Any, n_joints: int, sample_time: float, margin: int = 1) -> None:
        from mcpilco.models.collision import CollisionDetector

        if isinstance(detector, str | Path):
            if not Path(detector).is_file():
                raise FileNotFoundError(f"push_filter: no collision-detector file at {detector}")
            detector = CollisionDetector.load(detector)
        if detector.n_joints != n_joints:
            raise ValueError(
                f"push_filter: the detector is for {detector.n_joints} joints, the task has "
                f"{n_joints}"
            )
        T = detector.sample_time
        if T is not None and abs(T - sample_time) > SAMPLE_TIME_TOLERANCE * sample_time:
            raise ValueError(
                f"push_filter: the detector was made for samples of {T} s, the env samples "
                f"every {sample_time} s"
            )
        if int(margin) != margin or margin < 0:
            raise ValueError(f"margin must be an integer >= 0, got {margin!r}")
        self.detector = detector
        self.margin = int(margin)

    def alarms(self, infos: Sequence[Mapping[str, Any]]) -> np.ndarray:
        """The detector's alarms ``(K,)`` on the env samples whose ``info`` dicts are given."""
        from mcpilco.envs.arm_data import INFO_NAMES, log_from_infos

        missing = [
            INFO_NAMES.get(g, g) for g in FILTER_GROUPS if INFO_NAMES.get(g, g) not in infos[0]
        ]
        if missing:
            raise ValueError(f"push_filter: the env's info lacks {missing}")
        col = log_from_infos(infos, FILTER_GROUPS)
        X = {g: col[g] for g in FILTER_GROUPS if g != "i"}
        return np.asarray(self.detector.detect(X, col["i"]).alarm, dtype=bool)

    def excluded(self, steps: Sequence[Sequence[Mapping[str, Any]]]) -> np.ndarray:
        """``e_t`` ``(T,)`` for an episode's ``T`` transitions, given as the ``info`` dicts of
        each transition's env samples (``steps[t]``, ``R`` of them)."""
        if not steps:
            return np.zeros(0, dtype=bool)
        flat = [info for step in steps for info in step]
        alarm = self.alarms(flat)
        ends = np.cumsum([len(step) for step in steps])
        hit = np.array(
            [alarm[e - len(step) : e].any() for e, step in zip(ends, steps, strict=True)]
        )
        return dilate(hit, self.margin)


def dilate(mask: np.ndarray, margin: int) -> np.ndarray:
    """``mask`` with each true entry spread to ``margin`` entries on either side."""
    out = np.asarray(mask, dtype=bool).copy()
    for k in range(1, margin + 1):
        out[k:] |= mask[:-k]
        out[:-k] |= mask[k:]
    return out


def contact_steps(steps: Sequence[Sequence[Mapping[str, Any]]]) -> np.ndarray | None:
    """Ground truth ``(T,)``: a push acted during transition ``t`` (``info["contact"]`` on one
    of its samples ``steps[t]``), or None when the env's info has no ``contact``."""
    if not steps or not steps[0] or "contact" not in steps[0][0]:
        return None
    return np.array([any(float(r["contact"]) > 0 for r in step) for step in steps])

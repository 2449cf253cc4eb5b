"""Monitoring signal, thresholds and the collision detector (thesis sections 4.2-4.3).

Glossary
--------
``s = i - i_hat`` (section 4.3)
    monitoring signal: measured motor currents minus the currents a GP trained on
    collision-free data predicts; ``|s_j|`` grows when an external torque ``tau_e`` acts.
``f_CD(s) = TRUE iff |s_j| >= sigma_CD,j for at least one joint j`` (section 4.2)
    the binary collision function.
thesis rule (max-error)
    ``sigma_CD,j = max_k |s_j(t_k)|`` over collision-free validation data (section 4.6.2:
    "the maximum value of the estimation error in the test set").
variance rule (beyond the thesis; section 4.3 leaves it as future work)
    input-dependent thresholds ``sigma_CD,j(x) = k_j sigma_j(x)`` with the GP predictive
    standard deviation ``sigma_j(x) = sqrt(v_j(x) + sigma_n,j^2)`` (latent variance plus
    noise) and ``k_j`` the ``1 - alpha`` quantile of ``|s_j| / sigma_j(x)`` on validation
    data (``alpha`` the per-sample false-alarm rate; ``alpha = 0`` is the maximum, the
    analogue of the thesis rule).
persistence ``m``
    an alarm is raised at ``t_k`` when ``f_CD`` held on the ``m`` samples ``t_{k-m+1}..t_k``
    (``m = 1``: no persistence); it adds ``(m - 1) T`` of latency.
detection metrics (:func:`evaluate_detection`)
    a push (a run of ``contact = 1``) is detected when an alarm falls in
    ``[t_start, t_end + grace]``; latency = first such alarm time minus ``t_start``; an alarm
    event (run of alarm samples) touching no push window is a false alarm, counted per
    minute of push-free time.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from mcpilco.models.collision.estimators import CurrentEstimator, load_estimator
from mcpilco.models.torch_files import load_torch_file

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

__all__ = [
    "RULES",
    "CollisionDetector",
    "Detection",
    "alarm_flags",
    "evaluate_detection",
    "max_error_threshold",
    "monitoring_signal",
    "persistent",
    "quantile_threshold",
    "runs",
]

RULES: tuple[str, ...] = ("max", "variance")
"""Threshold rules: ``"max"`` constant ``sigma_CD`` per joint, ``"variance"`` ``k sigma(x)``."""

_FORMAT = "mcpilco.collision.CollisionDetector/1"
_RULES = ("max", "variance")  # threshold rules of a detector file


def _as_2d(value: Any, name: str) -> FloatArray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 2 or arr.shape[0] == 0:
        raise ValueError(f"{name} must be a non-empty (N, n) array, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        row, col = np.argwhere(~np.isfinite(arr))[0]
        raise ValueError(f"{name} has a NaN/inf at row {row}, joint {col + 1}")
    return arr


def monitoring_signal(i: Any, i_hat: Any) -> FloatArray:
    """``s = i - i_hat`` ``(N, n)`` [A] (thesis section 4.3)."""
    i, i_hat = _as_2d(i, "i"), _as_2d(i_hat, "i_hat")
    if i.shape != i_hat.shape:
        raise ValueError(f"i {i.shape} and i_hat {i_hat.shape} must have the same shape")
    return i - i_hat


def max_error_threshold(s: Any) -> FloatArray:
    """Thesis rule: ``sigma_CD,j = max_k |s_j(t_k)|`` on collision-free data, ``(n,)``."""
    return np.abs(_as_2d(s, "s")).max(axis=0)


def quantile_threshold(z: Any, false_alarm_rate: float = 0.0) -> FloatArray:
    """Per-joint ``1 - alpha`` quantile of ``|z_j|``, ``(n,)``; ``alpha = 0`` gives the maximum.

    With ``z = s`` this is a constant threshold; with ``z = s / sigma(x)`` it is the factor
    ``k_j`` of the variance rule. On ``N`` samples the empirical quantile (linear
    interpolation) is used, so ``alpha`` below ``1 / N`` acts like 0.
    """
    if not 0.0 <= false_alarm_rate < 1.0:
        raise ValueError(f"false_alarm_rate must be in [0, 1), got {false_alarm_rate}")
    a = np.abs(_as_2d(z, "z"))
    if false_alarm_rate == 0.0:
        return a.max(axis=0)
    return np.quantile(a, 1.0 - false_alarm_rate, axis=0)


def alarm_flags(s: Any, thresholds: Any) -> BoolArray:
    """``f_CD``: ``True`` where ``|s_j| >= sigma_CD,j`` for at least one joint, ``(N,)``.

    Args:
        s: ``(N, n)`` monitoring signal.
        thresholds: ``(n,)`` constant or ``(N, n)`` input-dependent thresholds (> 0).
    """
    s = _as_2d(s, "s")
    thr = np.asarray(thresholds, dtype=np.float64)
    if thr.shape not in ((s.shape[1],), s.shape):
        raise ValueError(
            f"thresholds must have shape ({s.shape[1]},) or {s.shape} like s, got {thr.shape}"
        )
    if not np.all(thr > 0):
        raise ValueError("thresholds must be > 0 (calibrate them on collision-free data)")
    return (np.abs(s) >= thr).any(axis=1)


def persistent(flags: Any, m: int = 1) -> BoolArray:
    """``out_k = flags_{k-m+1} and ... and flags_k`` (``m`` consecutive samples), ``(N,)``."""
    if isinstance(m, bool) or not isinstance(m, int | np.integer) or m < 1:
        raise ValueError(f"persistence must be an int >= 1 (samples), got {m!r}")
    f = np.asarray(flags, dtype=bool)
    if m == 1:
        return f.copy()
    # run length ending at k: count of consecutive True samples
    out = np.zeros_like(f)
    run = 0
    for k, v in enumerate(f):
        run = run + 1 if v else 0
        out[k] = run >= m
    return out


def runs(flags: Any) -> list[tuple[int, int]]:
    """Index ranges ``[(first, last), ...]`` (inclusive) of the runs of ``True`` in ``flags``."""
    f = np.asarray(flags, dtype=bool).astype(np.int8)
    d = np.diff(np.concatenate([[0], f, [0]]))
    starts = np.flatnonzero(d == 1)
    ends = np.flatnonzero(d == -1) - 1
    return list(zip(starts.tolist(), ends.tolist(), strict=True))


def evaluate_detection(alarm: Any, contact: Any, t: Any, grace: float = 0.25) -> dict[str, Any]:
    """Score alarms against ground-truth contact labels (definitions in the glossary).

    Args:
        alarm: ``(N,)`` bool alarms (after persistence).
        contact: ``(N,)`` 0/1 ground-truth labels.
        t: ``(N,)`` times [s], increasing.
        grace: alarms up to this long after a push ends still belong to it [s].

    Returns:
        ``pushes``: list of ``{"start", "end", "detected", "latency"}`` (latency ``None`` when
        missed); ``detection_rate``; ``median_latency`` [s] (NaN if none detected);
        ``false_alarms`` (count); ``push_free_minutes``; ``false_alarms_per_minute``.
    """
    alarm = np.asarray(alarm, dtype=bool)
    contact = np.asarray(contact).astype(bool)
    t = np.asarray(t, dtype=np.float64)
    if not (alarm.shape == contact.shape == t.shape) or alarm.ndim != 1:
        raise ValueError(
            f"alarm, contact and t must be 1-D of one length, got {alarm.shape}, "
            f"{contact.shape}, {t.shape}"
        )
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    windows = np.zeros_like(contact)
    pushes = []
    for a, b in runs(contact):
        t0, t1 = t[a], t[b]
        win = (t >= t0) & (t <= t1 + grace)
        windows |= win
        hits = np.flatnonzero(alarm & win)
        detected = hits.size > 0
        latency = float(t[hits[0]] - t0) if detected else None
        pushes.append(
            {"start": float(t0), "end": float(t1), "detected": detected, "latency": latency}
        )
    false_alarms = sum(1 for a, b in runs(alarm) if not windows[a : b + 1].any())
    free_minutes = float((~windows).sum()) * dt / 60.0
    latencies = [p["latency"] for p in pushes if p["detected"]]
    n = len(pushes)
    return {
        "pushes": pushes,
        "n_pushes": n,
        "detection_rate": float(sum(p["detected"] for p in pushes) / n) if n else float("nan"),
        "median_latency": float(np.median(latencies)) if latencies else float("nan"),
        "false_alarms": int(false_alarms),
        "push_free_minutes": free_minutes,
        "false_alarms_per_minute": (
            float(false_alarms / free_minutes) if free_minutes > 0 else float("nan")
        ),
    }


@dataclass
class Detection:
    """Output of :meth:`CollisionDetector.detect`.

    Attributes:
        s: ``(N, n)`` monitoring signal [A].
        i_hat: ``(N, n)`` estimated currents [A].
        thresholds: ``(N, n)`` thresholds in force at every sample [A].
        raw: ``(N,)`` ``f_CD`` before persistence.
        alarm: ``(N,)`` alarms after persistence.
    """

    s: FloatArray
    i_hat: FloatArray
    thresholds: FloatArray
    raw: BoolArray
    alarm: BoolArray

    def intervals(self, t: Any, merge_gap: float = 0.0) -> list[dict[str, Any]]:
        """Alarm intervals: ``start``/``end`` times [s], ``duration``, the joint with the
        largest ``|s_j| / sigma_CD,j`` in the interval and that ratio. Alarm runs less than
        ``merge_gap`` seconds apart form one interval (one contact often crosses the
        threshold several times)."""
        t = np.asarray(t, dtype=np.float64)
        if merge_gap < 0:
            raise ValueError(f"merge_gap must be >= 0 [s], got {merge_gap}")
        ratio = np.abs(self.s) / self.thresholds
        merged: list[list[int]] = []
        for a, b in runs(self.alarm):
            if merged and t[a] - t[merged[-1][1]] <= merge_gap:
                merged[-1][1] = b
            else:
                merged.append([a, b])
        out = []
        for a, b in merged:
            block = ratio[a : b + 1]
            k, j = np.unravel_index(int(np.argmax(block)), block.shape)
            out.append(
                {
                    "start": float(t[a]),
                    "end": float(t[b]),
                    "duration": float(t[b] - t[a]),
                    "joint": int(j + 1),
                    "peak_ratio": float(block[k, j]),
                }
            )
        return out


class CollisionDetector:
    """A current estimator plus calibrated thresholds and persistence (glossary above).

    Args:
        estimator: a fitted :class:`~mcpilco.models.collision.estimators.CurrentEstimator`.
        rule: ``"max"`` (constant ``sigma_CD``) or ``"variance"`` (``k sigma(x)``).
        false_alarm_rate: ``alpha`` of the calibration quantile (0 = the maximum, the thesis
            rule).
        persistence: ``m`` consecutive samples above threshold raise an alarm.
        sample_time: sampling time ``T`` [s] of the data the detector is made for (saved with
            it; ``mcpilco-detect-collisions`` rejects files sampled otherwise).

    Fitted (:meth:`calibrate`): ``scale_`` ``(n,)``: ``sigma_CD`` [A] (``"max"``) or ``k``
    (``"variance"``).
    """

    def __init__(
        self,
        estimator: CurrentEstimator,
        rule: str = "max",
        false_alarm_rate: float = 0.0,
        persistence: int = 1,
        sample_time: float | None = None,
    ) -> None:
        if rule not in RULES:
            raise ValueError(f"rule must be one of {RULES}, got {rule!r}")
        if not 0.0 <= false_alarm_rate < 1.0:
            raise ValueError(f"false_alarm_rate must be in [0, 1), got {false_alarm_rate}")
        persistent(np.zeros(1, dtype=bool), persistence)  # validates persistence
        self.estimator = estimator
        self.rule = rule
        self.false_alarm_rate = float(false_alarm_rate)
        self.persistence = int(persistence)
        if sample_time is not None and not sample_time > 0:
            raise ValueError(f"sample_time must be > 0 [s], got {sample_time}")
        self.sample_time = None if sample_time is None else float(sample_time)
        self.scale_: FloatArray | None = None

    def signal(self, X: Any, i: Any) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(s, i_hat, sigma)``: monitoring signal, estimate and predictive std ``(N, n)``
        (with the ``"max"`` rule the latent variance is skipped: ``sigma`` is the noise std)."""
        i_hat, var = self.estimator.predict(X, return_var=self.rule == "variance")
        s = monitoring_signal(i, i_hat)
        noise = np.asarray(self.estimator.noise_variance_, dtype=np.float64)
        var = np.zeros_like(s) if var is None else np.maximum(var, 0.0)
        return s, i_hat, np.sqrt(var + noise)

    def calibrate(self, X: Any, i: Any) -> CollisionDetector:
        """Set ``scale_`` from collision-free data ``X``, currents ``i`` (module glossary)."""
        s, _, sigma = self.signal(X, i)
        z = s if self.rule == "max" else s / sigma
        self.scale_ = quantile_threshold(z, self.false_alarm_rate)
        return self

    def thresholds(self, sigma: FloatArray) -> FloatArray:
        """``(N, n)`` thresholds for predictive stds ``sigma``."""
        if self.scale_ is None:
            raise RuntimeError("calibrate the detector on collision-free data first")
        if self.rule == "max":
            return np.broadcast_to(self.scale_, sigma.shape).copy()
        return self.scale_ * sigma

    def detect(self, X: Any, i: Any) -> Detection:
        """Run the detector on inputs ``X`` and measured currents ``i``."""
        s, i_hat, sigma = self.signal(X, i)
        thr = self.thresholds(sigma)
        raw = alarm_flags(s, thr)
        return Detection(s, i_hat, thr, raw, persistent(raw, self.persistence))

    def save(self, path: Any) -> None:
        """Write the estimator and the calibration to one file (``torch.save``)."""
        if self.scale_ is None:
            raise RuntimeError("calibrate the detector before saving it")
        buf = io.BytesIO()
        self.estimator.save(buf)
        torch.save(
            {
                "format": _FORMAT,
                "rule": self.rule,
                "false_alarm_rate": self.false_alarm_rate,
                "persistence": self.persistence,
                "sample_time": self.sample_time,
                "scale": torch.as_tensor(self.scale_),
                "estimator": torch.frombuffer(bytearray(buf.getvalue()), dtype=torch.uint8),
            },
            path,
        )

    @classmethod
    def load(cls, path: Any) -> CollisionDetector:
        """Read a detector written by :meth:`save`, checked against its format (the
        values' types and ranges, the thresholds one per joint of the estimator).

        Raises:
            FileNotFoundError: no file at ``path``.
            ValueError: one line naming the file and what does not match.
        """
        remedy = "write the detector again (mcpilco-detect-collisions --train ... --save FILE)"
        payload = load_torch_file(path, "collision-detector file", remedy)
        problem = _detector_problem(payload)
        if problem is not None:
            raise ValueError(
                f"collision-detector file {path} does not match its format: {problem}; {remedy}"
            )
        try:
            est = load_estimator(payload["estimator"].numpy().tobytes())
            det = cls(
                est,
                payload["rule"],
                payload["false_alarm_rate"],
                payload["persistence"],
                payload.get("sample_time"),
            )
        except ValueError as err:
            raise ValueError(f"collision-detector file {path}: {err}") from None
        det.scale_ = payload["scale"].numpy().astype(np.float64)
        if det.scale_.shape != (det.n_joints,):
            raise ValueError(
                f"collision-detector file {path} does not match its format: {det.scale_.size} "
                f"thresholds for {det.n_joints} joints; {remedy}"
            )
        return det

    @property
    def n_joints(self) -> int:
        return int(self.estimator.n_joints_)

    def describe(self) -> dict[str, Any]:
        """JSON-serialisable summary (rule, alpha, persistence, ``scale_``, estimator)."""
        return {
            "estimator": self.estimator.name,
            "rule": self.rule,
            "false_alarm_rate": self.false_alarm_rate,
            "persistence": self.persistence,
            "sample_time": self.sample_time,
            "scale": None if self.scale_ is None else self.scale_.tolist(),
        }


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and bool(np.isfinite(v))


def _detector_problem(payload: Any) -> str | None:
    """What in a loaded detector payload does not match the format of
    :meth:`CollisionDetector.save` (None: nothing)."""
    if not isinstance(payload, dict) or payload.get("format") != _FORMAT:
        return "not a collision-detector file (written by CollisionDetector.save)"
    if payload.get("rule") not in _RULES:
        return f"rule is not one of {_RULES}"
    rate = payload.get("false_alarm_rate")
    if not (_is_number(rate) and 0.0 <= rate < 1.0):
        return "false_alarm_rate is not a number in [0, 1)"
    persistence = payload.get("persistence")
    if not (isinstance(persistence, int) and not isinstance(persistence, bool)):
        return "persistence is not an integer"
    if not 1 <= persistence <= 10_000:
        return "persistence is not in [1, 10000]"
    dt = payload.get("sample_time")
    if dt is not None and not (_is_number(dt) and 0.0 < dt <= 10.0):
        return "sample_time is not a number in (0, 10] s"
    scale = payload.get("scale")
    if not isinstance(scale, torch.Tensor) or scale.ndim != 1 or not scale.is_floating_point():
        return "scale is not a 1-D float tensor"
    if not bool(torch.isfinite(scale).all()) or not bool((scale >= 0).all()):
        return "scale holds values that are not finite and >= 0"
    est = payload.get("estimator")
    if not isinstance(est, torch.Tensor) or est.dtype != torch.uint8 or est.ndim != 1:
        return "estimator is not the bytes of a saved estimator"
    return None

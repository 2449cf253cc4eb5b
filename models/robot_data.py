"""Robot measurement files: the one dataset schema, a validating loader and a saver, and
:class:`Trajectories`, the one container of robot logs (one file, or several stacked).

The arm envs' data (``mcpilco-collect-arm-data``) and the files users bring from their
robots share this format: one row per sample, CSV or Parquet, columns

======================  ============================================  ========================
column                  meaning                                       unit (R joint / P joint)
======================  ============================================  ========================
``t``                   time, strictly increasing                     s
``q1..qn``              joint positions                               rad / m
``qd1..qdn``            joint velocities (optional: computed)         rad/s / m/s
``qdd1..qddn``          joint accelerations (optional: computed)      rad/s^2 / m/s^2
``tau1..taun``          joint torques / forces (optional*)            N m / N
``i1..in``              measured motor currents (optional*)           A
``i_cmd1..i_cmdn``      controller current commands (optional)        A
``e_q1..e_qn``          reference minus measured position (optional)  rad / m
``e_qd1..e_qdn``        reference minus measured velocity (optional)  rad/s / m/s
``contact``             1 while an external contact acts (optional)   0/1
======================  ============================================  ========================

(*) at least one of the ``tau`` and ``i`` groups must be present. Joints are numbered from 1.
Other columns are kept in :attr:`Trajectories.extras`. A group is either complete
(``1..n``) or absent.

Derivatives when absent (:func:`differentiate`): on a uniform time grid (relative spread
of ``diff(t)`` below 1e-3) a Savitzky-Golay derivative (cubic, 9-sample window, i.e. a
local least-squares fit; offline and non-causal, with a delay-free phase); otherwise
second-order central differences on the actual times (``numpy.gradient``). ``qdd`` is the
same filter applied to ``qd`` (measured or computed).
"""

from __future__ import annotations

import json
import math
import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

JOINT_GROUPS: tuple[str, ...] = ("q", "qd", "qdd", "tau", "i", "i_cmd", "e_q", "e_qd")
"""Per-joint column groups, in file order; group ``g`` has columns ``g1..gn``."""

UNITS: dict[str, str] = {
    "t": "s",
    "q": "rad (m for prismatic joints)",
    "qd": "rad/s (m/s)",
    "qdd": "rad/s^2 (m/s^2)",
    "tau": "N m (N)",
    "i": "A",
    "i_cmd": "A",
    "e_q": "rad (m)",
    "e_qd": "rad/s (m/s)",
    "contact": "0/1",
}
"""Unit of every column group."""

OUTPUT_GROUPS: tuple[str, ...] = ("tau", "i")
"""At least one of these groups must be present."""

SAVGOL_WINDOW = 9
SAVGOL_ORDER = 3

PLAUSIBLE_LIMITS: dict[str, float] = {
    "t": 1e7,
    "q": 1e3,
    "qd": 1e3,
    "qdd": 1e5,
    "tau": 1e6,
    "i": 1e4,
    "i_cmd": 1e4,
    "e_q": 1e3,
    "e_qd": 1e3,
}
"""Largest plausible magnitude of each group in the units of :data:`UNITS`; beyond it a value
is a unit or logging error (1e3 rad is 160 turns)."""
UNIT_FACTOR_LIMIT = 3.0
"""A position and the time integral of its velocity that disagree by more than this factor
(either way) are in different units (180/pi = 57.3: an angle in degrees)."""
UNIT_CHECK_CORRELATION = 0.9
"""Correlation of ``diff(q)`` with the integral of ``qd`` above which their ratio is trusted
as a unit factor (below it the signals are too noisy or too still to tell)."""
MIN_SAMPLES_PER_SWING = SAVGOL_WINDOW
"""Fewest samples between velocity reversals for a computed derivative: fewer and the
derivative filter's window spans a whole swing and flattens it."""


def column_names(n_joints: int, groups: tuple[str, ...] = JOINT_GROUPS) -> list[str]:
    """``["t", "q1", ..., "qn", "qd1", ...]`` for the given groups, then ``"contact"``."""
    if n_joints < 1:
        raise ValueError(f"n_joints must be >= 1, got {n_joints}")
    cols = ["t"]
    for g in groups:
        cols += [f"{g}{j}" for j in range(1, n_joints + 1)]
    return [*cols, "contact"]


ROW_FIELDS: tuple[str, ...] = ("t", *JOINT_GROUPS, "contact", "y", "segment")
"""The per-row arrays of :class:`Trajectories` (``None`` where a group is absent)."""


@dataclass
class Trajectories:
    """Robot trajectories: one measured log, or several stacked (one segment each), as arrays
    ``(N,)`` / ``(N, n)`` in the units of :data:`UNITS`.

    The one container of robot logs: :func:`load_dataset` gives one file's (one segment), the
    diagnosis stacks several (:func:`~mcpilco.models.diagnosis.data.as_trajectories`), holds
    trajectories out *whole*, shifts targets in time inside one (delay scan) and averages
    residuals around velocity reversals inside one, so it keeps every sample's segment.

    Attributes:
        t, q, qd, qdd: time and joint states; ``qd``/``qdd`` always filled (computed when the
            file lacks them; see ``metadata["computed"]``).
        tau, i, i_cmd, e_q, e_qd, contact: the optional groups, ``None`` when absent.
        extras: the file's other columns.
        metadata: stored with the file, plus ``source`` (the path) and ``computed``.
        y: ``(N, n)`` the output a model predicts: ``tau``, or the motor currents ``i`` of a
            file without torques (``k_t i`` once put into torque units,
            :mod:`mcpilco.models.diagnosis.units`).
        output: ``"tau"`` or ``"i"`` (what ``y`` holds).
        segment: ``(N,)`` the segment (log) of every sample, ``0..k-1``, contiguous.
        names: the source of every segment (file path or ``"<arrays>"``; empty for one
            file as loaded, whose source is ``metadata["source"]``).
        warnings: data warnings of the diagnosis loader.
        estimated: per segment (aligned with ``names``), the
            :class:`~mcpilco.models.diagnosis.data.Estimate` of the ``qd``/``qdd`` groups it
            computed from ``q``, or ``None`` where the file gave them; ``None`` as a whole for
            a log the diagnosis loader has not yet prepared.
        torque_constants: the :class:`~mcpilco.models.diagnosis.units.TorqueConstants` that
            put motor currents into torque units (``y = k_t i``), or ``None``.
    """

    t: FloatArray
    q: FloatArray
    qd: FloatArray
    qdd: FloatArray
    tau: FloatArray | None = None
    i: FloatArray | None = None
    i_cmd: FloatArray | None = None
    e_q: FloatArray | None = None
    e_qd: FloatArray | None = None
    contact: NDArray[np.int64] | None = None
    extras: dict[str, FloatArray] = field(default_factory=dict)
    metadata: dict[str, Any] = field(default_factory=dict)
    y: FloatArray | None = None
    output: str | None = None
    segment: NDArray[np.int64] | None = None
    names: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    estimated: list[Any] | None = None
    torque_constants: Any = None

    def __post_init__(self) -> None:
        if self.output is None:
            self.output = "tau" if self.tau is not None else "i"
        if self.y is None:
            self.y = self.tau if self.output == "tau" else self.i
        if self.segment is None:
            self.segment = np.zeros(self.t.shape[0], dtype=np.int64)

    @property
    def n_joints(self) -> int:
        return int(self.q.shape[1])

    @property
    def n_samples(self) -> int:
        return int(self.t.shape[0])

    @property
    def n_segments(self) -> int:
        return int(self.segment.max()) + 1 if self.segment.size else 0

    @property
    def segments(self) -> list[tuple[int, int]]:
        """``(start, stop)`` row range of every segment (segments are contiguous)."""
        edges = np.flatnonzero(np.diff(self.segment)) + 1
        starts = np.concatenate([[0], edges])
        stops = np.concatenate([edges, [self.n_samples]])
        return list(zip(starts.tolist(), stops.tolist(), strict=True))

    @property
    def sample_time(self) -> float:
        """Median sample time [s] over all segments (``nan`` below two rows)."""
        dts = [np.diff(self.t[a:b]) for a, b in self.segments if b - a > 1]
        return float(np.median(np.concatenate(dts))) if dts else float("nan")

    def to_frame(self) -> pd.DataFrame:
        """The schema's columns (name and order, absent groups skipped), then the extras, as a
        ``DataFrame``: what :func:`save_dataset` writes."""
        cols: dict[str, Any] = {"t": self.t}
        for g in JOINT_GROUPS:
            arr = getattr(self, g)
            if arr is not None:
                for j in range(self.n_joints):
                    cols[f"{g}{j + 1}"] = arr[:, j]
        if self.contact is not None:
            cols["contact"] = self.contact
        cols.update(self.extras)
        return pd.DataFrame(cols)

    def subset(self, rows: ArrayLike) -> Trajectories:
        """Rows ``rows`` (index array or boolean mask) as new trajectories; the segments keep
        their numbers, names and derivative estimates."""

        def take(a: Any) -> Any:
            return None if a is None else a[rows]

        return replace(
            self,
            **{f: take(getattr(self, f)) for f in ROW_FIELDS},
            extras={k: v[rows] for k, v in self.extras.items()},
            metadata=dict(self.metadata),
            names=list(self.names),
            warnings=list(self.warnings),
            estimated=None if self.estimated is None else list(self.estimated),
        )

    def select(self, segments: Sequence[int]) -> Trajectories:
        """The listed segments only (renumbered ``0..k-1``)."""
        keep = np.isin(self.segment, list(segments))
        out = self.subset(keep)
        kept = sorted(set(out.segment.tolist()))
        remap = {s: k for k, s in enumerate(kept)}
        out.segment = np.array([remap[s] for s in out.segment.tolist()], dtype=np.int64)
        out.names = [self.names[s] for s in kept] if self.names else []
        if self.estimated:
            out.estimated = [self.estimated[s] for s in kept]
        return out

    def split_time(self, fraction: float) -> tuple[Trajectories, Trajectories]:
        """Cut every segment at ``fraction`` of its rows: (first parts, last parts).

        Used to hold out a contiguous block when only one training file is given.
        """
        first = np.zeros(self.n_samples, dtype=bool)
        for a, b in self.segments:
            first[a : a + int(round(fraction * (b - a)))] = True
        return self.subset(first), self.subset(~first)

    def edge_rows(self, segment: int) -> int:
        """Rows at each end of ``segment`` whose ``qd``/``qdd`` come from the derivative
        filter's edge fit (0 when the file gave them or they were dropped)."""
        est = self.estimated[segment] if self.estimated and segment < len(self.estimated) else None
        return 0 if est is None else est.edge_rows

    def interior(self) -> Trajectories:
        """These trajectories without the :meth:`edge_rows` of every segment
        (:mod:`mcpilco.models.diagnosis.data`); ``self`` when there are none. A segment keeps
        at least its middle row."""
        keep = np.ones(self.n_samples, dtype=bool)
        for a, b in self.segments:
            m = min(self.edge_rows(int(self.segment[a])), (b - a - 1) // 2)
            keep[a : a + m] = False
            keep[b - m : b] = False
        if keep.all():
            return self
        out = self.subset(keep)
        out.estimated = [None if e is None else replace(e, interior=True) for e in self.estimated]
        return out

    def shift_index(self, rows: NDArray[np.int64], k: int) -> NDArray[np.int64]:
        """Rows ``rows + k`` clipped to each row's own segment (targets ``k`` samples later)."""
        out = rows + k
        for a, b in self.segments:
            inside = (rows >= a) & (rows < b)
            out[inside] = np.clip(out[inside], a, b - 1)
        return out

    def at(self, values: FloatArray, rows: NDArray[np.int64], shift: float) -> FloatArray:
        """``values`` at the rows ``rows + shift`` (``shift`` in samples, any real number):
        linear interpolation between the two samples around each, both clipped to the row's
        own segment (:meth:`shift_index`); a whole ``shift`` reads the samples themselves."""
        k0 = math.floor(shift)
        frac = float(shift) - k0
        lower = values[self.shift_index(rows, k0)]
        if frac == 0.0:
            return lower
        upper = values[self.shift_index(rows, k0 + 1)]
        return (1.0 - frac) * lower + frac * upper

    def delayed(self, values: FloatArray, delay: float) -> FloatArray:
        """``values(t - delay)`` per segment by linear interpolation (clamped at the start).

        Args:
            values: ``(N,)`` samples of a signal on these trajectories.
            delay: [s] (>= 0: the output lags the states).
        """
        out = np.array(values, dtype=np.float64, copy=True)
        if delay == 0:
            return out
        for a, b in self.segments:
            out[a:b] = np.interp(self.t[a:b] - delay, self.t[a:b], values[a:b])
        return out


def differentiate(y: ArrayLike, t: ArrayLike) -> FloatArray:
    """``dy/dt`` along axis 0 with the filter of the module docstring."""
    y = np.asarray(y, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    if y.shape[0] < 3:
        raise ValueError(f"need at least 3 samples to differentiate, got {y.shape[0]}")
    dt = np.diff(t)
    if y.shape[0] >= SAVGOL_WINDOW and np.ptp(dt) <= 1e-3 * np.mean(dt):
        from scipy.signal import savgol_filter

        return savgol_filter(
            y, SAVGOL_WINDOW, SAVGOL_ORDER, deriv=1, delta=float(np.mean(dt)), axis=0
        )
    return np.gradient(y, t, axis=0, edge_order=2)


_COL = re.compile(r"^(q|qd|qdd|tau|i|i_cmd|e_q|e_qd)(\d+)$")


def _joint_count(columns: list[str]) -> int:
    """Number of joints = the largest index of the ``q`` group."""
    idx = [int(m.group(2)) for c in columns if (m := _COL.match(c)) and m.group(1) == "q"]
    if not idx:
        raise ValueError("missing column 'q1': a dataset needs joint positions q1..qn")
    return max(idx)


def _not_numbers(column: pd.Series) -> str | None:
    """``"booleans"`` for a boolean column or one holding a boolean, ``"text"`` for a column of
    strings that all read as numbers (a typed file storing numbers as text), else None.
    pandas would read ``True`` as 1.0 and ``"1.5"`` as 1.5: silent wrong or unchecked numbers.
    A text column with a value that is no number is reported by its row later."""
    if pd.api.types.is_bool_dtype(column):
        return "booleans"
    if column.dtype == object or pd.api.types.is_string_dtype(column):
        values = column.to_numpy()
        if any(isinstance(v, bool | np.bool_) for v in values):
            return "booleans"
        if len(values) and all(isinstance(v, str) for v in values):
            if pd.to_numeric(column, errors="coerce").notna().all():
                return "text"
    return None


def from_frame(
    df: pd.DataFrame, n_joints: int | None = None, source: str = "<frame>"
) -> Trajectories:
    """Validate a ``DataFrame`` against the schema and build a :class:`Trajectories`.

    Raises:
        ValueError: a missing column (named), a NaN/inf value (row index and column), time
            not strictly increasing (row index), a joint count different from ``n_joints``,
            or no ``tau``/``i`` group.
    """
    cols = [str(c) for c in df.columns]
    if "t" not in cols:
        raise ValueError(f"{source}: missing column 't' (time [s])")
    n_file = _joint_count(cols)
    if n_joints is not None and n_file != n_joints:
        raise ValueError(
            f"{source}: joint count mismatch: the data has {n_file} joints (q1..q{n_file}) "
            f"but {n_joints} were expected"
        )
    n = n_file
    present: dict[str, bool] = {}
    for g in JOINT_GROUPS:
        have = [f"{g}{j}" in cols for j in range(1, n + 1)]
        if any(have) and not all(have):
            missing = f"{g}{have.index(False) + 1}"
            raise ValueError(f"{source}: missing column '{missing}' (group {g}1..{g}{n})")
        if g == "q" and not all(have):
            raise ValueError(f"{source}: missing column 'q{have.index(False) + 1}'")
        extra = [
            c for c in cols if (m := _COL.match(c)) and m.group(1) == g and int(m.group(2)) > n
        ]
        if extra:
            raise ValueError(
                f"{source}: joint count mismatch: column '{extra[0]}' but only q1..q{n} present"
            )
        present[g] = all(have)
    if not any(present[g] for g in OUTPUT_GROUPS):
        raise ValueError(
            f"{source}: missing columns 'tau1'..'tau{n}' or 'i1'..'i{n}': give joint torques "
            "or motor currents"
        )
    used = ["t"] + [f"{g}{j}" for g in JOINT_GROUPS if present[g] for j in range(1, n + 1)]
    if "contact" in cols:
        used.append("contact")
    for c in used:
        kind = _not_numbers(df[c])
        if kind is not None and not (c == "contact" and kind == "booleans"):
            raise ValueError(
                f"{source}: column '{c}' holds {kind}, not numbers; store its measured values "
                "as numbers"
            )
    values = df[used].apply(pd.to_numeric, errors="coerce").to_numpy(dtype=np.float64)
    bad = ~np.isfinite(values)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise ValueError(
            f"{source}: row {df.index[row]} has a NaN/inf/non-numeric value in column "
            f"'{used[col]}'; drop or fill that row"
        )
    check_plausible(values, used, df.index, source)
    t = values[:, 0]
    if t.size < 2:
        raise ValueError(f"{source}: need at least 2 rows, got {t.size}")
    dt = np.diff(t)
    if (dt <= 0).any():
        k = int(np.argmax(dt <= 0)) + 1
        raise ValueError(
            f"{source}: time is not strictly increasing at row {df.index[k]} "
            f"(t={t[k]} after t={t[k - 1]})"
        )
    arrays: dict[str, Any] = {}
    for g in JOINT_GROUPS:
        if present[g]:
            idx = [used.index(f"{g}{j}") for j in range(1, n + 1)]
            arrays[g] = values[:, idx]
    check_units(arrays, t, source)
    computed: list[str] = []
    warned: list[str] = []
    for g, of in (("qd", "q"), ("qdd", "qd")):
        if g not in arrays:
            if t.size < 3:
                raise ValueError(
                    f"{source}: {t.size} rows; computing {g} from {of} needs at least 3 "
                    f"(give {g}1..{g}{n} or more rows)"
                )
            arrays[g] = differentiate(arrays[of], t)
            computed.append(g)
            warned += sampling_warnings(arrays[g], g, of, source)
    contact = None
    if "contact" in used:
        contact = values[:, used.index("contact")].astype(np.int64)
    extras = {c: df[c].to_numpy() for c in cols if c not in used}
    metadata: dict[str, Any] = {"source": source, "computed": computed}
    if warned:
        metadata["warnings"] = warned
        for text in warned:
            warnings.warn(text, RuntimeWarning, stacklevel=2)
    return Trajectories(t=t, contact=contact, extras=extras, metadata=metadata, **arrays)


def check_plausible(values: FloatArray, columns: list[str], index: Any, source: str) -> None:
    """Raise ValueError naming the column, row and value of the first entry beyond
    :data:`PLAUSIBLE_LIMITS` (``values`` holds ``columns``; ``index`` gives row labels)."""
    for c, name in enumerate(columns):
        m = _COL.match(name)
        limit = PLAUSIBLE_LIMITS.get(m.group(1) if m else name)
        if limit is None:
            continue
        big = np.abs(values[:, c]) > limit
        if big.any():
            r = int(np.argmax(big))
            group = m.group(1) if m else name
            raise ValueError(
                f"{source}: column '{name}' holds {values[r, c]:.3g} at row {index[r]}, beyond "
                f"the plausible +-{limit:g} {UNITS[group]}; check the unit of that column or "
                "drop the row"
            )


def unit_factor(x: FloatArray, xd: FloatArray, t: FloatArray) -> float | None:
    """Least-squares factor ``k`` in ``diff(x) = k * integral(xd dt)`` (trapezoid per
    sample), or None when the two do not correlate well enough to tell
    (:data:`UNIT_CHECK_CORRELATION`); ``k = 1`` when both are in the same unit."""
    dx = np.diff(x)
    integral = 0.5 * (xd[1:] + xd[:-1]) * np.diff(t)
    norm = float(np.linalg.norm(dx) * np.linalg.norm(integral))
    if not norm > 0 or not np.isfinite(norm):
        return None
    dot = float(dx @ integral)
    if dot / norm < UNIT_CHECK_CORRELATION:
        return None
    return dot / float(integral @ integral)


def check_units(arrays: dict[str, FloatArray], t: FloatArray, source: str) -> None:
    """Raise ValueError when a position and its given velocity (or a velocity and its given
    acceleration) disagree by more than :data:`UNIT_FACTOR_LIMIT`, e.g. ``q`` in degrees and
    ``qd`` in rad/s (factor 180/pi)."""
    for g, of in (("qd", "q"), ("qdd", "qd")):
        if g not in arrays or of not in arrays or t.size < 3:
            continue
        for j in range(arrays[of].shape[1]):
            k = unit_factor(arrays[of][:, j], arrays[g][:, j], t)
            if k is None or 1.0 / UNIT_FACTOR_LIMIT <= k <= UNIT_FACTOR_LIMIT:
                continue
            deg = 180.0 / np.pi
            if abs(k / deg - 1.0) < 0.1:
                hint = f"{of}{j + 1} looks like degrees: convert it to rad (x pi/180)"
            elif abs(k * deg - 1.0) < 0.1:
                hint = f"{g}{j + 1} looks like degrees per second: convert it to rad (x pi/180)"
            else:
                hint = f"give both in the units of the schema ({UNITS[of]}, {UNITS[g]})"
            raise ValueError(
                f"{source}: '{of}{j + 1}' and the time integral of '{g}{j + 1}' disagree by a "
                f"factor {k:.3g}; {hint}"
            )


def sampling_warnings(
    derivative: FloatArray,
    g: str,
    of: str,
    source: str,
    min_samples: int = MIN_SAMPLES_PER_SWING,
    how: str = "computed",
    limit: str | None = None,
) -> list[str]:
    """Warnings for joints whose ``g`` (derivative of ``of``, obtained ``how``) reverses sign
    (beyond 10 % of its peak) in fewer than ``min_samples`` samples on average (default
    :data:`MIN_SAMPLES_PER_SWING`): sampled too coarsely for it. ``limit`` names the bound in
    the message (default: what the finite difference needs)."""
    limit = f"the {min_samples} the derivative needs" if limit is None else limit
    out = []
    for j in range(derivative.shape[1]):
        d = derivative[:, j]
        big = np.abs(d) > 0.1 * float(np.max(np.abs(d)) or 1.0)
        signs = np.sign(d[big])
        reversals = int(np.count_nonzero(signs[1:] != signs[:-1]))
        if reversals and d.size / (reversals + 1) < min_samples:
            out.append(
                f"{source}: {g}{j + 1} {how} from {of}{j + 1} changes sign every "
                f"{d.size / (reversals + 1):.1f} samples on average, fewer than {limit}: "
                f"sample faster or give {g}{j + 1}; results that use {g} are unreliable"
            )
    return out


def _read_table(path: Path, suffix: str) -> tuple[pd.DataFrame, dict[str, Any]]:
    """The frame of a CSV or Parquet file and the metadata stored with it."""
    stored: dict[str, Any] = {}
    if suffix == ".csv":
        df = pd.read_csv(path)
        sidecar = path.with_suffix(path.suffix + ".json")
        if sidecar.exists():
            stored = json.loads(sidecar.read_text())
        return df, stored
    import pyarrow.parquet as pq

    table = pq.read_table(path)
    raw = (table.schema.metadata or {}).get(b"mcpilco")
    stored = json.loads(raw) if raw else {}
    return table.to_pandas(), stored


def load_dataset(path: str | Path, n_joints: int | None = None) -> Trajectories:
    """Read and validate a CSV (``.csv``) or Parquet (``.parquet``/``.pq``) robot file.

    Metadata stored by :func:`save_dataset` (Parquet key ``mcpilco``; CSV sidecar
    ``<file>.json``) is merged into :attr:`Trajectories.metadata`.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no dataset at {path}")
    if not path.is_file():
        raise ValueError(f"{path} is not a file; give a .csv or .parquet measurement file")
    suffix = path.suffix.lower()
    if suffix not in (".parquet", ".pq", ".csv"):
        raise ValueError(f"{path}: unknown file type {suffix!r}; use .csv or .parquet")
    try:
        df, stored = _read_table(path, suffix)
    except (ValueError, OSError, UnicodeDecodeError, ImportError, RecursionError) as err:
        what = " ".join(str(err).split())[:200] or type(err).__name__
        raise ValueError(
            f"{path}: cannot be read as {suffix[1:]} ({what}); check that it is a complete "
            "measurement file of that type"
        ) from err
    if df.shape[0] == 0:
        raise ValueError(f"{path}: holds no rows; give a file with measurements")
    ds = from_frame(df, n_joints=n_joints, source=str(path))
    ds.metadata = {**stored, **ds.metadata}
    return ds


def make_dataset(
    arrays: dict[str, ArrayLike], metadata: dict[str, Any] | None = None
) -> Trajectories:
    """A validated :class:`Trajectories` from arrays keyed by group name (``t``, ``q``, ...;
    other keys become extra columns: 1-D as is, ``(N, m)`` as ``key_1..key_m``, forces
    ``f_*`` of shape ``(N, 3)`` as ``key_x/y/z``)."""
    if "q" not in arrays or "t" not in arrays:
        raise ValueError("arrays need at least 't' and 'q'")
    q = np.asarray(arrays["q"], dtype=np.float64)
    if q.ndim != 2:
        raise ValueError(f"'q' must be (N, n), got shape {q.shape}")
    n = q.shape[1]
    cols: dict[str, Any] = {"t": np.asarray(arrays["t"], dtype=np.float64)}
    for key, value in arrays.items():
        if key == "t":
            continue
        arr = np.asarray(value)
        if key in JOINT_GROUPS:
            if arr.shape != q.shape:
                raise ValueError(f"'{key}' must have shape {q.shape} like 'q', got {arr.shape}")
            cols.update({f"{key}{j + 1}": arr[:, j] for j in range(n)})
        elif arr.ndim == 1:
            cols[key] = arr
        else:
            vector3 = key.startswith("f_") and arr.shape[1] == 3  # forces: _x, _y, _z
            names = "xyz" if vector3 else [str(k + 1) for k in range(arr.shape[1])]
            cols.update({f"{key}_{c}": arr[:, k] for k, c in enumerate(names)})
    ds = from_frame(pd.DataFrame(cols), n_joints=n)
    ds.metadata = {**(metadata or {}), **ds.metadata}
    ds.metadata["source"] = "<arrays>"
    return ds


def save_dataset(
    dataset: Trajectories | dict[str, ArrayLike],
    path: str | Path,
    metadata: dict[str, Any] | None = None,
) -> Path:
    """Write a dataset (or arrays, see :func:`make_dataset`) as CSV or Parquet by suffix.

    Columns follow :func:`column_names` order (absent groups skipped), then extras.
    ``metadata`` (JSON-serialisable) goes into the Parquet schema metadata (key
    ``mcpilco``) or a CSV sidecar ``<file>.json``.
    """
    if not isinstance(dataset, Trajectories):
        dataset = make_dataset(dataset, metadata)
    path = Path(path)
    meta = {**dataset.metadata, **(metadata or {})}
    meta.pop("source", None)
    meta["units"] = UNITS
    df = dataset.to_frame()
    path.parent.mkdir(parents=True, exist_ok=True)
    suffix = path.suffix.lower()
    if suffix in (".parquet", ".pq"):
        import pyarrow as pa
        import pyarrow.parquet as pq

        table = pa.Table.from_pandas(df, preserve_index=False)
        schema_meta = dict(table.schema.metadata or {})
        schema_meta[b"mcpilco"] = json.dumps(meta).encode()
        pq.write_table(table.replace_schema_metadata(schema_meta), path)
    elif suffix == ".csv":
        df.to_csv(path, index=False)
        path.with_suffix(path.suffix + ".json").write_text(json.dumps(meta, indent=1))
    else:
        raise ValueError(f"{path}: unknown file type {suffix!r}; use .csv or .parquet")
    return path

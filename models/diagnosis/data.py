"""Trajectories for the diagnosis loop: several measurement files stacked, one segment each.

A *trajectory* is one measurement file (one :class:`~mcpilco.models.robot_data.RobotDataset`).
The diagnosis loop holds trajectories out *whole* (never single samples of one), shifts
targets in time inside a trajectory (delay scan), and averages residuals around velocity
reversals inside a trajectory, so it keeps the segment of every sample.

Glossary
--------
``y``
    the measured joint output, ``(N, n)``: the ``tau`` group (N m / N) or, when a file has no
    torques, the motor currents ``i`` (A). All files of one set must give the same group.
``segment``
    ``(N,)`` index of the file each sample came from; ``segments`` are the ``(start, stop)``
    row ranges.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from mcpilco.models.robot_data import RobotDataset, load_dataset

FloatArray = NDArray[np.float64]

__all__ = [
    "MIN_FIT_ROWS",
    "MIN_HELDOUT_ROWS",
    "Trajectories",
    "as_trajectories",
    "load_trajectories",
    "require_rows",
]

MIN_FIT_ROWS = 100
"""Fewest training rows a diagnosis model is fitted on: the start model, the noise level
and up to a dozen effect parameters per joint are estimated from them."""
MIN_HELDOUT_ROWS = 50
"""Fewest held-out rows an effect is confirmed or rejected on (the held-out RMSE change
must stand out from its sampling noise)."""


@dataclass
class Trajectories:
    """Stacked trajectories ``t (N,)``, ``q, qd, qdd, y (N, n)``, ``segment (N,)``.

    Attributes:
        output: ``"tau"`` or ``"i"`` (what ``y`` holds).
        names: the source of every segment (file path or ``"<arrays>"``).
    """

    t: FloatArray
    q: FloatArray
    qd: FloatArray
    qdd: FloatArray
    y: FloatArray
    segment: NDArray[np.int64]
    output: str = "tau"
    names: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

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
        """Median sample time [s] over all segments."""
        dts = [np.diff(self.t[a:b]) for a, b in self.segments if b - a > 1]
        return float(np.median(np.concatenate(dts))) if dts else float("nan")

    def select(self, segments: Sequence[int]) -> Trajectories:
        """The listed segments only (renumbered ``0..k-1``)."""
        keep = np.isin(self.segment, list(segments))
        seg = self.segment[keep]
        remap = {s: k for k, s in enumerate(sorted(set(seg.tolist())))}
        return Trajectories(
            t=self.t[keep],
            q=self.q[keep],
            qd=self.qd[keep],
            qdd=self.qdd[keep],
            y=self.y[keep],
            segment=np.array([remap[s] for s in seg.tolist()], dtype=np.int64),
            output=self.output,
            names=[self.names[s] for s in sorted(remap)],
            warnings=list(self.warnings),
        )

    def split_time(self, fraction: float) -> tuple[Trajectories, Trajectories]:
        """Cut every segment at ``fraction`` of its rows: (first parts, last parts).

        Used to hold out a contiguous block when only one training file is given.
        """
        first = np.zeros(self.n_samples, dtype=bool)
        for a, b in self.segments:
            first[a : a + int(round(fraction * (b - a)))] = True
        return self._mask(first), self._mask(~first)

    def _mask(self, keep: NDArray[np.bool_]) -> Trajectories:
        return Trajectories(
            t=self.t[keep],
            q=self.q[keep],
            qd=self.qd[keep],
            qdd=self.qdd[keep],
            y=self.y[keep],
            segment=self.segment[keep],
            output=self.output,
            names=list(self.names),
            warnings=list(self.warnings),
        )

    def shift_index(self, rows: NDArray[np.int64], k: int) -> NDArray[np.int64]:
        """Rows ``rows + k`` clipped to each row's own segment (targets ``k`` samples later)."""
        out = rows + k
        for a, b in self.segments:
            inside = (rows >= a) & (rows < b)
            out[inside] = np.clip(out[inside], a, b - 1)
        return out

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


def as_trajectories(
    data: Trajectories | RobotDataset | Sequence[RobotDataset], n_joints: int | None = None
) -> Trajectories:
    """Stack datasets into :class:`Trajectories` (one segment per dataset).

    Raises:
        ValueError: no dataset, joint counts that differ between files or from ``n_joints``
            (the counts are named), or files that mix ``tau`` and current-only outputs.
    """
    if isinstance(data, Trajectories):
        if n_joints is not None and data.n_joints != n_joints:
            raise ValueError(
                f"joint count mismatch: the data has {data.n_joints} joints but the model "
                f"has {n_joints}"
            )
        return data
    datasets = [data] if isinstance(data, RobotDataset) else list(data)
    if not datasets:
        raise ValueError("no trajectories given; pass at least one dataset or file")
    expected = n_joints if n_joints is not None else datasets[0].n_joints
    for ds in datasets:
        if not isinstance(ds, RobotDataset):
            raise TypeError(f"expected RobotDataset objects, got {type(ds).__name__}")
        if ds.n_joints != expected:
            src = ds.metadata.get("source", "<dataset>")
            what = "the model" if n_joints is not None else "the first file"
            raise ValueError(
                f"joint count mismatch: {src} has {ds.n_joints} joints (q1..q{ds.n_joints}) "
                f"but {what} has {expected}"
            )
    output = "tau" if all(ds.tau is not None for ds in datasets) else "i"
    if output == "i" and any(ds.i is None for ds in datasets):
        raise ValueError(
            "missing columns 'tau1'..: some files have torques and others only currents; "
            "give the same output group (tau or i) in every file"
        )
    parts = {k: [] for k in ("t", "q", "qd", "qdd", "y", "segment")}
    for s, ds in enumerate(datasets):
        parts["t"].append(ds.t)
        parts["q"].append(ds.q)
        parts["qd"].append(ds.qd)
        parts["qdd"].append(ds.qdd)
        parts["y"].append(ds.tau if output == "tau" else ds.i)
        parts["segment"].append(np.full(ds.n_samples, s, dtype=np.int64))
    return Trajectories(
        **{k: np.concatenate(v) for k, v in parts.items()},
        output=output,
        names=[str(ds.metadata.get("source", "<arrays>")) for ds in datasets],
        warnings=[w for ds in datasets for w in ds.metadata.get("warnings", [])],
    )


def load_trajectories(paths: Sequence[str | Path], n_joints: int | None = None) -> Trajectories:
    """Load and validate measurement files (CSV/Parquet, schema of ``models.robot_data``)."""
    return as_trajectories([load_dataset(p, n_joints=n_joints) for p in paths], n_joints)


def require_rows(traj: Trajectories, needed: int, what: str) -> None:
    """Raise ValueError when ``traj`` has fewer than ``needed`` rows for ``what`` (e.g.
    ``"the fit"``); the message gives both numbers and the files."""
    if traj.n_samples < needed:
        files = ", ".join(traj.names) or "<arrays>"
        raise ValueError(
            f"{what} needs at least {needed} rows, got {traj.n_samples} ({files}); give longer "
            "or more measurement files"
        )

"""Trajectories for the diagnosis loop: several measurement files stacked, one segment each.

A *trajectory* is one measurement file. The loop's data are
:class:`~mcpilco.models.robot_data.Trajectories`, the package's one container of robot logs,
stacked by :func:`as_trajectories`: the loop holds trajectories out *whole* (never single
samples of one), shifts targets in time inside a trajectory (delay scan), and averages
residuals around velocity reversals inside a trajectory, so it keeps the segment of every
sample.

Glossary
--------
``y``
    the measured joint output, ``(N, n)``: the ``tau`` group (N m / N) or, when a file has no
    torques, the motor currents ``i`` (A, columns ``i1..in``). All files of one set must give
    the same group. Currents are put into torque units by
    :mod:`~mcpilco.models.diagnosis.units` (``y = k_t i``) before the loop scores effects.
``segment``
    ``(N,)`` index of the file each sample came from; ``segments`` are the ``(start, stop)``
    row ranges.

Position-only files
-------------------
A file that gives ``t, q`` and ``tau`` (or ``i``) but no ``qd``/``qdd`` columns, as a real
controller's log often does, gets them from :func:`estimate_derivatives`: a central
Savitzky-Golay filter of :func:`derivative_filter` (a local least-squares polynomial of order
``p = 4`` over ``L = 2 m + 1`` samples, ``m = round(W / (2 T))`` with ``T`` the sample time,
at least ``L = 7``). ``qd`` and ``qdd`` are the first and second derivatives of that
polynomial at the window's centre (both from ``q``, not ``qdd`` from ``qd``). The span ``W``
is chosen per file (:func:`choose_derivative_filter`) from :data:`DERIVATIVE_WINDOWS`
(0.1 to 0.4 s). Properties (all in :class:`DerivativeFilter`):

* zero lag: the coefficients are (anti)symmetric, so the phase is exactly ``-j w`` /
  ``-w^2`` times a real gain; no delay is introduced (offline, non-causal). The first and
  last ``m`` samples use a fit over the edge window (``mode="interp"``), evaluated ``m``
  samples off its centre: its second derivative there errs by far more than the central
  estimate (on a simulated arm, several N m of inverse-dynamics torque in the first rows,
  where the central rows are at the torque noise).
  :meth:`~mcpilco.models.robot_data.Trajectories.interior` drops these edge rows; the
  diagnosis fits and evaluates models on the interior rows only.
* noise gain: white noise of standard deviation ``sigma_q`` on ``q`` (e.g. encoder
  quantisation, ``sigma_q = step / sqrt(12)``) becomes ``sigma_qd = ||c_1|| sigma_q`` and
  ``sigma_qdd = ||c_2|| sigma_q`` with ``c_k`` the filter's coefficients (units 1/s and
  1/s^2); for ``T = 4`` ms these are about 17 /s and 1.9e3 /s^2.
* bandwidth: the highest frequency at which the gain of the ``k``-th derivative stays within
  5 % of the exact ``w^k`` (about 7-8 Hz for ``W = 0.1`` s, whatever ``T``); faster content
  is attenuated, which the residuals see as a model error.

Choice of the span (bias against noise). A longer window lowers the noise gain (``||c_2||``
falls about as ``W^-2.5``) and attenuates faster motion. With a fine encoder the noise of
``qdd`` is negligible at ``W = 0.1`` s; with a coarse one (``2^15`` counts per revolution,
``T = 4`` ms) it is about 0.15 rad/s^2, enough to carry several noise stds of torque through
the mass matrix: the noise floor rises, and a fit of an inertial effect on noisy ``qdd`` is
biased towards zero (errors in variables) while a model that merely damps the noisy
regressors looks better on held-out data. For every joint ``j`` and candidate span ``W``,
:func:`choose_derivative_filter` estimates the mean square error of ``qdd_j`` as
``bias^2 + ||c_2(W)||^2 sigma_j^2``: ``sigma_j`` is the noise std of ``q_j``
(:func:`smoother_noise_std`), and ``bias^2`` is the mean square difference between the
estimates at ``W`` and at the shortest span, less the part that their noise explains
(``||c_2(W) - c_2(W_0)||^2 sigma_j^2``, coefficient rows centred and zero-padded), taken as
0 when negative; the shortest span's own bias counts as 0. Each joint's best span is the one
of least error; the file gets the shortest of these (no joint gets a span that biases it
more than it gains in noise). Smooth, slow motion read by a coarse encoder gets a long
window; sharp motion (stick-slip at a velocity reversal) keeps the short one.

Files that already give ``qd`` and ``qdd`` are used as given. The estimate needs a uniform
time grid: a segment whose sample intervals depart from their median by more than
:data:`SAMPLING_TOLERANCE` (relative) is refused.
:attr:`~mcpilco.models.robot_data.Trajectories.estimated` records, per segment, which
groups were estimated and with which filter, so that the loop can count
the noise they carry.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy.signal import savgol_coeffs, savgol_filter

from mcpilco.models.robot_data import Trajectories, load_dataset, sampling_warnings

if TYPE_CHECKING:
    from mcpilco.models.diagnosis.bags import BagOptions

FloatArray = NDArray[np.float64]

__all__ = [
    "DERIVATIVE_ORDER",
    "DERIVATIVE_WINDOW",
    "DERIVATIVE_WINDOWS",
    "MIN_FIT_ROWS",
    "SAMPLING_TOLERANCE",
    "DerivativeFilter",
    "Estimate",
    "derivative_filter",
    "estimate_derivatives",
    "MIN_HELDOUT_ROWS",
    "as_trajectories",
    "choose_derivative_filter",
    "load_trajectories",
    "require_motion",
    "require_rows",
    "smoother_noise_std",
    "uniform_sample_time",
]

MIN_FIT_ROWS = 100
"""Fewest training rows a diagnosis model is fitted on: the start model, the noise level
and up to a dozen effect parameters per joint are estimated from them."""
MIN_HELDOUT_ROWS = 50
"""Fewest held-out rows an effect is confirmed or rejected on (the held-out RMSE change
must stand out from its sampling noise)."""
MIN_MOTION = 1e-3
"""Smallest range of a joint's position [rad or m] in a log that identifies anything: below
it (0.06 deg, 1 mm) the arm stood still and every regressor but gravity is noise."""

DERIVATIVE_WINDOW = 0.1
"""Shortest (and default) time span ``W`` [s] of the Savitzky-Golay window that estimates
``qd``/``qdd`` from ``q``."""
DERIVATIVE_WINDOWS = (0.1, 0.14, 0.2, 0.28, 0.4)
"""Candidate spans ``W`` [s] of :func:`choose_derivative_filter` (ratio about ``sqrt 2``)."""
DERIVATIVE_ORDER = 4
"""Polynomial order ``p`` of that filter."""
SAMPLING_TOLERANCE = 1e-3
"""Largest relative departure of a sample interval from the median one for an estimate."""
BANDWIDTH_ERROR = 0.05
"""Relative gain error that defines :attr:`DerivativeFilter.bandwidth`."""


@dataclass(frozen=True)
class DerivativeFilter:
    """The central Savitzky-Golay filter that estimated ``qd``/``qdd`` (module docstring).

    Attributes:
        sample_time: ``T`` [s].
        window: ``L = 2 m + 1`` samples (span ``(L - 1) T``).
        order: polynomial order ``p``.
        noise_gain_qd: ``||c_1||`` [1/s]: ``sigma_qd = noise_gain_qd * sigma_q``.
        noise_gain_qdd: ``||c_2||`` [1/s^2]: ``sigma_qdd = noise_gain_qdd * sigma_q``.
        bandwidth_qd: [Hz] highest frequency with ``qd`` gain within 5 % of exact.
        bandwidth_qdd: [Hz] the same for ``qdd``.
        lag: [s], 0 (central window).
    """

    sample_time: float
    window: int
    order: int
    noise_gain_qd: float
    noise_gain_qdd: float
    bandwidth_qd: float
    bandwidth_qdd: float
    lag: float = 0.0

    @property
    def name(self) -> str:
        return f"savgol(order={self.order}, window={self.window}, T={self.sample_time:g} s)"


def _bandwidth(coeffs: FloatArray, deriv: int, dt: float) -> float:
    """Frequency [Hz] where ``|H(w)| / w^deriv`` first departs from 1 by :data:`BANDWIDTH_ERROR`."""
    m = (coeffs.size - 1) // 2
    k = np.arange(-m, m + 1)
    omega = np.linspace(1e-3, np.pi / dt, 4000)
    gain = np.abs(np.exp(1j * np.outer(omega, k) * dt) @ coeffs) / omega**deriv
    off = np.abs(gain - 1.0) > BANDWIDTH_ERROR
    return float(omega[np.argmax(off)] / (2 * np.pi)) if off.any() else float(0.5 / dt)


def derivative_filter(
    sample_time: float, window: float = DERIVATIVE_WINDOW, order: int = DERIVATIVE_ORDER
) -> DerivativeFilter:
    """The filter for samples ``sample_time`` [s] apart: ``L = 2 round(window / (2 T)) + 1``
    samples, at least ``order + 3``, with its noise gains and bandwidths."""
    if not sample_time > 0:
        raise ValueError(f"sample_time must be > 0, got {sample_time}")
    half = max(int(round(window / (2.0 * sample_time))), (order + 2) // 2)
    length = 2 * half + 1
    c1 = savgol_coeffs(length, order, deriv=1, delta=sample_time, use="dot")
    c2 = savgol_coeffs(length, order, deriv=2, delta=sample_time, use="dot")
    return DerivativeFilter(
        sample_time=float(sample_time),
        window=length,
        order=order,
        noise_gain_qd=float(np.linalg.norm(c1)),
        noise_gain_qdd=float(np.linalg.norm(c2)),
        bandwidth_qd=_bandwidth(c1, 1, sample_time),
        bandwidth_qdd=_bandwidth(c2, 2, sample_time),
    )


def uniform_sample_time(t: FloatArray, source: str = "<arrays>") -> float:
    """The median sample interval of ``t`` [s]; ValueError when an interval departs from it
    by more than :data:`SAMPLING_TOLERANCE` (relative)."""
    dt = np.diff(np.asarray(t, dtype=np.float64))
    if dt.size == 0:
        raise ValueError(f"{source}: needs at least 2 samples to estimate derivatives")
    med = float(np.median(dt))
    worst = int(np.argmax(np.abs(dt - med)))
    if not med > 0 or abs(dt[worst] - med) > SAMPLING_TOLERANCE * med:
        raise ValueError(
            f"{source}: non-uniform sampling: interval {dt[worst]:.6g} s at row {worst + 1} "
            f"departs from the median {med:.6g} s by more than {SAMPLING_TOLERANCE:g} "
            "(relative); qd/qdd can only be estimated on a uniform grid: resample the file "
            "or give qd and qdd columns"
        )
    return med


def smoother_noise_std(x: FloatArray, filt: DerivativeFilter) -> FloatArray:
    """``(n,)`` std of white noise on the columns of ``x (N, n)``: ``rms(x - S x) /
    sqrt(1 - s_m)`` over the interior rows, ``S`` the Savitzky-Golay smoother of ``filt``'s
    window and order (a projection: white noise of std ``sigma`` leaves ``x - S x`` with
    variance ``sigma^2 (1 - s_m)``, ``s_m`` its centre coefficient; smooth motion passes ``S``
    unchanged). The rms and not a MAD: a uniform quantiser is far from Gaussian, and the rms
    is right for any white noise, quantisation and reading noise together."""
    m = filt.window // 2
    r = (x - savgol_filter(x, filt.window, filt.order, axis=0))[m:-m]
    s_m = float(savgol_coeffs(filt.window, filt.order, use="dot")[m])
    return np.sqrt(np.mean(r**2, axis=0) / (1.0 - s_m))


def choose_derivative_filter(
    t: FloatArray, q: FloatArray, source: str = "<arrays>"
) -> DerivativeFilter:
    """The filter of the span in :data:`DERIVATIVE_WINDOWS` with the least estimated mean
    square error of ``qdd`` (module docstring, "Choice of the span") for positions
    ``q (N, n)`` at times ``t (N,)``; spans whose window exceeds a quarter of the rows are
    not tried.

    Raises:
        ValueError: non-uniform sampling (:func:`uniform_sample_time`).
    """
    dt = uniform_sample_time(t, source)
    q = np.asarray(q, dtype=np.float64)
    base = derivative_filter(dt, DERIVATIVE_WINDOWS[0])
    if q.shape[0] < 4 * base.window:
        return base
    sigma2 = smoother_noise_std(q, base) ** 2
    kw = dict(polyorder=base.order, deriv=2, delta=dt, axis=0)
    c0 = savgol_coeffs(base.window, base.order, deriv=2, delta=dt, use="dot")
    qdd0 = savgol_filter(q, base.window, **kw)
    filters, errors = [base], [c0 @ c0 * sigma2]
    for span in DERIVATIVE_WINDOWS[1:]:
        filt = derivative_filter(dt, span)
        if filt.window <= filters[-1].window or q.shape[0] < 4 * filt.window:
            continue
        c = savgol_coeffs(filt.window, filt.order, deriv=2, delta=dt, use="dot")
        dc = c - np.pad(c0, (filt.window - base.window) // 2)
        m = filt.window // 2
        diff2 = np.mean((savgol_filter(q, filt.window, **kw) - qdd0)[m:-m] ** 2, axis=0)
        bias2 = np.maximum(diff2 - dc @ dc * sigma2, 0.0)
        filters.append(filt)
        errors.append(bias2 + c @ c * sigma2)
    return filters[int(np.argmin(np.stack(errors), axis=0).min())]


def estimate_derivatives(
    t: FloatArray,
    q: FloatArray,
    source: str = "<arrays>",
    window: float | None = DERIVATIVE_WINDOW,
) -> tuple[FloatArray, FloatArray, DerivativeFilter]:
    """``(qd, qdd, filter)`` estimated from positions ``q (N, n)`` sampled at times ``t (N,)``
    (module docstring): with the span ``window`` [s] (:func:`derivative_filter`), or, when
    ``None`` (as the loader does), the span :func:`choose_derivative_filter` picks for these
    positions.

    Raises:
        ValueError: non-uniform sampling (:func:`uniform_sample_time`) or fewer samples than
            the filter's window.
    """
    if window is None:
        filt = choose_derivative_filter(t, q, source)
    else:
        filt = derivative_filter(uniform_sample_time(t, source), window)
    q = np.asarray(q, dtype=np.float64)
    if q.shape[0] < filt.window:
        raise ValueError(
            f"{source}: {q.shape[0]} rows, fewer than the {filt.window}-sample window that "
            "estimates qd/qdd; give a longer file or qd and qdd columns"
        )
    kw = dict(window_length=filt.window, polyorder=filt.order, delta=filt.sample_time, axis=0)
    qd = savgol_filter(q, deriv=1, **kw)
    qdd = savgol_filter(q, deriv=2, **kw)
    return qd, qdd, filt


@dataclass(frozen=True)
class Estimate:
    """Which derivative groups of one segment were estimated, and by which filter.

    Attributes:
        groups: the estimated groups (``("qd", "qdd")`` or ``("qdd",)``).
        filter: the :class:`DerivativeFilter`.
        interior: ``True`` once the segment's ``window // 2`` edge rows at each end (the
            filter's edge fit) were dropped
            (:meth:`~mcpilco.models.robot_data.Trajectories.interior`).
    """

    groups: tuple[str, ...]
    filter: DerivativeFilter
    interior: bool = False

    @property
    def edge_rows(self) -> int:
        """Rows at each end of the segment whose derivatives come from the edge fit."""
        return 0 if self.interior else self.filter.window // 2


def as_trajectories(
    data: Trajectories | Sequence[Trajectories],
    n_joints: int | None = None,
    derivative_window: float | None = None,
) -> Trajectories:
    """Stack logs into one :class:`~mcpilco.models.robot_data.Trajectories` (one segment
    each) for the diagnosis; ``qd``/``qdd`` that a log lacks are estimated with the span
    ``derivative_window`` [s], or, when ``None``, the span chosen per file
    (:func:`choose_derivative_filter`). Trajectories this function prepared already
    (``estimated`` set) are returned as they are.

    Raises:
        ValueError: no log, joint counts that differ between files or from ``n_joints``
            (the counts are named), or files that mix ``tau`` and current-only outputs.
    """
    if isinstance(data, Trajectories) and data.estimated is not None:
        if n_joints is not None and data.n_joints != n_joints:
            raise ValueError(
                f"joint count mismatch: the data has {data.n_joints} joints but the model "
                f"has {n_joints}"
            )
        return data
    datasets = [data] if isinstance(data, Trajectories) else list(data)
    if not datasets:
        raise ValueError("no trajectories given; pass at least one dataset or file")
    expected = n_joints if n_joints is not None else datasets[0].n_joints
    for ds in datasets:
        if not isinstance(ds, Trajectories):
            raise TypeError(f"expected Trajectories objects, got {type(ds).__name__}")
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
    parts: dict[str, list] = {k: [] for k in ("t", "q", "qd", "qdd", "y", "segment")}
    estimated: list[Estimate | None] = []
    notes: list[str] = []
    for s, ds in enumerate(datasets):
        qd, qdd, est = _derivatives(ds, derivative_window)
        estimated.append(est)
        notes += _data_warnings(ds, est, qd, qdd)
        parts["t"].append(ds.t)
        parts["q"].append(ds.q)
        parts["qd"].append(qd)
        parts["qdd"].append(qdd)
        parts["y"].append(ds.tau if output == "tau" else ds.i)
        parts["segment"].append(np.full(ds.n_samples, s, dtype=np.int64))
    groups = {  # the optional groups every log has, stacked too
        g: np.concatenate([getattr(ds, g) for ds in datasets])
        for g in ("tau", "i", "i_cmd", "e_q", "e_qd", "contact")
        if all(getattr(ds, g) is not None for ds in datasets)
    }
    return Trajectories(
        **{k: np.concatenate(v) for k, v in parts.items()},
        **groups,
        output=output,
        names=[str(ds.metadata.get("source", "<arrays>")) for ds in datasets],
        warnings=notes,
        estimated=estimated,
    )


def _data_warnings(
    ds: Trajectories, est: Estimate | None, qd: FloatArray, qdd: FloatArray
) -> list[str]:
    """The loader's warnings of ``ds``; those about derivatives it computed are replaced by
    the same check on the estimates, with the estimate's window (``RuntimeWarning``)."""
    notes = list(ds.metadata.get("warnings", []))
    if est is None:
        return notes
    computed = re.compile(rf": ({'|'.join(est.groups)})\d+ computed from ")
    notes = [w for w in notes if not computed.search(w)]
    source = str(ds.metadata.get("source", "<arrays>"))
    new: list[str] = []
    for g, values in (("qd", qd), ("qdd", qdd)):
        if g in est.groups:
            of = "q" if "qd" in est.groups else "qd"
            new += _swing_warnings(values, g, of, est.filter.window, source)
    for text in new:
        warnings.warn(text, RuntimeWarning, stacklevel=3)
    return notes + new


def _swing_warnings(values: FloatArray, g: str, of: str, window: int, source: str) -> list[str]:
    """Joints whose estimated ``g`` reverses sign in fewer samples on average than the
    filter's ``window``: the window spans a whole swing and flattens it."""
    return sampling_warnings(
        values, g, of, source, window, "estimated", f"the {window} of the derivative filter"
    )


def _derivatives(
    ds: Trajectories, window: float | None = None
) -> tuple[FloatArray, FloatArray, Estimate | None]:
    """``qd, qdd`` of a dataset: as given, or estimated (module docstring) for the groups
    that the file lacked (``ds.metadata["computed"]``) with the span ``window`` (``None``:
    chosen); a given ``qd`` is differentiated once for a missing ``qdd``."""
    computed = tuple(g for g in ("qd", "qdd") if g in ds.metadata.get("computed", []))
    if not computed:
        return ds.qd, ds.qdd, None
    source = str(ds.metadata.get("source", "<arrays>"))
    # the span is chosen on q's second derivative; a given qd is differentiated at the default
    if "qd" not in computed:
        window = DERIVATIVE_WINDOW if window is None else window
    qd, qdd, filt = estimate_derivatives(ds.t, ds.q, source, window=window)
    if "qd" not in computed:
        qd = ds.qd
        kw = dict(window_length=filt.window, polyorder=filt.order, delta=filt.sample_time)
        qdd = savgol_filter(ds.qd, deriv=1, axis=0, **kw)
    return qd, qdd, Estimate(groups=computed, filter=filt)


def load_trajectories(
    paths: Sequence[str | Path],
    n_joints: int | None = None,
    derivative_window: float | None = None,
    bag: BagOptions | None = None,
    joint_names: Sequence[str] | None = None,
) -> Trajectories:
    """Load and validate measurement files (CSV/Parquet, schema of ``models.robot_data``;
    ROS 2 bags and MCAP files by :func:`~.bags.read_bag` with the topics of ``bag`` and the
    model's ``joint_names``); ``qd``/``qdd`` that a file lacks are estimated (module
    docstring) with the span ``derivative_window`` [s] (``None``: chosen per file)."""
    from mcpilco.models.diagnosis.bags import is_bag, read_bag

    def load(p: str | Path) -> Trajectories:
        if is_bag(p):
            return read_bag(p, joint_names, bag, n_joints=n_joints)
        if Path(p).is_dir():
            raise ValueError(
                f"{p} is a folder without metadata.yaml; give a ROS 2 bag folder, a .db3 or "
                ".mcap file, or a .csv or .parquet measurement file"
            )
        return load_dataset(p, n_joints=n_joints)

    with warnings.catch_warnings():
        # the loader's check of its own derivatives is redone on the estimates
        warnings.filterwarnings("ignore", r".* computed from .*", RuntimeWarning)
        datasets = [load(p) for p in paths]
    return as_trajectories(datasets, n_joints, derivative_window)


def require_rows(traj: Trajectories, needed: int, what: str) -> None:
    """Raise ValueError when ``traj`` has fewer than ``needed`` rows for ``what`` (e.g.
    ``"the fit"``); the message gives both numbers and the files."""
    if traj.n_samples < needed:
        files = ", ".join(traj.names) or "<arrays>"
        raise ValueError(
            f"{what} needs at least {needed} rows, got {traj.n_samples} ({files}); give longer "
            "or more measurement files"
        )


def require_motion(traj: Trajectories) -> None:
    """Raise ValueError when no joint's position range reaches :data:`MIN_MOTION` in
    ``traj``: a log of an arm at rest identifies no effect (the ranges and files are named)."""
    spans = np.ptp(traj.q, axis=0) if traj.n_samples else np.zeros(traj.n_joints)
    if (spans < MIN_MOTION).all():
        files = ", ".join(traj.names) or "<arrays>"
        ranges = ", ".join(f"{x:.2g}" for x in spans)
        raise ValueError(
            f"{files}: no joint moves more than {MIN_MOTION:g} rad or m (ranges {ranges}): a "
            "log of an arm at rest identifies nothing; record the arm moving through its range"
        )

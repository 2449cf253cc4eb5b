"""Kinematic structure identification from marker poses and joint signals (thesis 2.3-2.4).

Glossary (thesis chapter 2; markers ``M_a``, ``M_b``, joint signal ``q_k``, ``T`` frames)
---------------------------------------------------------------------------------------
``l^a_b(t), R^a_b(t)``
    relative translation / orientation of ``M_b`` seen from ``M_a``, measured from the
    camera poses (section 2.3.1, :func:`~mcpilco.models.kinematics.rotations.relative_poses`).
prismatic test (Prop. 2.3.1, eqs. 2.9 and 2.17)
    ``l^a_b(t) = [I_3, q_k(t) I_3] b`` with ``b^T H b = 1``, ``H = blkdiag(0_3, I_3)``: the
    constrained least squares has the closed form ``z = v / ||v||``,
    ``v = sum_t (q_k(t) - mean q_k)(l^a_b(t) - mean l^a_b)``, ``c = mean l - z mean q``.
    Positive when ``f_r(r) < xi_t`` **and** the relative orientation is constant: the largest
    standard deviation over time of an element of ``R^a_b`` is below ``xi_o`` (element
    deviations of a small rotation are angles in rad).
revolute linear test (Prop. 2.3.2, eqs. 2.12 and 2.18)
    ``l^a_b(t) = [I_3, R^a_b(t)] b_bar``, unconstrained least squares; positive when
    ``f_r < xi_t``. It does not involve ``q_k``.
revolute non-linear test (Prop. 2.3.3, eqs. 2.15 and 2.19)
    ``o^a_b(t) = f_o(R(o_1) Rz(q_k(t)) R(o_2))`` with 2 pi-wrapped residuals
    ``mod(o - f_o + pi, 2 pi) - pi``, solved with ``scipy.optimize.least_squares`` from an
    algebraic start (``R^a_b(t) = C_0 + cos q_k C_1 + sin q_k C_2`` by linear least squares,
    ``C_0 = a_3 b_3^T`` gives the joint axis, both signs tried) and optional random
    restarts; positive when ``f_r < xi_o``.
``f_r(r) = sqrt(r^T r / N)``
    root mean square of the ``N`` residuals (section 2.4.3).
iterative algorithm (Fig. 2.3)
    the base marker is the one whose camera pose is constant; then the chain grows one
    triplet (current marker, new marker, unused joint) at a time: prismatic test first, the
    revolute tests if it fails. Outputs ``S_M`` (markers), ``S_Q`` (types), ``S_q`` (joints).

Thresholds: ``xi_t = 0.02`` m and ``xi_o = 0.1`` rad (section 2.6.2) are the defaults.
"""

from __future__ import annotations

import itertools
import warnings
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from mcpilco.models.kinematics.rotations import (
    matrix_to_ypr,
    relative_poses,
    wrap_angle,
    ypr_to_matrix,
)

__all__ = [
    "KinematicStructure",
    "TripletResult",
    "classify_all_triplets",
    "classify_triplet",
    "find_base_marker",
    "identify_structure",
    "prismatic_test",
    "revolute_linear_test",
    "revolute_nonlinear_test",
    "rms",
]

FloatArray = NDArray[np.float64]
XI_T = 0.02
"""Default RMS threshold on translations [m] (thesis section 2.6.2)."""
XI_O = 0.1
"""Default RMS threshold on angles [rad] (thesis section 2.6.2)."""
NAN_POLICIES = ("raise", "drop", "pairwise")
"""What to do with missing marker poses (NaN): see :func:`identify_structure`."""
MIN_PAIR_FRAMES = 10
"""``nan_policy="pairwise"``: fewest frames showing both markers for a pair to be tested."""


def rms(r: ArrayLike) -> float:
    """``f_r(r) = sqrt(r^T r / N)`` (section 2.4.3)."""
    r = np.ravel(np.asarray(r, dtype=np.float64))
    return float(np.sqrt(np.mean(r**2))) if r.size else 0.0


# ----------------------------------------------------------------------------- the three tests


def prismatic_test(
    l_ab: ArrayLike, R_ab: ArrayLike, q: ArrayLike
) -> tuple[float, float, FloatArray]:
    """Prismatic test of Prop. 2.3.1: constrained least squares (2.17) + orientation spread.

    Args:
        l_ab: ``(T, 3)`` relative translations ``l^a_b(t)`` [m].
        R_ab: ``(T, 3, 3)`` relative orientations ``R^a_b(t)``.
        q: ``(T,)`` joint signal ``q_k(t)``.

    Returns:
        ``(f_r, orientation_std, b_hat)``: the RMS residual of eq. 2.9 at the constrained
        optimum [m], the largest standard deviation over time of an element of ``R^a_b``
        [~rad], and ``b_hat = [c, z]`` ``(6,)`` with ``||z|| = 1``.
    """
    l_ab, R_ab, q = (np.asarray(x, dtype=np.float64) for x in (l_ab, R_ab, q))
    dq = q - q.mean()
    dl = l_ab - l_ab.mean(0)
    v = dq @ dl
    norm = np.linalg.norm(v)
    z = v / norm if norm > 0 else np.array([0.0, 0.0, 1.0])
    c = l_ab.mean(0) - q.mean() * z
    resid = l_ab - c - q[:, None] * z
    orientation_std = float(np.sqrt(R_ab.reshape(-1, 9).var(0).max()))
    return rms(resid), orientation_std, np.concatenate([c, z])


def revolute_linear_test(l_ab: ArrayLike, R_ab: ArrayLike) -> tuple[float, FloatArray]:
    """Revolute linear test of Prop. 2.3.2: ``l^a_b = [I, R^a_b] b_bar`` by least squares (2.18).

    Returns ``(f_r, b_bar)``; a rank-deficient regressor (``R^a_b`` constant) is solved with
    the pseudo-inverse (footnote of eq. 2.18).
    """
    l_ab, R_ab = np.asarray(l_ab, dtype=np.float64), np.asarray(R_ab, dtype=np.float64)
    T = l_ab.shape[0]
    A = np.concatenate([np.broadcast_to(np.eye(3), (T, 3, 3)), R_ab], axis=2).reshape(3 * T, 6)
    y = l_ab.reshape(3 * T)
    b_bar, *_ = np.linalg.lstsq(A, y, rcond=None)
    return rms(y - A @ b_bar), b_bar


# elements (row, col) of R used by eq. 2.20: R11, R21, R31, R32, R33
_YPR_ELEMENTS = ([0, 1, 2, 2, 2], [0, 0, 0, 1, 2])


def _fo(params: FloatArray, cos_sin: FloatArray) -> FloatArray:
    """``f_o(R(o_1) Rz(q) R(o_2))`` for all ``q`` and a batch of parameters.

    ``params`` ``(K, 6)`` -> ``(K, T, 3)`` angles. Uses ``A Rz(q) B = a_3 b_3^T + cos q
    (a_1 b_1^T + a_2 b_2^T) + sin q (a_2 b_1^T - a_1 b_2^T)`` (``a_i`` columns of ``A``,
    ``b_i^T`` rows of ``B``) on the five elements eq. 2.20 needs; ``cos_sin`` is ``(T, 3)``
    with columns ``[1, cos q, sin q]``.
    """
    rows, cols = _YPR_ELEMENTS
    Ar = ypr_to_matrix(params[:, :3])[:, rows]  # (K, 5, 3): rows of A
    Bc = ypr_to_matrix(params[:, 3:])[:, :, cols]  # (K, 3, 5): columns of B
    C = np.stack(
        [
            Ar[..., 2] * Bc[:, 2],
            Ar[..., 0] * Bc[:, 0] + Ar[..., 1] * Bc[:, 1],
            Ar[..., 1] * Bc[:, 0] - Ar[..., 0] * Bc[:, 1],
        ],
        axis=1,
    )  # (K, 3, 5): C_0, C_1, C_2 restricted to the five elements
    E = cos_sin @ C  # (K, T, 5)
    r11, r21, r31, r32, r33 = np.moveaxis(E, -1, 0)
    return np.stack(
        [np.arctan2(r21, r11), np.arctan2(-r31, np.hypot(r32, r33)), np.arctan2(r32, r33)],
        axis=-1,
    )


_FD_STEP = 1e-7
_FD_BASIS = np.vstack([np.zeros(6), _FD_STEP * np.eye(6)])


def _project_so3(M: FloatArray) -> FloatArray:
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def _algebraic_starts(R_ab: FloatArray, q: FloatArray) -> list[FloatArray]:
    """Starting points for eq. 2.19 from ``R^a_b(t) = C_0 + cos q C_1 + sin q C_2`` (LS).

    ``C_0 = a_3 b_3^T`` (``a_3`` the joint axis in ``M_a``, ``b_3^T`` the third row of ``B``);
    ``A`` is completed around ``+-a_3`` and ``B = A^T (C_0 + C_1)`` projected on SO(3). Returns
    both axis signs (``[o_1, o_2]`` each), or nothing when ``cos q, sin q`` do not vary.
    """
    Phi = np.column_stack([np.ones_like(q), np.cos(q), np.sin(q)])
    if np.linalg.matrix_rank(Phi, tol=1e-6 * len(q)) < 3:
        return []
    C, *_ = np.linalg.lstsq(Phi, R_ab.reshape(-1, 9), rcond=None)
    C0, C1 = C[0].reshape(3, 3), C[1].reshape(3, 3)
    U, _, _ = np.linalg.svd(C0)
    starts = []
    for sign in (1.0, -1.0):
        a3 = sign * U[:, 0]
        helper = np.array([1.0, 0.0, 0.0]) if abs(a3[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        a1 = np.cross(helper, a3)
        a1 /= np.linalg.norm(a1)
        A = np.column_stack([a1, np.cross(a3, a1), a3])
        B = _project_so3(A.T @ (C0 + C1))
        starts.append(np.concatenate([matrix_to_ypr(A), matrix_to_ypr(B)]))
    return starts


def revolute_nonlinear_test(
    R_ab: ArrayLike,
    q: ArrayLike,
    *,
    n_random_starts: int = 0,
    tol: float | None = None,
    max_nfev: int = 100,
    seed: int = 0,
) -> tuple[float, FloatArray]:
    """Revolute non-linear test of Prop. 2.3.3: angles with wrapped residuals (eq. 2.19).

    Args:
        R_ab: ``(T, 3, 3)`` relative orientations.
        q: ``(T,)`` joint signal.
        n_random_starts: extra random starting points, tried after the two algebraic starts
            when these do not reach ``tol``; at least 2 are used when ``cos q, sin q`` do
            not vary (no algebraic start).
        tol: stop trying starts once ``f_r`` is below this (e.g. ``xi_o / 2``); ``None`` tries
            all of them.
        max_nfev: residual evaluations per start (the Jacobian, batched forward differences,
            is not counted).
        seed: seed of the random starts.

    Returns:
        ``(f_r, [o_1, o_2])``: the smallest RMS wrapped residual [rad] found and its minimiser
        (``o_1`` the yaw-pitch-roll of ``R^{M_a}_{L_j1}``, ``o_2`` of ``R^{L_j2}_{M_b}``).
    """
    R_ab, q = np.asarray(R_ab, dtype=np.float64), np.asarray(q, dtype=np.float64)
    o_meas = matrix_to_ypr(R_ab)
    cos_sin = np.column_stack([np.ones_like(q), np.cos(q), np.sin(q)])

    def residual(params: FloatArray) -> FloatArray:
        return wrap_angle(o_meas - _fo(params[None], cos_sin)[0]).ravel()

    def jacobian(params: FloatArray) -> FloatArray:
        # forward differences, all six perturbations in one batched evaluation
        f = _fo(params + _FD_BASIS, cos_sin)
        return -(wrap_angle(f[1:] - f[0]) / _FD_STEP).reshape(6, -1).T

    rng = np.random.default_rng(seed)
    starts = _algebraic_starts(R_ab, q)
    n_random = n_random_starts if starts else max(n_random_starts, 2)
    starts += [rng.uniform(-np.pi, np.pi, 6) for _ in range(n_random)]
    best_rms, best_x = np.inf, np.zeros(6)
    for x0 in starts:
        if rms(residual(x0)) < 1e-12:
            return rms(residual(x0)), x0
        sol = least_squares(residual, x0, jac=jacobian, method="lm", max_nfev=max_nfev)
        value = rms(sol.fun)
        if value < best_rms:
            best_rms, best_x = value, sol.x
        if tol is not None and best_rms < tol:
            break
    return best_rms, best_x


# ----------------------------------------------------------------------------- triplets


@dataclass(frozen=True)
class TripletResult:
    """The three tests on one triplet ``(M_a, M_b, q_k)`` (indices into the input arrays).

    ``revolute_angle_rms`` / ``revolute_nonlinear`` are ``None`` when the non-linear test
    was skipped (the linear test failed and ``evaluate_all`` was off, as in Fig. 2.3).
    """

    marker_a: int
    marker_b: int
    joint: int
    prismatic_rms: float
    orientation_std: float
    revolute_linear_rms: float
    revolute_angle_rms: float | None
    prismatic: bool
    revolute_linear: bool
    revolute_nonlinear: bool | None

    @property
    def joint_type(self) -> str | None:
        """``"P"`` if the prismatic test passes, else ``"R"`` if both revolute tests pass,
        else ``None`` (not connected), following the flow chart of Fig. 2.3."""
        if self.prismatic:
            return "P"
        if self.revolute_linear and self.revolute_nonlinear:
            return "R"
        return None

    def score(self, xi_t: float, xi_o: float) -> float:
        """Largest normalised residual of the passing test (lower is more certain)."""
        if self.prismatic:
            return max(self.prismatic_rms / xi_t, self.orientation_std / xi_o)
        assert self.revolute_angle_rms is not None
        return max(self.revolute_linear_rms / xi_t, self.revolute_angle_rms / xi_o)


def classify_triplet(
    pose_a: ArrayLike,
    pose_b: ArrayLike,
    q: ArrayLike,
    *,
    xi_t: float = XI_T,
    xi_o: float = XI_O,
    evaluate_all: bool = False,
    max_nfev: int = 100,
    indices: tuple[int, int, int] = (0, 1, 0),
    _relative: tuple[FloatArray, FloatArray] | None = None,
    _linear_rms: float | None = None,
) -> TripletResult:
    """Run the tests of Fig. 2.3 on one triplet.

    Args:
        pose_a, pose_b: ``(T, 6)`` camera poses ``[x, y, z, gamma, beta, alpha]`` of the
            two markers (finite).
        q: ``(T,)`` joint signal.
        xi_t: threshold on translation RMS residuals [m].
        xi_o: threshold on angle RMS residuals and on the orientation spread [rad].
        evaluate_all: run every test (for confusion matrices) instead of stopping early.
        max_nfev: evaluations per start of the non-linear least squares.
        indices: ``(a, b, k)`` stored in the result.
    """
    l_ab, R_ab = _relative if _relative is not None else relative_poses(pose_a, pose_b)
    q = np.asarray(q, dtype=np.float64)
    p_rms, o_std, _ = prismatic_test(l_ab, R_ab, q)
    prismatic = p_rms < xi_t and o_std < xi_o
    lin_rms = _linear_rms if _linear_rms is not None else revolute_linear_test(l_ab, R_ab)[0]
    linear = lin_rms < xi_t
    ang_rms, nonlinear = None, None
    if evaluate_all or (linear and not prismatic):
        ang_rms = revolute_nonlinear_test(R_ab, q, tol=0.5 * xi_o, max_nfev=max_nfev)[0]
        nonlinear = ang_rms < xi_o
    a, b, k = indices
    return TripletResult(
        marker_a=a,
        marker_b=b,
        joint=k,
        prismatic_rms=p_rms,
        orientation_std=o_std,
        revolute_linear_rms=lin_rms,
        revolute_angle_rms=ang_rms,
        prismatic=bool(prismatic),
        revolute_linear=bool(linear),
        revolute_nonlinear=None if nonlinear is None else bool(nonlinear),
    )


# ----------------------------------------------------------------------------- validation


def _validate(
    marker_poses: ArrayLike, joint_positions: ArrayLike, nan_policy: str
) -> tuple[FloatArray, FloatArray, int]:
    """Check shapes / finiteness; returns the (possibly row-dropped) arrays and the drop count."""
    P = np.asarray(marker_poses, dtype=np.float64)
    Q = np.asarray(joint_positions, dtype=np.float64)
    if P.ndim != 3 or P.shape[2] != 6:
        raise ValueError(
            "marker_poses must have shape (T, n_markers, 6) with columns "
            f"[x, y, z, gamma, beta, alpha], got {P.shape}"
        )
    if Q.ndim != 2 or Q.shape[0] != P.shape[0]:
        raise ValueError(
            f"joint_positions must have shape (T, n_joints) with T = {P.shape[0]} rows like "
            f"marker_poses, got {Q.shape}"
        )
    if nan_policy not in NAN_POLICIES:
        raise ValueError(f"nan_policy must be one of {NAN_POLICIES}, got {nan_policy!r}")
    if np.isinf(P).any() or np.isinf(Q).any():
        raise ValueError("marker_poses / joint_positions contain inf; remove those frames")
    if nan_policy == "pairwise":  # missing markers stay NaN; frames without joints go
        P = np.where(np.isnan(P).any(axis=2, keepdims=True), np.nan, P)
        bad_rows = np.isnan(Q).any(axis=1) | np.isnan(P).all(axis=(1, 2))
    else:
        bad_rows = np.isnan(P).any(axis=(1, 2)) | np.isnan(Q).any(axis=1)
    n_bad = int(bad_rows.sum())
    if n_bad:
        missing = sorted(set(np.nonzero(np.isnan(P).any(axis=(0, 2)))[0].tolist()))
        if nan_policy == "raise":
            raise ValueError(
                f"{n_bad} of {P.shape[0]} frames contain NaN (missing markers {missing} or "
                "joint values); drop those frames or pass nan_policy='drop' (or 'pairwise')"
            )
        warnings.warn(
            f"dropped {n_bad} of {P.shape[0]} frames with NaN (missing markers {missing})",
            stacklevel=3,
        )
        P, Q = P[~bad_rows], Q[~bad_rows]
    if P.shape[0] < 3:
        what = "frames with joint values" if nan_policy == "pairwise" else "complete frames"
        raise ValueError(f"need at least 3 {what}, got {P.shape[0]}")
    return P, Q, n_bad


def find_base_marker(marker_poses: FloatArray, xi_t: float = XI_T, xi_o: float = XI_O) -> int:
    """Index of the marker whose camera pose is the most constant (the base link ``L_1``).

    The spread of a marker is ``max(std(l^c) / xi_t, std(R^c elements) / xi_o)``; a warning
    is issued when even the smallest spread exceeds 1 (no marker is static within the noise).
    """
    seen = np.isfinite(marker_poses[..., 0]).sum(0)
    with warnings.catch_warnings():  # a marker never seen: all-NaN columns
        warnings.simplefilter("ignore", RuntimeWarning)
        pos_std = np.nanstd(marker_poses[..., :3], axis=0).max(-1)
        R = ypr_to_matrix(marker_poses[..., 3:])
        rot_std = np.sqrt(np.nanvar(R.reshape(*R.shape[:2], 9), axis=0).max(-1))
    pos_std = np.where(seen >= 3, pos_std, np.inf)  # too few sightings to call it static
    rot_std = np.where(seen >= 3, rot_std, np.inf)
    spread = np.maximum(pos_std / xi_t, rot_std / xi_o)
    base = int(np.argmin(spread))
    if spread[base] > 1.0:
        warnings.warn(
            f"no marker is static within the thresholds (smallest spread {spread[base]:.3g} "
            f"x threshold, marker {base}); check the data or raise xi_t / xi_o",
            stacklevel=2,
        )
    return base


# ----------------------------------------------------------------------------- algorithm


@dataclass(frozen=True)
class KinematicStructure:
    """Identified structure: ``S_M``, ``S_Q``, ``S_q`` of section 2.2.

    Attributes:
        markers: marker indices base to tip (``S_M``), ``len = len(joints) + 1``.
        joint_types: ``"R"``/``"P"`` per joint along the chain (``S_Q``; the thesis's 1/0).
        joints: joint-signal indices along the chain (``S_q``).
        complete: every joint signal was placed on the chain.
        triplets: the accepted triplets, one per joint.
        n_dropped_frames: frames removed for NaN (``nan_policy='drop'``; with
            ``'pairwise'`` only frames without joint values or without any marker).
    """

    markers: tuple[int, ...]
    joint_types: str
    joints: tuple[int, ...]
    complete: bool
    triplets: tuple[TripletResult, ...] = field(default=(), repr=False)
    n_dropped_frames: int = 0

    @property
    def base_marker(self) -> int:
        return self.markers[0]

    @property
    def end_marker(self) -> int:
        """The marker on the last link identified (the end effector when ``complete``)."""
        return self.markers[-1]


class _PairCache:
    """Relative poses and the (joint-independent) revolute linear test per marker pair, on
    the frames where both markers are seen (all frames unless ``nan_policy="pairwise"``)."""

    def __init__(self, P: FloatArray, min_frames: int) -> None:
        self.P = P
        self.min_frames = min_frames
        self.seen = np.isfinite(P[..., 0])  # (T, n_markers)
        self._rel: dict[tuple[int, int], tuple[FloatArray, FloatArray]] = {}
        self._lin: dict[tuple[int, int], float] = {}

    def rows(self, a: int, b: int) -> NDArray[np.bool_]:
        """Frames in which markers ``a`` and ``b`` are both seen."""
        return self.seen[:, a] & self.seen[:, b]

    def testable(self, a: int, b: int) -> bool:
        """At least ``min_frames`` common frames for the tests."""
        return int(self.rows(a, b).sum()) >= self.min_frames

    @classmethod
    def for_policy(cls, P: FloatArray, nan_policy: str) -> _PairCache:
        """``"pairwise"`` tests a pair on :data:`MIN_PAIR_FRAMES` common frames or more;
        the other policies leave only complete frames (at least 3, :func:`_validate`)."""
        return cls(P, MIN_PAIR_FRAMES if nan_policy == "pairwise" else 3)

    def relative(self, a: int, b: int) -> tuple[FloatArray, FloatArray]:
        if (a, b) not in self._rel:
            r = self.rows(a, b)
            self._rel[(a, b)] = relative_poses(self.P[r, a], self.P[r, b])
        return self._rel[(a, b)]

    def linear_rms(self, a: int, b: int) -> float:
        if (a, b) not in self._lin:
            self._lin[(a, b)] = revolute_linear_test(*self.relative(a, b))[0]
        return self._lin[(a, b)]


def classify_all_triplets(
    marker_poses: ArrayLike,
    joint_positions: ArrayLike,
    *,
    xi_t: float = XI_T,
    xi_o: float = XI_O,
    evaluate_all: bool = True,
    max_nfev: int = 100,
    nan_policy: str = "raise",
    pairs: Iterable[tuple[int, int]] | None = None,
) -> list[TripletResult]:
    """All triplets ``(a < b, k)`` (the tests are symmetric in ``a, b``), as in section 2.6.1.

    ``nan_policy`` as in :func:`identify_structure`; with ``"pairwise"`` pairs seen together
    in fewer than :data:`MIN_PAIR_FRAMES` frames are left out of the result.

    With ``evaluate_all`` (default) the non-linear test runs on every triplet so that the
    confusion matrices of Prop. 2.3.2 and 2.3.3 alone can be drawn (Fig. 2.4).
    """
    P, Q, _ = _validate(marker_poses, joint_positions, nan_policy)
    cache = _PairCache.for_policy(P, nan_policy)
    if pairs is None:
        pairs = itertools.combinations(range(P.shape[1]), 2)
    out = []
    for a, b in pairs:
        if not cache.testable(a, b):
            continue  # too few frames show both markers (nan_policy="pairwise")
        rows = cache.rows(a, b)
        for k in range(Q.shape[1]):
            out.append(
                classify_triplet(
                    None,
                    None,
                    Q[rows, k],
                    xi_t=xi_t,
                    xi_o=xi_o,
                    evaluate_all=evaluate_all,
                    max_nfev=max_nfev,
                    indices=(a, b, k),
                    _relative=cache.relative(a, b),
                    _linear_rms=cache.linear_rms(a, b),
                )
            )
    return out


def identify_structure(
    marker_poses: ArrayLike,
    joint_positions: ArrayLike,
    *,
    xi_t: float = XI_T,
    xi_o: float = XI_O,
    base_marker: int | None = None,
    selection: str = "best",
    nan_policy: str = "raise",
    seed: int = 0,
) -> KinematicStructure:
    """The iterative algorithm of section 2.4 (Fig. 2.3) with the noisy-data tests of 2.4.3.

    Args:
        marker_poses: ``(T, n_markers, 6)`` camera poses ``[x, y, z, gamma, beta, alpha]``
            (m, rad; ``R = Rz(gamma) Ry(beta) Rx(alpha)``), markers in any order.
        joint_positions: ``(T, n_joints)`` joint signals in any order.
        xi_t: translation threshold [m] (thesis 0.02).
        xi_o: angle threshold [rad] (thesis 0.1).
        base_marker: index of the base marker; ``None`` finds it (:func:`find_base_marker`).
        selection: ``"first"`` accepts the first positive triplet in a random order (the
            thesis); ``"best"`` tests every candidate of the current marker and keeps the
            positive one with the smallest normalised residual (more robust with noise; this
            costs more non-linear tests).
        nan_policy: ``"raise"`` (default); ``"drop"`` frames with a NaN (a missing marker),
            with a warning giving the count; or ``"pairwise"``: each triplet test uses the
            frames in which both of its markers are seen (at least
            :data:`MIN_PAIR_FRAMES`; pairs with fewer are not tested), for markers that are
            missing in different frames (a real detector).
        seed: seed of the random order for ``selection="first"``.

    Returns:
        :class:`KinematicStructure`; ``complete=False`` (and a warning) when the chain could
        not be grown to use every joint signal.
    """
    if selection not in ("first", "best"):
        raise ValueError(f"selection must be 'first' or 'best', got {selection!r}")
    if not (xi_t > 0 and xi_o > 0):
        raise ValueError(f"thresholds must be > 0, got xi_t={xi_t}, xi_o={xi_o}")
    P, Q, n_dropped = _validate(marker_poses, joint_positions, nan_policy)
    n_markers, n_joints = P.shape[1], Q.shape[1]
    if base_marker is None:
        base_marker = find_base_marker(P, xi_t, xi_o)
    elif not 0 <= base_marker < n_markers:
        raise ValueError(f"base_marker must be in [0, {n_markers}), got {base_marker}")
    rng = np.random.default_rng(seed)
    cache = _PairCache.for_policy(P, nan_policy)
    markers, types, joints, accepted = [base_marker], [], [], []
    free_m = [m for m in range(n_markers) if m != base_marker]
    free_q = list(range(n_joints))
    while free_m and free_q:
        cur = markers[-1]
        candidates = [(m, k) for m in free_m for k in free_q]
        if selection == "first":
            candidates = [candidates[i] for i in rng.permutation(len(candidates))]
        chosen = None
        for m, k in candidates:
            if not cache.testable(cur, m):
                continue  # too few frames show both markers (nan_policy="pairwise")
            res = classify_triplet(
                None,
                None,
                Q[cache.rows(cur, m), k],
                xi_t=xi_t,
                xi_o=xi_o,
                indices=(cur, m, k),
                _relative=cache.relative(cur, m),
                _linear_rms=cache.linear_rms(cur, m),
            )
            if res.joint_type is None:
                continue
            if chosen is None or res.score(xi_t, xi_o) < chosen.score(xi_t, xi_o):
                chosen = res
            if selection == "first":
                break
        if chosen is None:
            break
        markers.append(chosen.marker_b)
        types.append(chosen.joint_type)
        joints.append(chosen.joint)
        accepted.append(chosen)
        free_m.remove(chosen.marker_b)
        free_q.remove(chosen.joint)
    complete = len(joints) == n_joints
    if not complete:
        warnings.warn(
            f"structure identification stopped after {len(joints)} of {n_joints} joints: no "
            f"triplet from marker {markers[-1]} passes the tests (xi_t={xi_t}, xi_o={xi_o}); "
            "collect more varied data or loosen the thresholds",
            stacklevel=2,
        )
    return KinematicStructure(
        markers=tuple(markers),
        joint_types="".join(types),
        joints=tuple(joints),
        complete=complete,
        triplets=tuple(accepted),
        n_dropped_frames=n_dropped,
    )

"""Motor-current logs against a model in torque units: the per-joint torque constants.

A drive that logs motor currents ``i_j`` [A] rather than joint torques gives the torque as
``tau_j = k_j i_j`` with a joint-side torque constant ``k_j`` (the motor's constant times the
gear ratio, ``K_tau K_r``; negative for a motor mounted reversed) that the robot file does not
hold. Read in amperes against a model in N m, every joint's residual
``i_j - tau_hat_j = (1 / k_j - 1) tau_j`` is a scaled copy of its torque (gravity, inertia),
which the candidate library would name as springs, offsets, cogging or a payload. So, before
any effect is scored, the constants are estimated (or taken from the user) and the loop works
on ``k_j i_j`` in torque units.

Estimation (:func:`estimate_torque_constants`, on the training rows)
    ``k_j i_j = tau_hat_j(q, qd, qdd) + F_v qd_j + F_c tanh(qd_j / eps) + tau_0`` with
    ``tau_hat`` the model's torque and a small baseline that a real joint always has
    (viscous and Coulomb friction, an offset; ``eps`` = :data:`BASELINE_EPS`, the forms of
    :class:`~.effects.ViscousFriction`, :class:`~.effects.CoulombFriction` and
    :class:`~.effects.TorqueOffset`). Divided by ``k_j`` it is linear in
    ``beta = (1 / k_j, F_v / k_j, F_c / k_j, tau_0 / k_j)``:

    .. math::

        i_j = X \\beta + e_j, \\qquad X = [\\hat\\tau_j, \\dot q_j,
        \\tanh(\\dot q_j / \\epsilon), 1],

    with the measured current as the response, so that the current's own noise biases
    nothing. The model torque ``tau_hat_j`` is computed from estimated ``qd``/``qdd`` and
    carries their noise ``u`` (variance ``sigma_in,j^2``, :func:`~.analysis.input_noise`);
    plain least squares would shrink ``1 / k_j`` by ``1 - sigma_in^2 / var(tau_hat_j)``, which
    is not small on a joint with little torque. So the normal equations are corrected for it
    (errors in variables with a known noise variance):

    .. math::

        \\hat\\beta = (X^T X - N \\Sigma_u)^{-1} X^T i_j, \\qquad
        \\Sigma_u = \\mathrm{diag}(\\sigma_{in,j}^2, 0, 0, 0)

    (the noise of the ``qd`` columns is neglected: it barely moves the friction terms).
    Covariance: with ``A = X^T X - N Sigma_u`` and the per-row scores
    ``psi_t = x_t e_t + Sigma_u beta`` (mean zero), the Newey-West sandwich
    ``A^{-1} S A^{-1}``, ``S = sum_{|l| <= L} (1 - |l| / (L + 1)) sum_t psi_t psi_{t-l}^T``
    inside each file, with ``L`` the larger of ``floor(4 (N / 100)^{2/9})`` and the derivative
    filter's window (the residual is not white: filtered input noise, unmodelled effects); if
    the white-noise posterior ``s^2 A^{-1} X^T X A^{-1}`` gives ``1 / k_j`` a larger variance,
    that one. Then ``k_j = 1 / beta_0`` with the delta-method standard deviation
    ``sd(beta_0) / beta_0^2``, and the baseline ``F = beta_m / beta_0`` the same way
    (reported, not added: the loop scores friction itself). Rows where the joint is at rest
    (:func:`~.analysis.at_rest`) are left out of its fit: a dry friction there holds any
    torque up to its level (set-valued), which ``F_c tanh(qd / eps)`` cannot follow, and on a
    joint that sticks often these rows would bury its ``k_j`` (a joint at rest on nearly
    every row keeps them all).
Identifiability
    A joint whose 95% interval of ``k_j`` is wider than :data:`MAX_RELATIVE_CI` of ``|k_j|``
    (no torque excitation beyond friction and offset: a joint at rest, a current that carries
    only noise, or an unmodelled effect that loads a joint the model says carries little
    torque, e.g. a payload on the wrist), or whose corrected normal matrix ``A`` is not
    positive definite (the model torque is a combination of the baseline, or drowned in its
    own noise), is a finding, not the end of the run: the scale is not guessed, the joint is
    diagnosed in its own current units. Its data stay in A (``k_j`` taken as ``s_j = +-1``,
    :attr:`TorqueConstants.reasons` says why) and the loop's first version holds the free
    scale ``alpha tau_hat_j`` on it, fitted jointly with every candidate effect, so that
    ``(1 + alpha) tau_hat_j = tau_hat_j / k_j``; an effect on that joint is scored and named
    in A (its parameters are torque parameters divided by ``k_j``, :func:`widen_estimates`
    relabels their units). The other joints are converted and diagnosed as usual.
    The sign ``s_j`` is still known where the magnitude is not: friction opposes motion
    (``F_v, F_c >= 0``), so the sign of the baseline's ``F_c / k_j`` (else ``F_v / k_j``,
    else ``1 / k_j``) that is farther than :data:`SIGN_Z` standard deviations from zero is the
    sign of ``k_j`` (:func:`_sign_of_constant`; +1 where none is, and the reason says so).
    With it, a friction, damping or inertia found on the joint keeps its physical sign in A
    (a motor mounted reversed would otherwise turn a dry friction into a negative one, which
    no candidate may take).
Noise floor
    A perfect model in torque units with ``k`` taken as ``k_hat`` still misses
    ``y - tau = (k_hat - k) i`` on the data, of expected square ``sd(k)^2 mean(i^2)`` per
    joint; :func:`~.analysis.noise_floor` adds it (:meth:`TorqueConstants.output_variance`),
    so an uncertain constant widens the floor rather than showing up as an effect.
Given constants (:func:`given_torque_constants`)
    used as they are, with zero uncertainty; the user may give some joints' constants and
    have the others estimated (a wrist whose inertial torque is too small to pin it down).

The loop on the converted data
    Conditioned on ``k_hat``, the training residual ``k_hat i - tau_hat`` holds the fitted
    baseline exactly, offset included, with an interval far narrower than the one the joint
    estimate gives it (``k`` and ``tau_0`` trade off where the torque has a large mean, e.g.
    gravity): scored as candidates, offsets, springs and cogging would look significant.
    So the loop's first version holds a free scale of the model torque,
    ``alpha tau_hat_j`` (:meth:`TorqueConstants.effects`, :class:`~.effects.TorqueScale`), on
    the joints whose constant was estimated and where that pays: candidates are scored
    against a model in which ``k`` is still free. The block's column ``tau_hat_j`` carries the
    input noise ``sigma_in,j`` itself, which biases ``alpha`` by about
    ``-sigma_in^2 / mean(tau_hat^2)`` (a prediction error of ``sigma_in^2 / rms(tau_hat)``);
    so a joint gets the block only when the error it removes, ``sd(k) rms(i)``, is larger
    (:attr:`TorqueConstants.free_scale`; a joint with little torque keeps ``k_hat`` fixed and
    the floor term above). Nor does a joint at rest on more than
    :data:`FREE_SCALE_MAX_REST` of its rows (a dry friction that holds it): while it sticks,
    its torque is any value up to the friction level, so the loop's fit can move the scale of
    its small model torque together with the friction's smoothing and keep the training
    evidence while missing the held-out log (an iiwa wrist joint sticking 40% of the time
    ended at 2.6x the floor with the scale off by a factor 2, and at the floor with
    ``k_hat`` fixed). A model with the block carries the uncertainty of ``k`` in its
    prediction, and its floor leaves the ``sd(k)^2 mean(i^2)`` term out on those joints
    (:func:`without_fitted_scales`).
Effect parameters
    The effects found afterwards are fitted on ``k_hat i``: their parameters are in torque
    units, and every linear one (friction levels, offset, stiffness, amplitude, mass,
    inertia) is off by the factor ``k / k_hat`` of its joint. :func:`widen_estimates` adds
    that relative uncertainty to their intervals, ``ci^2 + (Z95 |value| sd(k) / |k_hat|)^2``
    (:data:`~mcpilco.models.stats.Z95`); a delay is not scaled.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mcpilco.models.diagnosis.analysis import at_rest, input_noise
from mcpilco.models.diagnosis.data import MIN_FIT_ROWS, require_rows
from mcpilco.models.diagnosis.effects import (
    CoulombFriction,
    Effect,
    FeatureContext,
    ParamEstimate,
    TorqueOffset,
    TorqueScale,
    ViscousFriction,
)
from mcpilco.models.robot_data import Trajectories
from mcpilco.models.stats import Z95

FloatArray = NDArray[np.float64]

__all__ = [
    "BASELINE_EPS",
    "MAX_RELATIVE_CI",
    "TorqueConstants",
    "currents_to_torque",
    "estimate_torque_constants",
    "current_unit",
    "given_torque_constants",
    "widen_estimates",
    "without_fitted_scales",
]

BASELINE_EPS = 0.01
"""Smoothing velocity ``eps`` [rad/s or m/s] of the baseline's Coulomb term ``tanh(qd / eps)``."""
MAX_RELATIVE_CI = 0.25
"""Widest 95% interval of an estimated ``k_t``, relative to ``|k_t|``, that counts as identified
(narrower ones are used; the noise floor carries their uncertainty)."""


@dataclass(frozen=True)
class TorqueConstants:
    """Joint-side torque constants ``k_t`` with their 95% intervals (module docstring).

    Attributes:
        value: ``(n,)`` ``k_t`` [N m/A or N/A].
        ci95: ``(n,)`` half-width of the 95% interval (0 for given constants).
        given: ``(n,)`` which joints' constants the user gave (the others were estimated).
        joint_types: e.g. ``"RRPR"`` (units: ``P`` joints in N/A).
        baseline: per joint, the baseline fitted with ``k_t`` (``F_v``, ``F_c``, ``tau_0`` in
            torque units), empty for a given constant.
        rows: training rows of the estimate (0 when every constant was given).
        free_scale: ``(n,)`` joints whose model holds a free scale (module docstring); none
            by default.
        reasons: per joint, why its ``k_t`` is not identifiable (the joint stays in A,
            ``value`` the sign of ``k_t``, module docstring), or ``None``; empty: every
            joint identified or given.
    """

    value: FloatArray
    ci95: FloatArray
    given: NDArray[np.bool_]
    joint_types: str
    baseline: tuple[tuple[ParamEstimate, ...], ...] = ()
    rows: int = 0
    free_scale: NDArray[np.bool_] | None = None
    reasons: tuple[str | None, ...] = ()

    @property
    def n_joints(self) -> int:
        return int(self.value.size)

    @property
    def in_current(self) -> NDArray[np.bool_]:
        """``(n,)`` joints diagnosed in their own current units (``k_t`` not identifiable)."""
        out = np.zeros(self.n_joints, dtype=bool)
        for j, why in enumerate(self.reasons):
            out[j] = why is not None
        return out

    @property
    def source(self) -> str:
        """``"given"``, ``"estimated"`` or ``"given and estimated"``."""
        if self.given.all():
            return "given"
        return "given and estimated" if self.given.any() else "estimated"

    @property
    def std(self) -> FloatArray:
        """``(n,)`` standard deviation of ``k_t``."""
        return self.ci95 / Z95

    def unit(self, joint: int) -> str:
        """Unit of ``k_t`` of joint ``joint`` (1-based)."""
        return "N/A" if self.joint_types[joint - 1] == "P" else "N·m/A"

    def to_torque(self, traj: Trajectories) -> Trajectories:
        """``traj`` with ``y = k_t i`` in torque units (``output = "tau"``), remembering the
        constants (:attr:`Trajectories.torque_constants`).

        Raises:
            ValueError: ``traj`` holds torques already, or another joint count.
        """
        if traj.output != "i":
            raise ValueError(
                "torque constants apply to motor-current logs (columns i1..in); these files "
                f"give {traj.output!r}: leave torque_constants out"
            )
        if traj.n_joints != self.n_joints:
            raise ValueError(
                f"torque_constants has {self.n_joints} values but the data has "
                f"{traj.n_joints} joints"
            )
        return dataclasses.replace(traj, y=traj.y * self.value, output="tau", torque_constants=self)

    def effects(self) -> list[TorqueScale]:
        """The blocks the loop's first version holds: a free scale of the model torque
        (:class:`~.effects.TorqueScale`) on the joints of :attr:`free_scale`."""
        if self.free_scale is None:
            return []
        return [TorqueScale(int(j) + 1) for j in np.flatnonzero(self.free_scale)]

    def output_variance(self, y: FloatArray) -> FloatArray:
        """``(n,)`` ``sd(k)^2 mean(i^2)`` with ``i = y / k``: the mean square that the
        uncertainty of ``k_t`` puts between a perfect model and ``y = k_hat i`` (torque units)."""
        current = np.asarray(y, dtype=np.float64) / self.value
        return self.std**2 * np.mean(current**2, axis=0)

    def text(self) -> str:
        """One line per joint: ``k_t`` given, or estimated with its interval (and the
        baseline fitted with it)."""
        lines = ["torque constants k_t (tau = k_t i):"]
        for j in range(self.n_joints):
            k, ci, unit = self.value[j], self.ci95[j], self.unit(j + 1)
            if self.in_current[j]:
                lines.append(
                    f"   joint {j + 1}: k_t not identifiable ({self.reasons[j]}); diagnosed in "
                    f"A{' (sign reversed: k_t < 0)' if k < 0 else ''}: its data stay in "
                    "motor current, the model torque gets a free scale "
                    f"fitted with the effects (scale:{j + 1}, 1 + alpha = 1 / k_t), and an "
                    "effect on it is named with its parameters in A"
                )
                continue
            if self.given[j]:
                lines.append(f"   joint {j + 1}: k_t = {k:.5g} {unit}   given, used as it is")
                continue
            fitted = "; ".join(p.text() for p in self.baseline[j])
            free = self.free_scale is not None and self.free_scale[j]
            lines.append(
                f"   joint {j + 1}: k_t = {k:.5g} ± {ci:.2g} {unit} ({100 * ci / abs(k):.2g} %)"
                f"{', scale left free in the model (scale:' + str(j + 1) + ')' if free else ''}"
                f"   estimated on {self.rows} training rows with {fitted}"
            )
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        return {
            "source": self.source,
            "rows": self.rows,
            "joints": [
                {
                    "joint": j + 1,
                    "k_t": float(self.value[j]),
                    "ci95": float(self.ci95[j]),
                    "unit": self.unit(j + 1),
                    "given": bool(self.given[j]),
                    "free_scale": bool(self.free_scale is not None and self.free_scale[j]),
                    "baseline": [p.__dict__ for p in self.baseline[j]],
                    "identifiable": not bool(self.in_current[j]),
                    "reason": self.reasons[j] if self.reasons else None,
                }
                for j in range(self.n_joints)
            ],
        }


def _given_values(values: Any, joint_types: str) -> FloatArray:
    """``(n,)`` user-given ``k_t``, ``nan`` where an entry is ``None`` or ``nan`` (to be
    estimated); ValueError for a wrong count or a zero or infinite value (the joint named)."""
    n_joints = len(joint_types)
    items = list(np.atleast_1d(np.asarray(values, dtype=object)).reshape(-1))
    if np.ndim(values) > 1 or len(items) != n_joints:
        raise ValueError(
            f"torque_constants needs {n_joints} values (one per joint), got {len(items)}: "
            f"{values!r}"
        )
    try:
        arr = np.array([np.nan if v is None else float(v) for v in items])
    except (TypeError, ValueError) as err:
        raise ValueError(f"torque_constants must be numbers, got {values!r}") from err
    bad = np.flatnonzero(np.isinf(arr) | (arr == 0))
    if bad.size:
        j = int(bad[0])
        raise ValueError(
            f"torque_constants: joint {j + 1} has k_t = {arr[j]}; a torque constant must be "
            "finite and nonzero (negative for a motor mounted reversed; None or nan: "
            "estimate it)"
        )
    return arr


def given_torque_constants(values: Any, joint_types: str) -> TorqueConstants:
    """User-given ``k_t``: one finite, nonzero value per joint of ``joint_types``, used as
    they are.

    Raises:
        ValueError: a wrong count, or a zero, infinite or missing value (the joint named).
    """
    arr = _given_values(values, joint_types)
    missing = np.flatnonzero(np.isnan(arr))
    if missing.size:
        raise ValueError(
            f"torque_constants: joint {missing[0] + 1} has no value; give every joint's "
            "constant, or estimate the missing ones (currents_to_torque)"
        )
    n = arr.size
    return TorqueConstants(arr, np.zeros(n), np.ones(n, bool), joint_types, ((),) * n)


def _fit_rows(traj: Trajectories) -> tuple[NDArray[np.int64], list[tuple[int, int]], int]:
    """Rows of the estimate (each file without the derivative filter's edge rows, where the
    estimate is less accurate), their per-file ranges in the stacked rows, and the longest
    filter window (0 when nothing was estimated)."""
    rows, ranges, window = [], [], 0
    for s, (a, b) in enumerate(traj.segments):
        est = traj.estimated[s] if s < len(traj.estimated or ()) else None
        m = traj.edge_rows(s)
        window = max(window, 0 if est is None else est.filter.window)
        r = np.arange(a + m, b - m)
        start = sum(len(x) for x in rows)
        rows.append(r)
        ranges.append((start, start + r.size))
    return np.concatenate(rows), ranges, window


def _sandwich(u: FloatArray, ranges: Sequence[tuple[int, int]], lags: int) -> FloatArray:
    """Newey-West ``S = sum_{|l| <= L} (1 - |l| / (L + 1)) sum_t u_t u_{t-l}^T`` of the
    per-row scores ``u (N, p)``, lags taken inside each range only."""
    meat = u.T @ u
    for lag in range(1, lags + 1):
        g = np.zeros_like(meat)
        for a, b in ranges:
            if b - a > lag:
                g += u[a + lag : b].T @ u[a : b - lag]
        meat += (1.0 - lag / (lags + 1.0)) * (g + g.T)
    return meat


def _corrected_least_squares(
    x: FloatArray,
    y: FloatArray,
    noise_var: float,
    ranges: Sequence[tuple[int, int]],
    lags: int,
) -> tuple[FloatArray | None, FloatArray | None]:
    """``(beta, cov)`` of ``y = x beta`` with white-noise variance ``noise_var`` on the first
    column of ``x`` removed from the normal equations (module docstring); ``(None, None)``
    when the corrected normal matrix is not positive definite (``beta`` not identifiable)."""
    n_rows, p = x.shape
    scale = np.sqrt(np.mean(x**2, axis=0))
    scale[scale == 0] = 1.0
    xs = x / scale
    sigma = np.zeros((p, p))
    sigma[0, 0] = noise_var / scale[0] ** 2
    normal = xs.T @ xs - n_rows * sigma
    eig = np.linalg.eigvalsh(normal)
    if not eig[0] > 1e-10 * eig[-1]:
        return None, None
    bread = np.linalg.inv(normal)
    beta = bread @ (xs.T @ y)
    e = y - xs @ beta
    dof = max(n_rows - p, 1)
    posterior = (bread @ (xs.T @ xs) @ bread) * float(e @ e) / dof
    scores = xs * e[:, None] + (sigma @ beta)[None, :]
    sandwich = bread @ _sandwich(scores, ranges, lags) @ bread * (n_rows / dof)
    cov = sandwich if sandwich[0, 0] >= posterior[0, 0] else posterior
    return beta / scale, cov / np.outer(scale, scale)


def _ratio(num: float, den: float, cov: FloatArray, i: int, k: int) -> tuple[float, float]:
    """``num / den`` and its delta-method standard deviation (``cov`` of ``(beta_i, beta_k)``
    with ``num = beta_i``, ``den = beta_k``)."""
    g = np.array([1.0 / den, -num / den**2])
    sub = cov[np.ix_([i, k], [i, k])]
    return num / den, math.sqrt(max(float(g @ sub @ g), 0.0))


FREE_SCALE_MAX_REST = 0.2
"""Largest share of rows at rest on which an identified joint still gets a free scale: on a
joint that sticks more, the scale and a set-valued dry friction trade off in the loop's
fit (module docstring)."""
SIGN_Z = 3.0
"""Standard deviations from zero by which a baseline coefficient fixes the sign of a ``k_t``
whose magnitude is not identifiable (:func:`_sign_of_constant`)."""


def _sign_of_constant(
    beta: FloatArray | None, cov: FloatArray | None, x: FloatArray, y: FloatArray
) -> tuple[float, str]:
    """The sign of ``k_j`` of a joint whose magnitude is not identifiable, and how it was
    found (module docstring).

    ``beta = (1/k, F_v/k, F_c/k, tau_0/k)`` with covariance ``cov`` from the joint fit, or,
    where that fit has no solution (``None``), the ordinary least squares of the current
    ``y`` on the baseline columns ``x = [qd, tanh(qd / eps), 1]`` alone (white-noise
    covariance). Friction opposes motion, so ``F_c / k`` and ``F_v / k`` carry the sign of
    ``k``; ``1 / k`` itself does where it is significant."""
    if beta is None or cov is None:
        coef, *_ = np.linalg.lstsq(x, y, rcond=None)
        e = y - x @ coef
        gram = np.linalg.pinv(x.T @ x) * float(e @ e) / max(y.size - x.shape[1], 1)
        terms = [(float(coef[1]), float(gram[1, 1]), "F_c"), (float(coef[0]), float(gram[0, 0]),
                 "F_v")]  # fmt: skip
    else:
        terms = [(float(beta[m]), float(cov[m, m]), name) for m, name in ((2, "F_c"), (1, "F_v"))]
        terms.append((float(beta[0]), float(cov[0, 0]), "1/k_t"))
    for value, var, name in terms:
        if abs(value) > SIGN_Z * math.sqrt(max(var, 0.0)):
            what = f"the sign of {name}" + ("" if name == "1/k_t" else " (friction opposes motion)")
            return (1.0 if value > 0 else -1.0), f"sign of k_t from {what}"
    return 1.0, "sign of k_t unknown (no friction or torque shows it): taken as +1"


PAYLOAD_EVIDENCE = 5.0
"""Log-likelihood gain (less its BIC penalty) for which the payload is kept in that fit."""


PAYLOAD_ITERATIONS = 30
"""Most Gauss-Newton steps of the joint fit of constants and payload (:func:`_flange_payload`)."""
PAYLOAD_TOLERANCE = 1e-6
"""Relative step of every unknown below which the joint fit of :func:`_flange_payload` stops."""


def _flange_payload(
    x: Callable[[int, FloatArray], tuple[FloatArray | None, FloatArray | None]],
    baseline: Callable[[int], FloatArray],
    y: FloatArray,
    tau_hat: FloatArray,
    cols: FloatArray,
    joints: Sequence[int],
    moving: NDArray[np.bool_],
) -> FloatArray:
    """``(N, n)`` the torque ``P_j w`` of a payload at the flange fitted jointly with the
    torque constants (module docstring), or zeros where the data do not show one.

    Every joint's current is ``i_j = (tau_hat_j + P_j w) / k_j + B_j b_j + e_j`` (``B_j`` the
    baseline's friction and offset columns, ``baseline(j)``; ``w`` one weight vector for
    every joint): bilinear in ``1 / k_j`` and ``w``. Fitting the joints one at a time cannot
    separate them: a payload that loads a joint is taken into its ``k_j`` (on a wrist by a
    factor of 2). So every unknown is fitted at once, by Gauss-Newton on the weighted
    least squares of the currents (the current is the response, so its own noise biases
    nothing; each joint weighted by its residual std without the payload, its rows at rest
    left out), from the joint-by-joint fit and ``w = 0``, until no unknown moves by more than
    :data:`PAYLOAD_TOLERANCE` of its value (at most :data:`PAYLOAD_ITERATIONS` steps); the
    constants are then refitted one joint at a time on ``tau_hat + P w`` (``x(j, tau)``, the
    corrected least squares). Alternating the two linear fits instead crawls along the
    valley in which a payload and the constants trade off (on the Panda it stopped with
    every ``k_j`` 5-50% low).
    The payload is kept when it raises the joints' Gaussian log-likelihood (in currents) by
    more than :data:`PAYLOAD_EVIDENCE` nats beyond the BIC penalty ``(p / 2) log(N m)`` of
    its ``p`` weights, with a positive mass, and when every joint whose ``k_j`` was
    identified without it keeps a 95% interval within :data:`MAX_RELATIVE_CI` of its value
    (Gauss-Newton covariance of every unknown at once: where the last body carries most of
    every joint's torque, a payload and a common scale of the constants trade off, and the
    constants are then fitted one joint at a time)."""
    n_rows, n, p = cols.shape
    zero = np.zeros((n_rows, n))

    def per_joint(torque: FloatArray) -> dict[int, tuple[FloatArray, FloatArray]]:
        out = {}
        for j in joints:
            beta, cov = x(j, torque[:, j])
            if beta is not None and beta[0] != 0:
                out[j] = (beta, cov)
        return out

    def rss(fits: dict[int, tuple[FloatArray, FloatArray]], torque: FloatArray) -> FloatArray:
        return np.array(
            [
                np.mean(
                    (y[:, j] - beta[0] * torque[:, j] - baseline(j) @ beta[1:])[moving[:, j]] ** 2
                )
                for j, (beta, _) in fits.items()
            ]
        )

    fits0 = per_joint(tau_hat)
    js = list(fits0)
    if not js:
        return zero
    rss0 = rss(fits0, tau_hat)
    sig = {j: math.sqrt(r) for j, r in zip(js, rss0, strict=True)}  # residual std [A]
    if not all(v > 0 for v in sig.values()):
        return zero
    m, nb = len(js), baseline(js[0]).shape[1]
    q_ = 1 + nb  # unknowns per joint: 1 / k_j and the baseline b_j
    theta = np.concatenate([fits0[j][0] for j in js] + [np.zeros(p)])

    def residual_and_jacobian(theta: FloatArray) -> tuple[FloatArray, FloatArray]:
        w = theta[m * q_ :]
        jac = np.zeros((n_rows * m, m * q_ + p))
        res = np.zeros(n_rows * m)
        for k, j in enumerate(js):
            r = slice(k * n_rows, (k + 1) * n_rows)
            inv_k, b_j = theta[k * q_], theta[k * q_ + 1 : (k + 1) * q_]
            torque = tau_hat[:, j] + cols[:, j] @ w
            wt = moving[:, j] / sig[j]
            res[r] = (y[:, j] - inv_k * torque - baseline(j) @ b_j) * wt
            jac[r, k * q_] = torque * wt
            jac[r, k * q_ + 1 : (k + 1) * q_] = baseline(j) * wt[:, None]
            jac[r, m * q_ :] += inv_k * cols[:, j] * wt[:, None]
        return res, jac

    for _ in range(PAYLOAD_ITERATIONS):  # Gauss-Newton on the bilinear least squares
        res, jac = residual_and_jacobian(theta)
        norm = np.linalg.norm(jac, axis=0)
        norm[norm == 0] = 1.0
        step = np.linalg.lstsq(jac / norm, res, rcond=None)[0] / norm
        theta = theta + step
        if np.max(np.abs(step) / np.maximum(np.abs(theta), 1e-12)) < PAYLOAD_TOLERANCE:
            break
    w = theta[m * q_ :]
    extra = np.einsum("tjp,p->tj", cols, w)
    fits = per_joint(tau_hat + extra)
    if list(fits) != js:
        return zero
    rss1 = rss(fits, tau_hat + extra)
    gain = 0.5 * n_rows * float(np.sum(np.log(rss0 / np.maximum(rss1, 1e-300))))
    if gain - 0.5 * p * math.log(n_rows * m) <= PAYLOAD_EVIDENCE:
        return zero
    _, jac = residual_and_jacobian(theta)
    norm = np.linalg.norm(jac, axis=0)
    norm[norm == 0] = 1.0
    scale2 = float(np.mean(rss1 / rss0))
    cov = np.linalg.pinv((jac / norm).T @ (jac / norm)) / np.outer(norm, norm) * scale2
    identified = [
        k
        for k, j in enumerate(js)
        if Z95 * math.sqrt(max(fits0[j][1][0, 0], 0.0))
        < MAX_RELATIVE_CI * abs(float(fits0[j][0][0]))
    ]
    rel = [
        Z95 * math.sqrt(max(cov[k * q_, k * q_], 0.0)) / abs(float(theta[k * q_]))
        for k in identified
    ]
    if not all(r_ < MAX_RELATIVE_CI for r_ in rel):  # a payload in place of a common scale
        return zero
    if not w[0] > 0:  # an unphysical mass: the fit took another direction for a payload
        return zero
    return extra


def estimate_torque_constants(
    traj: Trajectories,
    torque: Callable[[FloatArray, FloatArray, FloatArray], FloatArray],
    joint_types: str,
    given: Any = None,
    payload: Callable[[FloatArray, FloatArray, FloatArray], FloatArray] | None = None,
) -> TorqueConstants:
    """Estimate ``k_t`` per joint from a current log and the model torque (module docstring).

    Args:
        traj: training trajectories with ``output == "i"`` (currents in A).
        torque: ``tau_hat(q, qd, qdd) -> (N, n)``, the model's torque (N m or N).
        joint_types: e.g. ``"RRPR"``.
        given: optional per-joint ``k_t`` the user knows, ``None``/``nan`` for the joints to
            estimate (e.g. a wrist whose torque is too small to pin its constant down).
        payload: ``(q, qd, qdd) -> (N, n, p)``, the columns of a payload at the flange
            (one weight vector for every joint): fitted jointly with the constants
            (:func:`_flange_payload`), so that a payload the model lacks does not bias them.

    Returns:
        the constants; a joint whose ``k_t`` the data cannot pin down has ``value`` +-1 (the
        sign of ``k_t``, :func:`_sign_of_constant`), its
        reason in :attr:`TorqueConstants.reasons` and a free scale (module docstring).

    Raises:
        ValueError: ``traj`` holds torques, too few rows, or bad given values.
    """
    if traj.output != "i":
        raise ValueError(
            f"torque constants are estimated from motor currents (i1..in); the data give "
            f"{traj.output!r}"
        )
    require_rows(traj, MIN_FIT_ROWS, "estimating torque constants")
    rows, ranges, window = _fit_rows(traj)
    q, qd, qdd = traj.q[rows], traj.qd[rows], traj.qdd[rows]
    tau_hat = np.asarray(torque(q, qd, qdd), dtype=np.float64)
    ctx = FeatureContext(q=q, qd=qd, qdd=qdd, base=tau_hat, joint_types=joint_types)
    sigma_in = input_noise(traj, lambda tr: torque(tr.q, tr.qd, tr.qdd)).std
    n_rows = rows.size
    lags = max(int(4.0 * (n_rows / 100.0) ** (2.0 / 9.0)), window)
    known = np.full(traj.n_joints, np.nan) if given is None else _given_values(given, joint_types)
    value, ci95, baseline, reasons, free = [], [], [], [], []
    names = ("F_v", "F_c", "tau_0")

    def baseline_cols(j: int) -> FloatArray:
        return np.concatenate(
            [
                ViscousFriction(j + 1).columns(ctx, j),
                CoulombFriction(j + 1, eps=BASELINE_EPS).columns(ctx, j),
                TorqueOffset(j + 1).columns(ctx, j),
            ],
            axis=1,
        )

    moving = ~at_rest(traj)[rows]  # rows where dry friction is not set-valued
    for j in range(traj.n_joints):
        if moving[:, j].sum() < MIN_FIT_ROWS:  # a joint at rest nearly throughout: every row
            moving[:, j] = True

    def fit(j: int, tau: FloatArray) -> tuple[FloatArray | None, FloatArray | None]:
        keep = moving[:, j]
        x = np.concatenate([tau[:, None], baseline_cols(j)], axis=1)[keep]
        cum = np.concatenate([[0], np.cumsum(keep)])
        kept_ranges = [(int(cum[a]), int(cum[b])) for a, b in ranges]
        return _corrected_least_squares(
            x, traj.y[rows, j][keep], sigma_in[j] ** 2, kept_ranges, lags
        )

    unknown = [j for j in range(traj.n_joints) if not np.isfinite(known[j])]
    if payload is not None and unknown:
        tau_hat = tau_hat + _flange_payload(
            fit,
            baseline_cols,
            traj.y[rows],
            tau_hat,
            np.asarray(payload(q, qd, qdd)),
            unknown,
            moving,
        )
    for j in range(traj.n_joints):
        if np.isfinite(known[j]):
            value.append(float(known[j]))
            ci95.append(0.0)
            baseline.append(())
            free.append(False)
            reasons.append(None)
            continue
        beta, cov = fit(j, tau_hat[:, j])
        unit = "N/A" if joint_types[j] == "P" else "N·m/A"
        why = None
        if beta is None:
            why = (
                "its model torque is a combination of friction and offset, or drowned in the "
                "noise of the estimated qd/qdd"
            )
        else:
            inv_k, sd_inv = float(beta[0]), float(math.sqrt(cov[0, 0]))
            k = 1.0 / inv_k if inv_k != 0 else math.inf
            sd_k = sd_inv * k**2
            if not (math.isfinite(k) and Z95 * sd_inv < MAX_RELATIVE_CI * abs(inv_k)):
                why = (
                    f"k_t = {k:.3g} ± {Z95 * sd_k:.2g} {unit}, a 95% interval wider than "
                    f"{MAX_RELATIVE_CI:.0%} of k_t: the current shows too little of the model "
                    "torque beyond friction, offset and what the model lacks"
                )
        if why is not None:  # a finding: the joint is diagnosed in A (module docstring)
            keep = moving[:, j]
            sign, how = _sign_of_constant(beta, cov, baseline_cols(j)[keep], traj.y[rows, j][keep])
            why = f"{why}; {how}"
            value.append(sign)
            ci95.append(0.0)
            baseline.append(())
            free.append(True)
            reasons.append(why)
            continue
        force = "N" if joint_types[j] == "P" else "N·m"
        units = (f"{force}·s/{'m' if joint_types[j] == 'P' else 'rad'}", force, force)
        params = []
        for m, (name, u) in enumerate(zip(names, units, strict=True), start=1):
            f, sd_f = _ratio(float(beta[m]), inv_k, cov, m, 0)
            params.append(ParamEstimate(name, f, Z95 * sd_f, u))
        value.append(k)
        ci95.append(Z95 * sd_k)
        baseline.append(tuple(params))
        removed = sd_k * math.sqrt(float(np.mean(traj.y[rows, j] ** 2)))
        brought = sigma_in[j] ** 2 / max(math.sqrt(float(np.mean(tau_hat[:, j] ** 2))), 1e-300)
        free.append(removed > brought and 1.0 - moving[:, j].mean() <= FREE_SCALE_MAX_REST)
        reasons.append(None)
    return TorqueConstants(
        np.array(value),
        np.array(ci95),
        np.isfinite(known),
        joint_types,
        tuple(baseline),
        n_rows,
        np.array(free, dtype=bool),
        tuple(reasons) if any(r is not None for r in reasons) else (),
    )


def currents_to_torque(
    train: Trajectories,
    test: Trajectories,
    start: Any,
    torque_constants: ArrayLike | None = None,
) -> tuple[Trajectories, Trajectories, TorqueConstants | None]:
    """Put current logs into torque units before the loop scores effects.

    Torque files pass unchanged. Current files are multiplied by ``k_t``: the
    ``torque_constants`` given, and for the joints without one (``None``/``nan`` entries, or
    every joint when none are given) the constants estimated on ``train`` against the start
    model's robot file (:func:`estimate_torque_constants` with its rigid-body torque). A
    learned start without a robot file has no torque units: without given constants the loop
    stays in amperes.

    Args:
        train, test: training and held-out trajectories (same output group).
        start: the start model (its ``robot``, ``n_joints`` and ``joint_types`` are read).
        torque_constants: user-given ``k_t`` per joint [N m/A or N/A] (``None``/``nan``
            entries: estimate that joint), or ``None`` (estimate every joint).

    Returns:
        ``(train, test, constants)``; ``constants`` is ``None`` when nothing was converted.

    Raises:
        ValueError: constants given for torque files, or bad constants.
    """
    if train.output != "i":
        if torque_constants is not None:
            raise ValueError(
                "torque_constants apply to motor-current logs (columns i1..in); the files "
                "give torques (tau1..): leave them out"
            )
        return train, test, None
    known = (
        np.full(start.n_joints, np.nan)
        if torque_constants is None
        else _given_values(torque_constants, start.joint_types)
    )
    if np.isfinite(known).all():
        constants = given_torque_constants(known, start.joint_types)
    elif start.robot is not None:
        constants = estimate_torque_constants(
            train, start.robot.rnea, start.joint_types, known, payload=_payload_columns(start)
        )
    elif torque_constants is None:
        return train, test, None
    else:
        missing = [j + 1 for j in np.flatnonzero(np.isnan(known))]
        raise ValueError(
            f"torque_constants: joints {missing} have no value and there is no robot file to "
            "estimate them against; give every joint's constant or a robot file (--model)"
        )
    return constants.to_torque(train), constants.to_torque(test), constants


def _payload_columns(start: Any) -> Callable[[FloatArray, FloatArray, FloatArray], FloatArray]:
    """``(q, qd, qdd) -> (N, n, p)``: the columns of :class:`~.effects.Payload` on every joint
    of ``start``'s robot file (a payload at the flange, one weight vector)."""
    from mcpilco.models.diagnosis.effects import Payload

    robot = start.robot

    def columns(q: FloatArray, qd: FloatArray, qdd: FloatArray) -> FloatArray:
        ctx = FeatureContext(
            q=q,
            qd=qd,
            qdd=qdd,
            base=None,
            joint_types=start.joint_types,
            regressor=lambda: robot.regressor(q, qd, qdd),
            rigid=robot.rigid_body(),
        )
        return np.stack([Payload().columns(ctx, j) for j in range(q.shape[1])], axis=1)

    return columns


def widen_estimates(
    estimates: Sequence[ParamEstimate], constants: TorqueConstants | None, output: int
) -> list[ParamEstimate]:
    """``estimates`` of a linear effect block fitted on output ``output`` (0-based) of data
    put into torque units with ``constants``, their intervals widened by the relative
    uncertainty of that joint's ``k_t`` (module docstring); unchanged without constants. On a
    joint diagnosed in A (``k_t`` not identifiable) the values are torque parameters divided
    by ``k_t``: their units say so (:func:`current_unit`)."""
    if constants is None:
        return list(estimates)
    if constants.in_current[output]:
        return [dataclasses.replace(p, unit=current_unit(p.unit)) for p in estimates]
    rel = Z95 * float(constants.std[output]) / abs(float(constants.value[output]))
    if rel == 0:
        return list(estimates)
    return [dataclasses.replace(p, ci95=math.hypot(p.ci95, rel * p.value)) for p in estimates]


def current_unit(unit: str) -> str:
    """The unit of a torque parameter (``unit``) divided by a torque constant: ``N·m`` or
    ``N`` at its head becomes ``A`` (``N·m·s/rad`` -> ``A·s/rad``); other units (inertia,
    mass, none) get ``/k_t`` appended."""
    for head in ("N·m", "N"):
        if unit == head or unit.startswith(head + "·") or unit.startswith(head + "/"):
            return "A" + unit[len(head) :]
    return f"{unit}/k_t".lstrip("/") if unit else "1/k_t"


def without_fitted_scales(traj: Trajectories, effects: Sequence[Effect]) -> Trajectories:
    """``traj`` whose ``k_t`` uncertainty is cleared on the joints where ``effects`` hold a
    :class:`~.effects.TorqueScale` block: a model with that block fits the scale itself, so
    its prediction already carries the uncertainty (module docstring) and the noise floor
    must not count it again."""
    constants = traj.torque_constants
    free = [e.joint - 1 for e in effects if isinstance(e, TorqueScale)]
    if constants is None or not free:
        return traj
    ci95 = constants.ci95.copy()
    ci95[free] = 0.0
    return dataclasses.replace(traj, torque_constants=dataclasses.replace(constants, ci95=ci95))


DEGREE_FIT_GAIN = 4.0
"""Factor by which the nominal rigid-body model must fit the measured torques better (mean
squared residual) with a joint's ``q, qd, qdd`` read as degrees before the log is refused as
being in degrees (:func:`check_angle_units`)."""
DEGREE_CHECK_ROWS = 2000  # rows (evenly spaced) on which the rad / deg fits are compared


def check_angle_units(start: Any, traj: Trajectories) -> None:
    """Refuse a log whose revolute joint has ``q``, ``qd`` and ``qdd`` all in degrees.

    The kinematic check of the loader (``q`` against the integral of ``qd``) cannot see such
    a joint: its three columns agree with each other. The physics can: with a nominal
    rigid-body start model, the mean squared torque residual
    ``e(S) = mean ||y - tau_hat(D_S q, D_S qd, D_S qdd)||^2`` with ``D_S`` scaling the
    joints in ``S`` by ``pi / 180`` is compared with ``e({})`` (the log as given), for each
    revolute joint alone and all revolute joints together. When the best ``S`` fits
    :data:`DEGREE_FIT_GAIN` times better, the log is refused naming the joints: a joint in
    rad read as degrees would barely move and fit worse, never that much better.
    Only a nominal start on torque data can tell (learned starts and currents: no check).

    Raises:
        ValueError: naming the file(s), the joints and the conversion.
    """
    if getattr(start, "kind", None) != "nominal" or traj.output != "tau":
        return
    revolute = [j for j, c in enumerate(start.joint_types) if c == "R"]
    if not revolute or traj.n_samples < 10:
        return
    rows = np.unique(np.linspace(0, traj.n_samples - 1, DEGREE_CHECK_ROWS).astype(np.int64))
    q, qd, qdd, y = (
        np.asarray(a[rows], dtype=np.float64) for a in (traj.q, traj.qd, traj.qdd, traj.y)
    )

    def error(joints: Sequence[int]) -> float:
        s = np.ones(q.shape[1])
        s[list(joints)] = np.pi / 180.0
        r = y - start.torque(q * s, qd * s, qdd * s)
        return float(np.mean(r**2))

    base = error([])
    if not np.isfinite(base) or base <= 0.0:
        return
    options = [[j] for j in revolute] + ([revolute] if len(revolute) > 1 else [])
    errors = [error(s) for s in options]
    best = int(np.argmin(errors))
    if errors[best] * DEGREE_FIT_GAIN < base:
        joints = options[best]
        cols = ", ".join(f"q{j + 1}, qd{j + 1}, qdd{j + 1}" for j in joints)
        raise ValueError(
            f"{', '.join(dict.fromkeys(traj.names))}: joint(s) {[j + 1 for j in joints]} look "
            f"like degrees: the rigid-body model fits the torques {base / errors[best]:.3g} "
            f"times better with them read as degrees; convert {cols} to rad (x pi/180)"
        )

"""Compare a model with measurements and see where it fails: metrics and residual analysis.

Metrics per joint ``j`` (``y`` measured, ``y_hat`` predicted, ``N`` samples)
    ``nMSE = mean((y - y_hat)^2) / var(y)`` (thesis 3.4.1), ``RMSE = sqrt(mean((y -
    y_hat)^2))``, ``fit = 100 (1 - ||y - y_hat|| / ||y - mean(y)||)`` % (NRMSE fit, as in
    system-identification toolboxes).
Residual ``e = y - y_hat`` analysis
    * binned against ``qd_j``, ``q_j``, ``qdd_j`` (equal-count bins): mean ``+-`` Z95
      ``sd / sqrt(count)`` (95% interval of the bin mean);
    * averaged around velocity reversals of joint ``j`` (sign changes of ``qd_j``), ``+-W``
      samples, separately for ``+ -> -`` and ``- -> +`` reversals;
    * whiteness and correlation with the inputs, as MATLAB's ``resid`` tests them
      (:func:`whiteness_test`, :func:`cross_correlation_test`, :class:`CorrelationTest`): the
      autocorrelation ``rho_k``, ``k = 1..L``, and the cross-correlation with ``q_j``,
      ``qd_j`` and the predicted torque ``tau_hat_j``, ``tau = -L..L``, each with the 99%
      band ``+-2.576 / sqrt(N)`` of one lag;
    * in words: the state region (bin) whose mean residual is largest relative to the noise
      std ``sigma_j`` of the model, and the worst time windows (rms of ``e`` over ``window``
      seconds), e.g. ``"joint 2, qd in [-0.05, 0.04] rad/s: mean residual 2.9 N·m, 14x
      noise"``.

Noise floor (the error a perfect model still has on held-out data)
    ``floor_j = sqrt(sigma_meas,j^2 + sigma_in,j^2 + sigma_k,j^2)``. ``sigma_meas`` is the
    output's own measurement noise (:func:`noise_floor`, first differences of the residual).
    ``sigma_in`` is the noise the *prediction* inherits when ``qd``/``qdd`` were estimated from
    measured positions (:attr:`.Trajectories.estimated`, :func:`input_noise`): with white noise
    of std ``sigma_x,k`` on the differentiated signal ``x_k`` (``q_k``; ``qd_k`` when only
    ``qdd`` was estimated) and the filter's coefficient rows ``B = [delta, c_1, c_2]`` (the sample
    itself and the first/second derivative coefficients),
    ``sigma_in,j^2 = mean_t sum_k sigma_x,k^2 w_jk(t)^T B B^T w_jk(t)`` with
    ``w_jk = (d tau_j / d q_k, d tau_j / d qd_k, d tau_j / d qdd_k)`` (central differences of
    the model's prediction, step = the input's noise std; forward differences from the
    prediction itself when it is at hand, half the predictions: the step is small against
    the scale on which the torque bends). ``B B^T`` holds the noise gains
    ``||c_1||^2``, ``||c_2||^2`` on its diagonal and the correlations between the sample and its
    estimated derivatives off it. The filtered noise is not white, but the filter's edges make
    part of it visible to the first differences that estimate ``sigma_meas``: that part,
    ``sigma_x^2 w^T (Delta B)(Delta B)^T w / 2``, is taken out of ``sigma_meas^2`` so it is not
    counted twice. ``sigma_k`` is 0 except for motor currents put into torque units with
    estimated constants, ``y = k_hat i``: a perfect model still misses ``(k_hat - k) i``, of
    mean square ``sd(k)^2 mean(i^2)`` (:mod:`~mcpilco.models.diagnosis.units`).
Whiteness and cross-correlation tests
    Under the null hypothesis (a white residual; a residual independent of the input) every
    lag's sample correlation is ``N(0, 1/N)`` (Bartlett), hence the per-lag 99% band
    ``z_0.995 / sqrt(N)`` that MATLAB's ``resid`` draws. A verdict reads all ``m`` lags at once,
    so it compares the largest ``|r|`` with the band widened for ``m`` lags (Sidak:
    ``z`` at ``1 - (1 - (1 - alpha)^(1/m)) / 2``), which a null residual crosses at any lag with
    probability ``alpha = 1%`` (at most: correlated lags make it conservative).
    Bartlett's variance of a cross-correlation of two independent series is
    ``v = (1/N) sum_k rho_ee(k) rho_uu(k)``: the plain ``1/N`` of MATLAB's band holds only
    when one of them is white. Robot inputs (``q``, ``qd``) are smooth and a failing model's
    residual is not white; two independent smooth series correlate strongly by chance, and
    the ``1/N`` band would flag almost any pair. The band is therefore widened to ``v``:
    ``rho_uu`` is the input's sample autocorrelation, ``rho_ee`` that of an AR(``p``) model of
    the residual (least squares, ``p <= AR_MAX_ORDER`` by AIC; a model's autocorrelation has no
    estimation noise in its tail); ``v`` is never taken below ``1/N``. A white residual keeps
    MATLAB's band. (Prewhitening the input instead fails here: a smooth trajectory is almost
    perfectly predictable, its innovations are encoder noise, and a residual that is a smooth
    function of ``q`` is uncorrelated with them.) Lag ``tau > 0``: the input leads. The
    torque input is the *predicted* torque ``tau_hat_j``: the measured torque holds the
    residual's own noise, which correlates with it at lag 0 (by ``sigma / std(tau)``) even for a
    perfect model. Estimated ``qd``/``qdd`` colour even a perfect model's residual (the
    filter's noise, ``sigma_in`` below): the whiteness test speaks of the residual, not only
    of model error.
``sigma_x`` (:func:`position_noise`)
    estimated from ``x`` itself (:func:`~.data.smoother_noise_std`): ``r = x - S x`` with
    ``S`` the Savitzky-Golay *smoother* of the derivative filter's order and shortest span
    (:data:`~.data.DERIVATIVE_WINDOW`, the least biased) (a projection, so white noise of std
    ``sigma`` gives
    ``var(r) = sigma^2 (1 - s_m)``, ``s_m`` its centre coefficient; smooth motion passes
    ``S`` unchanged), ``sigma_x = rms(r) / sqrt(1 - s_m)`` over the interior rows. The rms and
    not a MAD: a uniform quantiser (step ``s``, std ``s / sqrt(12)``) is far from Gaussian, and
    the rms is right for any white noise, quantisation and reading noise together; the
    encoder step alone would miss the reading noise.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import ArrayLike, NDArray
from scipy.integrate import quad
from scipy.optimize import brentq
from scipy.signal import lfilter, savgol_coeffs
from scipy.stats import norm

from mcpilco.models.diagnosis.data import derivative_filter, smoother_noise_std
from mcpilco.models.gp.linear_gp import single_thread
from mcpilco.models.robot_data import Trajectories
from mcpilco.models.stats import Z95, mad_std

FloatArray = NDArray[np.float64]

__all__ = [
    "CorrelationTest",
    "InputNoise",
    "JointResiduals",
    "ResidualReport",
    "cross_correlation_test",
    "fit_metrics",
    "input_noise",
    "metrics_table",
    "noise_floor",
    "position_noise",
    "at_rest",
    "friction_kinks",
    "friction_smear",
    "projected_noise_share",
    "acceleration_kernel",
    "held_still",
    "residual_report",
    "whiteness_test",
]


def noise_floor(
    traj: Trajectories,
    y_hat: FloatArray | None = None,
    inputs: InputNoise | None = None,
    rest: NDArray[np.bool_] | None = None,
) -> FloatArray:
    """``(n,)`` noise floor per joint, independent of the model's fitted noise.

    Without ``inputs``: the measurement-noise std from first differences,
    ``sigma = 1.4826 MAD(diff(e)) / sqrt(2)`` per segment, pooled (``e = y - y_hat``, or
    ``y``). Smooth signals and model errors nearly cancel in ``diff``; white noise of std
    ``sigma`` gives ``diff`` std ``sqrt(2) sigma``; the MAD ignores the rare jumps.

    With ``inputs`` (:func:`input_noise` of the same model on ``traj``): the floor a perfect
    model sits at, ``sqrt(sigma_meas^2 + sigma_in^2)`` with the input noise's share of the
    first differences removed from ``sigma_meas^2`` (module docstring), and, for currents put
    into torque units with estimated constants, the mean square that their uncertainty adds
    (:meth:`~mcpilco.models.diagnosis.units.TorqueConstants.output_variance`).

    ``rest`` ``(N, n)``: rows where a set-valued prediction absorbs the noise (a joint at rest
    held by dry friction, :meth:`~.model.DiagnosisModel.set_valued`: its error there is the
    residual's distance to an interval, about 0). The measurement noise is then taken from
    the other rows' differences and the floor is the RMSE over all rows of a perfect model,
    ``sqrt(1 - f)`` times theirs (``f`` the share of such rows)."""
    e = traj.y if y_hat is None else traj.y - y_hat
    free = np.ones(e.shape, dtype=bool) if rest is None else ~np.asarray(rest, dtype=bool)
    parts = [(a, b) for a, b in traj.segments if b - a > 2]
    d = np.concatenate([np.diff(e[a:b], axis=0) for a, b in parts])
    ok = np.concatenate([free[a + 1 : b] & free[a : b - 1] for a, b in parts])
    sigma = np.zeros(e.shape[1])
    for j in range(e.shape[1]):
        dj = d[ok[:, j], j] if ok[:, j].sum() > 2 else d[:, j]
        sigma[j] = mad_std(dj) / np.sqrt(2.0)
    if inputs is None:
        return sigma
    meas2 = np.maximum(sigma**2 - inputs.diff_std**2, 0.0)
    share = free.mean(axis=0)
    scale2 = 0.0 if traj.torque_constants is None else traj.torque_constants.output_variance(traj.y)
    return np.sqrt(share * (meas2 + inputs.std**2) + scale2)


@dataclass
class InputNoise:
    """Noise that estimated ``qd``/``qdd`` put into a model's prediction (module docstring).

    Attributes:
        std: ``(n,)`` ``sigma_in`` per output joint (rms over all rows; 0 on rows whose
            derivatives were given).
        diff_std: ``(n,)`` the part of it that first differences see, ``sqrt(var(diff u) / 2)``.
        position_std: per segment, ``(n,)`` ``sigma_x`` of the differentiated signal, or
            ``None`` where nothing was estimated.
    """

    std: FloatArray
    diff_std: FloatArray
    position_std: list[FloatArray | None]


def _filter_rows(est: Any) -> tuple[tuple[str, ...], FloatArray]:
    """``(groups, B)``: the signals that the noise of the differentiated signal reaches and
    the filter's coefficient rows for each (the sample itself, then its derivatives)."""
    f = est.filter
    m = f.window // 2
    delta = np.zeros(f.window)
    delta[m] = 1.0
    c = [savgol_coeffs(f.window, f.order, deriv=k, delta=f.sample_time, use="dot") for k in (1, 2)]
    if "qd" in est.groups:
        return ("q", "qd", "qdd"), np.stack([delta, c[0], c[1]])
    return ("qd", "qdd"), np.stack([delta, c[0]])


def position_noise(traj: Trajectories) -> list[FloatArray | None]:
    """Per segment, ``(n,)`` noise std of the signal its derivatives were estimated from
    (``q``, or ``qd`` when only ``qdd`` was), or ``None`` where none was (module docstring)."""
    out: list[FloatArray | None] = []
    runs = {int(traj.segment[a]): (a, b) for a, b in traj.segments}
    for s, est in enumerate(traj.estimated):
        if est is None or s not in runs:
            out.append(None)
            continue
        a, b = runs[s]
        f = derivative_filter(est.filter.sample_time)  # the shortest span: least bias
        if b - a < 2 * f.window:
            out.append(None)
            continue
        x = traj.q[a:b] if "qd" in est.groups else traj.qd[a:b]
        out.append(smoother_noise_std(x, f))
    return out


def at_rest(traj: Trajectories) -> NDArray[np.bool_]:
    """``(N, n)``: rows where a joint is at rest as far as the data can tell, i.e. the sign
    of its velocity is unknown (where dry friction is set-valued).

    Where ``qd`` was estimated from ``q`` (noise std ``sigma_q``, :func:`position_noise`):
    ``|qd| <= REST_FACTOR sigma_qd`` (``sigma_qd = ||c_1|| sigma_q``, the filter's noise gain,
    :class:`.data.DerivativeFilter`), or ``q`` stays over the ``m`` samples of
    :data:`REST_SPAN` around the row within the range that ``m`` samples of its noise keep
    with probability ``1 - REST_MISS`` (:func:`noise_range_quantile` times ``sigma_q``; at
    least one encoder step, the smallest change of ``q`` in the segment). The second test is
    the local one: the derivative filter spreads a stop over its whole window, so that near a
    stick phase its ``qd`` is small but not within the noise. The range of ``m`` noise samples
    exceeds a fixed few ``sigma_q`` often (3 ``sigma_q`` in about one window of 5 in 4): a
    joint held still by dry friction whose encoder dithers over two steps would be taken as
    sliding, and its held torque, anywhere in ``[-F_s, F_s]``, as ``F_s`` times the sign of a
    velocity that is noise. Where ``qd`` was given: ``qd == 0``."""
    rest = traj.qd == 0.0
    pos = position_noise(traj)
    for a, b in traj.segments:
        s = int(traj.segment[a])
        est = traj.estimated[s]
        if est is None or pos[s] is None or "qd" not in est.groups:
            continue
        sigma_qd = est.filter.noise_gain_qd * pos[s]
        half = max(int(round(0.5 * REST_SPAN / est.filter.sample_time)), 1)
        q = np.pad(traj.q[a:b], ((half, half), (0, 0)), mode="edge")
        win = sliding_window_view(q, 2 * half + 1, axis=0)
        bound = np.maximum(noise_range_quantile(2 * half + 1) * pos[s], _encoder_step(traj.q[a:b]))
        still = win.max(axis=-1) - win.min(axis=-1) <= bound * (1 + 1e-9)
        rest[a:b] = still | (np.abs(traj.qd[a:b]) <= REST_FACTOR * sigma_qd)
    return rest


def friction_kinks(traj: Trajectories, rest: ArrayLike, joint: int) -> NDArray[np.bool_]:
    """``(N,)``: rows within the derivative filter's half window ``m`` (``window // 2``) of
    the start or the end of a stick phase of joint ``joint`` (1-based): a run of at least
    ``m`` rows at rest (``rest`` ``(N,)``, :func:`at_rest`).

    Dry friction holds a sticking joint with an unknown torque in ``[-F_s, F_s]`` and slides
    at ``+-F``; where the joint stops it switches within a physics step, so its acceleration
    jumps, and ``qd``/``qdd`` estimated from ``q`` by a filter whose window spans the jump
    are biased on the ``2 m`` rows around it (:class:`.data.DerivativeFilter`), as they are at
    a file's edges; the held torque, unknown, is spread over the same rows. A shorter run at
    rest is a reversal seen through the noise (the velocity crosses zero), whose rows stay
    scored: there the friction's form is what the data show. Rows of segments whose
    derivatives were given are never marked."""
    rest = np.asarray(rest, dtype=bool)
    out = np.zeros(traj.n_samples, dtype=bool)
    for a, b in traj.segments:
        s = int(traj.segment[a])
        est = traj.estimated[s] if traj.estimated and s < len(traj.estimated) else None
        if est is None or b - a < 2:
            continue
        m = est.filter.window // 2
        r = rest[a:b]
        edges = np.flatnonzero(np.diff(np.concatenate([[0], r.astype(np.int8), [0]])))
        switch = np.zeros(b - a + 1)  # row i: the state changed from row i - 1
        for start, stop in zip(edges[::2], edges[1::2], strict=True):  # at rest start..stop-1
            if stop - start >= STICK_ROWS:
                switch[[start, stop]] = 1.0
        switch[[0, b - a]] = 0.0  # a file's ends are no transition
        # rows i - m .. i + m - 1 around a switch at row i
        near = np.convolve(switch[: b - a], np.ones(2 * m), mode="full")[m : m + b - a]
        out[a:b] = near > 0
    return out


def acceleration_kernel(est: Any) -> FloatArray:
    """``(2 m + 3,)`` weights ``K_k``, ``k = -m - 1 .. m + 1`` (``m = window // 2``), with
    which the filter of ``est`` (a :class:`.data.Estimate`) sees the acceleration:
    ``qdd_hat(t) = sum_k K_k a(t + k)``, ``a`` the second difference of ``q`` over ``T^2``
    (or, where only ``qdd`` was estimated, the first difference of ``qd`` over ``T``). The
    filter is exact on quadratics, so the weights sum to 1; a jump of the acceleration comes
    out as a ramp over the window."""
    f = est.filter
    m = f.window // 2
    i = np.arange(-m, m + 1)
    ks = np.arange(-m - 1, m + 2)
    if "qd" in est.groups:  # qdd_hat = c_2 . q; q with one unit second difference at k
        c = savgol_coeffs(f.window, f.order, deriv=2, delta=f.sample_time, use="dot")
        return np.array([c @ (f.sample_time**2 * np.maximum(i - k, 0)) for k in ks])
    c = savgol_coeffs(f.window, f.order, deriv=1, delta=f.sample_time, use="dot")
    return np.array([c @ (f.sample_time * (i >= k)) for k in ks])


def friction_smear(
    traj: Trajectories, rest: ArrayLike, joint: int, torque: ArrayLike | None = None
) -> FloatArray:
    """``(N,)``: the part of a dry friction's torque ``s`` that the estimated ``qdd`` of
    joint ``joint`` (1-based) carries into the joint's own prediction on the rows around its
    stick phases (:func:`friction_kinks`), ``|(K * s)(t) - s(t)|`` with ``K`` the filter's
    :func:`acceleration_kernel`; 0 elsewhere and on segments whose derivatives were given.
    ``s``: ``torque`` ``(N,)`` (a fitted friction's torque, 0 at rest), or by default the
    friction's sign, ``sign(qd)`` while sliding and 0, the centre of the set, at rest
    (``rest`` ``(N,)``, :func:`at_rest`): the share of a sharp friction's level.

    Where the joint stops or starts, dry friction switches within a physics step, so its
    acceleration jumps by the switch over the joint's inertia; the torque the rest of the
    model predicts, ``M qdd_hat``, then differs from the measured one by about the filter's
    smear of the friction torque, ``F (K * s - s)``, with the torque held at rest unknown in
    ``[-F_s, F_s]``. :meth:`~.model.DiagnosisModel.set_valued` takes it, for the fitted
    friction's torque, as the half-width of the joint's own prediction interval there."""
    rest = np.asarray(rest, dtype=bool)
    out = np.zeros(traj.n_samples)
    near = friction_kinks(traj, rest, joint)
    for a, b in traj.segments:
        s_id = int(traj.segment[a])
        est = traj.estimated[s_id] if traj.estimated and s_id < len(traj.estimated) else None
        if est is None or not near[a:b].any():
            continue
        kern = acceleration_kernel(est)
        h = kern.size // 2
        if torque is None:
            s = np.where(rest[a:b], 0.0, np.sign(traj.qd[a:b, joint - 1]))
        else:
            s = np.asarray(torque, dtype=np.float64)[a:b]
        # the friction's sign as the differences see it, the switch midway between two rows:
        # a second difference weighs the sign over two rows by a hat, a first one over one row
        seen = np.pad(s, 1, mode="edge")
        if "qd" in est.groups:
            seen = (seen[:-2] + 6.0 * seen[1:-1] + seen[2:]) / 8.0
        else:
            seen = 0.5 * (seen[1:-1] + seen[2:])
        smooth = np.convolve(np.pad(seen, h, mode="edge"), kern[::-1], mode="valid")
        out[a:b] = np.where(near[a:b], np.abs(smooth - s), 0.0)
    return out


def projected_noise_share(a: ArrayLike) -> FloatArray:
    """``E[dist(Z, [-a, a])^2]`` for a standard normal ``Z``: the share of a noise's variance
    left when a prediction is an interval of half-width ``a`` noise stds around the truth
    (1 at ``a = 0``), ``2 ((1 + a^2) (1 - Phi(a)) - a phi(a))``."""
    a = np.abs(np.asarray(a, dtype=np.float64))
    return 2.0 * ((1.0 + a**2) * norm.sf(a) - a * norm.pdf(a))


def held_still(rest_share: ArrayLike) -> list[int]:
    """Joints (1-based) held still: at rest (:func:`at_rest`) on at least
    :data:`HELD_STILL_SHARE` of a log's rows (``rest_share``: ``(n,)``, each joint's share of
    rows at rest). On such a joint the torques that act in motion (friction, damping,
    inertia) do not show, and a torque that holds it (dry friction at rest, a brake, a
    preloaded spring) is one unknown value per row: no effect on it can be identified from
    these rows."""
    share = np.asarray(rest_share, dtype=float)
    return [int(j) + 1 for j in np.flatnonzero(share >= HELD_STILL_SHARE)]


@functools.lru_cache(maxsize=32)
def noise_range_quantile(m: int, miss: float | None = None) -> float:
    """The range ``r`` that ``m`` independent standard normal samples stay within with
    probability ``1 - miss`` (default :data:`REST_MISS`): the root of
    ``P(R <= r) = m int phi(x) (Phi(x + r) - Phi(x))^(m - 1) dx = 1 - miss`` (the
    distribution of the sample range)."""
    if m < 2:
        return 0.0
    miss = REST_MISS if miss is None else miss

    def cdf(r: float) -> float:
        f = lambda x: norm.pdf(x) * (norm.cdf(x + r) - norm.cdf(x)) ** (m - 1)  # noqa: E731
        return m * quad(f, -10.0, 10.0, limit=200)[0]

    return float(brentq(lambda r: cdf(r) - (1.0 - miss), 1e-6, 20.0))


def _encoder_step(q: FloatArray) -> FloatArray:
    """``(n,)`` the smallest nonzero change of each column of ``q`` between samples (an
    encoder's step when ``q`` is quantised; 0 for a column that never changes)."""
    d = np.abs(np.diff(q, axis=0))
    d = np.where(d > 0, d, np.inf)
    step = d.min(axis=0) if d.size else np.zeros(q.shape[1])
    return np.where(np.isfinite(step), step, 0.0)


def input_noise(
    traj: Trajectories,
    predict: Callable[[Trajectories], FloatArray],
    at: FloatArray | None = None,
) -> InputNoise:
    """``sigma_in`` of the prediction ``predict(traj)`` (``(N, n)`` output) on ``traj`` from
    the noise of its estimated derivatives (module docstring): central differences of
    ``predict`` on copies of ``traj`` with one input column moved by its noise std, or
    forward differences from ``at`` (``predict(traj)``, when at hand)."""
    n = traj.n_joints
    pos = position_noise(traj)
    var = np.zeros((traj.n_samples, n))
    dvar = np.zeros((traj.n_samples, n))
    if all(p is None for p in pos):
        return InputNoise(np.zeros(n), np.zeros(n), pos)
    # per-row steps of every input group: the noise std that group carries there
    steps = {g: np.zeros((traj.n_samples, n)) for g in ("q", "qd", "qdd")}
    parts: list[tuple[slice, tuple[str, ...], FloatArray, FloatArray, FloatArray]] = []
    for a, b in traj.segments:
        s = int(traj.segment[a])
        if pos[s] is None:
            continue
        groups, rows = _filter_rows(traj.estimated[s])
        padded = np.pad(rows, ((0, 0), (1, 1)))
        drows = np.diff(padded, axis=1)
        for g, row in zip(groups, rows, strict=True):
            steps[g][a:b] = np.linalg.norm(row) * pos[s]
        parts.append((slice(a, b), groups, rows @ rows.T, drows @ drows.T, pos[s]))
    grads: dict[str, FloatArray] = {}  # d y_j / d x_k per row: (N, n_out, n_in)
    for g, h in steps.items():
        if not h.any():
            continue
        grad = np.zeros((traj.n_samples, n, n))
        for k in range(n):
            hk = h[:, k]
            if not hk.any():
                continue
            col = getattr(traj, g)
            up = col.copy()
            up[:, k] += hk
            y_up = predict(dataclasses.replace(traj, **{g: up}))
            safe = np.where(hk > 0, hk, 1.0)[:, None]
            if at is None:
                down = col.copy()
                down[:, k] -= hk
                diff = (y_up - predict(dataclasses.replace(traj, **{g: down}))) / (2.0 * safe)
            else:
                diff = (y_up - at) / safe
            grad[:, :, k] = np.where(hk[:, None] > 0, diff, 0.0)
        grads[g] = grad
    for span, groups, gram, dgram, sigma in parts:
        # w: (rows, n_out, n_in, groups); var = sum_k sigma_k^2 w^T G w
        w = np.stack(
            [
                grads[g][span] if g in grads else np.zeros((span.stop - span.start, n, n))
                for g in groups
            ],
            axis=-1,
        )
        var[span] = np.einsum("tjkg,gh,tjkh,k->tj", w, gram, w, sigma**2)
        dvar[span] = 0.5 * np.einsum("tjkg,gh,tjkh,k->tj", w, dgram, w, sigma**2)
    return InputNoise(np.sqrt(var.mean(axis=0)), np.sqrt(dvar.mean(axis=0)), pos)


REST_FACTOR = 3.0
"""Noise stds within which a joint's ``qd`` (or its ``q``'s range) counts as at rest."""
REST_SPAN = 0.02
"""Span [s] over which a joint at rest keeps ``q`` within its noise (:func:`at_rest`)."""
REST_MISS = 1e-3
"""Chance that a joint at rest leaves the range its noise keeps over :data:`REST_SPAN`."""
STICK_ROWS = 2
"""Fewest consecutive rows at rest that :func:`friction_kinks` takes for a stick phase."""
HELD_STILL_SHARE = 0.95
"""Share of a log's rows at rest from which on a joint counts as held still (:func:`held_still`)."""
EXPLAINED_FRACTION = 0.05
"""Share of the residual variance that a state variable's bin means must explain to be named."""
CORRELATION_LEVEL = 0.01
"""Level of the whiteness and cross-correlation tests (the 99% band of MATLAB's ``resid``)."""
CORRELATION_LAGS = 25
"""Lags ``L`` of the whiteness (``1..L``) and cross-correlation (``-L..L``) tests (``resid``'s)."""
AR_MAX_ORDER = 20
"""Highest order of the residual's AR model behind Bartlett's band (chosen by AIC)."""

STATE_UNITS = {"q": ("rad", "m"), "qd": ("rad/s", "m/s"), "qdd": ("rad/s²", "m/s²")}


def fit_metrics(y: FloatArray, y_hat: FloatArray) -> dict[str, FloatArray]:
    """``{"nmse", "rmse", "fit_pct"}`` per joint, each ``(n,)`` (module docstring)."""
    y = np.asarray(y, dtype=np.float64)
    y_hat = np.asarray(y_hat, dtype=np.float64)
    if y.shape != y_hat.shape:
        raise ValueError(f"shapes differ: measured {y.shape}, predicted {y_hat.shape}")
    err = y - y_hat
    mse = np.mean(err**2, axis=0)
    var = np.var(y, axis=0)
    var = np.where(var > 0, var, np.nan)
    dev = np.linalg.norm(y - y.mean(axis=0), axis=0)
    dev = np.where(dev > 0, dev, np.nan)
    return {
        "nmse": mse / var,
        "rmse": np.sqrt(mse),
        "fit_pct": 100.0 * (1.0 - np.linalg.norm(err, axis=0) / dev),
    }


@dataclass
class CorrelationTest:
    """A whiteness or cross-correlation test of a residual (module docstring).

    Attributes:
        lags: lags in samples (``1..L`` for the autocorrelation, ``-L..L`` for the
            cross-correlation; ``tau > 0``: the input leads the residual).
        r: the correlation at each lag.
        band: the 99% band of one lag, ``z_0.995 sqrt(v)``: MATLAB's ``z_0.995 / sqrt(N)``
            for the autocorrelation, widened to Bartlett's ``v`` for the cross-correlation.
        threshold: the band for all lags at once (Sidak), which a null residual crosses with
            probability ``level``.
        level: the test's level.
        n: samples behind each correlation.
        ar_order: order of the AR model of the residual behind Bartlett's variance (``0``:
            white, MATLAB's band).
        inflation: ``N`` times the variance of one lag's correlation under the null
            hypothesis (``1`` for a white residual; bands scale with its root).
    """

    lags: NDArray[np.int64]
    r: FloatArray
    band: float
    threshold: float
    level: float
    n: int
    ar_order: int = 0
    inflation: float = 1.0

    @property
    def peak_index(self) -> int:
        return int(np.argmax(np.abs(self.r))) if self.r.size else 0

    @property
    def peak_lag(self) -> int:
        """The lag of the largest ``|r|``."""
        return int(self.lags[self.peak_index]) if self.r.size else 0

    @property
    def peak(self) -> float:
        """The largest correlation (signed)."""
        return float(self.r[self.peak_index]) if self.r.size else 0.0

    @property
    def passed(self) -> bool:
        """No lag outside :attr:`threshold`: white, or uncorrelated with the input."""
        return bool(abs(self.peak) <= self.threshold)

    @property
    def outside(self) -> int:
        """Lags outside the per-lag 99% :attr:`band`."""
        return int(np.sum(np.abs(self.r) > self.band))

    def to_dict(self) -> dict[str, Any]:
        return {
            "lags": self.lags.tolist(),
            "r": self.r.tolist(),
            "band": self.band,
            "threshold": self.threshold,
            "level": self.level,
            "n": self.n,
            "ar_order": self.ar_order,
            "inflation": self.inflation,
            "peak_lag": self.peak_lag,
            "peak": self.peak,
            "passed": self.passed,
        }


def _bands(n: int, m: int, level: float) -> tuple[float, float]:
    """``(per-lag band, band for m lags at once)`` of correlations over ``n`` samples."""
    sidak = 1.0 - (1.0 - level) ** (1.0 / max(m, 1))
    root = math.sqrt(max(n, 1))
    return float(norm.ppf(1 - level / 2) / root), float(norm.ppf(1 - sidak / 2) / root)


def _segments_of(
    x: FloatArray, segments: Sequence[tuple[int, int]] | None
) -> list[tuple[int, int]]:
    return [(0, x.shape[0])] if segments is None else [(int(a), int(b)) for a, b in segments]


def _check_series(name: str, x: FloatArray, segments: list[tuple[int, int]]) -> FloatArray:
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 1:
        raise ValueError(f"{name} must be one series (1-D), got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{name} has NaN/inf values")
    if any(a < 0 or b > x.size or b < a for a, b in segments):
        raise ValueError(f"segments must lie inside {name} (0..{x.size}), got {segments}")
    return x


def whiteness_test(
    e: FloatArray,
    segments: Sequence[tuple[int, int]] | None = None,
    *,
    max_lag: int = CORRELATION_LAGS,
    level: float = CORRELATION_LEVEL,
) -> CorrelationTest:
    """Autocorrelation of ``e`` at lags ``1..max_lag`` (pooled over ``segments``, each
    ``(start, stop)``; default one) against the 99% band; ``passed``: white at ``level``."""
    segs = _segments_of(np.asarray(e), segments)
    e = _check_series("e", e, segs)
    rho = _acf(e, segs, max_lag)[1:]
    n = sum(b - a for a, b in segs)
    band, threshold = _bands(n, rho.size, level)
    return CorrelationTest(np.arange(1, rho.size + 1), rho, band, threshold, level, n)


def _ar_filter(u: FloatArray, segments: list[tuple[int, int]], max_order: int) -> FloatArray:
    """``[1, -a_1, .., -a_p]``: the AR(``p``) model ``A(z) u = w`` of ``u`` (least squares over
    the segments, mean removed per segment, ``p`` by AIC over ``0..max_order``)."""
    rows, targets = [], []
    p_max = max(0, min(max_order, min(b - a for a, b in segments) // 4))
    for a, b in segments:
        x = u[a:b] - u[a:b].mean()
        targets.append(x[p_max:])
        rows.append(np.stack([x[p_max - k : b - a - k] for k in range(1, p_max + 1)], axis=1))
    if p_max == 0:
        return np.ones(1)
    X, y = np.concatenate(rows), np.concatenate(targets)
    Q, R = np.linalg.qr(X)
    c = Q.T @ y
    # residual sums of squares of the nested fits AR(0..p_max), all from one QR
    rss = np.maximum(float(y @ y) - np.concatenate([[0.0], np.cumsum(c**2)]), 1e-300)
    aic = y.size * np.log(rss / y.size) + 2.0 * np.arange(p_max + 1)
    p = int(np.argmin(aic))
    if p == 0:
        return np.ones(1)
    return np.concatenate([[1.0], -np.linalg.solve(R[:p, :p], c[:p])])


def _ar_acf(f: FloatArray, max_lag: int) -> FloatArray:
    """Autocorrelation ``rho(0..max_lag)`` of the AR process ``f(z) x = w`` (white ``w``),
    from its impulse response."""
    if f.size == 1:
        out = np.zeros(max_lag + 1)
        out[0] = 1.0
        return out
    n = max_lag + 1
    h = lfilter([1.0], f, np.eye(1, 4 * n, 0)[0])
    return _acf(h, [(0, h.size)], max_lag, centre=False)


def cross_correlation_test(
    e: FloatArray,
    u: FloatArray,
    segments: Sequence[tuple[int, int]] | None = None,
    *,
    max_lag: int = CORRELATION_LAGS,
    level: float = CORRELATION_LEVEL,
    max_order: int = AR_MAX_ORDER,
) -> CorrelationTest:
    """Cross-correlation ``r(tau) = corr(e(t), u(t - tau))``, ``tau = -max_lag..max_lag``, of
    residual ``e`` and input ``u`` (pooled over ``segments``), with the band of Bartlett's
    variance ``(1/N) sum_k rho_ee(k) rho_uu(k)`` (``rho_ee`` of an AR fit of ``e``; module
    docstring); ``passed``: no correlation at ``level``."""
    segs = _segments_of(np.asarray(e), segments)
    e = _check_series("e", e, segs)
    u = _check_series("u", u, segs)
    if e.shape != u.shape:
        raise ValueError(f"e and u differ in length: {e.size} and {u.size}")
    n = sum(b - a for a, b in segs)
    lags = np.arange(-max_lag, max_lag + 1)
    num = np.zeros(lags.size)
    for a, b in segs:
        x, w = e[a:b] - e[a:b].mean(), u[a:b] - u[a:b].mean()
        for i, k in enumerate(lags):
            if abs(k) < x.size:
                # sum_t x(t) w(t - k)
                num[i] += float(x[k:] @ w[: x.size - k]) if k >= 0 else float(x[:k] @ w[-k:])
    den = math.sqrt(
        sum(float(np.sum((e[a:b] - e[a:b].mean()) ** 2)) for a, b in segs)
        * sum(float(np.sum((u[a:b] - u[a:b].mean()) ** 2)) for a, b in segs)
    )
    r = num / den if den > 0 else np.zeros(lags.size)
    k_max = max(b - a for a, b in segs) - 1
    with single_thread():  # small matrices: BLAS threads would only contend
        f = _ar_filter(e, segs, max_order)
        rho_e = _ar_acf(f, k_max)
        rho_u = _acf(u, segs, k_max)
    inflation = max(float(rho_e[0] * rho_u[0] + 2.0 * np.sum(rho_e[1:] * rho_u[1:])), 1.0)
    band, threshold = _bands(n, lags.size, level)
    root = math.sqrt(inflation)
    return CorrelationTest(
        lags, r, band * root, threshold * root, level, n, ar_order=f.size - 1, inflation=inflation
    )


@dataclass
class JointResiduals:
    """Residual analysis of one joint (arrays for plotting, module docstring)."""

    joint: int
    noise_std: float
    bins: dict[str, dict[str, FloatArray]] = field(default_factory=dict)
    reversal_lags: FloatArray = field(default_factory=lambda: np.zeros(0))
    reversal_up: FloatArray = field(default_factory=lambda: np.zeros(0))
    reversal_down: FloatArray = field(default_factory=lambda: np.zeros(0))
    n_reversals: tuple[int, int] = (0, 0)
    acf: FloatArray = field(default_factory=lambda: np.zeros(0))
    whiteness_band: float = 0.0
    outside_fraction: float = 0.0
    whiteness: CorrelationTest | None = None
    xcorr: dict[str, CorrelationTest] = field(default_factory=dict)
    sample_time: float = 0.0
    explained: dict[str, float] = field(default_factory=dict)
    findings: list[tuple[float, str]] = field(default_factory=list)

    def _lag_text(self, lag: int) -> str:
        ms = f" = {1e3 * lag * self.sample_time:+.0f} ms" if self.sample_time > 0 and lag else ""
        return f"lag {lag:+d}{ms}" if lag else "lag 0"

    def correlation_text(self) -> str:
        """Whiteness and correlation with the inputs in words, e.g. ``"correlated with q2
        (peak +0.41 at lag 0); not white (autocorrelation +0.62 at lag +1)"``."""
        j = self.joint
        parts = []
        hits = [
            f"{name}{j} (peak {t.peak:+.2f} at {self._lag_text(t.peak_lag)})"
            for name, t in self.xcorr.items()
            if not t.passed
        ]
        quiet = [f"{name}{j}" for name, t in self.xcorr.items() if t.passed]
        if hits:
            parts.append("correlated with " + ", ".join(hits))
        if quiet:
            parts.append(("not with " if hits else "uncorrelated with ") + ", ".join(quiet))
        w = self.whiteness
        if w is not None:
            if w.passed:
                parts.append("white")
            else:
                parts.append(
                    f"not white (autocorrelation {w.peak:+.2f} at {self._lag_text(w.peak_lag)}; "
                    f"{w.outside} of {w.r.size} lags outside the 99% band +-{w.band:.3f})"
                )
        return "; ".join(parts)

    def structure(self) -> str:
        """The residual's structure in words: the state variables whose bins explain at least
        :data:`EXPLAINED_FRACTION` of its variance, its correlation with the inputs, its
        whiteness (:meth:`correlation_text`), and its worst finding."""
        j = self.joint
        deps = sorted(
            ((f, name) for name, f in self.explained.items() if f >= EXPLAINED_FRACTION),
            reverse=True,
        )
        if deps:
            words = ", ".join(f"{name}{j} {100 * f:.0f}%" for f, name in deps[1:])
            f0, name0 = deps[0]
            parts = [f"bins of {name0}{j} explain {100 * f0:.0f}% of its variance"]
            if words:
                parts[0] += f" ({words})"
        else:
            parts = [f"no dependence on q{j}, qd{j} or qdd{j} in equal-count bins"]
        corr = self.correlation_text()
        if corr:
            parts.append(corr)
        if self.findings:
            parts.append("largest: " + max(self.findings)[1])
        return "; ".join(parts)


@dataclass
class ResidualReport:
    """All joints' residual analyses plus the findings in words, worst first."""

    model_name: str
    joints: list[JointResiduals]
    windows: list[tuple[float, str]]

    def findings(self, top: int = 5) -> list[str]:
        items = sorted(
            [f for jr in self.joints for f in jr.findings] + self.windows, key=lambda x: -x[0]
        )
        return [text for _, text in items[:top]]

    def text(self, top: int = 5) -> str:
        lines = [f"where {self.model_name} fails (worst first):"]
        lines += [f"  - {t}" for t in self.findings(top)]
        lines.append("  whiteness and correlation with the inputs (99% bands):")
        lines += [f"    joint {jr.joint}: {jr.correlation_text()}" for jr in self.joints]
        return "\n".join(lines)


def _bins(x: FloatArray, e: FloatArray, n_bins: int) -> dict[str, FloatArray]:
    edges = np.unique(np.quantile(x, np.linspace(0, 1, n_bins + 1)))
    if edges.size < 2:
        edges = np.array([x.min(), x.max() + 1e-12])
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, edges.size - 2)
    k = edges.size - 1
    count = np.bincount(idx, minlength=k).astype(float)
    s = np.bincount(idx, weights=e, minlength=k)
    s2 = np.bincount(idx, weights=e**2, minlength=k)
    c = np.maximum(count, 1)
    mean = s / c
    sd = np.sqrt(np.maximum(s2 / c - mean**2, 0.0))
    rms = np.sqrt(s2 / c)
    return {
        "lo": edges[:-1],
        "hi": edges[1:],
        "centre": 0.5 * (edges[:-1] + edges[1:]),
        "mean": mean,
        "ci95": Z95 * sd / np.sqrt(c),
        "rms": rms,
        "count": count,
    }


def _acf(
    e: FloatArray, segments: Sequence[tuple[int, int]], max_lag: int, centre: bool = True
) -> FloatArray:
    """Autocorrelation ``rho(0..max_lag)`` pooled over segments (biased estimator: sums of
    lagged products over the total sum of squares; FFT per segment)."""
    num = np.zeros(max_lag + 1)
    den = 0.0
    for a, b in segments:
        x = e[a:b] - e[a:b].mean() if centre else e[a:b]
        if x.size == 0:
            continue
        size = 1 << int(2 * x.size - 1).bit_length()
        spec = np.fft.rfft(x, size)
        full = np.fft.irfft(spec * np.conj(spec), size)
        k = min(max_lag, x.size - 1) + 1
        num[:k] += full[:k]
        den += float(x @ x)
    return num / den if den > 0 else num


def residual_report(
    traj: Trajectories,
    y_hat: FloatArray,
    noise_std: FloatArray | None,
    joint_types: str,
    *,
    model_name: str = "model",
    n_bins: int = 10,
    reversal_window: int = 30,
    max_lag: int = CORRELATION_LAGS,
    window_s: float = 0.5,
    unit: str | Sequence[str | None] | None = None,
) -> ResidualReport:
    """Residual analysis of ``traj.y - y_hat`` (module docstring).

    Args:
        traj: measured trajectories.
        y_hat: ``(N, n)`` predicted output.
        noise_std: ``(n,)`` the "x noise" yardstick; ``None``: :func:`noise_floor` (the
            measurement noise, not the model's fitted noise, which absorbs model errors).
        joint_types: e.g. ``"RRPR"`` (units in the words).
        unit: the output's unit in the words, for all joints or per joint (``None``: N·m or
            N by joint type).
    """
    e_all = traj.y - y_hat
    if noise_std is None:
        noise_std = noise_floor(traj, y_hat)
    segs = traj.segments
    dt = traj.sample_time
    out, windows = [], []
    for j in range(traj.n_joints):
        prism = joint_types[j] == "P"
        own = unit if unit is None or isinstance(unit, str) else unit[j]
        force = own or ("N" if prism else "N·m")
        e = e_all[:, j]
        sigma = float(noise_std[j]) if noise_std[j] > 0 else float(np.std(e)) or 1.0
        jr = JointResiduals(joint=j + 1, noise_std=sigma)
        for name in ("qd", "q", "qdd"):
            x = getattr(traj, name)[:, j]
            b = _bins(x, e, n_bins)
            jr.bins[name] = b
            total = float(np.sum((e - e.mean()) ** 2))
            between = float(np.sum(b["count"] * (b["mean"] - e.mean()) ** 2))
            jr.explained[name] = between / total if total > 0 else 0.0
            score = np.abs(b["mean"]) / sigma
            significant = np.abs(b["mean"]) > b["ci95"]
            if np.any(significant):
                k = int(np.argmax(np.where(significant, score, -1)))
                su = STATE_UNITS[name][int(prism)]
                jr.findings.append(
                    (
                        float(score[k]),
                        f"joint {j + 1}, {name}{j + 1} in [{b['lo'][k]:.3g}, {b['hi'][k]:.3g}] "
                        f"{su}: mean residual {b['mean'][k]:+.3g} {force} "
                        f"(rms {b['rms'][k]:.3g}), {score[k]:.1f}x noise",
                    )
                )
        # velocity reversals
        lags = np.arange(-reversal_window, reversal_window + 1)
        up, down = [], []
        for a, b in segs:
            s = np.sign(traj.qd[a:b, j])
            rev = np.flatnonzero((s[:-1] != 0) & (s[1:] != 0) & (s[:-1] != s[1:])) + a + 1
            for r in rev:
                if r - reversal_window < a or r + reversal_window >= b:
                    continue
                w = e[r + lags]
                (up if traj.qd[r, j] > 0 else down).append(w)
        jr.reversal_lags = lags * dt
        jr.reversal_up = np.mean(up, axis=0) if up else np.zeros(lags.size)
        jr.reversal_down = np.mean(down, axis=0) if down else np.zeros(lags.size)
        jr.n_reversals = (len(up), len(down))
        if up and down:
            jump = float(np.max(np.abs(jr.reversal_up - jr.reversal_down)))
            if jump > 3 * sigma:
                jr.findings.append(
                    (
                        jump / sigma,
                        f"joint {j + 1}, velocity reversals ({len(up) + len(down)}): residual "
                        f"differs by {jump:.3g} {force} between - to + and + to - reversals, "
                        f"{jump / sigma:.1f}x noise (friction-like)",
                    )
                )
        # whiteness and correlation with the inputs (MATLAB's resid, module docstring)
        jr.sample_time = float(dt)
        jr.whiteness = whiteness_test(e, segs, max_lag=max_lag)
        jr.acf = np.concatenate([[1.0], jr.whiteness.r])
        jr.whiteness_band = jr.whiteness.band
        jr.outside_fraction = jr.whiteness.outside / max(jr.whiteness.r.size, 1)
        inputs = {"q": traj.q[:, j], "qd": traj.qd[:, j], "tau_hat": y_hat[:, j]}
        jr.xcorr = {
            name: cross_correlation_test(e, u, segs, max_lag=max_lag)
            for name, u in inputs.items()
            if np.ptp(u) > 0
        }
        # worst time windows
        w = max(int(round(window_s / dt)), 1)
        best: list[tuple[float, int, int]] = []
        for s_idx, (a, b) in enumerate(segs):
            if b - a < w:
                continue
            c = np.concatenate([[0.0], np.cumsum(e[a:b] ** 2)])
            rms = np.sqrt((c[w:] - c[:-w]) / w)
            k = int(np.argmax(rms))
            best.append((float(rms[k]), a + k, s_idx))
        for rms, start, s_idx in sorted(best, reverse=True)[:1]:
            t0, t1 = traj.t[start], traj.t[min(start + w, traj.n_samples - 1)]
            windows.append(
                (
                    rms / sigma,
                    f"joint {j + 1}, t = {t0:.2f}-{t1:.2f} s of {traj.names[s_idx]}: residual rms "
                    f"{rms:.3g} {force}, {rms / sigma:.1f}x noise",
                )
            )
        out.append(jr)
    return ResidualReport(model_name, out, windows)


def metrics_table(rows: list[tuple[str, str, dict[str, Any]]], n_joints: int) -> str:
    """Fixed-width table of :func:`fit_metrics` rows ``(version, set, metrics)``."""
    head = f"{'model':<6} {'data':<9} {'joint':>5} {'nMSE':>9} {'RMSE':>10} {'fit %':>7}"
    lines = [head, "-" * len(head)]
    for version, which, m in rows:
        for j in range(n_joints):
            lines.append(
                f"{version:<6} {which:<9} {j + 1:>5} {m['nmse'][j]:>9.2e} {m['rmse'][j]:>10.3g} "
                f"{m['fit_pct'][j]:>7.2f}"
            )
    return "\n".join(lines)

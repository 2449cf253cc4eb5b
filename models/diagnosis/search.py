"""Which effect is missing: score every candidate on every joint by the evidence it adds.

Score (Bayesian model comparison, thesis eq. 1.9 for the evidence)
    For candidate effect ``e`` with scan variants ``v = 1..G`` on output joint ``j``:
    ``Delta_v = max_{sigma^2, lambda_e} log p(r_j | current + e_v) - log p(r_j | current)``
    (the current model's other hyperparameters held at their fitted values; the new block's
    prior variance and the noise re-optimised; a delay re-optimises them all, its inputs
    ``k`` samples earlier and its targets the same measured samples), and with a uniform
    prior over the scan
    ``Delta = log( (1/G) sum_v exp(Delta_v) )``. A rigid-body effect (a link's inertia, a
    payload; :attr:`.Effect.shared`) has one weight vector for all the joints it moves:
    ``Delta`` is the gain of the stacked joints, its prior scale and every moved joint's
    noise re-optimised (:func:`~.shared.score_shared`).
Significance
    ``Delta > evidence_threshold`` (default 5 nats: a Bayes factor above e^5 ~ 150, "very
    strong" on Kass & Raftery's scale ``2 Delta > 10``), the physical sign respected, and the
    held-out RMSE of the joints it acts on lower by more than ``min_heldout_gain`` percent
    (default 1%) when the effect is added and the model refitted (trajectories held out
    whole: the held-out files never enter the fit; several joints are pooled in units of
    their noise std, :func:`heldout_change_pct`), and material: on some joint it acts on it
    explains more than ``min_explained`` (default :data:`MIN_EXPLAINED`) of the noise floor's
    variance, ``(e_before_j^2 - e_after_j^2) / f_j^2`` (held-out RMSE ``e_j``, floor ``f_j``).
    Many training rows make a negligible term significant (a Bayes factor grows with ``N``,
    and derivative noise correlated by the filter inflates it further); a term whose torque
    is a small fraction of the noise is not named as an effect.
Missing or only under-learned (learned starts)
    A GIP start's kernel spans a known, finite function space (thesis eq. 3.8/3.11): an offset,
    an armature ``qdd_j``, a payload (rigid-body torques), a prismatic spring. Such a candidate
    can gain evidence and held-out accuracy on a GIP start (its block gives those directions
    their own prior variance; the GIP product kernel ties them to others), but it cannot be
    *missing* from a GIP model fitted on data that hold it. It is reported as a refinement
    ("in the start model's span"), never as the missing effect; :func:`auto_improve` still
    adds it when no missing effect is left and it acts on a joint above the noise floor,
    since it lowers the held-out error there (at the floor there is nothing to refine).
Learned start not at the floor
    A learned start (GIP/RBF GP fitted on the training logs) may itself miss the held-out
    log: it extrapolates to states its rows do not cover, and its error there looks like a
    missing effect. On a joint above :data:`FLOOR_FACTOR` floors a learned-start candidate
    is named only when it explains at least :data:`MIN_EXCESS_SHARE` of that joint's excess
    held-out variance over the floor, ``(e_before^2 - e_after^2) / (e_before^2 - f^2)`` (a
    missing effect explains the bulk of the miss; a term fitted to the start's own error
    explains little of it); and a verdict that leaves such a joint above the floor says that
    a learned start cannot tell its own error from a missing effect, so effects found
    against it there are not reliable.
Groups (what the data cannot tell apart)
    Two candidates on the same joint are in one group when their fitted torque contributions
    on the training rows correlate with ``|rho| > group_correlation`` (default 0.9); the
    table then names them together, and when their evidences differ by less than
    ``indistinct_nats`` (default 2 nats, Bayes factor < e^2) the verdict says so. Within a
    group, the held-out data decide which significant member is the missing effect: the one
    with the most evidence, unless another lowers the held-out RMSE by more than
    ``min_heldout_gain`` percentage points more (the rule by which an alternative replaces
    an effect), both judged on the joints either acts on; then the one that lowers it
    most. The training evidences of correlated candidates differ mainly by how well each
    fits the noise that the derivative filter correlates across rows (which the white-noise
    likelihood overcounts); a held-out log is an independent test (a link 40 % heavier:
    link 2's inertia -40 % held-out RMSE against a payload's -20 %, though the payload led
    by 12 nats).
Continuous shape values
    The scan picks the best grid value of a continuous shape field (smoothing ``eps``,
    Stribeck velocity ``v_s``, dead-zone width ``c``, cogging order ``n``, delay ``k`` in
    samples); :func:`refine_shape` then maximises ``Delta_v`` over it, one field at a time,
    by bounded Brent search on ``log x`` between the neighbouring grid values (the profile
    log-evidence: the noise and the block's prior variance re-optimised at every ``x``), and
    reports each value with its 95% likelihood-ratio interval from that profile (and the
    cogging phase with its own; :mod:`.profile`). The refined variant is the one reported,
    added and confirmed; the ranking evidence ``Delta`` stays the scan's marginal.
Alternatives (one effect per group)
    A candidate of the same physical family on the same joint as an effect in the model
    (:meth:`.Effect.same_family`: Coulomb and Stribeck are both dry friction), or one that
    was indistinct from it (same group, within ``indistinct_nats``) when it was added, is
    its *alternative*: it is never added beside it. It *replaces* it only when clearly
    better: the model with it instead gains more than ``threshold`` nats of log-evidence
    on its joints and lowers their held-out RMSE by more than ``min_heldout_gain`` percent.
    (It is tried only when it gains more than ``threshold`` nats on top of the model: the
    model with both nests the one with it alone.)
Backward elimination (stepwise both ways)
    Forward selection alone keeps an effect whose evidence a later one has taken: on an arm
    with rotor inertia on several joints, a link's inertia (one weight vector over the
    joints it moves) can lead first and stay after the armatures of those joints explain
    the data. So after every addition, :func:`backward_step` asks of each earlier effect
    that shares a joint with the new one whether it would still be added now: the model
    without it (refitted) against the model with it must show the three tests of
    significance above, more than ``threshold`` nats of log-evidence on its joints, a
    held-out RMSE lower by more than ``min_heldout_gain`` percent and more than
    ``min_explained`` of a joint's floor variance explained. An effect that fails one is
    removed (the one whose removal loses the least evidence first, then the check repeats)
    as a new version, and becomes an alternative of the effect that took its evidence (it is
    only ever put back in its place). Rotor inertia, link inertia and payload are told
    apart this way by the joints each acts on (one joint's ``qdd``; the joints up to the
    link; every joint); where the data cannot tell the later effect from the earlier one,
    the earlier one is kept only if it still earns its place, and the removal says so.
Simpler of two that the data cannot tell apart
    Within a group, a missing candidate whose evidence is within ``indistinct_nats`` of the
    chosen one and whose held-out change is within ``min_heldout_gain`` percentage points of
    it cannot be told apart from it by these data; of such candidates the one with the fewest
    parameters (block weights plus shape values, :attr:`Candidate.complexity`) is named, and
    the verdict says that the data cannot tell them apart and the simpler one is kept: one
    effect per physical cause, the simpler description where the data do not choose (an
    armature before a link's inertia). This holds for every pair of kinds, not only
    inertias; two forms of one family are left to the alternatives' rule below.
Shape of a named effect (off-library effects are unexplained)
    An effect outside the library (friction whose level varies along the joint's travel)
    is fitted by the nearest library form, which may leave the joint within
    :data:`FLOOR_FACTOR` floors. When the loop stops, :func:`shape_check` adds beside every
    joint effect of the final model its level as a smooth function of the joint's position
    (:class:`~.effects.PositionLevel`: the block times Legendre polynomials of ``q_j`` up to
    degree 3 over the training range) and applies the three tests of significance; a library
    effect has a constant level, so when the position-dependent level passes them the verdict
    is "unexplained": the named effect explains part of the torque, not in the library's form.
Torque constants estimated with the effects
    On motor-current logs whose constants were estimated, the loop's first version holds a
    free scale of the model torque on those joints (:class:`~.effects.TorqueScale`): every
    candidate is scored and fitted jointly with it, so an effect that loads a joint (a
    payload on the wrist loads every joint) is not absorbed into that joint's ``k_t``. A
    rigid-body candidate is refused as confounded with the constants only where it cannot be
    told apart on any of its joints: each holds an estimated constant without a free scale,
    or the candidate's torque there is a scaled copy of the model torque
    (``|corr| >`` :data:`CONSTANT_COLLINEARITY`).
Verdict against the noise floor
    A verdict the data cannot support is not given. The held-out RMSE of the diagnosed model,
    and of that model with the lead (the missing effect, else the refinement) added, is
    compared per joint with the noise floor ``sqrt(sigma_meas^2 + sigma_in^2)`` (measurement
    noise plus the noise of estimated ``qd``/``qdd``, :mod:`.analysis`; :func:`floor_check`).
    "No significant missing effect" needs every joint within :data:`FLOOR_FACTOR` floors;
    otherwise the verdict says "unexplained", names the joint, its RMSE in floors and the
    residual's structure in words (binned against ``q``, ``qd``, ``qdd``; whiteness). A missing
    effect that leaves a joint above the floor is said to explain part of the residual. With
    fewer than :data:`MIN_VERDICT_ROWS` held-out rows the verdict is "not enough data".
Joints held still
    A joint at rest on nearly every row of a log (:func:`.analysis.held_still`: dry friction
    that the controller's torque never overcomes, a brake, a joint the reference leaves
    alone) shows neither the torques that act in motion nor what holds it: its held torque
    is one unknown value per row. A candidate acting only on joints held still in the
    training logs is not confirmed (a viscous term fitted to a velocity that is noise fits
    the held torque with an absurd coefficient); a verdict whose only unexplained joints were
    held still (in the training or the held-out log) is "not enough data", naming the joint
    and what to record; an at-floor verdict says which joints it cannot speak for.
Identifiability
    The estimates of every confirmed candidate (and of every effect in a model,
    :meth:`.DiagnosisModel.estimates`) say "not identifiable from these data" with the reason
    instead of a number where the data cannot pin a parameter down (:mod:`.identifiability`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize_scalar
from scipy.special import logsumexp

from mcpilco.models.diagnosis.analysis import (
    at_rest,
    held_still,
    input_noise,
    noise_floor,
    projected_noise_share,
    residual_report,
)
from mcpilco.models.diagnosis.data import (
    MIN_HELDOUT_ROWS,
    as_trajectories,
    require_rows,
)
from mcpilco.models.diagnosis.effects import (
    RELINEARISE_STEPS,
    Effect,
    ParamEstimate,
    default_library,
)
from mcpilco.models.diagnosis.identifiability import judge_estimates, weight_names
from mcpilco.models.diagnosis.model import DiagnosisModel
from mcpilco.models.diagnosis.profile import likelihood_interval, phase_interval
from mcpilco.models.diagnosis.shared import score_shared
from mcpilco.models.diagnosis.units import widen_estimates, without_fitted_scales
from mcpilco.models.gp.linear_gp import single_thread
from mcpilco.models.robot_data import Trajectories

FloatArray = NDArray[np.float64]

__all__ = [
    "Candidate",
    "Diagnosis",
    "FloorCheck",
    "Misfit",
    "Removal",
    "auto_improve",
    "backward_step",
    "diagnose",
    "explained_share",
    "floor_check",
    "smear_judged",
    "heldout_change_pct",
    "heldout_floor",
    "heldout_rmse",
    "next_version",
    "refine_shape",
    "score_candidates",
    "score_effect",
    "shape_check",
    "stepwise",
]

EVIDENCE_THRESHOLD = 5.0
"""Log-evidence gain of a significant candidate [nats] (Bayes factor e^5 ~ 150)."""
MIN_HELDOUT_GAIN = 1.0
"""Held-out RMSE reduction a significant candidate needs [%]."""
MIN_EXCESS_SHARE = 0.5
"""Share of a joint's excess held-out variance over the floor that a candidate on a
learned start explains to be named there (module docstring)."""
MIN_EXPLAINED = 0.1
"""Share of a joint's noise-floor variance a material candidate explains on held-out data
(its torque at least about a third of the noise std)."""
GROUP_CORRELATION = 0.9
INDISTINCT_NATS = 2.0
FLOOR_FACTOR = 1.2
"""Held-out RMSE within this many noise floors counts as explained (at the floor)."""
MIN_VERDICT_ROWS = 200
"""Fewest held-out rows for a verdict: the RMSE of ``N`` noise rows scatters by about
``1 / sqrt(2 N)`` (5% at 200), well inside :data:`FLOOR_FACTOR`."""


@dataclass
class Candidate:
    """A scored candidate: its best variant, evidence gain, estimates, verdict."""

    effect: Effect
    delta: float
    best_delta: float
    n_variants: int
    estimates: list[ParamEstimate]
    outputs: list[int]
    contributions: dict[int, FloatArray] = field(default_factory=dict, repr=False)
    heldout_delta_pct: float | None = None
    heldout_rmse: FloatArray | None = field(default=None, repr=False)
    """``(n,)`` held-out RMSE per joint of the model with this candidate (when confirmed)."""
    explained: float | None = None
    group: int = 0
    significant: bool = False
    in_start_span: bool = False
    alternative_to: str | None = None
    replace_delta: float | None = None
    confounded: str | None = None
    unreliable: str | None = None
    unmoved: str | None = None
    """Why the candidate was not confirmed: its joints were held still in the training logs."""
    n_weights: int = 0
    """Weights of the best variant's block (its linear parameters; :attr:`complexity`)."""

    @property
    def missing(self) -> bool:
        """Significant and outside the start model's span: a missing physical effect (or a
        clearly better form of one in the model, :attr:`alternative_to`)."""
        return self.significant and not self.in_start_span

    @property
    def label(self) -> str:
        return self.effect.label

    @property
    def complexity(self) -> int:
        """Parameters the candidate fits: its block's weights plus its shape values (the
        simpler of two candidates the data cannot tell apart is kept)."""
        return self.n_weights + len(self.effect.shape_grid)

    @property
    def wrong_sign(self) -> bool:
        return any(p.wrong_sign for p in self.estimates)

    @property
    def joint_text(self) -> str:
        return "all" if self.effect.joint is None else str(self.effect.joint)

    def estimate_text(self) -> str:
        return "; ".join(p.text() for p in self.estimates)


def _score_variant(
    model: DiagnosisModel, effect: Effect, output: int, judge: bool = False
) -> tuple[float, list[ParamEstimate], FloatArray | None]:
    """``(Delta_v, estimates, contribution)`` of one complete variant on one output joint
    (``contribution``: its fitted torque on the training rows; ``None`` for a delay);
    ``judge``: mark the estimates the data cannot pin down (:mod:`.identifiability`)."""
    d, est, post = _fit_variant(model, effect, output, judge)
    return d, est, _contribution(model, effect, output, post)


def _contribution(
    model: DiagnosisModel,
    effect: Effect,
    output: int,
    post: tuple[FloatArray, FloatArray] | None,
) -> FloatArray | None:
    """Fitted torque ``Phi w_mean`` of a scored variant on the training rows."""
    if post is None:
        return None
    return effect.calibrate(model.ctx_).columns(model.joint_context(output), output) @ post[0]


def _fit_variant(
    model: DiagnosisModel, effect: Effect, output: int, judge: bool = False
) -> tuple[float, list[ParamEstimate], tuple[FloatArray, FloatArray] | None]:
    """``(Delta_v, estimates, (mean, cov))``: the evidence gain of one complete variant on
    one output joint, its estimates and the posterior of its block's weights (``None`` for
    a delay). Kept in :meth:`.DiagnosisModel.score_cache` (the same variant against the same
    fit of the joint scores the same)."""
    e = effect.calibrate(model.ctx_)
    cache = model.score_cache(output)
    if (e, judge) in cache:
        return cache[(e, judge)]
    gp, theta = model.gps_[output], model.theta_[output]
    base = model.evidence_[output]
    n_head = int(gp.has_kernel)
    if e.is_shift:
        # the same measured samples y_j(rows), the inputs k samples earlier; every
        # hyperparameter re-optimised (as for the base evidence)
        g = model.joint_gp(output, shift=float(e.samples))
        th, ev = g.optimise(theta)
        if e.sample_time is None:
            e = dataclasses.replace(e, sample_time=model.train_.sample_time)
        ests = e.estimates(np.zeros(1), np.zeros((1, 1)), model.ctx_, output)
        out: tuple = (ev - base, ests, None)
    else:
        cols = e.columns(model.joint_context(output), output)
        if cols is None:
            out = (float("nan"), [], None)
        else:
            g = gp.with_block(cols)
            theta0 = np.append(theta, 0.0)
            free = np.zeros(g.n_theta, bool)
            free[n_head] = True  # noise
            free[-1] = True  # the new block's lambda
            th, ev = g.optimise(theta0, free=free)
            mean, cov = g.weights(th)
            sl = g.block_slices()[-1]
            ests = widen_estimates(
                e.estimates(mean[sl], cov[sl, sl], model.ctx_, output),
                model.train_.torque_constants,
                output,
            )
            if judge:
                names = weight_names([*model.block_effects(output), e], g.sizes)
                ests = judge_estimates(e, ests, g, th, len(g.sizes) - 1, names, model.ctx_, output)
            out = (ev - base, ests, (mean[sl], cov[sl, sl]))
    cache[(effect.calibrate(model.ctx_), judge)] = out
    return out


def _judged_estimates(model: DiagnosisModel, cand: Candidate) -> list[ParamEstimate]:
    """``cand``'s estimates on the output joint that gains most, marked where the data cannot
    pin them down (:mod:`.identifiability`)."""
    if cand.effect.is_shift:
        return cand.estimates
    best: tuple[float, list[ParamEstimate]] | None = None
    with single_thread():
        for j in cand.outputs:
            d, est, _ = _score_variant(model, cand.effect, j - 1, judge=True)
            if math.isfinite(d) and (best is None or d > best[0]):
                best = (d, est)
    return cand.estimates if best is None else best[1]


def score_shared_variant(
    model: DiagnosisModel, effect: Effect
) -> tuple[float, list[ParamEstimate], dict[int, FloatArray], Effect]:
    """``(Delta, estimates, contributions, effect)`` of a complete shared (rigid-body)
    variant: one weight vector for all the joints it moves (:func:`~.shared.score_shared`);
    a linearised block is re-expanded about its fit while that gains
    (:meth:`.Effect.relinearised`, :data:`~.effects.RELINEARISE_STEPS`)."""
    joints = effect.outputs(model.n_joints)

    def score(e: Effect) -> tuple[float, Any, list[FloatArray] | None]:
        cols = [e.columns(model.joint_context(j), j) for j in joints]
        if any(c is None for c in cols):
            return float("nan"), None, None
        gps = [model.gps_[j] for j in joints]
        thetas = [model.theta_[j] for j in joints]
        delta, fit = score_shared(gps, thetas, [model.evidence_[j] for j in joints], cols)
        return delta, fit, cols

    delta, fit, cols = score(effect)
    if cols is None:
        return float("nan"), [], {}, effect
    for _ in range(RELINEARISE_STEPS):
        nxt = effect.relinearised(fit.mean)
        if nxt is None:
            break
        d2, fit2, cols2 = score(nxt)
        if not d2 > delta:
            break
        effect, delta, fit, cols = nxt, d2, fit2, cols2
    ests = effect.estimates(fit.mean, fit.cov, model.ctx_, joints[0])
    return delta, ests, {j: c @ fit.mean for j, c in zip(joints, cols, strict=True)}, effect


@single_thread()
def score_effect(
    model: DiagnosisModel, effect: Effect, refine: bool = False, **scan: Any
) -> Candidate:
    """Score one candidate (all its scan variants) against the current model.

    Args:
        refine: refine the best variant's continuous shape values (:func:`refine_shape`).

    Returns:
        the :class:`Candidate` with its best variant.
    """
    model._check_fitted()
    outputs = effect.outputs(model.n_joints)
    variants = effect.variants(max_delay_samples=model.max_delay_samples, **scan)
    variants = [v.calibrate(model.ctx_) for v in variants]
    deltas, ests, posts = [], [], []
    shared_contribs: dict[int, dict[int, FloatArray]] = {}
    for i, v in enumerate(variants):
        if v.shared:  # one weight vector for all its joints
            total, best_est, con, variants[i] = score_shared_variant(model, v)
            deltas.append(total)
            ests.append(best_est)
            posts.append({})
            shared_contribs[i] = con
            continue
        total, best_est, post = 0.0, [], {}
        best_d = -math.inf
        for j in outputs:
            d, est, p = _fit_variant(model, v, j)
            if not math.isfinite(d):
                total = float("nan")
                break
            total += d
            post[j] = p
            if d > best_d:  # estimates from the joint that gains most
                best_est, best_d = est, d
        deltas.append(total)
        ests.append(best_est)
        posts.append(post)
    deltas_arr = np.array(deltas)
    if not np.any(np.isfinite(deltas_arr)):
        return Candidate(effect, float("nan"), float("nan"), len(variants), [], outputs)
    finite = np.where(np.isfinite(deltas_arr), deltas_arr, -np.inf)
    k = int(np.argmax(finite))
    delta = float(logsumexp(finite) - math.log(len(variants)))
    v = variants[k]
    if v.is_shift and getattr(v, "sample_time", None) is None:
        v = dataclasses.replace(v, sample_time=model.train_.sample_time)
    cand = Candidate(
        effect=v,
        delta=delta,
        best_delta=float(finite[k]),
        n_variants=len(variants),
        estimates=ests[k],
        outputs=[j + 1 for j in outputs],
        contributions=shared_contribs[k]
        if k in shared_contribs
        else {
            j: c
            for j, p in posts[k].items()
            if (c := _contribution(model, variants[k], j, p)) is not None
        },
        in_start_span=model.start.spans(v),
        n_weights=_block_width(model, v, outputs),
    )
    return refine_shape(model, cand) if refine else cand


def _block_width(model: DiagnosisModel, effect: Effect, outputs: Sequence[int]) -> int:
    """Columns of ``effect``'s block (its weights; 0 for a delay or without a block)."""
    if effect.is_shift:
        return 0
    cols = effect.columns(model.joint_context(outputs[0]), outputs[0])
    return 0 if cols is None else int(cols.shape[1])


REFINE_XTOL = 0.01
"""Tolerance of the shape refinement on ``log x`` (1% of the value)."""
PHASE_ORDERS = 41
"""Orders on which the cogging phase's profile is evaluated (across the order's interval)."""


def refine_shape(model: DiagnosisModel, cand: Candidate) -> Candidate:
    """Refine ``cand``'s continuous shape values (:attr:`.Effect.shape_grid`) in place:
    maximise ``Delta_v`` over each field in turn (bounded Brent search on ``log x`` within
    :meth:`.Effect.shape_bracket`; a delay at most the model's ``max_delay_samples``), keep
    the result where it beats the scan's best, and give every field its 95%
    likelihood-ratio interval from the profile ``Delta_v(x)``
    (:func:`.profile.likelihood_interval`; with two fields, the other held at its refined
    value), a cogging effect also its phase's (:func:`.profile.phase_interval`). The
    intervals are kept in the effect's :attr:`~.Effect.profile` and reported with its
    estimates. A field of :attr:`.Effect.sharp_shapes` (a dry friction's smoothing width
    ``eps``) then takes the lower end of its interval: the sharpest form the data do not
    reject, as Coulomb's law is a sign. The evidence is nearly flat in ``eps`` below a few
    mrad/s, and its maximum there leaves the last and first sliding rows of each stick phase,
    whose velocity the derivative filter smears into that range, short of the full level
    (on the Panda with 2.1 N m on the elbow: ``eps`` = 0.0015, those rows 3-14 noise stds
    off, the elbow at 1.16x the noise floor; at the interval's lower end, 1e-5, 1.02x).

    Returns:
        ``cand`` (updated: effect, ``best_delta``, estimates, contributions).
    """
    effect = cand.effect
    if not effect.shape_grid or effect.joint is None or not effect.is_complete():
        return cand
    output = effect.joint - 1
    cap = float(model.max_delay_samples) if effect.is_shift else math.inf
    seen: dict[tuple, float] = {}

    def delta(e: Effect) -> float:
        key = tuple(float(getattr(e, n)) for n in e.shape_grid)
        if key not in seen:
            d = _score_variant(model, e, output)[0]
            seen[key] = d if math.isfinite(d) else -math.inf
        return seen[key]

    best = (cand.best_delta, effect, cand.estimates, cand.contributions.get(output))
    with single_thread():
        for name in effect.shape_grid:
            current = best[1]

            def loss(log_x: float, current: Effect = current, name: str = name) -> float:
                d = delta(dataclasses.replace(current, **{name: float(np.exp(log_x))}))
                return -d if math.isfinite(d) else math.inf

            lo, hi = current.shape_bracket(name)
            hi = min(hi, cap)
            if not hi > lo:
                continue
            res = minimize_scalar(
                loss,
                bounds=(math.log(lo), math.log(hi)),
                method="bounded",
                options={"xatol": REFINE_XTOL},
            )
            if math.isfinite(res.fun) and -res.fun > best[0]:
                trial = dataclasses.replace(current, **{name: round(float(np.exp(res.x)), 6)})
                d, est, con = _score_variant(model, trial, output)
                if math.isfinite(d) and d > best[0]:
                    best = (d, trial, est, con)
        effect = best[1]
        profile = []
        for name in effect.shape_grid:
            x_hat = float(getattr(effect, name))
            lo_b, hi_b = effect.shape_bounds[name]
            hi_b = min(hi_b, cap)

            def prof(log_x: float, name: str = name, effect: Effect = effect) -> float:
                return delta(dataclasses.replace(effect, **{name: float(np.exp(log_x))}))

            u_lo, u_hi, limited = likelihood_interval(
                prof, math.log(x_hat), best[0], math.log(lo_b), math.log(max(hi_b, x_hat))
            )
            lo, hi = float(np.exp(u_lo)), float(np.exp(u_hi))
            if name in effect.sharp_shapes and lo < x_hat:  # the sharpest form the data allow
                trial = dataclasses.replace(effect, **{name: round(lo, 8)})
                d, est, con = _score_variant(model, trial, output)
                if math.isfinite(d):
                    effect, best, x_hat = trial, (d, trial, est, con), float(getattr(trial, name))
            profile.append(effect.shape_estimate(name, x_hat, lo, hi, model.ctx_, limited))
            if effect.key == "cogging":
                profile.append(_phase_estimate(model, effect, output, lo, hi))
    effect = dataclasses.replace(effect, profile=tuple(profile))
    cand.best_delta, cand.effect = best[0], effect
    cand.estimates = effect.with_profile(best[2])
    if best[3] is not None:
        cand.contributions = {output: best[3]}
    return cand


def _phase_estimate(
    model: DiagnosisModel, effect: Effect, output: int, lo: float, hi: float
) -> ParamEstimate:
    """The cogging phase at ``q = 0`` with its profile interval over amplitude and order
    (:func:`.profile.phase_interval`), the orders spanning the order's interval
    ``[lo, hi]``."""
    orders = np.unique(np.append(np.linspace(lo, hi, PHASE_ORDERS), float(effect.order)))
    deltas, means, covs = [], [], []
    for n in orders:
        d, _, post = _fit_variant(model, dataclasses.replace(effect, order=float(n)), output)
        if post is None or not math.isfinite(d):
            continue
        deltas.append(d)
        means.append(post[0])
        covs.append(post[1])
    phi, p_lo, p_hi, limited = phase_interval(np.array(deltas), np.array(means), np.array(covs))
    return ParamEstimate.from_interval("phi", phi, p_lo, p_hi, "rad", limited)


def score_candidates(
    model: DiagnosisModel, library: Sequence[Effect] | None = None, progress: bool = False
) -> list[Candidate]:
    """Score every candidate not already in the model, best first."""
    model._check_fitted()
    if library is None:
        library = default_library(model.n_joints, rigid_body=model.start.robot is not None)
    todo = [e for e in library if not any(e.same_slot(m) for m in model.effects)]
    if progress:
        from tqdm import tqdm

        todo = tqdm(todo, desc="scoring candidates", unit="candidate")
    with single_thread():
        out = [score_effect(model, e) for e in todo]
    out = [c for c in out if math.isfinite(c.delta)]
    out.sort(key=lambda c: -c.delta)
    return out


def heldout_rmse(model: DiagnosisModel, heldout: Trajectories) -> FloatArray:
    """``(n,)`` RMSE of the posterior mean on held-out trajectories (set-valued where a joint
    sticks, :meth:`.DiagnosisModel.set_valued`)."""
    mean, _ = model.predict(heldout, with_var=False)
    mean, _ = model.set_valued(heldout, mean)
    return np.sqrt(np.mean((heldout.y - mean) ** 2, axis=0))


def heldout_floor(
    model: DiagnosisModel, heldout: Trajectories, mean: FloatArray | None = None
) -> FloatArray:
    """``(n,)`` noise floor of ``model`` on held-out trajectories: measurement noise plus the
    noise its prediction inherits from estimated ``qd``/``qdd`` (:func:`.analysis.noise_floor`
    with :func:`.analysis.input_noise`), plus, for currents in torque units, the uncertainty
    of ``k_t`` on the joints whose scale the model does not fit itself
    (:func:`.units.without_fitted_scales`), over the rows where a set-valued prediction
    absorbs it counted as 0 (:func:`.analysis.noise_floor`'s ``rest``); ``mean``: the model's
    prediction (before :meth:`.DiagnosisModel.set_valued`), if at hand. Kept
    in the model (``floors_``) for the same held-out object: the loop asks for it again."""
    model._check_fitted()
    key = id(heldout)
    kept = model.floors_.get(key)
    if kept is not None and kept[0] is heldout:  # the same held-out object, this fit
        return kept[1].copy()
    if mean is None:
        mean, _ = model.predict(heldout, with_var=False)
    inputs = input_noise(heldout, lambda tr: model.predict(tr, with_var=False)[0], at=mean)
    mean, rest = model.set_valued(heldout, mean)
    floor = noise_floor(without_fitted_scales(heldout, model.effects), mean, inputs, rest)
    model.floors_[key] = (heldout, floor)
    return floor.copy()


@dataclass
class FloorCheck:
    """Held-out RMSE of one model against its noise floor, with the residual's structure in
    words on every joint above :data:`FLOOR_FACTOR` floors (``structure``, 1-based keys)."""

    model: str
    rmse: FloatArray
    floor: FloatArray
    rows: int
    structure: dict[int, str] = field(default_factory=dict)
    rest_share: FloatArray | None = None
    """``(n,)`` share of the held-out rows on which each joint is at rest
    (:func:`.analysis.at_rest`)."""
    judged: FloatArray | None = None
    """``(n,)`` the RMSE held to the floor: ``rmse`` with a sticking joint's own rows around
    its stops forgiven the filter's smear (:func:`smear_judged`); ``rmse`` where not given.
    Models are compared on ``rmse``."""
    judged_floor: FloatArray | None = None
    """``(n,)`` the floor of a perfect model under the same intervals (:func:`smear_judged`);
    ``floor`` where not given."""

    @property
    def still(self) -> list[int]:
        """Joints (1-based) held still in the held-out rows (:func:`.analysis.held_still`)."""
        if self.rest_share is None:
            return []
        return held_still(self.rest_share)

    @property
    def held(self) -> FloatArray:
        """``(n,)`` the RMSE held to the floor (:attr:`judged`, else :attr:`rmse`)."""
        return self.rmse if self.judged is None else self.judged

    @property
    def held_floor(self) -> FloatArray:
        """``(n,)`` the floor it is held to (:attr:`judged_floor`, else :attr:`floor`)."""
        return self.floor if self.judged_floor is None else self.judged_floor

    @property
    def ratio(self) -> FloatArray:
        """``(n,)`` held-out RMSE / noise floor (``inf`` where the floor is 0 and the RMSE not)."""
        rmse, floor = self.held, self.held_floor
        with np.errstate(divide="ignore", invalid="ignore"):
            r = rmse / floor
        return np.where(rmse == 0, 0.0, np.where(floor > 0, r, np.inf))

    @property
    def failing(self) -> list[int]:
        """Joints (1-based) whose held-out RMSE exceeds :data:`FLOOR_FACTOR` floors."""
        return [j + 1 for j in np.flatnonzero(self.ratio > FLOOR_FACTOR)]

    def failing_text(self, verb: str = "") -> str:
        """``"joint 2{verb} at 1.43x the noise floor (held-out RMSE 0.0712, floor 0.0498;
        residual: ...)"`` for every failing joint."""
        out = []
        for j in self.failing:
            text = (
                f"joint {j}{verb} at {self.ratio[j - 1]:.2f}x the noise floor (held-out RMSE "
                f"{self.held[j - 1]:.3g}, floor {self.held_floor[j - 1]:.3g}"
            )
            if j in self.structure:
                text += f"; residual: {self.structure[j]}"
            out.append(text + ")")
        return "; ".join(out)

    def to_dict(self) -> dict[str, Any]:
        return {
            "model": self.model,
            "heldout_rmse": self.rmse.tolist(),
            "heldout_rmse_judged": self.held.tolist(),
            "noise_floor": self.floor.tolist(),
            "rmse_over_floor": self.ratio.tolist(),
            "rows": self.rows,
            "unexplained_joints": self.failing,
            "held_still_joints": self.still,
            "structure": {str(k): v for k, v in self.structure.items()},
        }


def smear_judged(
    model: DiagnosisModel, heldout: Trajectories, raw: FloatArray, floor: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """``(rmse, floor)`` per joint as a joint is held to the noise floor: with a sticking
    joint's own rows around its stops predicted as intervals of the filter's smear of its
    friction's switch (:meth:`.DiagnosisModel.smear_widths`; ``raw``: the prediction before
    :meth:`.DiagnosisModel.set_valued`), and the floor ``floor`` (:func:`heldout_floor`) of
    a perfect model under the same intervals: the noise they absorb is taken off it too
    (:func:`.analysis.projected_noise_share` of each row's half-width in noise stds)."""
    widths = model.smear_widths(heldout)
    mean, rest = model.set_valued(heldout, raw, widths)
    rmse = np.sqrt(np.mean((heldout.y - mean) ** 2, axis=0))
    free = ~rest
    share = free.mean(axis=0)
    sigma = np.where(share > 0, floor / np.sqrt(np.maximum(share, 1e-12)), 0.0)
    safe = np.where(sigma > 0, sigma, 1.0)
    kept = np.where(free, projected_noise_share(widths / safe), 0.0).sum(axis=0)
    scale = np.sqrt(kept / np.maximum(free.sum(axis=0), 1))
    return rmse, np.where(sigma > 0, floor * scale, floor)


def floor_check(
    model: DiagnosisModel, heldout: Trajectories, name: str | None = None
) -> FloorCheck:
    """Held-out RMSE and noise floor of ``model`` (:class:`FloorCheck`), the residual's
    structure on the joints above the floor (:func:`.analysis.residual_report`)."""
    raw, _ = model.predict(heldout, with_var=False)
    floor = heldout_floor(model, heldout, raw)
    mean, _ = model.set_valued(heldout, raw)
    rmse = np.sqrt(np.mean((heldout.y - mean) ** 2, axis=0))
    judged, judged_floor = smear_judged(model, heldout, raw, floor)
    rest = at_rest(heldout)
    check = FloorCheck(
        name or model.name,
        rmse,
        floor,
        heldout.n_samples,
        rest_share=rest.mean(axis=0),
        judged=judged,
        judged_floor=judged_floor,
    )
    if check.failing:
        rep = residual_report(
            heldout,
            mean,
            floor,
            model.start.joint_types,
            model_name=check.model,
            unit="A" if heldout.output == "i" else None,
        )
        check.structure = {j: rep.joints[j - 1].structure() for j in check.failing}
    return check


def heldout_change_pct(
    before: FloatArray, after: FloatArray, noise_std: FloatArray, outputs: FloatArray
) -> float:
    """Held-out change ``100 (e_after / e_before - 1)`` [%] on the joints ``outputs``
    (0-based), ``e = sqrt(mean_j (RMSE_j / sigma_j)^2)``: each joint's RMSE in units of its
    fitted noise std ``sigma_j``, so that an effect acting on several joints (payload) is
    judged on every one of them and not only on the one with the largest torque units."""
    j = np.asarray(outputs, dtype=int)
    s = np.where(noise_std[j] > 0, noise_std[j], 1.0)
    e_before = math.sqrt(float(np.mean((before[j] / s) ** 2)))
    e_after = math.sqrt(float(np.mean((after[j] / s) ** 2)))
    return 100.0 * (e_after / e_before - 1.0)


def explained_share(
    before: FloatArray,
    after: FloatArray,
    floor: FloatArray,
    outputs: Sequence[int] | FloatArray,
    excess: bool = False,
) -> float:
    """Largest share of a joint's held-out variance that a change of the model explains,
    ``max_j (e_before_j^2 - e_after_j^2) / d_j`` over the joints ``outputs`` (0-based; RMSE
    ``e_j``, floor ``f_j``): of the noise floor's variance, ``d_j = f_j^2``, or of the excess
    over it, ``d_j = e_before_j^2 - f_j^2`` (``excess``); joints with ``d_j <= 0`` skipped
    (``0.0`` when none is left)."""
    j = np.asarray(outputs, dtype=int)
    d = np.square(floor[j])
    if excess:
        d = np.square(before[j]) - d
    ok = d > 0
    if not ok.any():
        return 0.0
    gain = (np.square(before[j]) - np.square(after[j]))[ok] / d[ok]
    return float(np.max(gain))


CONSTANT_COLLINEARITY = 0.99
"""``|corr|`` of an inertial candidate's torque with a joint's model torque above which the
two cannot be told apart on that joint (a torque-constant error is a scaled model torque)."""


def _confounded_with_constants(model: DiagnosisModel, cand: Candidate) -> str | None:
    """Why ``cand`` cannot be told apart from an estimated torque constant, or ``None``.

    A change of a body's inertia scales the rigid-body torque of the joints that move it, as
    an error of their torque constants ``k_t`` does (``k_hat i = k/k_hat tau``). Where the
    model holds a free scale of the joint's torque (:class:`~.effects.TorqueScale`), the
    candidate was scored and is fitted jointly with that scale (``k_t`` estimated with the
    effect, so an effect that loads the joint does not bias its constant): it is told apart
    from it unless its torque there is a scaled copy of the model torque (``|corr| >``
    :data:`CONSTANT_COLLINEARITY`). An inertial candidate is reported as not identifiable
    (give the constants to score it) when on none of its joints it can be told apart: each
    has an estimated constant held fixed, or a torque collinear with the model's."""
    tc = getattr(model.train_, "torque_constants", None)
    if tc is None or cand.effect.family != "body inertia":
        return None
    estimated = [j for j in cand.outputs if not bool(tc.given[j - 1])]
    if not estimated or len(estimated) < len(cand.outputs):
        return None  # a joint with a given constant tells the effect apart
    scaled = {e.joint for e in model.effects if e.key == "scale"}
    for j in estimated:
        con = cand.contributions.get(j - 1)
        if j not in scaled or con is None:
            continue
        tau = model.joint_context(j - 1).start_torque()[:, j - 1]
        if np.std(con) > 0 and np.std(tau) > 0 and con.shape == tau.shape:
            if abs(float(np.corrcoef(con, tau)[0, 1])) <= CONSTANT_COLLINEARITY:
                return None
    joints = ", ".join(str(j) for j in estimated)
    return f"confounded with the estimated torque constant of joint {joints}"


def _group(cands: Sequence[Candidate], threshold: float) -> None:
    """Single-linkage groups by correlation of the fitted contributions on a shared joint."""
    parent = list(range(len(cands)))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for a in range(len(cands)):
        for b in range(a + 1, len(cands)):
            shared = set(cands[a].contributions) & set(cands[b].contributions)
            for j in shared:
                x, y = cands[a].contributions[j], cands[b].contributions[j]
                if np.std(x) > 0 and np.std(y) > 0 and abs(np.corrcoef(x, y)[0, 1]) > threshold:
                    parent[find(b)] = find(a)
    roots: dict[int, int] = {}
    for i, c in enumerate(cands):
        c.group = roots.setdefault(find(i), len(roots) + 1)


@dataclass
class Diagnosis:
    """Result of :func:`diagnose`: the ranked candidates and the verdict."""

    model_name: str
    candidates: list[Candidate]
    threshold: float
    min_heldout_gain: float
    indistinct_nats: float
    min_explained: float = MIN_EXPLAINED
    base: FloorCheck | None = None
    after: FloorCheck | None = None
    noise_std: FloatArray | None = field(default=None, repr=False)
    """``(n,)`` the diagnosed model's fitted noise std per joint (units of held-out changes)."""
    learned_start: bool = False
    """Whether the model's start is a learned GP (its own error cannot be told apart from a
    missing effect, module docstring)."""
    misfits: list[Misfit] = field(default_factory=list)
    """Effects of the model whose level varies with position (:func:`shape_check`)."""
    train_rest_share: FloatArray | None = field(default=None, repr=False)
    """``(n,)`` share of the training rows on which each joint is at rest."""

    def still_joints(self, check: FloorCheck | None = None) -> list[int]:
        """Joints (1-based) held still in the training logs or in ``check``'s held-out rows
        (module docstring)."""
        train = [] if self.train_rest_share is None else held_still(self.train_rest_share)
        return sorted(set(train) | set([] if check is None else check.still))

    def _still_text(self, joints: Sequence[int], check: FloorCheck | None) -> str:
        """What a joint held still means for the verdict, and what to record."""
        parts = []
        for j in joints:
            shares = []
            if self.train_rest_share is not None:
                shares.append(f"{100 * self.train_rest_share[j - 1]:.0f}% of the training rows")
            if check is not None and check.rest_share is not None:
                shares.append(f"{100 * check.rest_share[j - 1]:.0f}% of the held-out rows")
            parts.append(f"joint {j} did not move (at rest on {' and '.join(shares)})")
        names = ", ".join(str(j) for j in joints)
        return (
            "; ".join(parts)
            + ": a torque that holds a joint at rest (dry friction, a brake, a preloaded "
            "spring) cannot be identified there and torques that act in motion do not show; "
            f"record logs in which joint {names} moves (a larger reference on it, or a "
            "controller whose torque overcomes its friction)"
        )

    @property
    def significant(self) -> list[Candidate]:
        return [c for c in self.candidates if c.significant]

    @property
    def best(self) -> Candidate | None:
        """The missing effect: the first significant candidate outside the start's span,
        unless another one of its group lowers the held-out RMSE by more than
        ``min_heldout_gain`` percentage points more (module docstring: within a group, the
        held-out data decide); then the one that lowers it most."""
        missing = [c for c in self.candidates if c.missing]
        if not missing:
            return None
        first = missing[0]
        if first.heldout_rmse is None or self.base is None or self.noise_std is None:
            return first
        best, gain = first, 0.0
        for c in missing[1:]:
            if c.group != first.group or c.heldout_rmse is None:
                continue
            mine, theirs = self._heldout_pair(first, c)
            if mine - theirs > max(self.min_heldout_gain, gain):
                best, gain = c, mine - theirs
        return self._simplest_alike(best, missing)

    def _heldout_pair(self, a: Candidate, b: Candidate) -> tuple[float, float]:
        """Held-out changes [%] of ``a`` and ``b``, both judged on the joints either acts on
        (a payload moves every joint)."""
        outs = np.array(sorted(set(a.outputs) | set(b.outputs))) - 1
        return (
            heldout_change_pct(self.base.rmse, a.heldout_rmse, self.noise_std, outs),
            heldout_change_pct(self.base.rmse, b.heldout_rmse, self.noise_std, outs),
        )

    def _indistinct(self, a: Candidate, b: Candidate) -> bool:
        """Whether the data cannot tell ``a`` and ``b`` apart: one group (correlated
        torques), evidences within ``indistinct_nats``, held-out changes within
        ``min_heldout_gain`` percentage points."""
        if a.group != b.group or a.heldout_rmse is None or b.heldout_rmse is None:
            return False
        if abs(a.delta - b.delta) >= self.indistinct_nats:
            return False
        mine, theirs = self._heldout_pair(a, b)
        return abs(mine - theirs) <= self.min_heldout_gain

    def _simplest_alike(self, best: Candidate, missing: Sequence[Candidate]) -> Candidate:
        """Of ``best`` and the missing candidates the data cannot tell apart from it
        (:meth:`_indistinct`), the one with the fewest parameters (:attr:`Candidate.
        complexity`; ties: ``best``): one effect per physical cause, and where the data do
        not choose, the simpler description (an armature before a link's inertia, a damping
        before a dead-zone). Two forms of one family (Coulomb and Stribeck friction, a
        payload and the last link's inertia) are left to the alternatives' rule (module
        docstring): the block with fewer weights is not the simpler body (a payload's point
        mass has five, the last link's identifiable part may have four)."""
        alike = [
            c
            for c in missing
            if c is not best and not c.effect.same_family(best.effect) and self._indistinct(best, c)
        ]
        simpler = [c for c in alike if c.complexity < best.complexity]
        return min(simpler, key=lambda c: (c.complexity, -c.delta)) if simpler else best

    @property
    def refinement(self) -> Candidate | None:
        """The first significant candidate inside the start model's span (not missing) that
        acts on a joint above the noise floor (on a model at the floor on its joints there is
        nothing left for it to refine)."""
        failing = set(self.base.failing) if self.base is not None else None
        inside = [
            c
            for c in self.significant
            if c.in_start_span and (failing is None or failing & set(c.outputs))
        ]
        return inside[0] if inside else None

    @property
    def lead(self) -> Candidate | None:
        """What to add next: the missing effect, else the refinement (None: nothing)."""
        return self.best if self.best is not None else self.refinement

    def verdict(self) -> str:
        """The verdict in words (module docstring): the missing effect, "no significant
        missing effect" only at the noise floor, else "unexplained" or "not enough data".
        A hand-made :class:`Diagnosis` without floor checks speaks of the candidates only."""
        if self.base is not None and self.base.rows < MIN_VERDICT_ROWS:
            text = (
                f"{self.model_name}: not enough data: {self.base.rows} held-out rows, a verdict "
                f"needs at least {MIN_VERDICT_ROWS} to tell a model error from noise"
            )
            lead = self.lead
            if lead is not None:
                text += (
                    f"; the leading candidate, {lead.effect.variant_label} (+{lead.delta:.1f} "
                    "nats), is not confirmed"
                )
            return text
        best = self.best
        if best is None:
            ref = self.refinement
            check = self.after if ref is not None and self.after is not None else self.base
            rule = (
                f"no candidate outside the start model's span gains more than "
                f"{self.threshold:g} nats of evidence with a physical sign and a held-out "
                f"improvement above {self.min_heldout_gain:g}% that explains more than "
                f"{100 * self.min_explained:g}% of a joint's noise-floor variance"
            )
            failing = [] if check is None else check.failing
            held = set(self.still_joints(check))
            still = [j for j in failing if j in held]
            if self.misfits:
                text = f"{self.model_name}: unexplained: " + "; ".join(
                    m.text() for m in self.misfits
                )
                if failing:
                    text += f"; {check.failing_text()}"
                if still:
                    text += f"; {self._still_text(still, check)}"
                return text + f"; {rule}"
            if failing and len(still) == len(failing):
                return (
                    f"{self.model_name}: not enough data: {self._still_text(still, check)}; "
                    f"{check.failing_text()}"
                )
            if failing:
                text = f"{self.model_name}: unexplained: {check.failing_text()}; {rule}"
                if ref is not None:
                    text += f", and the refinement {ref.effect.variant_label} leaves it there"
                if still:
                    text += f"; {self._still_text(still, check)}"
                return text + self._learned_text(check)
            text = f"{self.model_name}: no significant missing effect ({rule})"
            if ref is not None:
                text += (
                    f"; {ref.effect.variant_label} is in the start model's span, so it is not "
                    f"missing, but its own block refines the learned model (+{ref.delta:.1f} "
                    f"nats, held-out RMSE {ref.heldout_delta_pct:+.1f}%)"
                )
            if check is not None:
                text += self._at_floor_text(check)
            still = self.still_joints(check)
            if still:
                names = ", ".join(str(j) for j in still)
                text += (
                    f"; it cannot speak for joint {names}: held still in these logs, an effect "
                    "there that acts in motion would not show"
                )
            return text
        alike = [
            c
            for c in self.candidates
            if c is not best
            and c.group == best.group
            and best.delta - c.delta < self.indistinct_nats
            and not c.wrong_sign
        ]
        forms = [
            c
            for c in self.candidates
            if c is not best
            and c not in alike
            and c.effect.same_family(best.effect)
            and c.delta > self.threshold
            and not c.wrong_sign
        ]
        if best.alternative_to is not None:
            text = (
                f"{self.model_name}: {best.alternative_to} is better described as "
                f"{best.effect.title} {best.effect.place} ({best.effect.variant_label} "
                f"in its place: +{best.replace_delta or math.nan:.1f} nats, held-out RMSE "
                f"{best.heldout_delta_pct:+.1f}%; {best.estimate_text()})"
            )
        else:
            text = (
                f"{self.model_name}: missing effect: {best.effect.title} {best.effect.place} "
                f"({best.effect.variant_label}, +{best.delta:.1f} nats, "
                f"held-out RMSE {best.heldout_delta_pct:+.1f}%; {best.estimate_text()})"
            )
        if alike:
            names = ", ".join(c.effect.variant_label for c in alike)
            text += f"; the data cannot tell it apart from {names}"
            if any(c.complexity > best.complexity for c in alike):
                text += f" (the simpler one, with {best.complexity} parameters, is kept)"
        if forms:
            names = ", ".join(f"{c.effect.variant_label} (+{c.delta:.1f} nats)" for c in forms)
            text += (
                f"; alternative form of the same {best.effect.family or best.effect.key}: {names}"
            )
        if self.base is not None and not self.base.failing:
            text += (
                f"; the model was already at the noise floor on every joint (at most "
                f"{float(np.max(self.base.ratio)):.2f}x), so the effect is small against the noise"
            )
        if self.after is not None:
            if self.after.failing:
                text += "; it explains part of the residual: with it, " + self.after.failing_text(
                    " remains unexplained"
                )
                held = set(self.still_joints(self.after))
                still = [j for j in self.after.failing if j in held]
                if still:
                    text += f"; {self._still_text(still, self.after)}"
            else:
                text += self._at_floor_text(self.after, " with it")
        if self.after is not None:
            text += self._learned_text(self.after)
        return text

    def _learned_text(self, check: FloorCheck) -> str:
        """With a learned start, what a joint left above the floor means (module
        docstring), or ``""``."""
        if not self.learned_start or not check.failing:
            return ""
        at = ", ".join(
            f"{check.ratio[j - 1]:.2f}x the noise floor on joint {j}" for j in check.failing
        )
        return (
            f"; the start model is learned from these logs and this model is at {at}: a "
            "learned start cannot tell its own error from a missing effect, so effects found "
            "against it there are not reliable (a nominal robot file as the start can tell "
            "them apart)"
        )

    def alternatives(self, cand: Candidate) -> list[Candidate]:
        """Candidates the data cannot tell apart from ``cand``: in its group, sharing a joint,
        within ``indistinct_nats`` of its evidence, with a physical sign; and every candidate
        of its physical family on its joint (:meth:`.Effect.same_family`). Adding ``cand``
        makes them its alternatives (module docstring)."""
        out = []
        for c in self.candidates:
            if c is cand or c.wrong_sign:
                continue
            indistinct = (
                c.group == cand.group
                and bool(set(c.outputs) & set(cand.outputs))
                and abs(cand.delta - c.delta) < self.indistinct_nats
            )
            if indistinct or c.effect.same_family(cand.effect):
                out.append(c)
        return out

    @staticmethod
    def _at_floor_text(check: FloorCheck, where: str = "") -> str:
        return (
            f";{where} the held-out RMSE is at the noise floor on every joint (at most "
            f"{float(np.max(check.ratio)):.2f}x, limit {FLOOR_FACTOR:g}x)"
        )

    def status(self, c: Candidate) -> str:
        """The table's verdict on candidate ``c`` in a word or two (``"SIGNIFICANT"``,
        ``"weak"``, ``"alternative to coulomb:2"``, ...)."""
        if c.missing and c.alternative_to is not None:
            return f"REPLACES {c.alternative_to}"
        if c.missing:
            return "SIGNIFICANT"
        if c.significant:
            return "in start span"
        if c.wrong_sign:
            return "wrong sign"
        if c.confounded is not None:
            return "not identifiable"
        if c.unreliable is not None:
            return "not reliable (learned start)"
        if c.unmoved is not None:
            return "joint held still"
        if c.alternative_to is not None:
            return f"alternative to {c.alternative_to}"
        if c.delta <= self.threshold:
            return "weak"
        if c.heldout_delta_pct is None:
            return "untested"
        if c.heldout_delta_pct >= -self.min_heldout_gain:
            return "no held-out gain"
        if c.explained is not None and c.explained <= self.min_explained:
            return "negligible"
        return "no held-out gain"

    def table(self, top: int = 12) -> str:
        """The ranked table as fixed-width text."""
        head = (
            f"{'#':>2}  {'effect':<34} {'joint':>5} {'Δlog-ev':>9} {'held-out ΔRMSE':>15} "
            f"{'grp':>3}  {'estimate ± 95% CI':<40} verdict"
        )
        lines = [head, "-" * len(head)]
        for i, c in enumerate(self.candidates[:top], 1):
            held = "" if c.heldout_delta_pct is None else f"{c.heldout_delta_pct:+.1f} %"
            verdict = self.status(c)
            lines.append(
                f"{i:>2}  {c.effect.variant_label:<34} {c.joint_text:>5} {c.delta:>9.1f} "
                f"{held:>15} {c.group:>3}  {c.estimate_text():<40} {verdict}"
            )
        lines.append("")
        lines.append(self.verdict())
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        return {
            "model": self.model_name,
            "threshold_nats": self.threshold,
            "verdict": self.verdict(),
            "heldout": None if self.base is None else self.base.to_dict(),
            "heldout_with_lead": None if self.after is None else self.after.to_dict(),
            "learned_start": self.learned_start,
            "misfits": [m.to_dict() for m in self.misfits],
            "candidates": [
                {
                    "effect": c.effect.variant_label,
                    "key": c.effect.key,
                    "joint": c.effect.joint,
                    "delta_log_evidence": c.delta,
                    "heldout_delta_rmse_pct": c.heldout_delta_pct,
                    "group": c.group,
                    "significant": c.significant,
                    "in_start_span": c.in_start_span,
                    "alternative_to": c.alternative_to,
                    "replace_delta_log_evidence": c.replace_delta,
                    "wrong_sign": c.wrong_sign,
                    "confounded": c.confounded,
                    "unreliable": c.unreliable,
                    "unmoved": c.unmoved,
                    "explained_floor_variance": c.explained,
                    "estimates": [p.__dict__ for p in c.estimates],
                }
                for c in self.candidates
            ],
        }


@single_thread()
def diagnose(
    model: DiagnosisModel,
    heldout: Any,
    *,
    library: Sequence[Effect] | None = None,
    n_confirm: int = 3,
    threshold: float = EVIDENCE_THRESHOLD,
    min_heldout_gain: float = MIN_HELDOUT_GAIN,
    min_explained: float = MIN_EXPLAINED,
    group_correlation: float = GROUP_CORRELATION,
    indistinct_nats: float = INDISTINCT_NATS,
    alternatives: Mapping[str, str] | None = None,
    progress: bool = False,
) -> Diagnosis:
    """Score all candidates, refine and confirm the top ``n_confirm`` on held-out
    trajectories, group.

    Args:
        model: a fitted :class:`DiagnosisModel`.
        heldout: held-out trajectories (files never used in the fit); every held-out figure
            is taken on their interior rows (:meth:`~.data.Trajectories.interior`: without the
            rows whose ``qd``/``qdd`` come from the derivative filter's edge fit).
        library: candidates (default: :func:`default_library`).
        min_explained: least share of a joint's noise-floor variance a significant
            candidate explains on ``heldout`` (module docstring).
        alternatives: candidate label -> label of the effect in ``model`` it is an
            alternative to (kept by :func:`next_version`); effects of the same family are
            alternatives without it. An alternative is confirmed as a replacement (module
            docstring).

    Returns:
        a :class:`Diagnosis` (``.table()``, ``.verdict()``, ``.best``).
    """
    held = as_trajectories(heldout, model.n_joints).interior()
    require_rows(held, MIN_HELDOUT_ROWS, "confirming effects on held-out data")
    cands = score_candidates(model, library, progress=progress)
    in_model = {e.label: e for e in model.effects}
    for c in cands:
        family = [e.label for e in model.effects if e.same_family(c.effect)]
        other = (alternatives or {}).get(c.label)
        if family:
            c.alternative_to = family[0]
        elif other in in_model:
            c.alternative_to = other
    base = floor_check(model, held)
    train_rest = model.rest_.mean(axis=0)
    still_train = set(held_still(train_rest))
    learned = model.start.has_kernel
    noise = model.noise_std_
    confirmed = 0
    tried: dict[int, DiagnosisModel] = {}
    for c in cands:
        if confirmed >= n_confirm or c.delta <= threshold:
            break
        if c.wrong_sign:
            continue
        if set(c.outputs) <= still_train:
            joints = ", ".join(str(j) for j in c.outputs)
            c.unmoved = (
                f"joint {joints} at rest on "
                + ", ".join(f"{100 * train_rest[j - 1]:.0f}%" for j in c.outputs)
                + " of the training rows"
            )
            continue
        refine_shape(model, c)
        if c.wrong_sign:
            continue
        c.estimates = _judged_estimates(model, c)
        c.confounded = _confounded_with_constants(model, c)
        if c.confounded is not None:
            continue
        if c.alternative_to is None:
            new = model.with_effect(c.effect)
        else:
            new = model.replacing(c.alternative_to, c.effect)
            outs = [j - 1 for j in c.outputs]
            c.replace_delta = float(sum(new.evidence_[j] - model.evidence_[j] for j in outs))
            c.estimates = new.estimates(c.effect, outs[0]) or c.estimates
        tried[id(c)] = new
        rmse = heldout_rmse(new, held)
        outs = np.array(c.outputs) - 1
        c.heldout_delta_pct = heldout_change_pct(base.rmse, rmse, noise, outs)
        c.heldout_rmse = rmse
        c.explained = explained_share(base.rmse, rmse, base.floor, outs)
        failing = [j for j in outs if j + 1 in base.failing]
        if learned and failing:
            share = explained_share(base.rmse, rmse, base.floor, failing, excess=True)
            if share < MIN_EXCESS_SHARE:
                joints = ", ".join(str(j + 1) for j in failing)
                c.unreliable = (
                    f"explains {100 * max(share, 0.0):.0f}% of the learned start's miss on "
                    f"joint {joints}"
                )
        c.significant = (
            c.heldout_delta_pct < -min_heldout_gain
            and c.explained > min_explained
            and c.unreliable is None
            and (c.replace_delta is None or c.replace_delta > threshold)
        )
        confirmed += 1
    _group(cands[:12], group_correlation)
    cands.sort(key=lambda c: (not c.significant, -c.delta))
    d = Diagnosis(model.name, cands, threshold, min_heldout_gain, indistinct_nats, min_explained)
    d.base = base
    d.noise_std = noise
    d.learned_start = learned
    d.train_rest_share = train_rest
    lead = d.lead
    if lead is not None:
        d.after = floor_check(
            tried[id(lead)], held, name=f"{model.name} + {lead.effect.variant_label}"
        )
    return d


@dataclass(frozen=True)
class Removal:
    """An effect taken out by :func:`backward_step` (module docstring).

    Attributes:
        label: the removed effect's label (``link 2 inertia``, ``armature:3``).
        variant: its variant label (with its shape values).
        by: the later effect that took its evidence.
        version: the name of the version without it.
        evidence: log-evidence it still adds on its joints given the rest [nats].
        heldout_delta_pct: held-out RMSE change it makes on its joints given the rest [%].
        explained: largest share of a joint's floor variance it explains given the rest.
    """

    label: str
    variant: str
    by: str
    version: str
    evidence: float
    heldout_delta_pct: float
    explained: float

    def text(self) -> str:
        return (
            f"{self.version}: removed {self.variant}: with {self.by} in the model it adds "
            f"{self.evidence:+.1f} nats and changes the held-out RMSE of its joints by "
            f"{self.heldout_delta_pct:+.1f}% (explains {100 * max(self.explained, 0.0):.0f}% "
            "of a joint's floor variance): the model without it is as good, its evidence was "
            f"taken by {self.by}"
        )

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def backward_step(
    model: DiagnosisModel,
    heldout: Any,
    newest: Effect,
    *,
    threshold: float = EVIDENCE_THRESHOLD,
    min_heldout_gain: float = MIN_HELDOUT_GAIN,
    min_explained: float = MIN_EXPLAINED,
) -> tuple[DiagnosisModel, Removal] | None:
    """One step of backward elimination after ``newest`` was added to ``model`` (module
    docstring): the version without the earlier effect (sharing a joint with ``newest``)
    that no longer earns its place and loses the least evidence, with the record of its
    removal; ``None`` when every earlier effect still earns its place. Blocks the loop puts
    in itself (a free torque scale) are never removed."""
    from mcpilco.models.diagnosis.effects import MODEL_ONLY_EFFECTS

    held = as_trajectories(heldout, model.n_joints).interior()
    n = model.n_joints
    reach = set(newest.outputs(n))
    full = heldout_rmse(model, held)
    found: tuple[DiagnosisModel, Removal] | None = None
    for e in model.effects:
        if e.same_slot(newest) or e.key in MODEL_ONLY_EFFECTS:
            continue
        outs = e.outputs(n)
        if not reach & set(outs):
            continue
        minus = model.without(e.label)
        evidence = float(sum(model.evidence_[j] - minus.evidence_[j] for j in outs))
        rmse = heldout_rmse(minus, held)
        pct = heldout_change_pct(rmse, full, minus.noise_std_, np.array(outs))
        explained = explained_share(rmse, full, heldout_floor(minus, held), outs)
        if evidence > threshold and pct < -min_heldout_gain and explained > min_explained:
            continue  # it still earns its place
        removal = Removal(
            e.label, e.variant_label, newest.variant_label, minus.name, evidence, pct, explained
        )
        if found is None or evidence < found[1].evidence:
            found = (minus, removal)
    return found


@dataclass(frozen=True)
class Misfit:
    """An effect of the model whose level varies with its joint's position
    (:func:`shape_check`): the torque has its shape but not its form.

    Attributes:
        label, variant: the effect's label and variant label.
        joint: its joint (1-based).
        evidence: log-evidence the position-dependent level adds on the joint [nats].
        heldout_delta_pct: held-out RMSE change it makes there [%].
        explained: share of the joint's floor variance it explains on held-out data.
    """

    label: str
    variant: str
    joint: int
    evidence: float
    heldout_delta_pct: float
    explained: float

    def text(self) -> str:
        return (
            f"{self.variant} explains part of the torque on joint {self.joint}, but its level "
            f"varies with q{self.joint} (a position-dependent level adds {self.evidence:+.1f} "
            f"nats, changes the held-out RMSE by {self.heldout_delta_pct:+.1f}% and explains "
            f"{100 * self.explained:.0f}% of the joint's floor variance): the torque there is "
            "not of a form in the library"
        )

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def shape_check(
    model: DiagnosisModel,
    heldout: Any,
    *,
    threshold: float = EVIDENCE_THRESHOLD,
    min_heldout_gain: float = MIN_HELDOUT_GAIN,
    min_explained: float = MIN_EXPLAINED,
) -> list[Misfit]:
    """Whether each joint effect of ``model`` has the form it is named for: its level made a
    smooth function of its joint's position (:class:`~.effects.PositionLevel`, added beside
    it, refitted) must fail one of the three tests of significance (module docstring: more
    than ``threshold`` nats on the joint, a held-out RMSE lower by more than
    ``min_heldout_gain`` percent, more than ``min_explained`` of the floor variance
    explained). A library effect has a constant level; an effect outside the library that
    the nearest library form was fitted to (friction that varies along the joint's travel)
    passes them, and the named effect then only explains part of the torque: the verdict
    says "unexplained" rather than force it into the library. Rigid-body effects, delays
    and the loop's own blocks are not checked (their form is the robot's kinematics)."""
    from mcpilco.models.diagnosis.effects import MODEL_ONLY_EFFECTS, PositionLevel

    held = as_trajectories(heldout, model.n_joints).interior()
    if not model.effects:
        return []
    base = heldout_rmse(model, held)
    floor = heldout_floor(model, held)
    out: list[Misfit] = []
    for e in model.effects:
        if e.shared or e.all_joints or e.is_shift or e.key in MODEL_ONLY_EFFECTS:
            continue
        try:
            new = model.with_effect(PositionLevel(e.joint, of=e))
        except ValueError:
            continue
        j = e.joint - 1
        evidence = float(new.evidence_[j] - model.evidence_[j])
        rmse = heldout_rmse(new, held)
        pct = heldout_change_pct(base, rmse, model.noise_std_, np.array([j]))
        explained = explained_share(base, rmse, floor, [j])
        if evidence > threshold and pct < -min_heldout_gain and explained > min_explained:
            out.append(Misfit(e.label, e.variant_label, e.joint, evidence, pct, explained))
    return out


def auto_improve(
    model: DiagnosisModel, heldout: Any, max_steps: int = 4, **kwargs: Any
) -> tuple[list[DiagnosisModel], list[Diagnosis | None]]:
    """Add the missing effect (else the in-span refinement, :attr:`Diagnosis.lead`), refit,
    remove the earlier effects whose evidence it took (:func:`backward_step`), re-diagnose,
    until none is left.

    Returns:
        ``(versions, diagnoses)``: ``versions[0] = model``, then every version (additions and
        removals); ``diagnoses[k]`` of ``versions[k]``, ``None`` for a version that a removal
        replaced before it was diagnosed (the last one says what remains).
    """
    versions: list[DiagnosisModel] = [model]
    diags: list[Diagnosis | None] = []
    alternatives: dict[str, str] = {}
    held = as_trajectories(heldout, model.n_joints).interior()  # one object: floors are kept
    tests = {
        k: kwargs[k] for k in ("threshold", "min_heldout_gain", "min_explained") if k in kwargs
    }
    added = 0
    while True:
        d = diagnose(versions[-1], held, alternatives=alternatives, **kwargs)
        diags.append(d)
        if d.lead is None or added >= max_steps:
            if d.lead is None:
                d.misfits = shape_check(versions[-1], held, **tests)
            break
        steps = stepwise(versions[-1], d, held, alternatives, **tests)
        added += 1
        for new, _ in steps:
            versions.append(new)
            diags.append(None)
        diags.pop()  # the last new version is diagnosed next
    return versions, diags


def stepwise(
    model: DiagnosisModel,
    diagnosis: Diagnosis,
    heldout: Any,
    alternatives: dict[str, str],
    *,
    threshold: float = EVIDENCE_THRESHOLD,
    min_heldout_gain: float = MIN_HELDOUT_GAIN,
    min_explained: float = MIN_EXPLAINED,
) -> list[tuple[DiagnosisModel, Removal | None]]:
    """One step of stepwise selection (module docstring): the diagnosis's lead added
    (:func:`next_version`), then every earlier effect it superseded removed
    (:func:`backward_step`), and, for a rigid-body lead (a link's inertia, a payload), the
    rotor inertias of its joints tried in its place (:func:`_rotor_inertias_instead`).

    Returns:
        the new versions in order, each with its :class:`Removal` (``None`` for an addition).
    """
    tests = dict(
        threshold=threshold, min_heldout_gain=min_heldout_gain, min_explained=min_explained
    )
    newest = diagnosis.lead.effect
    out: list[tuple[DiagnosisModel, Removal | None]] = [
        (next_version(model, diagnosis, alternatives), None)
    ]
    while (step := backward_step(out[-1][0], heldout, newest, **tests)) is not None:
        out.append(step)
        alternatives[step[1].label] = newest.label  # only ever put back in its place
    out += _rotor_inertias_instead(out[-1][0], diagnosis, heldout, alternatives, **tests)
    return out


def _rotor_inertias_instead(
    model: DiagnosisModel,
    diagnosis: Diagnosis,
    heldout: Any,
    alternatives: dict[str, str],
    **tests: float,
) -> list[tuple[DiagnosisModel, Removal | None]]:
    """Rotor inertia against link inertia and payload, told apart by the joints each acts on
    (module docstring): with a rigid-body lead just added, the armatures of its joints that
    the same diagnosis found significant in evidence (with a physical sign) are added on top,
    one version each, and backward elimination run after each; the versions are kept only
    if the rigid-body effect is then removed (the armatures took its evidence: one cause per
    joint), else none of them is (``[]``)."""
    lead = diagnosis.lead.effect
    if not lead.shared or not any(e.same_slot(lead) for e in model.effects):
        return []
    reach = set(lead.outputs(model.n_joints))
    rotors = [
        c.effect
        for c in diagnosis.candidates
        if c.effect.key == "armature"
        and c.delta > tests["threshold"]
        and not c.wrong_sign
        and c.effect.joint - 1 in reach
        and not any(c.effect.same_slot(e) for e in model.effects)
    ]
    out: list[tuple[DiagnosisModel, Removal | None]] = []
    alts = dict(alternatives)
    for rotor in rotors:
        out.append(((out[-1][0] if out else model).with_effect(rotor, backfit=True), None))
        while (step := backward_step(out[-1][0], heldout, rotor, **tests)) is not None:
            out.append(step)
            alts[step[1].label] = rotor.label
    if any(r is not None and r.label == lead.label for _, r in out):
        alternatives.update(alts)
        return out
    return []


def next_version(
    model: DiagnosisModel, diagnosis: Diagnosis, alternatives: dict[str, str]
) -> DiagnosisModel:
    """The next version of ``model``: its diagnosis's lead added, or put in place of the
    effect it is an alternative to (refitted, backfitted); ``alternatives`` (candidate label
    -> label of the effect in the model) gains the lead's alternatives
    (:meth:`Diagnosis.alternatives`), so that they are never added beside it."""
    lead = diagnosis.lead
    if lead is None:
        raise ValueError(f"the diagnosis of {model.name} has nothing to add")
    new_label = lead.effect.label
    if lead.alternative_to is not None:
        old = lead.alternative_to
        new = model.replacing(old, lead.effect, backfit=True)
        for k, v in list(alternatives.items()):
            if v == old:
                alternatives[k] = new_label
        alternatives[old] = new_label
    else:
        new = model.with_effect(lead.effect, backfit=True)
    alternatives.pop(new_label, None)
    for c in diagnosis.alternatives(lead):
        if c.label != new_label and not any(c.effect.same_slot(e) for e in new.effects):
            alternatives[c.label] = new_label
    return new

"""A versioned diagnosis model: a start model plus added physical effects, one GP per joint.

Version ``v0`` is the start model (nominal physics or a learned GIP GP);
``model.with_effect(effect)`` returns version ``v(k+1)`` with the effect's block added (a
linear kernel on it, see :mod:`mcpilco.models.gp.linear_gp`) and refits it on the same
training data:

.. code-block:: python

    model = DiagnosisModel(NominalStart("robot.xml")).fit(train)
    model = add_effect(model, CoulombFriction(joint=2))  # v1, refitted
    mean, var = model.predict(test)

Refitting re-optimises, per joint, the start kernel's scale ``alpha``, the noise
``sigma^2`` and every block's prior variance ``lambda_b`` (type-II ML); the GIP kernel's own
hyperparameters stay at their version-0 values (a learned start is backfitted when an effect
is added, :func:`~.add.add_effect`). :func:`~.add.add_effect` scans an effect's shape values
(cogging order, delay, ...) by evidence before adding it; the model itself takes only
complete effects, and never imports the search.

Rigid-body effects (a link's inertia, a payload: :attr:`.Effect.shared`) have one weight
vector ``w`` for all the joints they move, so they are not blocks of one joint's GP: the fit
alternates (:data:`SHARED_ROUNDS` times) the posterior of ``w`` given every joint's GP
(:func:`~.shared.fit_shared`) with each joint's own fit on ``r_j - Y_j E[w]``; predictions
add ``Y_j E[w]`` and the variance ``Y_j Cov[w] Y_j^T``.

Delays: ``y_j(t) = f_j(x(t - d))``. The targets always stay the measured ``y_j`` at the
training rows ``t``; a delay of ``k`` samples on joint ``j`` (any real ``k >= 0``; between two
samples the states are interpolated linearly, :meth:`.Trajectories.at`) moves that joint's
*inputs* to the states ``k`` samples earlier (its effect blocks, its start-kernel Gram matrix
and its prior mean are evaluated at ``x(t - d)``), and its predictions are ``mean_j(t - d)``. So
every delay of the scan is scored on the same measured samples, i.e. on the same noise
realisation: shifting the targets instead would compare different noise samples whenever
the rows are a subset (with a start kernel), whose log-likelihoods differ by
``~ sqrt(N / 2)`` nats by chance alone.

Dry friction at rest is set-valued (:mod:`.effects`): on the rows where a joint with a
Coulomb or Stribeck block is at rest (:func:`.analysis.at_rest`), its torque is any value in
``[-F_s, F_s]``. The fit takes the point of that interval nearest to the residual of the rest
of the model off the joint's target and refits (:data:`STICK_ROUNDS` times); held-out
predictions are projected onto the interval the same way (:meth:`DiagnosisModel.set_valued`).
Where ``qd``/``qdd`` were estimated from ``q``, the rows within the derivative filter's half
window of the start or end of such a joint's stick phase (:func:`.analysis.friction_kinks`)
are set-valued on every *other* joint: dry friction switches there within a physics step, so
the joint's acceleration jumps, a filter whose window spans the jump smears it, and a joint
``j`` that the sticking joint ``k`` couples to inherits ``M_jk`` times the error of the
estimated ``qdd_k`` (no function of the estimated states predicts those rows; as with the
filter's edge rows, those joints are held to the rows whose inputs the data gives). The
sticking joint's own rows stay scored: near zero velocity they are what tells one
friction form from another (a sharp sign from a smoothed one, a level that varies with
position), so models are compared on them as they are. Held to the noise floor, though,
the joint is forgiven there the part of its error that the filter's smear of the switch
explains, which no model of the estimated states predicts: its prediction is an interval of
half-width ``|K * f - f|`` (``f`` the fitted friction torque, 0 at rest, ``K`` the filter's
weights on the acceleration, :func:`.analysis.friction_smear`), at most ``F_s`` next to the
stop of a sharp friction, less for a smoothed one, and 0 half a window away
(:meth:`DiagnosisModel.smear_widths`).

Training rows: every sample except the first and last ``max_delay_samples`` of each file
(so that any scanned delay reads states, and the start model's backfit reads outputs,
inside the same file); with a start kernel, at most ``max_points`` of them, evenly spaced
in time (the exact GP costs ``O(N^3)``). A start that learns from every row
(:attr:`.StartModel.all_rows`: a GIP start with ``inducing``) is fitted, and backfitted, on
all of them; its kernel still enters the joints' GPs on the ``max_points`` rows.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mcpilco.models.diagnosis.analysis import at_rest, friction_kinks, friction_smear
from mcpilco.models.diagnosis.data import (
    MIN_FIT_ROWS,
    as_trajectories,
    require_rows,
)
from mcpilco.models.diagnosis.effects import (
    Delay,
    Effect,
    FeatureContext,
    ParamEstimate,
    effect_from_spec,
)
from mcpilco.models.diagnosis.identifiability import judge_estimates, weight_names
from mcpilco.models.diagnosis.shared import SharedFit
from mcpilco.models.diagnosis.start_models import (
    LEARNED_STARTS,
    LearnedStart,
    NominalStart,
    StartModel,
)
from mcpilco.models.diagnosis.units import widen_estimates
from mcpilco.models.gp.linear_gp import JointGP, single_thread
from mcpilco.models.robot_data import Trajectories

FloatArray = NDArray[np.float64]

__all__ = ["DiagnosisModel"]

SHARED_ROUNDS = 3
"""Alternations of the shared (rigid-body) weights and the joints' own fits in a fit."""
STICK_ROUNDS = 2
"""Refits of a joint with set-valued dry friction after re-estimating its torque at rest."""


class DiagnosisModel:
    """Start model + effects; one :class:`JointGP` per joint.

    Args:
        start: :class:`NominalStart`, :class:`GIPStart` or :class:`RBFStart`.
        effects: effects already in the model (complete variants).
        version: version number (``v0`` = start model).
        max_points: most training rows with a start kernel.
        max_delay_samples: longest delay scanned [samples].

    Fitted attributes: ``train_`` (:class:`Trajectories`, interior rows), ``rows_`` (training
    rows),
    ``ctx_`` (:class:`FeatureContext` of the rows), ``gps_`` / ``theta_`` / ``evidence_`` per
    joint (each joint's GP reads its inputs at ``rows_ - delay``, :meth:`joint_context`),
    ``effects`` calibrated.
    """

    def __init__(
        self,
        start: StartModel,
        effects: Sequence[Effect] = (),
        *,
        version: int = 0,
        max_points: int = 600,
        max_delay_samples: int = 10,
        history: Sequence[str] = (),
    ) -> None:
        if not isinstance(start, StartModel):
            raise TypeError(
                f"start must be a NominalStart, GIPStart or RBFStart, got {type(start).__name__}"
            )
        self.start = start
        self.effects: tuple[Effect, ...] = tuple(effects)
        for e in self.effects:
            e.outputs(start.n_joints)
            if not e.is_complete():
                raise ValueError(
                    f"{e.label} has unscanned shape values; add it with add_effect(model, ...) "
                    "so that the scan picks them"
                )
        self.version = int(version)
        self.max_points = int(max_points)
        self.max_delay_samples = int(max_delay_samples)
        self.history = tuple(history)
        self.train_: Trajectories | None = None

    # ------------------------------------------------------------------ identity
    @property
    def n_joints(self) -> int:
        return self.start.n_joints

    @property
    def name(self) -> str:
        return f"v{self.version}"

    def describe(self) -> str:
        added = ", ".join(e.variant_label for e in self.effects) or "no effects"
        return f"{self.name}: {self.start.describe()} + {added}"

    # ------------------------------------------------------------------ fitting
    def _training_rows(self, traj: Trajectories, subset: bool = True) -> NDArray[np.int64]:
        """Every sample but ``max_delay_samples`` at each end of each file; with a start
        kernel and ``subset``, at most ``max_points`` of them evenly spaced in time."""
        rows = []
        k = self.max_delay_samples
        for a, b in traj.segments:
            if b - a > 2 * k:
                rows.append(np.arange(a + k, b - k))
            else:  # a file too short to spare both ends: keep its middle sample
                rows.append(np.array([(a + b) // 2]))
        rows = np.concatenate(rows)
        if subset and self.start.has_kernel and rows.size > self.max_points:
            pick = np.unique(np.round(np.linspace(0, rows.size - 1, self.max_points)).astype(int))
            rows = rows[pick]
        return rows

    def context(self, traj: Trajectories, rows: NDArray[np.int64] | None = None) -> FeatureContext:
        """Feature context of ``traj`` (all rows, or ``rows``)."""
        sel = slice(None) if rows is None else rows
        return self._context_at(
            (traj.q[sel], traj.qd[sel], traj.qdd[sel]), traj.output, rest=at_rest(traj)[sel]
        )

    def _context_at(
        self,
        states: tuple[FloatArray, ...],
        output: str,
        base: FloatArray | None = None,
        regressor: Callable[[], FloatArray | None] | None = None,
        rest: NDArray[np.bool_] | None = None,
    ) -> FeatureContext:
        """Feature context at ``states = (q, qd, qdd)``; ``base``: the start model's torque
        there, ``regressor``: the joint-torque regressor of every body, if at hand,
        ``rest``: where each joint is at rest (:func:`.analysis.at_rest`)."""
        q, qd, qdd = states
        if regressor is None and self.start.robot is not None:

            def regressor() -> FloatArray | None:
                return self.start.robot.regressor(q, qd, qdd)

        return FeatureContext(
            q=q,
            qd=qd,
            qdd=qdd,
            base=base,
            joint_types=self.start.joint_types,
            output=output,
            regressor=regressor,
            rigid=None if self.start.robot is None else self._rigid_body(),
            base_fn=lambda: self.start.torque(q, qd, qdd),
            at_rest=rest,
        )

    def _rigid_body(self) -> Any:
        if getattr(self, "_rigid", None) is None:
            self._rigid = self.start.robot.rigid_body()
        return self._rigid

    def _delay_samples(self, output: int) -> float:
        for e in self.effects:
            if isinstance(e, Delay) and e.joint - 1 == output:
                return float(e.samples)
        return 0.0

    def _shifted(self, shift: float) -> tuple[FeatureContext, FloatArray, tuple[FloatArray, ...]]:
        """``(context, prior mean (N, n), (q, qd, qdd))`` at the inputs ``x(rows - shift)``
        (``shift`` in samples, interpolated between samples; cached until the next
        :meth:`fit`)."""
        shift = float(shift)
        if shift not in self._shift_cache:
            traj = self.train_
            if shift.is_integer():
                # whole samples: the start model's values on the whole files (kept by the
                # start model for every shift and version), then the rows picked
                idx = traj.shift_index(self.rows_, -int(shift))
                full = (traj.q, traj.qd, traj.qdd)
                states = tuple(x[idx] for x in full)
                prior = self.start.prior_mean(*full)[idx]
                base = prior if self.start.torque_is_prior_mean else None
                regressor = None
                if self.start.robot is not None:

                    def regressor() -> FloatArray | None:
                        return self.start.robot.regressor(*full)[idx]

            else:
                states = tuple(traj.at(x, self.rows_, -shift) for x in (traj.q, traj.qd, traj.qdd))
                prior = self.start.prior_mean(*states)
                base = prior if self.start.torque_is_prior_mean else None
                regressor = None
            self._shift_cache[shift] = (
                self._context_at(
                    states,
                    traj.output,
                    base,
                    regressor,
                    self.rest_[traj.shift_index(self.rows_, -int(round(shift)))],
                ),
                prior,
                states,
            )
        return self._shift_cache[shift]

    def joint_context(self, output: int, shift: float | None = None) -> FeatureContext:
        """Feature context of output ``output``'s inputs, ``x(rows - k)`` (``k``: ``shift``,
        default the joint's delay in samples)."""
        k = self._delay_samples(output) if shift is None else shift
        return self._shifted(k)[0]

    def target(self, output: int, shift: float | None = None) -> FloatArray:
        """Residual target ``r = y_j(rows) - m_j(x(rows - k))`` of output ``output``
        (0-based; ``k``: ``shift``, default the joint's delay in samples)."""
        k = self._delay_samples(output) if shift is None else shift
        mean = self._shifted(k)[1]
        r = self.train_.y[self.rows_, output] - mean[:, output] - self.stick_[:, output]
        return r - self._shared_part(self.joint_context(output, k), output)

    # ------------------------------------------------------------------ shared effects
    @property
    def shared_effects(self) -> list[Effect]:
        """The added effects with one weight vector for several joints (rigid-body ones)."""
        return [e for e in self.effects if e.shared and self._has_columns(e)]

    def _shared_columns(self, ctx: FeatureContext, output: int) -> FloatArray | None:
        """``(N, P)``: the shared effects' columns on ``output`` (zeros where one does not
        act), in :attr:`shared_effects` order; ``None`` without shared effects."""
        parts = []
        for e in self.shared_effects:
            cols = e.columns(ctx, output) if output in e.outputs(self.n_joints) else None
            width = self._shared_sizes()[len(parts)]
            parts.append(np.zeros((ctx.q.shape[0], width)) if cols is None else cols)
        return np.concatenate(parts, axis=1) if parts else None

    def _shared_sizes(self) -> list[int]:
        if getattr(self, "_sizes", None) is None:
            self._sizes = [e.columns(self.ctx_, 0).shape[1] for e in self.shared_effects]
        return self._sizes

    def _shared_part(self, ctx: FeatureContext, output: int) -> FloatArray:
        """Fitted torque of the shared effects on ``output`` at the states of ``ctx``."""
        fit = getattr(self, "shared_", None)
        if fit is None:
            return np.zeros(ctx.q.shape[0])
        return self._shared_columns(ctx, output) @ fit.mean

    def _fit_shared(self) -> None:
        """Posterior of the shared weights given every joint's current GP
        (:func:`~.shared.fit_shared`)."""
        from mcpilco.models.diagnosis.shared import fit_shared

        joints = sorted({j for e in self.shared_effects for j in e.outputs(self.n_joints)})
        old = self.shared_
        self.shared_ = None  # the joints' targets without the shared part
        gps = [self.joint_gp(j, self._delay_samples(j)) for j in joints]
        cols = [self._shared_columns(self.joint_context(j), j) for j in joints]
        self.shared_ = fit_shared(
            gps,
            [self.theta_[j] for j in joints],
            cols,
            self._shared_sizes(),
            None if old is None else old.log_lambda,
        )

    def _start_eig(
        self, states: tuple[FloatArray, ...], joints: Sequence[int] | None = None
    ) -> dict[int, tuple[FloatArray, FloatArray]]:
        """``{j: (U, S)}`` of the start kernel's Gram matrix at ``states`` for the output
        joints ``joints`` (0-based; default all)."""
        K0 = self.start.kernel(states, states)
        out = {}
        for j in range(self.n_joints) if joints is None else joints:
            S, U = np.linalg.eigh(0.5 * (K0[j] + K0[j].T))
            out[j] = (U, S)
        return out

    def joint_gp(self, output: int, shift: float) -> JointGP:
        """Output ``output``'s GP with the current blocks, its inputs at ``x(rows - shift)``
        and the same target samples ``y_j(rows)`` and scale as the fitted one (the delay
        scan: evidences of different ``shift`` compare models of the same data)."""
        self._check_fitted()
        ctx, _, states = self._shifted(shift)
        eig = None
        if self.start.has_kernel:
            if shift == self._delay_samples(output):
                eig = self.eig_[output]
            else:
                eig = self._start_eig(states, [output])[output]
        return JointGP(
            self.target(output, shift),
            self.blocks(ctx, output),
            eig=eig,
            scale=self.gps_[output].scale,
        )

    def _start_targets(self, rows: NDArray[np.int64] | None = None) -> FloatArray:
        """``(N, n)`` outputs that the start model sees at the states ``x(rows)`` (default
        the training rows): ``y_j(rows + k_j)`` for a joint delayed by ``k_j`` samples."""
        traj = self.train_
        rows = self.rows_ if rows is None else rows
        cols = [traj.at(traj.y[:, j], rows, self._delay_samples(j)) for j in range(self.n_joints)]
        return np.stack(cols, axis=1)

    def blocks(self, ctx: FeatureContext, output: int) -> list[FloatArray]:
        """The effect blocks acting on ``output`` (0-based), in effect order."""
        out = []
        for e in self.effects:
            if output in e.outputs(self.n_joints) and not e.shared:
                cols = e.columns(ctx, output)
                if cols is not None:
                    out.append(cols)
        return out

    def block_effects(self, output: int) -> list[Effect]:
        """Effects with a block on ``output``, in the order of :meth:`blocks`."""
        return [
            e
            for e in self.effects
            if output in e.outputs(self.n_joints)
            and not e.is_shift
            and not e.shared
            and self._has_columns(e)
        ]

    def _has_columns(self, e: Effect) -> bool:
        return not (e.needs_robot and self.start.robot is None)

    def fit(
        self,
        train: Trajectories | Sequence[Trajectories],
        refit_start: bool | None = None,
        _warm: dict[int, FloatArray] | None = None,
        backfit: bool = False,
        _parent: DiagnosisModel | None = None,
    ) -> DiagnosisModel:
        """Fit on training trajectories (whole files), without the rows at their ends whose
        ``qd``/``qdd`` come from the derivative filter's edge fit
        (:meth:`~.data.Trajectories.interior`).

        Args:
            train: datasets or :class:`Trajectories`.
            refit_start: refit a learned start model (default: only when not yet fitted).
            backfit: with a learned (GIP/RBF) start and added effects, re-optimise the GP's own
                hyperparameters on ``y`` minus the fitted effects (warm start), then refit
                (one backfitting pass; :func:`~.add.add_effect` does it, held-out
                confirmations do not).

        Raises:
            ValueError: joint count of the data differs from the model's (both named).
        """
        traj = as_trajectories(train, self.n_joints).interior()
        require_rows(traj, MIN_FIT_ROWS, "fitting a diagnosis model")
        if self.start.robot is not None:
            self.start.robot.check(traj.n_joints)
        self.train_ = traj
        self.rows_ = self._training_rows(traj)
        self._shift_cache: dict[float, tuple] = {}
        self.floors_: dict[int, tuple] = {}  # held-out noise floors (search.heldout_floor)
        self.rest_ = at_rest(traj)  # (N, n) rows where a joint is at rest
        # set-valued dry-friction torque of the rows at rest, taken off the targets
        self.stick_ = np.zeros((self.rows_.size, self.n_joints))
        # a start that learns from every row (LearnedStart.all_rows) reads them all; its
        # kernel K_0 still enters the joints' GPs on the training rows
        start_rows = self._training_rows(traj, subset=False) if self.start.all_rows else self.rows_
        q, qd, qdd = traj.q[start_rows], traj.qd[start_rows], traj.qdd[start_rows]
        fitted = getattr(self.start, "estimator_", True) is not None
        if refit_start or (refit_start is None and not fitted):
            self.start.output = traj.output  # torques or motor currents
            self.start.fit(q, qd, qdd, self._start_targets(start_rows))
            _parent = None
        self.ctx_ = self._shifted(0)[0]
        dt = traj.sample_time
        effects = []
        for e in self.effects:
            e = e.calibrate(self.ctx_)
            if isinstance(e, Delay) and e.sample_time is None:
                e = dataclasses.replace(e, sample_time=dt)
            effects.append(e)
        self.effects = tuple(effects)
        shifts = [self._delay_samples(j) for j in range(self.n_joints)]
        reused = [j for j in range(self.n_joints) if self._same_joint(_parent, j)]
        eigs: dict[int, tuple[FloatArray, FloatArray]] = {}
        if self.start.has_kernel:
            for k in sorted(set(shifts)):  # the Gram matrix at each joint's inputs
                joints = [j for j in range(self.n_joints) if shifts[j] == k and j not in reused]
                if joints:
                    eigs.update(self._start_eig(self._shifted(k)[2], joints))
        self.eig_: list[tuple[FloatArray, FloatArray] | None] = [
            _parent.eig_[j] if j in reused else eigs.get(j) for j in range(self.n_joints)
        ]
        self.shared_: SharedFit | None = None
        self._sizes: list[int] | None = None
        for j in reused:
            self.stick_[:, j] = _parent.stick_[:, j]
        self._fit_joints(_warm, reused, _parent)
        if self.shared_effects:  # alternate the shared weights and the joints' own fits
            for _ in range(SHARED_ROUNDS):
                self._fit_shared()
                self._fit_joints(dict(enumerate(self.theta_)))
        self._fit_stick([j for j in range(self.n_joints) if j not in reused])
        if backfit and isinstance(self.start, LearnedStart) and self.effects:
            # backfitting: the learned start model refitted on the output minus the effects,
            # both at the states x(rows) it reads
            ctx = self.ctx_ if start_rows is self.rows_ else self.context(traj, start_rows)
            y_adj = self._start_targets(start_rows) - np.stack(
                [self._effect_part(j, ctx) for j in range(self.n_joints)], axis=1
            )
            self.start = self.start.refit(q, qd, qdd, y_adj)
            return self.fit(traj, refit_start=False, _warm=dict(enumerate(self.theta_)))
        return self

    def _same_joint(self, parent: DiagnosisModel | None, output: int) -> bool:
        """Whether ``parent`` (the version this one derives from) fitted output ``output``'s
        GP on the same data with the same start model and the same effects on it: its fit
        is then this one's (:meth:`fit` reuses it and its candidate scores). Never with a
        shared (rigid-body) effect in either: its weights couple every joint's target."""
        if parent is None or parent.train_ is not self.train_ or parent.start is not self.start:
            return False
        if any(e.shared for e in (*self.effects, *parent.effects)):
            return False
        if not np.array_equal(parent.rows_, self.rows_):
            return False
        mine = [e for e in self.effects if output in e.outputs(self.n_joints)]
        theirs = [e for e in parent.effects if output in e.outputs(parent.n_joints)]
        return mine == theirs

    def score_cache(self, output: int) -> dict[Effect, tuple]:
        """Scores of candidate variants on output ``output`` (0-based) against this fit,
        kept by :func:`~.search.score_effect` and shared with a later version whose fit of
        that joint is this one's."""
        self._check_fitted()
        return self.scores_[output]

    def _fit_joints(
        self,
        warm: dict[int, FloatArray] | None,
        reused: Sequence[int] = (),
        parent: DiagnosisModel | None = None,
    ) -> None:
        """Type-II ML fit of every joint's GP on its target (``warm``: starting values);
        the joints in ``reused`` take ``parent``'s fit and candidate scores."""
        noise0 = self.start.noise_variance()
        kept = (parent.gps_, parent.theta_, parent.evidence_, parent.scores_) if reused else None
        self.gps_, self.theta_, self.evidence_ = [], [], []
        self.scores_: list[dict[Effect, tuple]] = []
        for j in range(self.n_joints):
            if j in reused:  # the parent's fit of this joint, and its candidate scores
                for mine, theirs in zip(
                    (self.gps_, self.theta_, self.evidence_, self.scores_), kept, strict=True
                ):
                    mine.append(theirs[j])
                continue
            self.scores_.append({})
            base_r = self.target(j, shift=0)
            scale = float(np.sqrt(np.mean(base_r**2)) or 1.0)
            gp = JointGP(
                self.target(j), self.blocks(self.joint_context(j), j), eig=self.eig_[j], scale=scale
            )
            theta0 = gp.default_theta(None if noise0 is None else float(noise0[j]))
            starts = []
            if warm and j in warm and warm[j].shape == theta0.shape:
                starts.append(warm[j])
            if gp.sizes:
                low = theta0.copy()
                low[-len(gp.sizes) :] = -6.0
                starts.append(low)
            with single_thread():
                theta, ev = gp.optimise(theta0, starts=starts)
            self.gps_.append(gp)
            self.theta_.append(theta)
            self.evidence_.append(ev)

    def _stick(self, output: int) -> tuple[Effect, float] | None:
        """``(effect, F_s)``: the set-valued dry friction on ``output`` (0-based) and the
        half-width of its torque at rest from the fitted weights, or ``None``."""
        gp = self.gps_[output]
        if not gp.sizes:
            return None
        mean, _ = gp.weights(self.theta_[output])
        for e, sl in zip(self.block_effects(output), gp.block_slices(), strict=True):
            bound = e.stick_bound(mean[sl])
            if bound is not None:
                return e, bound
        return None

    def _stick_torque(self, ctx: FeatureContext, output: int) -> FloatArray:
        """``(N,)`` the fitted torque of the set-valued dry friction on ``output`` (0-based)
        at the rows of ``ctx`` (0 at rest, the centre of the set)."""
        gp = self.gps_[output]
        mean, _ = gp.weights(self.theta_[output])
        for e, sl in zip(self.block_effects(output), gp.block_slices(), strict=True):
            if e.stick_bound(mean[sl]) is not None:
                return e.columns(ctx, output) @ mean[sl]
        return np.zeros(ctx.q.shape[0])

    def _fit_stick(self, joints: Sequence[int]) -> None:
        """Set-valued dry friction in the fit: on the training rows where a joint with one is
        at rest, its torque is the residual of the rest of the model clipped to ``[-F_s,
        F_s]`` (the set's point nearest to it); it is taken off the target and the joint
        refitted, :data:`STICK_ROUNDS` times (``F_s`` moves with the refit)."""
        for _ in range(STICK_ROUNDS):
            changed = []
            for j in joints:
                hit = self._stick(j)
                if hit is None:
                    continue
                effect, bound = hit
                ctx = self.joint_context(j)
                rest = ctx.rest(effect.joint)
                mean, _ = self.gps_[j].weights(self.theta_[j])
                fitted = np.concatenate(self.blocks(ctx, j), axis=1) @ mean
                resid = self.target(j) + self.stick_[:, j] - fitted
                self.stick_[:, j] = np.where(rest, np.clip(resid, -bound, bound), 0.0)
                changed.append(j)
            if not changed:
                return
            warm = dict(enumerate(self.theta_))
            self._fit_joints(warm, [j for j in range(self.n_joints) if j not in changed], self)

    def smear_widths(self, traj: Trajectories) -> FloatArray:
        """``(N, n)``: on a joint with set-valued dry friction, the filter's smear of its
        fitted friction torque's switches on its own rows around its stops
        (:func:`.analysis.friction_smear`; module docstring); 0 elsewhere."""
        self._check_fitted()
        out = np.zeros((traj.n_samples, self.n_joints))
        ctx = None
        for j in range(self.n_joints):
            hit = self._stick(j)
            if hit is None:
                continue
            if ctx is None:
                ctx = self.context(traj)
            joint = hit[0].joint
            out[:, j] = friction_smear(traj, ctx.rest(joint), joint, self._stick_torque(ctx, j))
        return out

    def set_valued(
        self, traj: Trajectories, mean: FloatArray, widths: FloatArray | None = None
    ) -> tuple[FloatArray, NDArray[np.bool_]]:
        """The prediction ``mean (N, n)`` on ``traj`` with set-valued dry friction: where a
        joint with one is at rest (:meth:`.FeatureContext.rest`), any torque in ``[-F_s,
        F_s]`` is predicted, so the prediction is the measurement projected onto
        ``[mean - F_s, mean + F_s]`` and its error the residual's distance to that interval;
        on the other joints, the rows around its stick phases
        (:func:`.analysis.friction_kinks`) are predicted as measured (module docstring).
        With ``widths`` (``(N, n)``, :meth:`smear_widths`), the prediction is then the
        measurement projected onto ``[out - w, out + w]``: the figure a joint is held to the
        noise floor by (:func:`.search.floor_check`), not the one that compares models.
        Returns it and the
        ``(N, n)`` rows where one of the first two holds (the rows whose noise the prediction
        absorbs; the narrower intervals are not counted)."""
        self._check_fitted()
        out = np.array(mean, dtype=np.float64, copy=True)
        rest = np.zeros(out.shape, dtype=bool)
        ctx = None
        kinks = np.zeros(out.shape, dtype=bool)
        for j in range(self.n_joints):
            hit = self._stick(j)
            if hit is None:
                continue
            effect, bound = hit
            if ctx is None:
                ctx = self.context(traj)
            r = ctx.rest(effect.joint)
            out[r, j] += np.clip(traj.y[r, j] - out[r, j], -bound, bound)
            rest[:, j] = r
            others = np.arange(self.n_joints) != effect.joint - 1  # the joints it couples to
            kinks[:, others] |= friction_kinks(traj, r, effect.joint)[:, None]
        if widths is not None:  # a sticking joint's own rows around its stops
            out += np.clip(traj.y - out, -widths, widths)
        out[kinks] = traj.y[kinks]
        rest |= kinks
        return out, rest

    def _effect_part(self, output: int, ctx: FeatureContext) -> FloatArray:
        """Fitted torque of the added blocks on ``output`` at the states of ``ctx``."""
        blocks = self.blocks(ctx, output)
        shared = self._shared_part(ctx, output)
        if not blocks:
            return shared
        mean, _ = self.gps_[output].weights(self.theta_[output])
        return np.concatenate(blocks, axis=1) @ mean + shared

    def _check_fitted(self) -> None:
        if self.train_ is None:
            raise RuntimeError(f"model {self.name} is not fitted; call fit(train) first")

    @property
    def log_evidence_(self) -> FloatArray:
        """``(n,)`` log marginal likelihood of each joint's training residual [nats]."""
        self._check_fitted()
        return np.array(self.evidence_)

    @property
    def noise_std_(self) -> FloatArray:
        """``(n,)`` fitted noise std per joint (output units)."""
        self._check_fitted()
        pairs = zip(self.gps_, self.theta_, strict=True)
        return np.sqrt([gp.noise_variance(th) for gp, th in pairs])

    # ------------------------------------------------------------------ prediction
    def predict(
        self, data: Trajectories | Sequence[Trajectories], with_var: bool = True
    ) -> tuple[FloatArray, FloatArray]:
        """Posterior mean and latent variance of the output at every sample, ``(N, n)``."""
        self._check_fitted()
        traj = as_trajectories(data, self.n_joints)
        ctx = self.context(traj)
        mean = self.start.prior_mean(traj.q, traj.qd, traj.qdd)
        var = np.zeros_like(mean)
        K0x: dict[int, FloatArray] = {}
        K0d = None
        shifts = [self._delay_samples(j) for j in range(self.n_joints)]
        if self.start.has_kernel:
            te = (traj.q, traj.qd, traj.qdd)
            for k in sorted(set(shifts)):  # each joint's training inputs x(rows - k_j)
                K0x[k] = self.start.kernel(self._shifted(k)[2], te)
            K0d = self.start.kernel_diag(te)
        for j in range(self.n_joints):
            m, v = self.gps_[j].predict(
                self.theta_[j],
                self.blocks(ctx, j),
                K0x[shifts[j]][j] if K0x else None,
                None if K0d is None else K0d[j],
                with_var=with_var,
                n_test=traj.n_samples,
            )
            if self.shared_ is not None:
                cols = self._shared_columns(ctx, j)
                m = m + cols @ self.shared_.mean
                if with_var:
                    v = v + np.einsum("ij,jk,ik->i", cols, self.shared_.cov, cols)
            k = self._delay_samples(j)
            if k:
                d = k * self.train_.sample_time
                m = traj.delayed(mean[:, j] + m, d) - mean[:, j]
                v = traj.delayed(v, d)
            mean[:, j] += m
            var[:, j] = v
        return mean, var

    # ------------------------------------------------------------------ versions
    def with_effect(self, effect: Effect, backfit: bool = False) -> DiagnosisModel:
        """The next version with ``effect`` (complete) appended, fitted if ``self`` is
        (``backfit``: see :meth:`fit`)."""
        for e in self.effects:
            if e.same_slot(effect):
                raise ValueError(f"{effect.label} is already in model {self.name}")
        new = DiagnosisModel(
            self.start,
            (*self.effects, effect),
            version=self.version + 1,
            max_points=self.max_points,
            max_delay_samples=self.max_delay_samples,
            history=(*self.history, f"{self.name} + {effect.variant_label}"),
        )
        if self.train_ is not None:
            warm = {j: np.append(th, 0.0) for j, th in enumerate(self.theta_)}
            new.fit(self.train_, refit_start=False, _warm=warm, backfit=backfit, _parent=self)
        return new

    def replacing(self, label: str, effect: Effect, backfit: bool = False) -> DiagnosisModel:
        """The next version with the effect labelled ``label`` (e.g. ``coulomb:2``) replaced
        by ``effect`` (complete) in its place, fitted if ``self`` is (``backfit``: see
        :meth:`fit`).

        Raises:
            ValueError: no effect ``label`` in the model, or ``effect``'s slot taken by another.
        """
        labels = [e.label for e in self.effects]
        if label not in labels:
            raise ValueError(f"model {self.name} holds no {label}; it holds {labels or 'none'}")
        k = labels.index(label)
        for i, e in enumerate(self.effects):
            if i != k and e.same_slot(effect):
                raise ValueError(f"{effect.label} is already in model {self.name}")
        effects = (*self.effects[:k], effect, *self.effects[k + 1 :])
        new = DiagnosisModel(
            self.start,
            effects,
            version=self.version + 1,
            max_points=self.max_points,
            max_delay_samples=self.max_delay_samples,
            history=(*self.history, f"{self.name}: {label} -> {effect.variant_label}"),
        )
        if self.train_ is not None:
            same = effect.is_shift == self.effects[k].is_shift
            warm = dict(enumerate(self.theta_)) if same else None
            new.fit(self.train_, refit_start=False, _warm=warm, backfit=backfit, _parent=self)
        return new

    def without(self, label: str, backfit: bool = False) -> DiagnosisModel:
        """The next version with the effect labelled ``label`` removed (backward elimination,
        :func:`~mcpilco.models.diagnosis.search.backward_step`), fitted if ``self`` is; the
        joints it does not act on keep ``self``'s fit.

        Raises:
            ValueError: no effect ``label`` in the model.
        """
        labels = [e.label for e in self.effects]
        if label not in labels:
            raise ValueError(f"model {self.name} holds no {label}; it holds {labels or 'none'}")
        k = labels.index(label)
        new = DiagnosisModel(
            self.start,
            (*self.effects[:k], *self.effects[k + 1 :]),
            version=self.version + 1,
            max_points=self.max_points,
            max_delay_samples=self.max_delay_samples,
            history=(*self.history, f"{self.name} - {self.effects[k].variant_label}"),
        )
        if self.train_ is not None:
            new.fit(self.train_, refit_start=False, backfit=backfit, _parent=self)
        return new

    # ------------------------------------------------------------------ parameters
    def estimates(self, effect: Effect, output: int) -> list[ParamEstimate]:
        """Posterior estimates of ``effect``'s parameters on ``output`` (0-based), each marked
        where the data cannot pin it down (:func:`.identifiability.judge_estimates`); ``[]``
        when ``effect`` has no block there."""
        self._check_fitted()
        effs = self.block_effects(output)
        k = next((i for i, e in enumerate(effs) if e.same_slot(effect)), None)
        if k is None:
            return []
        gp, theta = self.gps_[output], self.theta_[output]
        sl = gp.block_slices()[k]
        mean, cov = gp.weights(theta)
        ests = widen_estimates(  # current logs: k_t's uncertainty carried into the interval
            effs[k].estimates(mean[sl], cov[sl, sl], self.ctx_, output),
            self.train_.torque_constants,
            output,
        )
        names = weight_names(effs, gp.sizes)
        return judge_estimates(effs[k], ests, gp, theta, k, names, self.ctx_, output)

    def parameters(self, shape: bool = False) -> list[dict[str, Any]]:
        """Posterior estimates of every added effect's physical parameters (95% intervals),
        or why the data cannot pin one down (``unidentified``, :meth:`estimates`); with
        ``shape`` also its refined shape values (cogging order, smoothing, delay, ...) with
        their likelihood-ratio intervals (:attr:`.Effect.profile`)."""
        self._check_fitted()
        rows = []
        shared = self.shared_effects
        for e in self.effects:
            if e in shared:
                k = shared.index(e)
                off = sum(self._shared_sizes()[:k])
                sl = slice(off, off + self._shared_sizes()[k])
                mean, cov = self.shared_.mean[sl], self.shared_.cov[sl, sl]
                for p in e.estimates(mean, cov, self.ctx_, 0):
                    rows.append(
                        dict(effect=e.variant_label, output="all", **p.__dict__, text=p.text())
                    )
                continue
            for j in e.outputs(self.n_joints):
                if e.is_shift:
                    ests = e.estimates(np.zeros(1), np.zeros((1, 1)), self.ctx_, j)
                else:
                    if e not in self.block_effects(j):
                        continue
                    ests = self.estimates(e, j)
                for p in e.with_profile(ests, shape):
                    rows.append(
                        dict(effect=e.variant_label, output=j + 1, **p.__dict__, text=p.text())
                    )
        return rows

    # ------------------------------------------------------------------ persistence
    def spec(self) -> dict[str, Any]:
        return {
            "format": "mcpilco-diagnosis-model/1",
            "version": self.version,
            "start": self.start.spec(),
            "effects": [e.spec() for e in self.effects],
            "max_points": self.max_points,
            "max_delay_samples": self.max_delay_samples,
            "history": list(self.history),
        }

    def save(self, directory: str | Path) -> Path:
        """Write ``<directory>/model_v<k>.json`` (spec, fitted hyperparameters, parameter
        estimates, training files). Never overwrites: an existing name gets ``-2``, ``-3``..

        Returns:
            the path written.
        """
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        path = directory / f"model_v{self.version}.json"
        k = 2
        while path.exists():
            path = directory / f"model_v{self.version}-{k}.json"
            k += 1
        payload = self.spec()
        if self.train_ is not None:
            payload["fitted"] = {
                "train_files": self.train_.names,
                "theta": [th.tolist() for th in self.theta_],
                "log_evidence": [float(v) for v in self.evidence_],
                "noise_std": self.noise_std_.tolist(),
                "parameters": [
                    {k: v for k, v in p.items() if k != "text"} for p in self.parameters(shape=True)
                ],
            }
        path.write_text(json.dumps(payload, indent=1))
        return path

    @classmethod
    def from_spec(cls, spec: dict[str, Any]) -> DiagnosisModel:
        """Rebuild an (unfitted) model from :meth:`spec`; call :meth:`fit` on its data."""
        start_spec = spec["start"]
        if start_spec["kind"] == "nominal":
            start: StartModel = NominalStart(start_spec["robot_text"], name=start_spec.get("name"))
        elif start_spec["kind"] in LEARNED_STARTS:
            start = LEARNED_STARTS[start_spec["kind"]](
                start_spec["joint_types"],
                robot=start_spec.get("robot_text"),
                adam_iters=start_spec.get("adam_iters", 100),
                lbfgs_iters=start_spec.get("lbfgs_iters", 30),
                converge_nats=start_spec.get("converge_nats", 0.5),
                max_rounds=start_spec.get("max_rounds", 10),
                hyper_points=start_spec.get("hyper_points"),
                **{
                    key: start_spec[key]
                    for key in ("inducing", "span")
                    if start_spec.get(key) is not None
                },
            )
        else:
            raise ValueError(f"unknown start model kind {start_spec['kind']!r}")
        return cls(
            start,
            [effect_from_spec(e) for e in spec["effects"]],
            version=spec["version"],
            max_points=spec.get("max_points", 600),
            max_delay_samples=spec.get("max_delay_samples", 10),
            history=spec.get("history", ()),
        )

    @classmethod
    def load(cls, path: str | Path) -> DiagnosisModel:
        """An unfitted model from a saved JSON (refit it with :meth:`fit`: the fit is
        deterministic, so the same training files give the same model)."""
        return cls.from_spec(json.loads(Path(path).read_text()))

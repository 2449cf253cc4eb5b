"""The record of each trial of a run, written and read here (``records.json``).

A run of MC-PILCO or of the PILCO baseline writes, after every trial, ``records.json``:
``{"config": <the run's config as a dict>, "records": [<one record per trial>]}``. A record
is a :class:`TrialRecord`: what happened on the real system (every trial), and for a policy
trial how the model was fitted and the policy optimised. A field that does not apply to a
trial (None) is not written. Files written before a field existed load with it None; keys
this version does not know are kept in :attr:`TrialRecord.extra` and written back as they
were, so that reading and writing an old file loses nothing.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcpilco.models.files import write_atomic

RECORDS_NAME = "records.json"
"""The records file in a run's output folder."""

TRIAL_KINDS = ("exploration", "policy")
"""Kinds of trial: the random exploration trial 0, and a trial under the learned policy."""


@dataclass
class TrialRecord:
    """One trial ``k`` of a run (thesis Algorithm 1: one pass of its loop).

    Attributes:
        index: ``k``.
        kind: ``"exploration"`` (trial 0, random actions) or ``"policy"``.
        cost: the task's evaluation cost ``sum_t c(x_t)`` on the true states.
        success: the task's success test.
        started_in_goal: the trial started in the set it had to reach (its success is then
            no swing-up and counts as none).
        time_in_goal: seconds within the task's goal bounds.
        steps: control steps of the trial (of all its episodes).
        wall_s: wall-clock seconds of the whole trial.
        experience_s: seconds of interaction of the run so far (``H T_s (k + 1)`` when no
            episode ends early).
        tracking_rms: a tracking task's RMS error per tracked state.
        gp_fit_s: seconds of the model fit; ``gp_points``: its training points;
            ``n_data``: the transitions the fit could use; ``n_at_limits``: transitions left
            out because they touch one of the task's limits.
        compiled_step, compile_check, compile_error, compile_backend, rollout_shards: the
            fast rollout of the trial (MC-PILCO's ``compile_rollout``): whether it ran, its
            check against the eager rollout, why it failed, its backend and thread shards.
        opt_steps, opt_s, s_per_opt_step, cpu_s_per_opt_step: the policy optimisation's
            steps, seconds, wall and CPU seconds per step.
        opt_stop, opt_lr_reductions, opt_reinits: why it stopped, learning-rate reductions,
            re-initialisations (MC-PILCO's monitoring rule).
        opt_restarts, opt_restart_reasons, opt_success_level: plateau restarts of the
            policy search, why each ran (its step, plateau and level), and the success level
            ``J_succ`` they compare with (None: the task's success set is no box).
        explore_braked: steps of the exploration trial whose random action was replaced by
            braking before a declared limit (:class:`~mcpilco.agents.common.trials.LimitGuard`).
        opt_final_cost: ``J^`` at the last step (mean over candidates).
        candidate_costs, chosen_candidate, chosen_cost: ``J^`` of each candidate policy of
            the chosen snapshot, the applied one and its ``J^``.
        snapshot_steps, snapshot_costs, chosen_step: the optimisation steps whose
            parameters were compared, their best ``J^``, and the step applied (0: the
            parameters the optimisation started from, the previous trial's, were kept);
            ``opt_snapshot_every``: the steps between the compared copies (0: the final
            parameters only); ``choose_s``: seconds of that comparison.
        gp_rmse: one-step RMSE of the model (fitted before the trial) per output on the
            trial's transitions.
        rollout_dtype, rollout_dtype_error: dtype of the GP posterior in the trial's particle
            rollouts (float64 where the config's dtype lost the posterior to round-off) and
            that dtype's error
            (:meth:`~mcpilco.agents.mc_pilco.dynamics.GPDynamicsModel.posterior_dtype_error`).
        n_contact, n_filtered, n_filtered_contact: steps the env reports a contact (a
            push), transitions a push filter left out, and those of them that overlap one.
        episodes: episodes the trial spanned (more than one where the env ended one early and
            the trial collected its steps across resets; ``exploration_episodes`` in files
            written before, read as this field).
        opt_skipped: PILCO optimisation steps skipped on a non-finite ``J``.
        eval_episodes, eval_counted, eval_successes, eval_ci: evaluation episodes after the
            trial (not experience), those that started outside the goal set, their
            successes, and the 95 % Wilson interval of the success rate
            (:func:`~mcpilco.agents.common.trials.evaluate`).
        horizon, goal_fraction, next_horizon: the particle horizon ``H_k`` of the trial
            (steps), the fraction of the applied policy's predicted particles that reach the
            goal a success window before its end, and the horizon of the next trial
            (:mod:`~mcpilco.agents.mc_pilco.horizon`).
        predicted_success: the fraction of the applied policy's predicted particles that
            stay in the goal over the task's final success window (the model's success
            rate, :func:`~mcpilco.agents.mc_pilco.horizon.predicted_success`; None: the task
            has no success window).
        extra: keys of a record this version does not know, kept as read.
    """

    index: int
    kind: str
    cost: float | None = None
    success: bool | None = None
    started_in_goal: bool | None = None
    time_in_goal: float | None = None
    steps: int | None = None
    wall_s: float | None = None
    experience_s: float | None = None
    tracking_rms: dict[str, float] | None = None
    gp_fit_s: float | None = None
    gp_points: int | None = None
    n_data: int | None = None
    n_at_limits: int | None = None
    rollout_dtype: str | None = None
    rollout_dtype_error: float | None = None
    compiled_step: bool | None = None
    compile_check: dict[str, Any] | None = None
    compile_error: str | None = None
    compile_backend: str | None = None
    rollout_shards: int | None = None
    opt_steps: int | None = None
    opt_s: float | None = None
    s_per_opt_step: float | None = None
    cpu_s_per_opt_step: float | None = None
    opt_stop: str | None = None
    opt_lr_reductions: int | None = None
    opt_reinits: int | None = None
    opt_restarts: int | None = None
    opt_restart_reasons: list[str] | None = None
    opt_success_level: float | None = None
    explore_braked: int | None = None
    opt_final_cost: float | None = None
    candidate_costs: list[float] | None = None
    chosen_candidate: int | None = None
    chosen_cost: float | None = None
    snapshot_steps: list[int] | None = None
    snapshot_costs: list[float] | None = None
    chosen_step: int | None = None
    opt_snapshot_every: int | None = None
    choose_s: float | None = None
    gp_rmse: list[float] | None = None
    n_contact: int | None = None
    n_filtered: int | None = None
    n_filtered_contact: int | None = None
    episodes: int | None = None
    opt_skipped: int | None = None
    eval_episodes: int | None = None
    eval_counted: int | None = None
    eval_successes: int | None = None
    eval_ci: list[float] | None = None
    horizon: int | None = None
    goal_fraction: float | None = None
    next_horizon: int | None = None
    predicted_success: float | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.kind not in TRIAL_KINDS:
            raise ValueError(f"trial record kind must be one of {TRIAL_KINDS}, got {self.kind!r}")

    def update(self, **values: Any) -> None:
        """Set the named fields (a ``TypeError`` names a field the record does not have)."""
        names = _field_names()
        for name, value in values.items():
            if name not in names or name == "extra":
                raise TypeError(f"TrialRecord has no field {name!r}")
            setattr(self, name, value)

    def to_dict(self) -> dict[str, Any]:
        """The record as ``records.json`` and the checkpoint hold it: the fields that are
        not None, then the :attr:`extra` keys."""
        out = {
            f.name: getattr(self, f.name)
            for f in dataclasses.fields(self)
            if f.name != "extra" and getattr(self, f.name) is not None
        }
        return {**out, **self.extra}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> TrialRecord:
        """Inverse of :meth:`to_dict`, for records of any version: a missing field is None,
        an unknown key goes to :attr:`extra`.

        Raises:
            ValueError: ``d`` has no ``index`` or ``kind``.
        """
        if "index" not in d or "kind" not in d:
            raise ValueError(f"a trial record needs 'index' and 'kind', got keys {sorted(d)}")
        names = _field_names() - {"extra"}
        if "exploration_episodes" in d and "episodes" not in d:  # the field's former name
            d = {("episodes" if k == "exploration_episodes" else k): v for k, v in d.items()}
        return cls(
            **{k: v for k, v in d.items() if k in names},
            extra={k: v for k, v in d.items() if k not in names},
        )


def _field_names() -> set[str]:
    return {f.name for f in dataclasses.fields(TrialRecord)}


def write_records(out: str | Path, config: Any, records: Sequence[TrialRecord]) -> Path:
    """Write ``out/records.json`` (the config's ``to_dict()`` and one record per trial)
    atomically (a temporary file moved over the old one); returns its path."""
    path = Path(out) / RECORDS_NAME
    data = {"config": config.to_dict(), "records": [r.to_dict() for r in records]}
    write_atomic(path, json.dumps(data, indent=1))  # a link at records.json.tmp is refused
    return path


def read_records(path: str | Path) -> tuple[dict[str, Any], list[TrialRecord]]:
    """The config dict and the trial records of a run's ``records.json`` (``path``: the
    file or its run folder).

    Raises:
        FileNotFoundError: no records file at ``path``.
        ValueError: the file is not a records file (the message names it).
    """
    path = Path(path)
    if path.is_dir():
        path = path / RECORDS_NAME
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise ValueError(f"{path} is not a records file (invalid JSON: {err})") from None
    if not isinstance(data, dict) or not isinstance(data.get("records"), list):
        raise ValueError(f"{path} is not a records file (no 'records' list)")
    return dict(data.get("config") or {}), [TrialRecord.from_dict(r) for r in data["records"]]


def record_line(r: TrialRecord) -> str:
    """One line per trial: cost, success, time in the goal region, wall time (and the
    optimisation figures of a policy trial)."""
    line = (
        f"trial {r.index} ({r.kind}, {r.experience_s:.0f} s of experience): "
        f"cost {r.cost:.2f}, success {r.success}, in goal {r.time_in_goal:.2f} s, "
        f"time {r.wall_s:.1f} s"
    )
    if r.episodes is not None and r.episodes > 1:
        line += f", {r.steps} steps in {r.episodes} episodes"
    if r.started_in_goal:
        line += " [started in the goal set: not counted as a success]"
    if r.eval_counted:
        lo, hi = (100 * v for v in r.eval_ci)
        rate = 100 * r.eval_successes / r.eval_counted
        line += (
            f", eval {r.eval_successes}/{r.eval_counted} "
            f"({rate:.0f} %, 95 % CI {lo:.0f}-{hi:.0f} %)"
        )
    elif r.eval_episodes:
        line += f", eval: all {r.eval_episodes} episodes started in the goal set"
    if r.tracking_rms:
        line += ", tracking RMS " + " / ".join(f"{v:.4f}" for v in r.tracking_rms.values())
    if r.kind == "policy":
        line += (
            f" (GP fit {r.gp_fit_s:.1f} s on N={r.gp_points}, {r.opt_steps} opt steps "
            f"x {r.s_per_opt_step:.3f} s (CPU {r.cpu_s_per_opt_step:.3f} s), "
            f"J^ {r.opt_final_cost:.2f})"
        )
        if r.predicted_success is not None:
            line += f"; predicted success {100 * r.predicted_success:.0f} % of the particles"
        if r.goal_fraction is not None:
            line += (
                f"; horizon {r.horizon}: {100 * r.goal_fraction:.0f} % of the particles reach "
                "the goal a success window before its end"
            )
            if r.next_horizon is not None and r.next_horizon != r.horizon:
                line += f", next horizon {r.next_horizon}"
        if r.snapshot_steps and len(r.snapshot_steps) > 1:
            kept = " (the previous policy kept)" if r.chosen_step == 0 else ""
            line += (
                f"; applied the step-{r.chosen_step} parameters{kept}, J^ {r.chosen_cost:.2f} "
                f"without dropout, the best of {len(r.snapshot_steps)} copies"
            )
        if r.n_filtered is not None:
            line += f"; {r.n_filtered} transitions filtered as pushes"
            if r.n_contact is not None:
                line += f" ({r.n_filtered_contact or 0} of the {r.n_contact} pushed)"
        if r.n_at_limits:
            line += f"; {r.n_at_limits} transitions at the task's limits left out of the GP data"
        if r.compile_error:
            line += f"; compiling the step failed ({r.compile_error}): ran eagerly"
        elif r.compiled_step is False:
            line += "; the compiled step failed its check against the eager step: ran eagerly"
    return line


@dataclass
class RunSummary:
    """What a run of MC-PILCO or PILCO returns: its records (as written to
    ``records.json``, :meth:`TrialRecord.to_dict`) and its output files."""

    config: dict[str, Any]
    records: list[dict[str, Any]]
    out_dir: Path
    checkpoint: Path
    rrd: Path | None
    pngs: list[Path]
    seconds: float
    resumed_from_trial: int | None = None

    @property
    def trials(self) -> list[TrialRecord]:
        """The records as :class:`TrialRecord` s."""
        return [TrialRecord.from_dict(r) for r in self.records]

    @property
    def success(self) -> bool:
        """Success of the last policy trial."""
        return bool(self.records and self.records[-1].get("success"))

    @property
    def first_success_trial(self) -> int | None:
        """Index of the first policy trial that succeeded from outside the goal set (a trial
        that started in it, ``started_in_goal``, is no swing-up; None: none did)."""
        for r in self.records:
            if r["kind"] == "policy" and r["success"] and not r.get("started_in_goal"):
                return int(r["index"])
        return None

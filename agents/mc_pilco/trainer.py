"""MC-PILCO's outer loop (thesis Algorithm 1) as a :class:`Trainer`.

Algorithm 1, one method each::

    set_up()                        task, env, folder, policy, model, cost (or resume)
    explore()                       trial 0: random actions u ~ U(low, high) for H steps
    for trial k = 1 .. num_trials:
        fit_model()                 GP dynamics on all transitions D (marginal likelihood)
        improve_policy()            minimise the particle estimate J^ (5.8; J^_W with a
                                    success window), monitoring rule
        apply_policy()              run the policy on the system for H steps, D += its data
        evaluate_policy()           E evaluation episodes (eval_episodes; not in D), from
                                    the task's eval_init, of the env's own episode length
        plan_horizon()              the next trial's horizon (grown while too few predicted
                                    particles reach the goal a success window before its end)
        commit_trial()              record, plots, checkpoint (the trial's commit point)

Glossary
--------
The task (state layout, cost, success test, action bounds) comes from a
:class:`~mcpilco.envs.tasks.spec.TaskSpec`, the hyperparameters from an
:class:`~mcpilco.agents.mc_pilco.config.MCPilcoConfig`.

trial ``k = 0``
    random exploration for ``H`` steps: actions ``u ~ U(low, high)``, each drawn once per
    ``explore_hold`` control steps.
trial ``k >= 1``
    fit the velocity-change GPs on all transitions ``D`` by marginal likelihood (fresh
    hyperparameters each trial; subset of data beyond ``max_points``), optimise the policy on
    the particle estimate ``J^`` (5.8) with the monitoring rule, apply the policy (no dropout)
    to the env for ``H`` steps, append the transitions to ``D``.
experience
    ``H T_s (k + 1)`` seconds after trial ``k`` (3, 6, 9, 12, 15 s ... on the cart-pole);
    ``sum_j H_j T_s`` where the horizon grew (:mod:`~mcpilco.agents.mc_pilco.horizon`).
    An env that ends an episode early (the task's ``termination``) is reset until the trial
    has taken the task's ``trial_steps`` (default ``H``) steps: every step counts, and the
    record says how many ``episodes`` the trial spanned; the trial's outcome (cost,
    success) is its first episode's, from the trial's reset seed.
record of a trial
    a :class:`~mcpilco.agents.common.records.TrialRecord`: the task's evaluation cost
    ``sum_t c(x_t)`` on the true state, ``success``, the time within the task's goal bounds,
    wall-clock of the GP fit, of the optimisation and of the trial, optimisation steps and
    seconds per step, the one-step GP error on the trial's data (model fitted before the
    trial). The particle predictions of the final policy go to the plots and the checkpoint.

After every trial the run is checkpointed atomically
(:mod:`mcpilco.agents.common.checkpoint`): data, policy, GP state, RNG states, records.
``resume=True`` continues from it.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mcpilco.agents.common.checkpoint import (
    CHECKPOINT_NAME,
    check_resume,
    load_checkpoint,
    restore_state,
    rng_state,
    save_checkpoint,
    set_rng_state,
)
from mcpilco.agents.common.records import RunSummary, TrialRecord, record_line, write_records
from mcpilco.agents.common.run_folder import RUN_OUTPUTS, open_run_folder
from mcpilco.agents.common.trials import (
    LimitGuard,
    episode_outcome,
    evaluate,
    exploration_episodes,
    make_env,
    transitions,
    trial_episodes,
    trial_seed,
)
from mcpilco.agents.mc_pilco.config import RESUME_FIXED, MCPilcoConfig
from mcpilco.agents.mc_pilco.cost import SaturatingCost
from mcpilco.agents.mc_pilco.dynamics import GPDynamicsModel
from mcpilco.agents.mc_pilco.fast import cpp_compiler, cpp_compiler_names, use_fast_rollout
from mcpilco.agents.mc_pilco.features import StateLayout
from mcpilco.agents.mc_pilco.filters import CollisionFilter, contact_steps
from mcpilco.agents.mc_pilco.horizon import (
    goal_fraction,
    grows,
    missed_catch,
    next_horizon,
    predicted_success,
    scaled_opt_steps,
    success_window,
)
from mcpilco.agents.mc_pilco.loss import MCPilcoLoss, TerminationSet
from mcpilco.agents.mc_pilco.optimize import choose_policy, optimize_policy
from mcpilco.agents.mc_pilco.policy import (
    PolicyPopulation,
    SquashedRBFPolicy,
    data_init,
    make_policy_module,
    policy_act,
)
from mcpilco.agents.mc_pilco.regulator import catch_gate, feature_gains, regulator_lqr
from mcpilco.agents.mc_pilco.viz import (
    plot_optimisation,
    plot_trial_particles,
    write_rerun_recording,
)
from mcpilco.envs.tasks.spec import TaskSpec
from mcpilco.models.device import resolve_device

PLAN_PARTICLES = 100  # predicted particles the next trial's horizon is judged on (at least)
ROLLOUT_DTYPE_TOL = 0.01
"""Largest RMS error of the rollout-dtype GP posterior mean, as a fraction of each output's
spread on the training data, before the rollout runs in float64 instead (a model that
misses by 1 % per step is not the model fitted; round-off on data with measurement noise
is 1e-4 of the spread and below)."""

CATCH_RESTART_SEED = 104729  # seed offset of the catch restart's fresh policy draw

CANDIDATE_SEED_STRIDE = 7919
"""Candidate ``k`` of run ``seed`` is initialised with seed ``seed + 7919 k``."""


class Trainer:
    """Run (or resume) MC-PILCO in one output folder; writes the checkpoint, the PNGs,
    ``run.rrd`` and ``records.json``.

    Args:
        config: the experiment.
        out_dir: output folder (created).
        resume: continue from ``out_dir/checkpoint.pt``; finished trials are kept and not
            re-run; ``config.num_trials`` may be larger than in the first call.
        progress: tqdm bars on trials and optimisation steps.
        log: called with one line per trial (None: silent).
        write_rrd: write the Rerun recording.
        task: the task (None: :meth:`MCPilcoConfig.task_spec`); pass one to use a Python
            cost function (``TaskSpec.cost_fn``).
        overwrite: delete another run found in ``out_dir`` first (else it is refused; the
            folder is locked and its files listed in ``manifest.json``:
            :mod:`mcpilco.agents.common.run_folder`).

    After :meth:`set_up`: ``task``, ``env``, ``policy`` (the applied policy),
    ``population`` (the ``K`` candidates optimised side by side), ``model`` (the GP
    dynamics), ``cost_fn`` (the optimised cost), ``episodes`` (the data ``D``), ``records``
    and ``arrays`` (per trial: the record and what the plots draw).
    """

    def __init__(
        self,
        config: MCPilcoConfig,
        out_dir: str | Path,
        resume: bool = False,
        progress: bool = True,
        log: Callable[[str], None] | None = print,
        write_rrd: bool = True,
        task: TaskSpec | None = None,
        overwrite: bool = False,
    ) -> None:
        self.config = config
        self.out = Path(out_dir)
        self.checkpoint_path = self.out / CHECKPOINT_NAME
        self.resume = resume
        self.progress = progress
        self.log = log
        self.write_rrd = write_rrd
        self.task = task
        self.overwrite = overwrite
        self.episodes: list[dict[str, Any]] = []  # D: the observed episodes of every trial
        self.records: list[TrialRecord] = []
        self.arrays: list[dict[str, Any]] = []  # per trial: what the plots draw
        self.pngs: list[Path] = []
        self.start_trial = 0
        self.resumed_from: int | None = None
        self.eval_env = None  # the evaluation episodes' env (set_up, with eval_episodes)

    # ------------------------------------------------------------------------ the loop
    def run(self) -> RunSummary:
        """Algorithm 1: set up, then one trial after the other up to ``num_trials``."""
        t_start = time.perf_counter()
        self.set_up()
        total = self.config.num_trials + 1
        bar = self._progress_bar(total)
        try:
            for k in range(self.start_trial, total):
                self.run_trial(k)
                if bar is not None:
                    bar.update(1)
        finally:
            if bar is not None:
                bar.close()
            self.env.close()
            if self.eval_env is not None:
                self.eval_env.close()
            self.run_folder.close()
        return self.summary(time.perf_counter() - t_start)

    def run_trial(self, k: int) -> None:
        """Trial ``k``: explore (``k = 0``) or fit, improve and apply; then commit it."""
        t0 = time.perf_counter()
        rec = TrialRecord(index=k, kind="exploration" if k == 0 else "policy")
        arr: dict[str, Any] = {"index": k, "particles": None, "opt_costs": None}
        if k == 0:
            episodes = self.explore(rec)
        else:
            self.init_policy_from_data(k)
            dynamics = self.fit_model(rec)
            self.init_regulator(k, dynamics)
            self.improve_policy(k, dynamics, rec, arr)
            episodes = self.apply_policy(k, rec, arr)
            self.evaluate_policy(k, rec)
            self.plan_horizon(rec, arr)
        self.commit_trial(k, episodes, rec, arr, t0)
        if rec.next_horizon is not None and rec.next_horizon != self.horizon:
            self.use_horizon(rec.next_horizon)

    # ----------------------------------------------------------------------- the steps
    def set_up(self) -> None:
        """Open the folder, then build the task, env, policies, model and cost, and load the
        checkpoint on resume (the folder is released if any of it fails)."""
        config = self.config
        check_dynamics_task(self.task if self.task is not None else config.task_spec())
        self.run_folder = open_run_folder(self.out, resume=self.resume, overwrite=self.overwrite)
        self.env = self.eval_env = None
        try:
            self._set_up_task()
            self.env = make_env(config.env_id, self.horizon, self.task, config.env_kwargs)
            self.eval_steps = evaluation_steps(self.task, self.env)
            self.max_horizon = (
                max(self.horizon, self.eval_steps)
                if config.grow_horizon and grows(self.task)
                else self.horizon
            )
            if config.eval_episodes:  # episodes of the evaluation's length
                self.eval_env = make_env(
                    config.env_id, self.eval_steps, self.task, config.env_kwargs
                )
            self._set_up_parts()
            if self.resume:
                self._load_checkpoint()
            self.cost_fn = optimised_cost(self.config, self.task)
            self.success_level = success_cost_level(
                self.task, self.cost_fn, self.config.window_objective
            )
            self.init_std = initial_std(self.config, self.task, self.layout)
        except BaseException:
            for env in (self.env, self.eval_env):
                if env is not None:
                    env.close()
            self.run_folder.close()
            raise

    def explore(self, rec: TrialRecord | None = None) -> list[dict[str, Any]]:
        """Trial 0: episodes of random actions held ``explore_hold`` steps each, of
        ``explore_steps`` (else the task's ``trial_steps``) steps in all; braked before the
        task's limits (and termination box) as ``explore_limits`` says
        (:class:`~mcpilco.agents.common.trials.LimitGuard`; the braked steps go to ``rec``)."""
        config = self.config
        guard = (
            None
            if config.explore_limits == "none"
            else LimitGuard(self.task, termination=config.explore_limits == "termination")
        )
        episodes = exploration_episodes(
            self.env,
            self.np_rng,
            config.seed,
            config.explore_steps or self.horizon,
            self.task,
            config.explore_hold,
            config.explore_steps or self.task.steps_per_trial,
            record_info=True,
            guard=guard,
        )
        if rec is not None and guard is not None and guard.bounds:
            rec.update(explore_braked=guard.interventions)
        return episodes

    def init_policy_from_data(self, k: int) -> None:
        """With ``policy_init="data"``: draw the policy's centres and lengthscales from the
        exploration trial's states; with a linear feedback term: its feature scales ``s``,
        the spread of those states (once, before the first policy trial; the same settings
        on a resumed run, whose checkpoint holds them)."""
        from_data = self.config.policy_init == "data" and self.policy.center_mean is None
        if not (from_data or (self.policy.linear and k == 1)):
            return
        task = self.task
        n_explore = self.records[0].episodes or 1  # the exploration trial's episodes
        init = data_init(
            task.features(np.concatenate([e["obs"] for e in self.episodes[:n_explore]]))
        )
        if self.policy.linear:
            init["linear_scale"] = init["center_std"]
        if not from_data:
            init.update(center_mean=None, center_std=None, lengthscale_init=None)
        self.population.use_data_init(init)
        self.policy.use_data_init(init)
        if k == 1:  # the first policy starts there
            self.population.reset_parameters(self.config.seed)
            self.population.copy_to(0, self.policy)

    def init_regulator(self, k: int, dynamics: torch.nn.Module) -> None:
        """With a linear feedback term, before the first policy optimisation: start its gains
        at the LQR ``K`` of the first model linearised at the regulation point
        (:func:`~mcpilco.agents.mc_pilco.regulator.regulator_lqr`), for every candidate and
        for the policy's later re-draws (restarts); a catch (a task that starts outside its
        goal, :func:`catch_point`) also gates the term around that point with widths from
        ``K`` (:func:`~mcpilco.agents.mc_pilco.regulator.catch_gate`). Zero gains where the
        linearised model has no stabilising LQR. Later trials refine the optimised gains."""
        if not (self.policy.linear and k == 1):
            return
        task = self.task
        x_star = linear_reference(self.config, task)
        u_half = self.policy.u_half.cpu().numpy()
        lqr = regulator_lqr(dynamics, self.cost_fn, x_star, self.policy.u_mid.cpu().numpy(), u_half)
        if lqr is None:
            if self.log:
                self.log(
                    "linear feedback: no stabilising LQR of the model at the regulation point, "
                    "gains start at 0"
                )
            return
        scale = self.policy.linear_scale.cpu().numpy()
        init = {"gains_init": feature_gains(lqr, self.layout, x_star, scale, u_half).tolist()}
        gated = regulation_point(task) is None
        if gated:
            init["linear_gate"] = catch_gate(lqr, self.layout, u_half).tolist()
        if self.log:
            gain = np.array2string(lqr, precision=3, separator=", ")
            self.log(
                f"linear feedback: gains start at the LQR of the model at the "
                f"{'goal (a catch, gated)' if gated else 'regulation point'}: K = {gain} "
                f"(states {', '.join(task.state_names)})"
                + (
                    f"; gate widths {[round(v, 3) for v in init['linear_gate']]} (features)"
                    if gated
                    else ""
                )
            )
        self.population.use_data_init(init)
        self.policy.use_data_init(init)
        self.population.reset_parameters(self.config.seed)
        self.population.copy_to(0, self.policy)

    def fit_model(self, rec: TrialRecord) -> torch.nn.Module:
        """Model learning: fit the GP dynamics on the transitions of all episodes (less those
        at the task's limits or marked by a push filter); returns the particle dynamics, in
        the config's ``rollout_dtype`` unless its posterior mean misses the float64 one by
        more than :data:`ROLLOUT_DTYPE_TOL`
        (:meth:`~mcpilco.agents.mc_pilco.dynamics.GPDynamicsModel.posterior_dtype_error`:
        noise-free data), then in float64; the record says which."""
        t_fit = time.perf_counter()
        data = transitions(self.episodes, self.task)
        self.model.fit(*data)
        n_data = int(len(data[1]))
        n_filtered = sum(
            int(np.sum(e["filtered"])) for e in self.episodes if e.get("filtered") is not None
        )
        dtype = getattr(torch, self.config.rollout_dtype)
        dtype_error = self.model.posterior_dtype_error(dtype)
        if dtype_error > ROLLOUT_DTYPE_TOL:  # the posterior lost to round-off: float64
            dtype = torch.float64
        rec.update(
            gp_fit_s=time.perf_counter() - t_fit,
            gp_points=int(self.model.gp_.train_x_.shape[0]),
            n_data=n_data,
            n_at_limits=int(sum(len(e["actions"]) for e in self.episodes)) - n_data - n_filtered,
            rollout_dtype=str(dtype).removeprefix("torch."),
            rollout_dtype_error=dtype_error,
        )
        return self.model.particle_dynamics(dtype)

    def improve_policy(
        self, k: int, dynamics: torch.nn.Module, rec: TrialRecord, arr: dict[str, Any]
    ) -> None:
        """Policy update: minimise ``J^`` over the candidates with the monitoring rule, choose
        the candidate and snapshot to apply, and predict its particles (for the plots)."""
        config = self.config
        loss = self._loss(self.policy_module, dynamics)
        if config.compile_rollout:  # built, then checked against the eager rollout
            fast = use_fast_rollout(loss, config.rollout_backend, dynamic=False)
            rec.update(
                compiled_step=fast.in_use,
                compile_check=fast.check,
                compile_error=fast.error,
                compile_backend=fast.backend,
                rollout_shards=fast.shards,
            )
        opt_cfg = config.opt
        if k == 1 and config.opt_steps_first is not None:
            opt_cfg = dataclasses.replace(
                opt_cfg, max_steps=min(opt_cfg.max_steps, config.opt_steps_first)
            )
        if self.horizon > self.horizon0:  # a grown horizon: the trial's budgeted seconds
            opt_cfg = dataclasses.replace(
                opt_cfg,
                max_steps=scaled_opt_steps(opt_cfg.max_steps, self.horizon0, self.horizon),
            )
        obar = self._progress_bar(opt_cfg.max_steps, f"trial {k} policy opt")

        def on_step(i, c, s, lr):
            if obar is not None:
                obar.update(1)
                if i % 10 == 0:
                    J = c / config.num_candidates
                    obar.set_postfix(J=f"{J:.2f}", std=f"{s:.2f}", lr=f"{lr:.4f}")

        res = optimize_policy(
            loss,
            self.population,
            opt_cfg,
            on_step=on_step,
            success_level=self.success_level,
            num_candidates=config.num_candidates,
        )
        if obar is not None:
            obar.close()
        judged = self._choose_and_judge(loss, dynamics, res.snapshots, rec, arr)
        if judged is not None and config.opt.catch_restart and missed_catch(judged, self.task):
            reach, success = goal_fraction(judged, self.task), predicted_success(judged, self.task)
            seed = trial_seed(config.seed, k) + CATCH_RESTART_SEED
            self.population.reset_parameters(seed)  # a fresh draw, the first run's kept
            later = optimize_policy(
                loss,
                self.population,
                opt_cfg,
                success_level=self.success_level,
                num_candidates=config.num_candidates,
            )
            reason = f"reach {reach:.2f}, predicted success {success:.2f}"
            res.restarts.append(f"catch restart at step {res.num_steps}: {reason}")
            res.extend(later)
            judged = self._choose_and_judge(loss, dynamics, res.snapshots, rec, arr)
        rec.update(
            opt_steps=res.num_steps,
            opt_s=res.seconds,
            s_per_opt_step=res.seconds_per_step,
            cpu_s_per_opt_step=res.cpu_seconds_per_step,
            opt_stop=res.stop_reason,
            opt_lr_reductions=res.num_lr_reductions,
            opt_reinits=res.num_reinits,
            opt_restarts=len(res.restarts),
            opt_restart_reasons=list(res.restarts),
            opt_success_level=res.success_level,
            opt_final_cost=res.costs[-1] / config.num_candidates if res.costs else math.nan,
            opt_snapshot_every=res.snapshot_every,
        )
        # mean J^_k over candidates per step (J^ itself for one candidate)
        arr["opt_costs"] = np.asarray(res.costs, dtype=np.float32) / config.num_candidates

    def _choose_and_judge(
        self,
        loss: Any,
        dynamics: torch.nn.Module,
        snapshots: list[tuple[int, Any]],
        rec: TrialRecord,
        arr: dict[str, Any],
    ) -> np.ndarray | None:
        """Apply the candidate and snapshot with the lowest ``J^`` (:func:`choose_policy`),
        record the choice, predict its particles (plots) and return the particles its
        success and the next horizon are judged on (None where the task has neither)."""
        config = self.config
        t_choose = time.perf_counter()
        snap_costs, snap = choose_policy(loss, self.population, self.policy, snapshots)
        rec.choose_s = time.perf_counter() - t_choose
        cand_costs = snap_costs[snap]
        rec.update(
            candidate_costs=cand_costs.tolist(),
            chosen_candidate=int(cand_costs.argmin()),
            chosen_cost=float(cand_costs.min()),
            snapshot_steps=[step for step, _ in snapshots],
            snapshot_costs=snap_costs.min(1).values.tolist(),
            chosen_step=snapshots[snap][0],
        )
        self.policy.eval()  # particle predictions of the applied policy (for the plots)
        predict = self._loss(make_policy_module(self.policy), dynamics)
        with torch.no_grad():
            n_log = min(config.log_particles, config.num_particles)
            arr["particles"] = predict.rollout(num_particles=n_log).states.cpu().numpy()
            judged = None  # the particles the success and the next horizon are judged on
            if grows(self.task) or success_window(self.task) is not None:
                judged = (
                    arr["particles"]
                    if n_log >= PLAN_PARTICLES
                    else predict.rollout(num_particles=PLAN_PARTICLES).states.cpu().numpy()
                )
            if grows(self.task):
                arr["plan_particles"] = judged
        if success_window(self.task) is not None:
            rec.predicted_success = predicted_success(judged, self.task)
        return judged

    def apply_policy(self, k: int, rec: TrialRecord, arr: dict[str, Any]) -> list[dict[str, Any]]:
        """Apply the chosen policy (no dropout) to the system for ``H`` steps (episodes of
        the task's ``trial_steps`` steps in all, where the env ends one early); record the
        model's one-step error on the new transitions."""
        act = policy_act(self.policy)
        episodes = trial_episodes(
            self.env,
            lambda _n: act,
            trial_seed(self.config.seed, k),
            self.horizon,
            self.task,
            self.task.steps_per_trial,
            True,
        )
        free = transitions(episodes, self.task)
        rec.gp_rmse = (
            self.model.one_step_rmse(*free).tolist()
            if len(free[1])
            else [math.nan] * self.layout.output_dim
        )
        arr["gp_rmse"] = rec.gp_rmse
        return episodes

    def evaluate_policy(self, k: int, rec: TrialRecord) -> None:
        """With ``eval_episodes`` ``E``: ``E`` episodes of the applied policy, each started
        from the task's evaluation start (``eval_init``, else the env's own reset) and run
        for :func:`evaluation_steps` control steps (the env's full episode, which may be
        longer than the horizon the policy was optimised over), not added to ``D``; their
        success rate (the task's success test) goes to the record."""
        cfg = self.config
        if cfg.eval_episodes:
            act = policy_act(self.policy)
            rec.update(
                **evaluate(
                    self.eval_env,
                    act,
                    cfg.seed,
                    k,
                    cfg.eval_episodes,
                    self.task,
                    self.eval_steps,
                )
            )

    def plan_horizon(self, rec: TrialRecord, arr: dict[str, Any]) -> None:
        """The next trial's horizon (:mod:`~mcpilco.agents.mc_pilco.horizon`): judged on the
        applied policy's predicted particles (``arr["plan_particles"]``, set by
        :meth:`improve_policy` for a task whose horizon can grow), grown while fewer than
        :data:`~mcpilco.agents.mc_pilco.horizon.GOAL_FRACTION` of them reach the goal a
        success window before its end, up to the env's episode length; the record holds the
        horizon, the fraction and the next horizon."""
        states = arr.pop("plan_particles", None)
        if states is None:
            return
        fraction = goal_fraction(states, self.task)
        rec.update(
            horizon=self.horizon,
            goal_fraction=fraction,
            next_horizon=next_horizon(self.horizon, fraction, self.max_horizon),
        )

    def use_horizon(self, horizon: int) -> None:
        """Optimise and run the following trials over ``horizon`` steps: the task's horizon
        replaced, the plateau restarts' success level ``J_succ`` of that horizon, and the
        env's episodes that long."""
        config = self.config
        if self.log:
            self.log(
                f"horizon {self.horizon} -> {horizon} steps ({horizon * self.task.dt:.2f} s): "
                "too few predicted particles reach the goal a success window before its end"
            )
        self.task = self.task.replace(horizon=int(horizon))
        self.horizon = self.task.horizon
        if hasattr(self, "cost_fn"):  # J_succ of the new horizon (set_up computes it on resume)
            self.success_level = success_cost_level(
                self.task, self.cost_fn, self.config.window_objective
            )
        self.env.close()
        self.env = make_env(config.env_id, self.horizon, self.task, config.env_kwargs)

    def commit_trial(
        self,
        k: int,
        episodes: list[dict[str, Any]],
        rec: TrialRecord,
        arr: dict[str, Any],
        t0: float,
    ) -> None:
        """Add the trial's data (all its episodes) to ``D``, complete its record (the
        outcome of its first episode), write the plots and ``records.json``, then the
        checkpoint (last: it is the commit point of the trial)."""
        task = self.task
        marks = []  # per episode: the push filter's marks (None: no filter)
        for i, ep in enumerate(episodes):
            filtered = None if self.push_filter is None else self.push_filter.excluded(ep["infos"])
            marks.append(filtered)
            contact = contact_steps(ep.pop("infos"))
            if contact is not None:  # the env says when it was pushed (ground truth)
                rec.n_contact = (rec.n_contact or 0) + int(contact.sum())
                if i == 0:
                    arr["contact"] = contact
            if filtered is not None:
                rec.n_filtered = (rec.n_filtered or 0) + int(filtered.sum())
                if contact is not None:  # filtered transitions that overlap a push
                    both = int((filtered & contact).sum())
                    rec.n_filtered_contact = (rec.n_filtered_contact or 0) + both
            self.episodes.append({"obs": ep["obs"], "actions": ep["actions"], "filtered": filtered})
        episode, filtered = episodes[0], marks[0]  # the plots draw the first episode
        rec.update(**episode_outcome(episode, t0))
        rec.update(steps=sum(e["steps"] for e in episodes), episodes=len(episodes))
        # seconds of interaction so far (episodes that terminate early count what they ran)
        rec.experience_s = sum(len(e["actions"]) for e in self.episodes) * task.dt
        arr.update(real=episode["states"], cost=rec.cost, success=rec.success)
        excluded = (
            task.touches_limit(episode["obs"][:-1], episode["obs"][1:]) if task.limits else None
        )
        if filtered is not None:
            excluded = filtered | (False if excluded is None else excluded)
        arr.update(excluded=excluded, time_in_goal=rec.time_in_goal)
        self.records.append(rec)
        self.arrays.append(arr)
        if arr["particles"] is not None:
            self.pngs.append(
                plot_trial_particles(
                    self.out / f"trial_{k:02d}_particles.png",
                    arr["particles"],
                    episode["states"],
                    task.dt,
                    task.state_names,
                    title=f"trial {k}: particles (model) vs real, success={episode['success']}",
                    references=task.tracked_states(),
                    excluded=excluded,
                    contact=arr.get("contact"),
                )
            )
        self._write_outputs()
        self._save_checkpoint(k)
        self.run_folder.record(*RUN_OUTPUTS)  # the manifest lists every file written so far
        if self.log:
            self.log(record_line(rec))

    def summary(self, seconds: float) -> RunSummary:
        """The run's records and output files."""
        pngs = self.pngs or sorted(self.out.glob("trial_*_particles.png"))
        opt_png = self.out / "optimisation.png"
        return RunSummary(
            config=self.config.to_dict(),
            records=[r.to_dict() for r in self.records],
            out_dir=self.out,
            checkpoint=self.checkpoint_path,
            rrd=(self.out / "run.rrd") if self.write_rrd else None,
            pngs=pngs + ([opt_png] if opt_png.exists() else []),
            seconds=seconds,
            resumed_from_trial=self.resumed_from,
        )

    # --------------------------------------------------------------------- the details
    def _set_up_task(self) -> None:
        """Device, threads, the task (the config's horizon replaces the task's)."""
        config = self.config
        self.device = resolve_device(config.device)
        if config.compile_rollout:
            check_compile_toolchain(self.device, config.rollout_backend)
        if config.torch_threads is not None:
            torch.set_num_threads(int(config.torch_threads))
        if self.task is None:
            self.task = config.task_spec()
        elif config.horizon is not None and config.horizon != self.task.horizon:
            self.task = self.task.replace(horizon=int(config.horizon))
        self.horizon = self.horizon0 = self.task.horizon
        if config.explore_steps is not None and config.explore_steps > self.horizon:
            raise ValueError(
                f"explore_steps ({config.explore_steps}) exceeds the horizon ({self.horizon} steps)"
            )

    def _set_up_parts(self) -> None:
        """Push filter, seeded generators, candidate policies, the GP dynamics model."""
        config, task = self.config, self.task
        self.layout = StateLayout.from_task(task)
        self.push_filter = None
        if config.push_filter is not None:
            if not task.joints:
                raise ValueError("push_filter needs an arm task (task.joints)")
            self.push_filter = CollisionFilter(
                config.push_filter,
                len(task.joints),
                task.dt / task.action_repeat,
                config.push_filter_margin,
            )
        torch.manual_seed(config.seed)
        self.np_rng = np.random.default_rng(config.seed)
        candidates = policy_candidates(config, task, self.layout)
        self.policy = candidates[0].to(self.device)  # the policy applied (the chosen one)
        self.population = PolicyPopulation(candidates).to(self.device)
        self.policy_module = make_policy_module(self.population)
        self.model = dynamics_model(config, task)

    def _load_checkpoint(self) -> None:
        """Continue after the checkpoint's last trial (same data, policy, GP, RNG states)."""
        ckpt = load_checkpoint(self.checkpoint_path)
        check_resume(ckpt["config"], self.config, RESUME_FIXED)
        self.episodes = ckpt["episodes"]
        self.records = [TrialRecord.from_dict(r) for r in ckpt["records"]]
        self.arrays = ckpt["arrays"]
        restore_state(self.policy, ckpt["policy"], "policy", self.checkpoint_path)
        restore_state(
            self.population, ckpt["population"], "policy population", self.checkpoint_path
        )
        if ckpt["gp_file"] is not None:
            self.model.load(self.out / ckpt["gp_file"])
        set_rng_state(ckpt["rng"], self.np_rng)
        self.start_trial = self.resumed_from = int(ckpt["next_trial"])
        grown = self.records[-1].next_horizon if self.records else None
        if grown is not None and grown != self.horizon:  # the horizon the run had grown to
            self.use_horizon(int(grown))
        if self.log:
            self.log(f"resumed {self.checkpoint_path}: trials 0..{self.start_trial - 1} done")

    def _loss(self, module: torch.nn.Module, dynamics: torch.nn.Module) -> MCPilcoLoss:
        """The particle estimate ``J^`` of the policy ``module`` under ``dynamics``."""
        config, task = self.config, self.task
        return MCPilcoLoss(
            module,
            dynamics,
            self.cost_fn,
            horizon=self.horizon,
            num_particles=config.num_particles,
            init_mean=task.init_mean,
            init_std=self.init_std,
            obs_noise_std=config.sim_obs_noise_std,
            termination=TerminationSet.from_task(task),
            success_window=success_window(task) if config.window_objective else None,
        ).to(self.device)  # with the policy module and the dynamics in it

    def _progress_bar(self, total: int, desc: str | None = None):
        """A tqdm bar (None without ``progress``): over trials, or an optimisation's steps."""
        if not self.progress:
            return None
        from tqdm.auto import tqdm

        if desc is None:
            return tqdm(
                total=total, initial=min(self.start_trial, total), desc="trials", unit="trial"
            )
        return tqdm(total=total, desc=desc, leave=False)

    def _write_outputs(self) -> None:
        """The optimisation plot, the Rerun recording and ``records.json``."""
        task = self.task
        curves = [
            (a["opt_costs"], f"trial {a['index']}")
            for a in self.arrays
            if a["opt_costs"] is not None
        ]
        if curves:
            plot_optimisation(
                self.out / "optimisation.png", [c for c, _ in curves], [n for _, n in curves]
            )
        if self.write_rrd:
            write_rerun_recording(
                self.out / "run.rrd",
                self.arrays,
                task.dt,
                task.state_names,
                task.gp_output_names(),
                references=task.tracked_states(),
            )
        write_records(self.out, self.config, self.records)

    def _save_checkpoint(self, k: int) -> None:
        """The GP file, then the checkpoint of trials ``0 .. k``; older GP files removed."""
        gp_file = None
        if self.model.gp_ is not None:
            gp_file = f"gp_trial{k:02d}.pt"
            self.model.save(self.out / gp_file)
        save_checkpoint(
            self.checkpoint_path,
            self.config,
            k + 1,
            episodes=self.episodes,
            records=[r.to_dict() for r in self.records],
            arrays=self.arrays,
            policy=self.policy.state_dict(),
            policy_settings=self.policy.settings(),
            population=self.population.state_dict(),
            optimizer=None,  # Adam restarts at each trial (MC-PILCO): no state to keep
            gp_file=gp_file,
            rng=rng_state(self.np_rng),
        )
        for old_gp in self.out.glob("gp_trial*.pt"):
            if old_gp.name != gp_file:
                old_gp.unlink(missing_ok=True)


class _CostFn(torch.nn.Module):
    """A task's plain cost function as a module."""

    def __init__(self, task: TaskSpec) -> None:
        super().__init__()
        self.fn = task.cost_fn

    def forward(self, state: torch.Tensor) -> torch.Tensor:
        return self.fn(state)


def policy_candidates(
    config: MCPilcoConfig, task: TaskSpec, layout: StateLayout
) -> list[SquashedRBFPolicy]:
    """The ``K`` candidate policies of a run (``config.num_candidates``), candidate ``k``
    with initial weight scale ``s_k`` and seed ``seed + CANDIDATE_SEED_STRIDE k``; with a
    linear feedback term around the task's regulation point where ``config.policy_linear``
    says so (None: for a regulation task, :func:`regulation_point`, and a catch,
    :func:`catch_point`)."""
    scales = config.candidate_weight_scales or [config.policy_weight_scale] * config.num_candidates
    ref = linear_reference(config, task)
    return [
        SquashedRBFPolicy(
            layout,
            task.action_low,
            task.action_high,
            num_basis=config.num_basis,
            centers_box=config.policy_centers_box,
            weight_scale=scale,
            seed=config.seed + CANDIDATE_SEED_STRIDE * k,
            linear_ref=None if ref is None else [float(v) for v in task.features(ref)],
        )
        for k, scale in enumerate(scales)
    ]


def _target_state(task: TaskSpec) -> np.ndarray:
    """The task's initial mean with each cost term's state at its target (a term that
    tracks another state leaves it as is): the point the cost pulls the state to."""
    x = np.asarray(task.init_mean, dtype=np.float64).copy()
    for term in task.cost_terms:
        if term.reference is None:
            x[task.index(term.state)] = term.target
    return x


def linear_reference(config: MCPilcoConfig, task: TaskSpec) -> np.ndarray | None:
    """The state ``x*`` the policy's linear feedback term acts around, or None for a policy
    without one: ``config.policy_linear`` None derives it (:func:`regulation_point`, else
    :func:`catch_point`), true takes the point the cost pulls the state to, false has none."""
    if config.policy_linear is None:
        x_star = regulation_point(task)
        return catch_point(task) if x_star is None else x_star
    return _target_state(task) if config.policy_linear else None


def regulation_point(task: TaskSpec) -> np.ndarray | None:
    """The state ``x*`` a regulation task holds, or None when ``task`` is no regulation
    task.

    A regulation task starts inside the set it must stay in for the whole episode: its
    success is ``full_horizon`` and the initial mean lies in its goal box (``success.bounds``,
    else the ``termination`` box), as a balance from upright. Its policy needs a feedback
    that is near linear around the point the cost pulls the state to (the initial mean with
    the cost terms at their targets), the linear feedback term of the policy
    (:mod:`~mcpilco.agents.mc_pilco.policy`). A swing-up (its start outside the goal) or a
    task judged at its end is none."""
    s = task.success
    if not s.full_horizon:
        return None
    box = {k: (b.target - b.tol, b.target + b.tol) for k, b in s.bounds.items()}
    box = box or dict(task.termination)
    if not box:
        return None
    x0 = np.asarray(task.init_mean, dtype=np.float64)
    if not all(lo <= x0[task.index(k)] <= hi for k, (lo, hi) in box.items()):
        return None
    return _target_state(task)


def catch_point(task: TaskSpec) -> np.ndarray | None:
    """The state ``x*`` a swing-up must end held at, where its policy gets a gated linear
    feedback term (a catch, :mod:`~mcpilco.agents.mc_pilco.policy`), or None.

    A catch task's success is a goal held over a window from a start outside it
    (:func:`~mcpilco.agents.mc_pilco.horizon.grows`; not a regulation task,
    :func:`regulation_point`), and it has an action per position coordinate (``len(pairs)``
    actions or more: fully actuated, as a pendulum with a motor at its hinge). Holding such
    a goal is a near-linear feedback around the point the cost pulls the state to; a motor
    too weak to hold the pole a few degrees from upright must arrive slowly and then hold,
    which the gated linear term started at the model's LQR gives the optimisation from the
    first step. An underactuated swing-up (a cart-pole: one force, two positions) keeps the
    RBF policy alone."""
    if not grows(task) or regulation_point(task) is not None:
        return None
    if not task.pairs or len(task.action_low) < len(task.pairs):
        return None
    return _target_state(task)


def dynamics_model(config: MCPilcoConfig, task: TaskSpec) -> GPDynamicsModel:
    """The GP dynamics model of a run, with the config's kernel, subset size and fit."""
    return GPDynamicsModel(
        task,
        kernel=config.kernel,
        max_points=config.max_points,
        adam_iters=config.gp_adam_iters,
        lbfgs_iters=config.gp_lbfgs_iters,
        noise_min=config.gp_noise_min,
        min_lengthscale=config.gp_min_lengthscale,
        mpk_degree=config.mpk_degree,
    )


def evaluation_steps(task: TaskSpec, env: Any) -> int:
    """Control steps of an evaluation episode: the task's ``eval_steps``, else the env's own
    episode length (its registered ``max_episode_steps``, or an adapter's own limit such as
    dm-control's time limit, :attr:`mcpilco.envs.dmc.DMControlEnv.episode_limit`) in
    control steps of ``action_repeat`` env steps, else the horizon."""
    if task.eval_steps is not None:
        return int(task.eval_steps)
    import gymnasium as gym

    spec = getattr(env, "spec", None)  # the made env's spec holds the horizon's limit
    own = gym.spec(spec.id).max_episode_steps if spec is not None else None
    if own is None:
        own = getattr(env.unwrapped, "episode_limit", None)
    return task.horizon if own is None else max(1, int(own) // task.action_repeat)


def initial_std(config: MCPilcoConfig, task: TaskSpec, layout: StateLayout) -> np.ndarray:
    """``sigma_0`` per state of the initial particles (0 on a known reference)."""
    init_std = np.broadcast_to(
        np.asarray(task.init_std if config.init_std is None else config.init_std, float),
        (task.state_dim,),
    ).copy()
    init_std[list(layout.oscillator_idx)] = 0.0  # a known reference starts on it
    return init_std


def optimised_cost(config: MCPilcoConfig, task: TaskSpec) -> torch.nn.Module:
    """The cost the policy optimisation minimises: the task's cost function, or its
    saturating cost terms with the config's length scales, angle mode and barriers."""
    if task.cost_fn is not None:
        if config.cost_limit_widths:
            raise ValueError(
                "cost_limit_widths adds barriers to the task's cost terms; the task has a "
                "cost function instead (put the barrier in it)"
            )
        return task.cost_fn if isinstance(task.cost_fn, torch.nn.Module) else _CostFn(task)
    return SaturatingCost.from_task(
        task, config.cost_length_scales, config.cost_angle_mode, config.cost_limit_widths
    )


MAX_GOAL_CORNERS = 4096  # corners of a goal box evaluated by success_cost_level (2^12)


@torch.no_grad()
def success_cost_level(
    task: TaskSpec, cost: Callable[[torch.Tensor], torch.Tensor], window_objective: bool = False
) -> float | None:
    """``J_succ``: the largest cumulative cost ``cost`` gives a trajectory that succeeds on
    ``task`` and is never costlier than its start before it reaches the goal (the level of
    the optimiser's plateau restarts, :mod:`~mcpilco.agents.mc_pilco.optimize`).

    A success keeps the state in the goal box ``G`` (``success.bounds``: each bounded state
    within ``target +- tol``; for a ``full_horizon`` task without bounds, the
    ``termination`` box) for the last ``W`` steps (``success.window``; all ``H`` steps for
    a ``full_horizon`` task), and before them moves from the initial state ``x_0`` (the
    task's ``init_mean``) towards it. With ``c_G`` the largest cost on ``G`` (at its
    corners, the unbounded coordinates at ``x_0``; the cost terms rise away from their
    targets) and ``c_0 = c(x_0)``::

        J_succ = (H - W) max(c_0, c_G) + W c_G

    With ``window_objective`` (the objective ``J^_W`` counts a final success window twice,
    :mod:`~mcpilco.agents.mc_pilco.loss`) and a task that has such a window
    (:func:`~mcpilco.agents.mc_pilco.horizon.success_window`), ``W c_G`` more.

    A plateau above it is a trajectory that stays costlier than its start for the whole
    approach or misses the goal at the end. None where the task's success set is no box
    (an ``info`` flag or a tracking bound only): then nothing restarts.
    """
    s = task.success
    box = {k: (b.target - b.tol, b.target + b.tol) for k, b in s.bounds.items()}
    if not box and s.full_horizon:
        box = dict(task.termination)
    if not box or 2 ** len(box) > MAX_GOAL_CORNERS:
        return None
    x0 = torch.as_tensor(np.asarray(task.init_mean, dtype=np.float64), dtype=torch.float32)
    corners = x0.repeat(2 ** len(box), 1)
    for j, (name, (lo, hi)) in enumerate(box.items()):
        upper = (torch.arange(len(corners)) >> j) & 1
        corners[:, task.index(name)] = torch.where(upper.bool(), hi, lo)
    c_goal = float(cost(corners).max())
    c_start = float(cost(x0[None])[0])
    h = task.horizon
    w = h if s.full_horizon or s.window is None else min(int(s.window), h)
    again = w * c_goal if window_objective and success_window(task) is not None else 0.0
    return (h - w) * max(c_start, c_goal) + w * c_goal + again


def check_compile_toolchain(device: torch.device, backend: str = "auto") -> None:
    """Raise ValueError when ``compile_rollout`` with ``backend`` cannot work here: the
    native rollout and inductor's CPU backend build C++ (``$CXX``, else ``g++`` or
    ``clang++`` on ``PATH``); the torch backend needs none. Checked before any trial runs,
    so that a missing compiler does not stop the run inside its first policy trial."""
    if device.type != "cpu" or backend == "torch":
        return
    if cpp_compiler() is None:
        names = cpp_compiler_names()
        raise ValueError(
            f"compile_rollout on the CPU needs a C++ compiler ({' or '.join(names)} not found "
            "on PATH): install one (e.g. apt install g++), set CXX, use the torch backend "
            "(--set rollout_backend=torch), or run without --compile-rollout"
        )


def check_dynamics_task(task: TaskSpec) -> None:
    """Raise ``ValueError`` for a task on which MC-PILCO learns kinematics, not dynamics
    (``TaskSpec.model``): the trainer cannot run it."""
    if task.model != "dynamics":
        raise ValueError(
            f"{task.env_id}: MC-PILCO learns the {task.model} on this task, not GP dynamics; "
            "run it with mcpilco-bench-kinematics --reaching-seeds (mcpilco.agents.mc_pilco."
            "reaching), and compare with mcpilco-compare --mcpilco-json "
            "results/kinematics_reaching.json"
        )


def run_mcpilco(config: MCPilcoConfig, out_dir: str | Path, **options: Any) -> RunSummary:
    """``Trainer(config, out_dir, **options).run()``: run (or resume) MC-PILCO."""
    return Trainer(config, out_dir, **options).run()

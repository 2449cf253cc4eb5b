"""Budgets derived from the task: particles ``M``, optimisation steps ``S`` and GP size
``N_max`` chosen so that a run of a new env fits a time budget on two CPU cores.

Cost model of one policy-optimisation step (a rollout of ``J^`` and its gradient)::

    t_step(M, N) = H (c_H + E M (c_0 + c_1 N D))   [s]

with ``H`` the horizon, ``E`` the GP outputs, ``D`` the GP input size (state features and
actions) and ``N`` the GP's training points: per time step a fixed part that does not
grow with the particles (the op-by-op dispatch of the rollout, ``c_H``), and per particle
and output a fixed part (the policy, the features, the sampling, ``c_0``) and a part
linear in ``N D`` (the cross-kernel ``k(x, X)`` and its products, ``c_1``). The ``N^2`` terms of
the variance (``k^T K^-1 k``) are left out at these sizes. The constants are measured, not
assumed: :func:`fit_step_constants` fits them (non-negative least squares on relative
error) to the CPU seconds per step timed on several task specs, particle counts and GP
sizes (the eager rollout on one thread, as a run's worker has it); ``mcpilco-bench-budget``
re-runs the measurement and writes the rows, the fit and the machine's load to
``results/mcpilco_budget.md``, whose fit the constants below are. CPU seconds grow on a
machine busy with other work (shared caches and memory bandwidth); the results file says
how busy it was.

With ``N_k = min(N_max, k T)`` points before policy trial ``k`` (``T`` steps per trial), the
optimisation of ``K`` trials takes ``sum_k S t_step(M, N_k)``. Starting from the thesis's
budget (``M = 400``, ``S = 1500``, ``N_max = 300``), ``M`` and ``S`` are scaled down by the
same factor ``f`` (the largest, found by bisection: with the fixed part ``c_H`` the time is
not proportional to ``M S``) until that sum fits :data:`OPT_TIME_BUDGET_S` (no lower than
:data:`MIN_PARTICLES`, :data:`MIN_OPT_STEPS`), then ``N_max`` is lowered (no lower than
:data:`MIN_POINTS`) if it still does not fit: the model's data are the last thing given
up. :data:`OPT_TIME_BUDGET_S` is the
optimisation's share of :data:`RUN_TIME_BUDGET_S`, a 5-trial run on two cores; the rest is
the GP fits, the env and the plots. :func:`shipped_budgets` checks every shipped task file
against it.

A run may grow its horizon over trials (:mod:`.horizon`): a trial over ``H_k > H`` runs
``S H / H_k`` optimisation steps, which take the seconds of ``S`` steps over ``H`` because
``t_step`` is linear in ``H``; only the GP points come sooner (the longer trials give more
data). :func:`grown_run_seconds` bounds such a run by ``N = N_max`` in every trial.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from mcpilco.agents.mc_pilco.horizon import grows
from mcpilco.envs.tasks.spec import TaskSpec

CH_S = 1.44e-3  # c_H [s] per time step (fit_step_constants; results/mcpilco_budget.md)
C0_S = 0.0  # c_0 [s] per particle, time step and GP output (the fit gives 0)
C1_S = 3.09e-9  # c_1 [s] per particle, time step, GP output and training point x input
RUN_TIME_BUDGET_S = 900.0  # a run of 5 policy trials of a new env on two cores: 15 minutes
OPT_TIME_BUDGET_S = 600.0  # the optimisation's share of RUN_TIME_BUDGET_S
BUDGET_TRIALS = 5  # policy trials the budget is sized for
DEFAULT_PARTICLES, DEFAULT_OPT_STEPS, DEFAULT_POINTS = 400, 1500, 300  # thesis 5.5.1
MIN_PARTICLES, MIN_OPT_STEPS, MIN_POINTS = 50, 200, 50  # the least a run is given


@dataclass(frozen=True)
class Budget:
    """A derived budget: ``num_particles`` ``M``, ``opt_steps`` ``S`` (``opt.max_steps``),
    ``max_points`` ``N_max``, and ``predicted_s``, the optimisation's predicted seconds over
    :data:`BUDGET_TRIALS` trials."""

    num_particles: int
    opt_steps: int
    max_points: int
    predicted_s: float


def model_seconds(
    particles: float,
    horizon: float,
    outputs: float,
    inputs: float,
    points: float,
    constants: tuple[float, float, float] | None = None,
) -> float:
    """``t_step = H (c_H + E M (c_0 + c_1 N D))`` with ``constants`` ``(c_H, c_0, c_1)``
    (None: the module's :data:`CH_S`, :data:`C0_S`, :data:`C1_S`)."""
    ch, c0, c1 = (CH_S, C0_S, C1_S) if constants is None else constants
    return horizon * (ch + outputs * particles * (c0 + c1 * points * inputs))


def step_seconds(task: TaskSpec, particles: int, points: int) -> float:
    """``t_step(M, N)`` of the module's cost model for ``task``."""
    e = len(task.output_idx)
    d = task.feature_dim + task.action_dim
    return model_seconds(particles, task.horizon, e, d, points)


def run_seconds(task: TaskSpec, particles: int, steps: int, max_points: int) -> float:
    """Predicted optimisation seconds of :data:`BUDGET_TRIALS` policy trials."""
    per_trial = task.steps_per_trial
    return sum(
        steps * step_seconds(task, particles, min(max_points, k * per_trial))
        for k in range(1, BUDGET_TRIALS + 1)
    )


def grown_run_seconds(task: TaskSpec, particles: int, steps: int, max_points: int) -> float:
    """Predicted optimisation seconds of :data:`BUDGET_TRIALS` policy trials whose horizon
    grows (module docstring): at most ``K S t_step(M, N_max)``."""
    return BUDGET_TRIALS * steps * step_seconds(task, particles, max_points)


def derive_budget(task: TaskSpec, seconds: float = OPT_TIME_BUDGET_S) -> Budget:
    """The budget of ``task`` (module docstring) for ``seconds`` of optimisation."""
    n = DEFAULT_POINTS

    def scaled(f: float) -> tuple[int, int]:  # M, S at factor f (rounded down, floored)
        m = max(MIN_PARTICLES, int(DEFAULT_PARTICLES * f) // 10 * 10)
        return m, max(MIN_OPT_STEPS, int(DEFAULT_OPT_STEPS * f) // 50 * 50)

    lo, hi = 0.0, 1.0
    if run_seconds(task, *scaled(hi), n) <= seconds:
        lo = hi
    for _ in range(30):  # the largest f whose budget fits (bisection)
        if lo == hi:
            break
        mid = (lo + hi) / 2.0
        lo, hi = (mid, hi) if run_seconds(task, *scaled(mid), n) <= seconds else (lo, mid)
    m, s = scaled(lo)
    while n > MIN_POINTS and run_seconds(task, m, s, n) > seconds:
        n -= 10
    return Budget(m, s, n, run_seconds(task, m, s, n))


def fit_step_constants(rows: Sequence[Mapping[str, float]]) -> tuple[float, float, float]:
    """``(c_H, c_0, c_1)`` of ``t_step = H (c_H + E M (c_0 + c_1 N D))`` fitted to measured
    steps: each row holds ``particles`` ``M``, ``horizon`` ``H``, ``outputs`` ``E``,
    ``inputs`` ``D``, ``points`` ``N`` and ``seconds`` (per step). Non-negative least
    squares on the relative error ``(t_model - t) / t``, so that small and large steps weigh
    alike.

    Raises:
        ValueError: fewer than three rows, or rows that cannot tell the three constants
            apart (one particle count, or one ``N D``).
    """
    from scipy.optimize import nnls

    if len(rows) < 3:
        raise ValueError(f"fit_step_constants needs at least three rows, got {len(rows)}")
    a = np.array(
        [
            [
                1.0,
                r["outputs"] * r["particles"],
                r["outputs"] * r["particles"] * r["points"] * r["inputs"],
            ]
            for r in rows
        ],
        dtype=np.float64,
    )
    a *= np.array([r["horizon"] for r in rows], dtype=np.float64)[:, None]
    t = np.array([r["seconds"] for r in rows], dtype=np.float64)
    if np.linalg.matrix_rank(a / t[:, None]) < 3:
        raise ValueError(
            "fit_step_constants needs rows with two particle counts and two values of N D"
        )
    c, _ = nnls(a / t[:, None], np.ones(len(t)))
    return float(c[0]), float(c[1]), float(c[2])


def shipped_budgets() -> list[dict[str, Any]]:
    """The derived budget of every shipped task file that learns dynamics
    (:func:`mcpilco.envs.tasks.task_ids`), with the predicted optimisation seconds of
    :data:`BUDGET_TRIALS` trials, whether they fit :data:`OPT_TIME_BUDGET_S` (a budget
    already at its floors may not: ``at_floor``), and their bound when the horizon grows
    (``grown_s``, :func:`grown_run_seconds`; None for a task whose horizon stays: no goal
    held over a window, or an episode no longer than the horizon)."""
    from mcpilco.envs.tasks import task_ids

    out = []
    for env_id in task_ids():
        task = TaskSpec.for_env(env_id)
        if task.model != "dynamics":
            continue
        b = derive_budget(task)
        out.append(
            {
                "env_id": env_id,
                "states": task.state_dim,
                "actions": task.action_dim,
                "outputs": len(task.output_idx),
                "horizon": task.horizon,
                "num_particles": b.num_particles,
                "opt_steps": b.opt_steps,
                "max_points": b.max_points,
                "predicted_s": b.predicted_s,
                "grown_s": grown_run_seconds(task, b.num_particles, b.opt_steps, b.max_points)
                if grows(task) and _episode_steps(task) > task.horizon
                else None,
                "fits": b.predicted_s <= OPT_TIME_BUDGET_S,
                "at_floor": (b.num_particles, b.opt_steps, b.max_points)
                == (MIN_PARTICLES, MIN_OPT_STEPS, MIN_POINTS),
            }
        )
    return out


def _episode_steps(task: TaskSpec) -> float:
    """Control steps of the task's evaluation episodes as far as known without making the
    env (``eval_steps``, else the registered ``max_episode_steps``; inf where neither says):
    the most its horizon may grow to."""
    import gymnasium as gym

    if task.eval_steps is not None:
        return float(task.eval_steps)
    try:
        steps = gym.spec(task.env_id).max_episode_steps
    except gym.error.Error:
        steps = None
    return math.inf if steps is None else float(steps // task.action_repeat)


def budget_line(task: TaskSpec, budget: Budget, overridden: dict[str, int]) -> str:
    """One line saying what was derived and from what, and what a config overrode."""
    line = (
        f"budget: {budget.num_particles} particles, {budget.opt_steps} opt steps, "
        f"N <= {budget.max_points} GP points (derived from {task.state_dim} states, "
        f"{task.action_dim} action{'s' if task.action_dim > 1 else ''}, "
        f"{len(task.output_idx)} GP outputs, horizon {task.horizon}: about "
        f"{budget.predicted_s / 60:.0f} min of optimisation for {BUDGET_TRIALS} trials by the "
        f"measured step-time model, within the {OPT_TIME_BUDGET_S / 60:.0f} of a "
        f"{RUN_TIME_BUDGET_S / 60:.0f}-minute run on 2 cores"
        f"{'' if budget.predicted_s <= OPT_TIME_BUDGET_S else ' NOT met even at the floors'}; "
        "set num_particles=..., opt.max_steps=..., max_points=... to override)"
    )
    if overridden:
        line += "; the config sets " + ", ".join(f"{k}={v}" for k, v in overridden.items())
    return line

"""Budgets derived from the task: particles ``M``, optimisation steps ``S`` and GP size
``N_max`` chosen so that a run of a new env fits a time budget on two CPU cores.

Cost model of one policy-optimisation step (a rollout of ``J^`` and its gradient)::

    t_step(M, N) = M H E (c_0 + c_1 N D)   [s]

with ``H`` the horizon, ``E`` the GP outputs, ``D`` the GP input size (state features and
actions) and ``N`` the GP's training points: per particle, step and output the posterior
mean and variance cost a fixed part (the policy, the features, the sampling) and a part
linear in ``N D`` (the cross-kernel ``k(x, X)`` and its products). The ``N^2`` terms of the
variance (``k^T K^-1 k``) are left out at these sizes. The constants ``c_0``, ``c_1`` are
measured, not assumed: :func:`fit_step_constants` fits them by least squares on relative
error to CPU seconds per step timed on several tasks, particle counts and GP sizes (the
eager rollout on one thread, as a run's worker has it); ``mcpilco-bench-budget`` re-runs
the measurement and writes the numbers and the fit to ``results/mcpilco_budget.md``. The
model predicts the CPU time of an unloaded core; on a machine loaded by other work a step
takes longer in wall-clock time.

With ``N_k = min(N_max, k T)`` points before policy trial ``k`` (``T`` steps per trial), the
optimisation of ``K`` trials takes ``sum_k S t_step(M, N_k)``. Starting from the thesis's
budget (``M = 400``, ``S = 1500``, ``N_max = 300``), ``M`` and ``S`` are scaled down by the
same factor until that sum fits :data:`OPT_TIME_BUDGET_S` (no lower than
:data:`MIN_PARTICLES`, :data:`MIN_OPT_STEPS`), then ``N_max`` is lowered (no lower than
:data:`MIN_POINTS`) if it still does not fit. :data:`OPT_TIME_BUDGET_S` is the
optimisation's share of :data:`RUN_TIME_BUDGET_S`, a 5-trial run on two cores; the rest is
the GP fits, the env and the plots. :func:`shipped_budgets` checks every shipped task file
against it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from mcpilco.envs.tasks.spec import TaskSpec

C0_S = 1.6e-6  # c_0 [s] per particle, step and GP output (fit_step_constants; results/)
C1_S = 1.9e-9  # c_1 [s] per particle, step, GP output and training point x input
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


def step_seconds(task: TaskSpec, particles: int, points: int) -> float:
    """``t_step(M, N)`` of the module's cost model for ``task``."""
    e = len(task.output_idx)
    d = task.feature_dim + task.action_dim
    return particles * task.horizon * e * (C0_S + C1_S * points * d)


def run_seconds(task: TaskSpec, particles: int, steps: int, max_points: int) -> float:
    """Predicted optimisation seconds of :data:`BUDGET_TRIALS` policy trials."""
    per_trial = task.steps_per_trial
    return sum(
        steps * step_seconds(task, particles, min(max_points, k * per_trial))
        for k in range(1, BUDGET_TRIALS + 1)
    )


def derive_budget(task: TaskSpec, seconds: float = OPT_TIME_BUDGET_S) -> Budget:
    """The budget of ``task`` (module docstring) for ``seconds`` of optimisation."""
    m, s, n = DEFAULT_PARTICLES, DEFAULT_OPT_STEPS, DEFAULT_POINTS
    f = math.sqrt(seconds / run_seconds(task, m, s, n))
    if f < 1.0:
        m = max(MIN_PARTICLES, int(m * f) // 10 * 10)
        s = max(MIN_OPT_STEPS, int(s * f) // 50 * 50)
    while n > MIN_POINTS and run_seconds(task, m, s, n) > seconds:
        n -= 10
    return Budget(m, s, n, run_seconds(task, m, s, n))


def fit_step_constants(rows: Sequence[Mapping[str, float]]) -> tuple[float, float]:
    """``(c_0, c_1)`` of ``t_step = M H E (c_0 + c_1 N D)`` fitted to measured steps:
    each row holds ``particles`` ``M``, ``horizon`` ``H``, ``outputs`` ``E``, ``inputs``
    ``D``, ``points`` ``N`` and ``seconds`` (per step). Least squares on the relative
    error ``(t_model - t) / t``, so that small and large steps weigh alike.

    Raises:
        ValueError: fewer than two rows, or rows that do not tell ``c_0`` from ``c_1``
            (one ``N D`` only).
    """
    if len(rows) < 2:
        raise ValueError(f"fit_step_constants needs at least two rows, got {len(rows)}")
    a = np.array(
        [[r["particles"] * r["horizon"] * r["outputs"]] * 2 for r in rows],
        dtype=np.float64,
    )
    a[:, 1] *= np.array([r["points"] * r["inputs"] for r in rows], dtype=np.float64)
    t = np.array([r["seconds"] for r in rows], dtype=np.float64)
    if np.linalg.matrix_rank(a / t[:, None]) < 2:
        raise ValueError("fit_step_constants needs rows with at least two values of N D")
    c, *_ = np.linalg.lstsq(a / t[:, None], np.ones(len(t)), rcond=None)
    return float(c[0]), float(c[1])


def shipped_budgets() -> list[dict[str, Any]]:
    """The derived budget of every shipped task file that learns dynamics
    (:func:`mcpilco.envs.tasks.task_ids`), with the predicted optimisation seconds of
    :data:`BUDGET_TRIALS` trials and whether they fit :data:`OPT_TIME_BUDGET_S` (a budget
    already at its floors may not: ``at_floor``)."""
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
                "fits": b.predicted_s <= OPT_TIME_BUDGET_S,
                "at_floor": (b.num_particles, b.opt_steps, b.max_points)
                == (MIN_PARTICLES, MIN_OPT_STEPS, MIN_POINTS),
            }
        )
    return out


def budget_line(task: TaskSpec, budget: Budget, overridden: dict[str, int]) -> str:
    """One line saying what was derived and from what, and what a config overrode."""
    line = (
        f"budget: {budget.num_particles} particles, {budget.opt_steps} opt steps, "
        f"N <= {budget.max_points} GP points (derived from {task.state_dim} states, "
        f"{task.action_dim} action{'s' if task.action_dim > 1 else ''}, "
        f"{len(task.output_idx)} GP outputs, horizon {task.horizon}: about "
        f"{budget.predicted_s / 60:.0f} min of optimisation for {BUDGET_TRIALS} trials on an "
        f"idle core, within the {OPT_TIME_BUDGET_S / 60:.0f} of a "
        f"{RUN_TIME_BUDGET_S / 60:.0f}-minute run on 2 cores"
        f"{'' if budget.predicted_s <= OPT_TIME_BUDGET_S else ' NOT met even at the floors'}; "
        "set num_particles=..., opt.max_steps=..., max_points=... to override)"
    )
    if overridden:
        line += "; the config sets " + ", ".join(f"{k}={v}" for k, v in overridden.items())
    return line

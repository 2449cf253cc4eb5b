"""Budgets derived from the task: particles ``M``, optimisation steps ``S`` and GP size
``N_max`` chosen so that a run of a new env fits a time budget on two CPU cores.

Cost model of one policy-optimisation step (a rollout of ``J^`` and its gradient)::

    t_step(M, N) = M H E (c_0 + c_1 N D)   [s]

with ``H`` the horizon, ``E`` the GP outputs, ``D`` the GP input size (state features and
actions) and ``N`` the GP's training points: per particle, step and output the posterior
mean and variance cost a fixed part (the policy, the features, the sampling) and a part
linear in ``N D`` (the cross-kernel ``k(x, X)`` and its products). The constants are
calibrated on the cart-pole swing-up (``M = 400``, ``H = 60``, ``E = 2``, ``D = 6``, the
eager rollout, one thread): its mean seconds per step were 0.107, 0.131, 0.164, 0.203 s at
``N = 60, 120, 180, 240`` points (trials 1-4 of 20 seeds), a straight line in ``N`` whose
slope and intercept give ``c_1`` and ``c_0``. The ``N^2`` terms of the variance
(``k^T K^-1 k``) did not show at these sizes and are left out. On a machine loaded by other
work a step takes several times longer (the same cart-pole step measured 2.0 s at a load of
13 on two cores): the model predicts an unloaded machine.

With ``N_k = min(N_max, k T)`` points before policy trial ``k`` (``T`` steps per trial), the
optimisation of ``K`` trials takes ``sum_k S t_step(M, N_k)``. Starting from the thesis's
budget (``M = 400``, ``S = 1500``, ``N_max = 300``), ``M`` and ``S`` are scaled down by the
same factor until that sum fits :data:`OPT_TIME_BUDGET_S` (no lower than
:data:`MIN_PARTICLES`, :data:`MIN_OPT_STEPS`), then ``N_max`` is lowered (no lower than
:data:`MIN_POINTS`) if it still does not fit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from mcpilco.envs.tasks.spec import TaskSpec

C0_S = 1.6e-6  # c_0 [s] per particle, step and GP output (cart-pole calibration above)
C1_S = 1.9e-9  # c_1 [s] per particle, step, GP output and training point x input
OPT_TIME_BUDGET_S = 600.0  # the optimisation's share of a 15-minute run of 5 policy trials
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


def budget_line(task: TaskSpec, budget: Budget, overridden: dict[str, int]) -> str:
    """One line saying what was derived and from what, and what a config overrode."""
    line = (
        f"budget: {budget.num_particles} particles, {budget.opt_steps} opt steps, "
        f"N <= {budget.max_points} GP points (derived from {task.state_dim} states, "
        f"{task.action_dim} action{'s' if task.action_dim > 1 else ''}, "
        f"{len(task.output_idx)} GP outputs, horizon {task.horizon}: about "
        f"{budget.predicted_s / 60:.0f} min of optimisation for {BUDGET_TRIALS} trials on an "
        "idle 2-core machine; set num_particles=..., opt.max_steps=..., max_points=... to "
        "override)"
    )
    if overridden:
        line += "; the config sets " + ", ".join(f"{k}={v}" for k, v in overridden.items())
    return line

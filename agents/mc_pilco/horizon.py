"""The particle horizon grown over trials until the model's particles reach the goal in
time to hold it for the success window.

A swing-up has to reach the goal set and then stay in it for the success window: the
horizon ``H`` must cover the time to reach the goal ``T_reach`` plus the window ``w``. A
task file's horizon is a first guess; ``T_reach`` depends on the system (a weak motor
pumps a pendulum up over many swings) and is not known before the model is. Too short a
horizon leaves the particles that start far from the goal (a pendulum hanging at rest)
with no reachable goal inside ``H``: ``J^`` is then minimised by pumping energy without
regard to what follows, and a policy run past ``H`` spins the pole through upright
instead of holding it.

Rule (PILCO-style horizon growth): after the policy of trial ``k`` is optimised over
``H_k``, its predicted particles ``x^(m)_t`` (the policy applied without dropout) are
judged by the task's success set ``G`` (:meth:`~mcpilco.envs.tasks.spec.TaskSpec.in_goal`).
The fraction

    p_k = (1 / M) sum_m 1[x^(m)_t in G for some t <= H_k - w]

is the model's probability that a particle reaches the goal early enough to be held there
for the last ``w`` steps: ``H_k >= T_reach + w``. A particle that reaches the goal and
leaves it again (spins through it) counts as reached: holding it is the policy's task, not
the horizon's; one that never gets there in time says the horizon is too short for the
system (or the policy too weak for it, which a longer horizon lets the optimiser see).
When ``p_k < GOAL_FRACTION``, trial ``k + 1`` optimises and runs over

    H_{k+1} = min(H_max, ceil(HORIZON_GROWTH H_k))

with ``H_max`` the env's own episode length (the evaluation episodes' length): the horizon
grows geometrically until the particles reach the goal in time, or it is the episode. A
task whose success is not a goal held over a window (a balance task judged over the whole
episode, an env's own success flag, tracking) keeps its horizon. Trial ``k + 1`` also
collects ``H_{k+1}`` steps of experience (the trial runs the horizon, as in PILCO).

A longer horizon makes every optimisation step longer (``t_step`` is linear in ``H``,
:mod:`.budget`): the optimisation steps of a trial are scaled by ``H_0 / H_k``
(:func:`scaled_opt_steps`), so that a trial's optimisation takes the seconds the derived
budget gave it at ``H_0``.

Success window in the objective
-------------------------------
The same goal held over the last ``W`` steps (:func:`success_window`) shapes the objective:
the summed cost of (5.8) does not ask a swing-up to be in the goal by ``H - W``: a
trajectory that arrives at ``H - W/2`` can have the lowest sum and still fail.
:class:`~mcpilco.agents.mc_pilco.loss.MCPilcoLoss` with ``success_window=W`` replaces the
window's summed cost of each particle by ``W`` times its largest step cost (module glossary
of :mod:`.loss`). The trainer records :func:`predicted_success`, the fraction of the applied
policy's particles that the task's success test would pass.
"""

from __future__ import annotations

import math

import numpy as np

from mcpilco.envs.tasks.spec import TaskSpec

GOAL_FRACTION = 0.9  # predicted particles that must reach the goal w steps before the end
HORIZON_GROWTH = 1.5  # factor of each growth of the horizon
CATCH_REACH = 0.5  # fraction of particles reaching the goal in time above which a catch is due
CATCH_SUCCESS = 0.5  # predicted success below which that catch counts as missed


def grows(task: TaskSpec) -> bool:
    """Whether the task's success is a goal held over a window (then its horizon can grow):
    success bounds with a window, no ``full_horizon``, no env success flag, no tracking."""
    s = task.success
    return bool(
        s.bounds and s.window is not None and not s.full_horizon and s.info_key is None
    ) and not bool(s.tracking_rms)


def success_window(task: TaskSpec) -> int | None:
    """``W``: the steps at the end of the horizon over which the task's success keeps the
    state within its goal bounds (success bounds with a window, no ``full_horizon``, no
    tracking bound; an env success flag beside the bounds is the same test), at most the
    horizon ``H``. None where success is no goal held over a final window (a balance task
    judged over the whole episode, tracking, an env flag alone): there the objective is the
    plain sum."""
    s = task.success
    if not s.bounds or s.window is None or s.full_horizon or s.tracking_rms:
        return None
    return min(int(s.window), int(task.horizon))


def predicted_success(states: np.ndarray, task: TaskSpec) -> float:
    """The fraction of particles ``(M, H + 1, n)`` (``x_0 .. x_H``) within the task's goal
    bounds at each of their last ``W`` states ``x_{H-W+1} .. x_H`` (:func:`success_window`,
    ``W`` at most ``H``): the model's estimate of the success rate.

    Raises:
        ValueError: ``states`` is not ``(M, T, n)`` with ``n`` the task's states, or the task
            has no success window.
    """
    states = np.asarray(states, dtype=np.float64)
    if states.ndim != 3 or states.shape[-1] != task.state_dim or states.shape[1] < 2:
        raise ValueError(
            f"states must be (particles, steps + 1, {task.state_dim}), got {states.shape}"
        )
    window = success_window(task)
    if window is None:
        raise ValueError(f"task {task.env_id} has no goal held over a success window")
    w = min(window, states.shape[1] - 1)
    return float(task.in_goal(states[:, -w:]).all(axis=1).mean())


def goal_fraction(states: np.ndarray, task: TaskSpec) -> float:
    """``p``: the fraction of particles ``(M, H + 1, n)`` (``x_0 .. x_H``) within the task's
    success bounds at some step ``t <= H - w`` (``w`` the success window, at most ``H``).

    Raises:
        ValueError: ``states`` is not ``(M, T, n)`` with ``n`` the task's states, or the task
            has no goal held over a window (:func:`grows`).
    """
    states = np.asarray(states, dtype=np.float64)
    if states.ndim != 3 or states.shape[-1] != task.state_dim or states.shape[1] < 2:
        raise ValueError(
            f"states must be (particles, steps + 1, {task.state_dim}), got {states.shape}"
        )
    if not grows(task):
        raise ValueError(f"task {task.env_id} has no goal held over a success window")
    last = max(0, states.shape[1] - 1 - int(task.success.window))  # H - w
    reached = task.in_goal(states[:, : last + 1]).any(axis=1)
    return float(reached.mean())


def missed_catch(states: np.ndarray, task: TaskSpec) -> bool:
    """Whether the particles ``(M, H + 1, n)`` of an applied policy reach the goal in time
    but are not held there: ``p >= CATCH_REACH`` (:func:`goal_fraction`) and the predicted
    success below ``CATCH_SUCCESS`` (:func:`predicted_success`). The horizon is then long
    enough (or nearly) and the policy pumps the system to the goal and through it: the
    search settled without finding the catch, which a longer horizon does not supply.
    False for a task without a goal held over a window."""
    if not grows(task):
        return False
    return bool(
        goal_fraction(states, task) >= CATCH_REACH
        and predicted_success(states, task) < CATCH_SUCCESS
    )


def next_horizon(horizon: int, fraction: float, max_horizon: int) -> int:
    """``H_{k+1}``: ``horizon`` when ``fraction`` (``p_k``) is at least
    :data:`GOAL_FRACTION` or ``horizon`` is already ``max_horizon``, else
    ``min(max_horizon, ceil(HORIZON_GROWTH horizon))``."""
    if fraction >= GOAL_FRACTION or horizon >= max_horizon:
        return int(horizon)
    return int(min(max_horizon, math.ceil(HORIZON_GROWTH * horizon)))


def scaled_opt_steps(steps: int, horizon0: int, horizon: int) -> int:
    """Optimisation steps of a trial over ``horizon`` when ``steps`` were budgeted over
    ``horizon0``: ``round(steps H_0 / H)`` (at least 1) for a longer horizon, else
    ``steps``. The step time is linear in ``H`` (:func:`~.budget.step_seconds`), so the
    trial's optimisation keeps its budgeted seconds."""
    if horizon <= horizon0:
        return int(steps)
    return int(max(1, round(steps * horizon0 / horizon)))

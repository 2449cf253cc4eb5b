"""Trials on the real system, shared by every agent and benchmark (thesis Algorithm 1, the
"apply the policy" and "explore" steps).

An *episode* is one run of an env under an action rule, read through a
:class:`~mcpilco.envs.tasks.spec.TaskSpec`: observed states ``obs`` (T+1, n), true states,
actions (T, A), the task's evaluation cost, success and time in the goal region
(:func:`run_episode`). Trial ``k`` of run ``seed`` resets the env with
:func:`trial_seed`, so that MC-PILCO and its baselines see the same initial states.
Trial 0 explores with random actions (:func:`exploration_episodes`); a trial spans several
episodes where the env ends one early (:func:`trial_episodes`); the model's data are
the :func:`transitions` ``(s_t, a_t, s_{t+1})`` of all episodes, less those that touch one of
the task's limits or that a push filter marked.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from mcpilco.envs.tasks.spec import TaskSpec

DEFAULT_ENV_ID = "mcpilco/CartpoleSwingUp-v0"
"""The env of the scripts and configs when none is named (the thesis's cart-pole)."""


def registered_ids(prefix: str = "mcpilco/") -> list[str]:
    """The registered Gymnasium ids that start with ``prefix`` (the package's envs)."""
    import gymnasium as gym

    import mcpilco.envs  # noqa: F401  (registers the ids)

    return sorted(k for k in gym.registry if k.startswith(prefix))


def plain_env_id(env_id: str) -> str:
    """The registered id of ``env_id``: ``"pkg.module:MyEnv-v0"`` -> ``"MyEnv-v0"`` (the
    ``module:id`` form of ``gymnasium.make``); an id without a module as it is."""
    return env_id.rpartition(":")[2]


def import_user_module(module: str) -> None:
    """Import ``module`` as ``gymnasium.make("module:id")`` does; a module that is not on the
    Python path is looked for in the current folder too (appended to ``sys.path``, so that
    it never shadows an installed package), as ``python -m`` would find it.

    Raises:
        ImportError: the module is found nowhere, or its import fails.
    """
    import importlib
    import os
    import sys

    try:
        importlib.import_module(module)
    except ModuleNotFoundError as err:
        cwd = os.getcwd()
        top = module.partition(".")[0]
        if err.name != top or cwd in sys.path or "" in sys.path:
            raise
        sys.path.append(cwd)
        importlib.import_module(module)


def resolve_env_id(env_id: str) -> str:
    """The registered id of ``env_id`` after importing what registers it: mcpilco's own envs
    (:mod:`mcpilco.envs`), and for ``"pkg.module:MyEnv-v0"`` the module ``pkg.module``, as
    ``gymnasium.make`` does. Any id registered by an imported package is found.

    Raises:
        ValueError: the module cannot be imported, or the id is not registered (the message
            lists mcpilco's ids and says how to name a module).
    """
    import gymnasium as gym

    import mcpilco.envs  # noqa: F401  (registers the ids)

    module, sep, name = env_id.rpartition(":")
    if sep:
        if not module or not name:
            raise ValueError(f"--env {env_id!r}: expected pkg.module:EnvId")
        try:
            import_user_module(module)
        except ImportError as err:
            raise ValueError(
                f"--env {env_id!r}: cannot import module {module!r} ({err}); is it installed, "
                "on PYTHONPATH or in the current folder?"
            ) from None
    if name not in gym.registry:
        if sep:
            raise ValueError(
                f"--env {env_id!r}: module {module!r} registers no env id {name!r} (it must call "
                f"gymnasium.register(id={name!r}, ...) when imported)"
            )
        raise ValueError(
            f"unknown env id {name!r}; registered mcpilco ids: {', '.join(registered_ids())}; "
            "for your own env give --env your.module:YourEnv-v0 (the module registers it)"
        )
    return name


def make_env(
    env_id: str,
    horizon: int,
    task: TaskSpec | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
):
    """``gym.make(env_id, **env_kwargs)`` with episodes of ``horizon`` control steps
    (``horizon`` times the task's ``action_repeat`` env steps), clear errors for an unknown
    id (:func:`resolve_env_id`; ``env_id`` may be ``"pkg.module:MyEnv-v0"``), for spaces
    that do not fit ``task``
    (:meth:`~mcpilco.envs.tasks.spec.TaskSpec.check_env`), and for a horizon that differs
    from the env's own episode length when the task's success is the env's ``info`` flag
    (defined at the env's own last step), and for ``render_mode="human"`` where no window
    can open (:func:`mcpilco.envs.display.check_render_mode`)."""
    import gymnasium as gym

    from mcpilco.envs.display import check_render_mode

    env_id = resolve_env_id(env_id)
    steps = gym.spec(env_id).max_episode_steps
    horizon = int(horizon) * (task.action_repeat if task is not None else 1)
    if steps is not None and steps != horizon and task is not None and task.success.info_key:
        raise ValueError(
            f"horizon mismatch: the config's horizon is {horizon} steps but {env_id} episodes "
            f"last {steps} steps (its success flag is set at its last step); set horizon={steps}"
        )
    kwargs = dict(env_kwargs or {})
    # "human" needs a window: refused with one line where none can open (a GLFW or pygame
    # window on a machine without a display aborts or raises deep inside the env)
    check_render_mode(kwargs.get("render_mode"), ("rgb_array", "depth_array"))
    try:
        env = gym.make(env_id, max_episode_steps=int(horizon), **kwargs)
    except TypeError as err:  # an argument the env does not take
        raise ValueError(f"{env_id}: env_kwargs {kwargs}: {err}") from None
    if task is not None:
        try:
            task.check_env(env)
        except ValueError:
            env.close()
            raise
    return env


def env_dt(env, task: TaskSpec | None = None) -> float:
    """The control period: the task's, else the env's ``dt``."""
    if task is not None:
        return float(task.dt)
    return float(env.unwrapped.dt)


def run_episode(
    env,
    act: Callable[[np.ndarray], np.ndarray],
    seed: int,
    horizon: int,
    task: TaskSpec,
    record_info: bool = False,
    init_state: Mapping[str, float] | None = None,
) -> dict[str, Any]:
    """One episode of at most ``horizon`` control steps under ``act(state)``, each action held
    for the task's ``action_repeat`` env steps (the observation after the last is the next
    state). ``record_info``: also return ``infos``, per control step the ``info`` dicts of
    its env steps (what a push filter reads, :mod:`mcpilco.agents.mc_pilco.filters`).
    ``init_state``: entries of the env's state set after the reset
    (:func:`mcpilco.envs.reset_state.set_env_state`; an evaluation episode's start).

    Returns the observed states ``obs`` (T+1, n) (read from the observations by the task),
    the true states ``states`` (T+1, n), ``actions`` (T, A), per-step evaluation ``costs``,
    their sum ``cost``, ``success`` (the task's test), ``time_in_goal`` [s] (steps within
    the task's success bounds times ``T_s``), ``started_in_goal``
    (:meth:`~mcpilco.envs.tasks.spec.TaskSpec.starts_in_goal`: the episode started in the set
    it had to reach), ``final_info`` (the numeric scalars of the last
    step's ``info``, e.g. the marker camera's pose errors) and, for a task whose cost tracks states,
    ``tracking_rms`` (:meth:`~mcpilco.envs.tasks.spec.TaskSpec.tracking_rms`).

    Raises:
        RuntimeError: the env truncated the episode before ``horizon`` steps (a time limit of
            its own, shorter than the horizon; a termination ends the episode normally).
    """
    obs, info = env.reset(seed=seed, options=task.reset_options())
    if init_state is not None:
        from mcpilco.envs.reset_state import set_env_state

        obs, info = set_env_state(env, init_state, obs, info)
    observed = [task.state_from_obs(obs, info)]
    states = [task.true_state(obs, info)]
    actions = []
    infos: list[list[dict[str, Any]]] = []
    low, high = np.asarray(task.action_low), np.asarray(task.action_high)
    for _ in range(horizon):
        a = np.clip(np.asarray(act(observed[-1]), dtype=np.float64).reshape(-1), low, high)
        step_infos = []
        for _ in range(task.action_repeat):
            obs, _, terminated, truncated, info = env.step(a.astype(np.float32))
            if record_info:
                step_infos.append(info)
            if terminated or truncated:
                break
        if record_info:
            infos.append(step_infos)
        observed.append(task.state_from_obs(obs, info))
        states.append(task.true_state(obs, info))
        actions.append(a)
        if terminated or truncated:
            break
    if truncated and not terminated and len(actions) < horizon:
        name = env.spec.id if env.spec is not None else type(env.unwrapped).__name__
        raise RuntimeError(
            f"{name} truncated the episode after {len(actions)} of the horizon's {horizon} "
            "control steps (its own episode length is shorter than the horizon): pass the "
            "env's episode-length argument in the config's env_kwargs"
        )
    states_arr = np.stack(states)
    costs = task.cost(states_arr[1:])
    steps = len(actions)
    extra: dict[str, Any] = {"infos": infos} if record_info else {}
    if task.tracked_states():
        extra["tracking_rms"] = task.tracking_rms(states_arr)
    return {
        **extra,
        "obs": np.stack(observed),
        "states": states_arr,
        "actions": np.stack(actions) if actions else np.zeros((0, task.action_dim)),
        "costs": np.asarray(costs),
        "success": task.is_success(states_arr[1:], info, steps, planned=horizon),
        "started_in_goal": task.starts_in_goal(states_arr[0]),
        "cost": float(np.sum(costs)),
        "time_in_goal": float(np.sum(task.in_goal(states_arr[1:])) * task.dt),
        "steps": steps,
        "final_info": {
            k: float(v)
            for k, v in info.items()
            if isinstance(v, int | float | np.number) and not isinstance(v, bool | np.bool_)
        },
    }


def transitions(
    episodes: list[dict[str, Any]], task: TaskSpec | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(s_t, a_t, s_{t+1})`` of all episodes (observed states), stacked. With ``task``, the
    transitions that touch one of its declared limits are left out
    (:meth:`~mcpilco.envs.tasks.spec.TaskSpec.touches_limit`), and so are those an
    episode's ``filtered`` mask marks (a push filter's, :mod:`mcpilco.agents.mc_pilco.filters`):
    the dynamics data of the free motion."""
    s = np.concatenate([e["obs"][:-1] for e in episodes])
    a = np.concatenate([e["actions"] for e in episodes])
    s1 = np.concatenate([e["obs"][1:] for e in episodes])
    free = np.ones(len(a), dtype=bool)
    if task is not None and task.limits:
        free &= ~task.touches_limit(s, s1)
    if any(e.get("filtered") is not None for e in episodes):  # a push filter's marks
        free &= ~np.concatenate(
            [
                np.zeros(len(e["actions"]), bool) if e.get("filtered") is None else e["filtered"]
                for e in episodes
            ]
        )
    return s[free], a[free], s1[free]


def trial_seed(seed: int, k: int) -> int:
    """Env reset seed of trial ``k`` of run ``seed`` (shared by MC-PILCO and its baselines)."""
    return int(seed) * 10_007 + int(k)


def exploration_actions(
    rng: np.random.Generator, horizon: int, hold: int = 1, low=(-1.0,), high=(1.0,)
) -> np.ndarray:
    """``(horizon, A)`` random actions: ``ceil(horizon / hold)`` draws ``u ~ U(low, high)``
    from ``rng``, each repeated for ``hold`` steps (``hold = 1``: i.i.d. per step)."""
    if int(hold) != hold or hold < 1:
        raise ValueError(f"hold must be an integer >= 1, got {hold!r}")
    low, high = np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)
    draws = rng.uniform(low, high, size=(-(-horizon // hold), low.size))
    return np.repeat(draws, hold, axis=0)[:horizon]


def trial_episodes(
    env,
    actor: Callable[[int], Callable[[np.ndarray], np.ndarray]],
    reset_seed: int,
    horizon: int,
    task: TaskSpec,
    min_steps: int | None = None,
    record_info: bool = False,
) -> list[dict[str, Any]]:
    """The episodes of one trial: the first runs ``horizon`` steps from the reset seed
    ``reset_seed`` (fewer when the env terminates it). With ``min_steps``, further episodes
    follow, each reset from the env's own generator (seeded by the first reset) and at most
    ``horizon`` steps long, the last one cut so that exactly ``min_steps`` steps are taken
    in all: experience that resets whenever an episode ends, as in TorchRL's PILCO example
    (``initial_rollout_length``). ``actor(n)`` gives the action rule of an episode of at
    most ``n`` steps. Returns the episodes in order (:func:`run_episode`'s dicts).
    """
    if min_steps is not None and (int(min_steps) != min_steps or min_steps < 1):
        raise ValueError(f"min_steps must be a positive integer, got {min_steps!r}")
    episodes: list[dict[str, Any]] = []
    taken, seed = 0, reset_seed
    while not episodes or (min_steps is not None and taken < min_steps):
        n = horizon if not episodes else min(horizon, int(min_steps) - taken)
        episodes.append(run_episode(env, actor(n), seed, n, task, record_info))
        taken += episodes[-1]["steps"]
        seed = None
    return episodes


class LimitGuard:
    """Keeps random exploration inside the task's declared ``limits`` (end stops, joint
    ranges) and, with ``termination``, its ``termination`` box (the set outside which the
    env ends an episode) by braking before a bound, with no model of the system given.

    For each bounded position ``q_i`` with a velocity ``v_i`` (the task's ``pairs``; an
    angle that wraps has no bound), the velocity change of one control step is fitted
    online by least squares on the transitions seen so far (those that stay strictly
    inside the bounds)::

        Delta v_i ~ b_i^T u + c_i

    With ``m``, ``h`` the middle and half width of the action box and ``c'_i = c_i +
    b_i^T m``, the worst action pushes ``v_i`` towards a bound in direction ``s = +-1`` by
    ``p_s = sum_j |b_ij| h_j + s c'_i`` per step, and braking (``u_j = m_j - s sign(b_ij)
    h_j``) slows it by ``g_s = sum_j |b_ij| h_j - s c'_i``. After one more free step the
    speed towards the bound is at most ``w = s v_i + p_s``, and from there the coordinate
    travels ``T_s w (w / (2 g_s) + 1)`` before it stops. Whenever ``q_i + s T_s w`` plus
    that distance would reach the bound on side ``s``, the random action is replaced by
    the braking one: an action that could drive past a bound is reversed. The fit needs
    actions that differ (held random actions do not), so the first ``2 A`` steps of the
    first episode probe each action ``j`` with a pulse ``m + h_j e_j`` and its reverse
    ``m - h_j e_j`` (``A`` actions; their pushes cancel); until the fit has full rank, the
    random actions pass unchanged. ``interventions`` counts the steps braked, ``probes`` the
    probe steps. The rule is exact for a coordinate whose velocity change is affine in the
    action; for others it is a margin that grows with the speed. On the angle of an
    unstable pole (a ``termination`` range) the worst push is always close to the bound,
    so the guard brakes on most steps and the exploration becomes a crude balancer rather
    than random: that is why the termination box is a bound only on request.
    """

    def __init__(self, task: TaskSpec, termination: bool = False) -> None:
        self.task = task
        velocity = dict(task.pairs)
        box: dict[str, tuple[float, float]] = {}
        ranges = [*(task.termination.items() if termination else ()), *task.limits.items()]
        for name, (lo, hi) in ranges:
            if name in velocity and name not in task.angles:
                old = box.get(name, (-np.inf, np.inf))
                box[name] = (max(lo, old[0]), min(hi, old[1]))
        self.bounds = [
            (task.index(n), task.index(velocity[n]), lo, hi) for n, (lo, hi) in box.items()
        ]
        self.low = np.asarray(task.action_low, dtype=np.float64)
        self.high = np.asarray(task.action_high, dtype=np.float64)
        self.rows: list[np.ndarray] = []  # [u, 1] of each transition fitted
        self.dv: list[np.ndarray] = []  # Delta v of the bounded coordinates
        self.coef: np.ndarray | None = None  # (A + 1, bounds): b_i and c_i per column
        self.interventions = 0
        self.probes = 0
        self._prev: tuple[np.ndarray, np.ndarray] | None = None

    def start_episode(self) -> None:
        """A new episode: the next state follows a reset, not the last action."""
        self._prev = None

    def __call__(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The action to apply in observed state ``x`` instead of the random ``u``."""
        x = np.asarray(x, dtype=np.float64)
        u = np.clip(np.asarray(u, dtype=np.float64).reshape(-1), self.low, self.high)
        if not self.bounds:
            return u
        self._learn(x)
        if self.probes < 2 * len(u):
            j, sign = divmod(self.probes, 2)
            out = (self.high + self.low) / 2.0
            out[j] += (self.high[j] - self.low[j]) / 2.0 * (1.0 if sign == 0 else -1.0)
            self.probes += 1
        else:
            out = u if self.coef is None else self._brake(x, u)
        self._prev = (x, out)
        return out

    def _learn(self, x: np.ndarray) -> None:
        if self._prev is None:
            return
        x0, u0 = self._prev
        for i, _, lo, hi in self.bounds:
            if not (lo < x0[i] < hi and lo < x[i] < hi):
                return  # a stop or the termination set acted: no free motion
        vel = [v for _, v, _, _ in self.bounds]
        self.rows.append(np.append(u0, 1.0))
        self.dv.append(x[vel] - x0[vel])
        a = np.stack(self.rows)
        if len(a) >= a.shape[1] and np.linalg.matrix_rank(a) == a.shape[1]:
            self.coef = np.linalg.lstsq(a, np.stack(self.dv), rcond=None)[0]

    def _brake(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        mid, half = (self.high + self.low) / 2.0, (self.high - self.low) / 2.0
        dt = self.task.dt
        for col, (i, iv, lo, hi) in enumerate(self.bounds):
            b = self.coef[:-1, col]
            c = float(self.coef[-1, col] + b @ mid)
            reach = float(np.abs(b) @ half)
            for s, bound in ((1.0, hi), (-1.0, lo)):
                w = s * x[iv] + reach + s * c  # speed towards the bound after a free step
                if w <= 0.0:
                    continue
                g = reach - s * c
                stop = dt * w * (w / (2.0 * g) + 1.0) if g > 0 else np.inf
                if s * (x[i] - bound) + dt * w + stop >= 0.0:
                    self.interventions += 1
                    return mid - s * np.sign(b) * half
        return u


def exploration_episodes(
    env,
    rng: np.random.Generator,
    seed: int,
    horizon: int,
    task: TaskSpec,
    hold: int = 1,
    min_steps: int | None = None,
    record_info: bool = False,
    guard: LimitGuard | None = None,
) -> list[dict[str, Any]]:
    """Trial 0: :func:`trial_episodes` from the reset seed ``trial_seed(seed, 0)`` under the
    random actions of :func:`exploration_actions` (drawn from ``rng`` per episode), each
    passed through ``guard`` (:class:`LimitGuard`: braking before the task's limits) when
    given."""

    def actor(n: int) -> Callable[[np.ndarray], np.ndarray]:
        it = iter(exploration_actions(rng, n, hold, task.action_low, task.action_high))
        if guard is None:
            return lambda _o: next(it)
        guard.start_episode()
        return lambda o: guard(o, next(it))

    return trial_episodes(env, actor, trial_seed(seed, 0), horizon, task, min_steps, record_info)


EVAL_SEED_BASE = 10**12
"""Evaluation episode ``i`` after trial ``k`` of run ``seed`` resets with seed
``EVAL_SEED_BASE + 1000 trial_seed(seed, k) + i``: above every trial seed (``< 10^12`` for
run seeds below ``10^8``), distinct for up to 1000 episodes per trial."""

MAX_EVAL_EPISODES = 1000  # evaluation episodes per trial with distinct seeds


def eval_seed(seed: int, k: int, i: int) -> int:
    """Reset seed of evaluation episode ``i`` after trial ``k`` of run ``seed``
    (:data:`EVAL_SEED_BASE`; disjoint from every :func:`trial_seed`)."""
    return EVAL_SEED_BASE + MAX_EVAL_EPISODES * trial_seed(seed, k) + int(i)


def evaluate(
    env,
    act: Callable[[np.ndarray], np.ndarray],
    seed: int,
    k: int,
    episodes: int,
    task: TaskSpec,
    steps: int | None = None,
) -> dict[str, Any]:
    """``episodes`` evaluation episodes of the policy ``act`` after trial ``k``, each of
    ``steps`` control steps (None: the horizon; ``env`` must allow them) from the task's
    evaluation start (reset seeds :func:`eval_seed`; the env's state entries of
    ``task.eval_init`` drawn from a generator seeded by the same seed), not counted as
    experience. The success rate counts the episodes that started outside the goal set
    (``started_in_goal`` ones are left out) with its 95 % Wilson interval.

    Returns the record fields ``eval_episodes`` (run), ``eval_counted`` (started outside
    the goal set), ``eval_successes`` and ``eval_ci`` ([low, high]; None when none counted).
    """
    from mcpilco.models.stats import wilson_interval

    if int(episodes) != episodes or not 1 <= episodes <= MAX_EVAL_EPISODES:
        raise ValueError(f"eval episodes must be in 1..{MAX_EVAL_EPISODES}, got {episodes!r}")
    counted = successes = 0
    for i in range(int(episodes)):
        s = eval_seed(seed, k, i)
        init = task.sample_eval_init(np.random.default_rng(s))
        ep = run_episode(env, act, s, steps or task.horizon, task, init_state=init)
        if not ep["started_in_goal"]:
            counted += 1
            successes += bool(ep["success"])
    ci = [float(v) for v in wilson_interval(successes, counted)] if counted else None
    return {
        "eval_episodes": int(episodes),
        "eval_counted": counted,
        "eval_successes": successes,
        "eval_ci": ci,
    }


def episode_outcome(ep: dict[str, Any], t0: float) -> dict[str, Any]:
    """The real-system part of a trial record: evaluation cost, ``success``, whether the
    episode ``started_in_goal`` (its success then counts as none), time in the goal region of
    episode ``ep``, its ``tracking_rms`` where it has one, and the wall-clock since
    ``t0`` (``time.perf_counter``)."""
    out = {
        "cost": ep["cost"],
        "success": ep["success"],
        "started_in_goal": ep["started_in_goal"],
        "time_in_goal": ep["time_in_goal"],
        "steps": ep["steps"],
        "wall_s": time.perf_counter() - t0,
    }
    if "tracking_rms" in ep:
        out["tracking_rms"] = ep["tracking_rms"]
    return out

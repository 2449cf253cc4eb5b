"""One Gymnasium adapter for every task of the dm-control suite: ``dm_control/<domain>-<task>-v0``.

:class:`DMControlEnv` wraps ``dm_control.suite.load(domain, task)`` behind the Gymnasium API
without changing its physics, its initial-state distribution, its reward or its control
timestep. A task file (:mod:`mcpilco.envs.tasks`) reads its states by name from

* the observation: dm-control's observation dict flattened in its own key order, entry
  ``k`` of key ``name`` called ``name[k]`` (a scalar entry is called ``name``), listed in
  :attr:`DMControlEnv.observation_names`; e.g. ``orientation[0]``, ``orientation[1]``,
  ``velocity[0]`` for ``pendulum``;
* the physics state ``info["physics"] = [qpos, qvel]`` (noise-free), each entry called
  ``qpos[joint]`` / ``qvel[joint]`` (``qpos[joint][k]`` for a free or ball joint), listed in
  :attr:`DMControlEnv.physics_names`; e.g. ``qpos[hinge]`` for ``pendulum``.

Registration (:func:`register_dmc_envs`) lists the suite's tasks from :data:`DMC_TASKS`, so
that ``import mcpilco.envs`` does not import dm-control; it is imported when an env is made.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.spaces import Box
from numpy.typing import ArrayLike, NDArray

__all__ = ["DMC_TASKS", "DMControlEnv", "dmc_env_id", "register_dmc_envs"]

DMC_TASKS: tuple[tuple[str, str], ...] = (
    ("acrobot", "swingup"),
    ("acrobot", "swingup_sparse"),
    ("ball_in_cup", "catch"),
    ("cartpole", "balance"),
    ("cartpole", "balance_sparse"),
    ("cartpole", "swingup"),
    ("cartpole", "swingup_sparse"),
    ("cartpole", "two_poles"),
    ("cartpole", "three_poles"),
    ("cheetah", "run"),
    ("dog", "stand"),
    ("dog", "walk"),
    ("dog", "trot"),
    ("dog", "run"),
    ("dog", "fetch"),
    ("finger", "spin"),
    ("finger", "turn_easy"),
    ("finger", "turn_hard"),
    ("fish", "upright"),
    ("fish", "swim"),
    ("hopper", "stand"),
    ("hopper", "hop"),
    ("humanoid", "stand"),
    ("humanoid", "walk"),
    ("humanoid", "run"),
    ("humanoid", "run_pure_state"),
    ("humanoid_CMU", "stand"),
    ("humanoid_CMU", "walk"),
    ("humanoid_CMU", "run"),
    ("lqr", "lqr_2_1"),
    ("lqr", "lqr_6_2"),
    ("manipulator", "bring_ball"),
    ("manipulator", "bring_peg"),
    ("manipulator", "insert_ball"),
    ("manipulator", "insert_peg"),
    ("pendulum", "swingup"),
    ("point_mass", "easy"),
    ("point_mass", "hard"),
    ("quadruped", "walk"),
    ("quadruped", "run"),
    ("quadruped", "escape"),
    ("quadruped", "fetch"),
    ("reacher", "easy"),
    ("reacher", "hard"),
    ("stacker", "stack_2"),
    ("stacker", "stack_4"),
    ("swimmer", "swimmer6"),
    ("swimmer", "swimmer15"),
    ("walker", "stand"),
    ("walker", "walk"),
    ("walker", "run"),
)
"""``(domain, task)`` of every dm-control suite task (``dm_control.suite.ALL_TASKS``)."""

DMC_ID_PREFIX = "dm_control/"  # namespace of the registered dm-control ids


def dmc_env_id(domain: str, task: str) -> str:
    """The registered id of ``domain``/``task``: ``dm_control/<domain>-<task>-v0``."""
    return f"{DMC_ID_PREFIX}{domain}-{task}-v0"


def register_dmc_envs() -> None:
    """Register :class:`DMControlEnv` under :func:`dmc_env_id` for every task of
    :data:`DMC_TASKS` (string entry point: nothing is imported until an env is made). The
    episode length is dm-control's own time limit unless ``max_episode_steps`` is given."""
    for domain, task in DMC_TASKS:
        env_id = dmc_env_id(domain, task)
        if env_id not in gym.registry:
            gym.register(
                id=env_id,
                entry_point="mcpilco.envs.dmc:DMControlEnv",
                kwargs={"domain": domain, "task": task},
            )


def _physics_names(physics: Any) -> tuple[str, ...]:
    """``qpos[joint]`` per position entry, then ``qvel[joint]`` per velocity entry (a joint
    with several entries, free or ball: ``qpos[joint][k]``)."""
    import mujoco

    model = physics.model
    names: dict[str, list[str]] = {"qpos": [""] * model.nq, "qvel": [""] * model.nv}
    widths = {
        int(mujoco.mjtJoint.mjJNT_FREE): (7, 6),
        int(mujoco.mjtJoint.mjJNT_BALL): (4, 3),
    }
    for j in range(model.njnt):
        joint = physics.model.id2name(j, "joint") or f"joint{j}"
        npos, nvel = widths.get(int(model.jnt_type[j]), (1, 1))
        for field, start, width in (
            ("qpos", int(model.jnt_qposadr[j]), npos),
            ("qvel", int(model.jnt_dofadr[j]), nvel),
        ):
            for k in range(width):
                suffix = f"[{k}]" if width > 1 else ""
                names[field][start + k] = f"{field}[{joint}]{suffix}"
    return tuple(names["qpos"] + names["qvel"])


def _flatten(observation: Any) -> tuple[NDArray[np.float64], tuple[str, ...]]:
    """dm-control's observation dict as one float64 vector and the name of each entry."""
    parts, names = [], []
    for key, value in observation.items():
        v = np.asarray(value, dtype=np.float64).reshape(-1)
        parts.append(v)
        names.extend([key] if np.ndim(value) == 0 else [f"{key}[{k}]" for k in range(v.size)])
    return np.concatenate(parts) if parts else np.zeros(0), tuple(names)


class DMControlEnv(gym.Env):
    r"""
    ## Description
    Any dm-control suite task (Tassa et al., 2018) behind the Gymnasium API, registered as
    ``dm_control/<domain>-<task>-v0`` (e.g. ``dm_control/pendulum-swingup-v0``). The physics,
    initial-state distribution, reward and control timestep are dm-control's own.

    ## Action Space
    `Box(minimum, maximum, (A,), float32)` from dm-control's action spec. An action is clipped
    to the bounds and held for ``action_repeat`` dm-control control steps; a wrong shape or a
    NaN/inf raises ``ValueError``.

    ## Observation Space
    `Box(-Inf, Inf, (n,), float64)`: dm-control's observation dict flattened in its key
    order, plus optional Gaussian noise ``obs_noise_std``; the entries' names are
    :attr:`observation_names` (``key[k]``, or ``key`` for a scalar). ``info["physics"]``
    holds the noise-free physics state ``[qpos, qvel]``, named by :attr:`physics_names`.

    ## Rewards
    dm-control's reward, summed over the ``action_repeat`` control steps of one env step.

    ## Starting State
    dm-control's own, drawn from a ``numpy.random.RandomState`` owned by the adapter and
    reseeded by ``reset(seed=...)`` (unseeded resets continue its stream; a seed of 2^32 or
    more, which ``RandomState`` refuses, through ``numpy.random.SeedSequence``).
    :meth:`set_physics_state` then sets named entries of the state (an episode started
    from a given state).

    ## Episode End
    Truncated at dm-control's own time limit, or after ``episode_steps`` env steps when
    given (dm-control's time limit is then disabled); terminated when dm-control ends an
    episode with discount 0.

    ## Arguments
    | Parameter       | Type      | Default | Description                                      |
    |-----------------|-----------|---------|--------------------------------------------------|
    | `domain`        | **str**   |         | dm-control domain, e.g. ``"pendulum"``           |
    | `task`          | **str**   |         | dm-control task of the domain, e.g. ``"swingup"``|
    | `action_repeat` | **int**   | `1`     | dm-control control steps per env step            |
    | `episode_steps` | **int**   | `None`  | env steps per episode (None: dm-control's limit) |
    | `obs_noise_std` | **float** | `0.0`   | Std of Gaussian noise added to each observation  |

    ## Version History
    * v0: Initial version (dm-control 1.0.x, MuJoCo 3.x).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(
        self,
        domain: str,
        task: str,
        action_repeat: int = 1,
        episode_steps: int | None = None,
        obs_noise_std: float = 0.0,
        render_mode: str | None = None,
    ) -> None:
        if not obs_noise_std >= 0:
            raise ValueError(f"obs_noise_std must be >= 0, got {obs_noise_std}")
        if isinstance(action_repeat, bool) or int(action_repeat) != action_repeat:
            raise ValueError(f"action_repeat must be a positive integer, got {action_repeat!r}")
        if action_repeat < 1:
            raise ValueError(f"action_repeat must be a positive integer, got {action_repeat!r}")
        if episode_steps is not None and (int(episode_steps) != episode_steps or episode_steps < 1):
            raise ValueError(f"episode_steps must be a positive integer, got {episode_steps!r}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        if (domain, task) not in DMC_TASKS:
            raise ValueError(
                f"unknown dm-control task {domain}/{task} (suite tasks: "
                f"{', '.join(f'{d}/{t}' for d, t in DMC_TASKS)})"
            )
        with warnings.catch_warnings():  # glfw warns about a missing X display on import
            warnings.simplefilter("ignore")
            from dm_control import suite

        self.domain, self.task = domain, task
        self._random = np.random.RandomState()
        task_kwargs: dict[str, Any] = {"random": self._random}
        if episode_steps is not None:
            task_kwargs["time_limit"] = float("inf")
        self._dmc = suite.load(domain, task, task_kwargs=task_kwargs)
        self.action_repeat = int(action_repeat)
        self.episode_steps = None if episode_steps is None else int(episode_steps)
        self.dt = self.action_repeat * float(self._dmc.control_timestep())
        self.metadata = {"render_modes": ["rgb_array"], "render_fps": int(round(1.0 / self.dt))}
        self.render_mode = render_mode
        self._obs_noise_std = float(obs_noise_std)
        spec = self._dmc.action_spec()
        self.action_space = Box(
            np.asarray(spec.minimum, dtype=np.float32).reshape(spec.shape),
            np.asarray(spec.maximum, dtype=np.float32).reshape(spec.shape),
            dtype=np.float32,
        )
        obs, names = _flatten(self._dmc.reset().observation)
        self.observation_names: tuple[str, ...] = names
        """Name of each observation entry (module docstring)."""
        self.physics_names: tuple[str, ...] = _physics_names(self.physics)
        """Name of each entry of ``info["physics"]`` (module docstring)."""
        self.observation_space = Box(-np.inf, np.inf, shape=obs.shape, dtype=np.float64)
        self._steps = 0
        limit = self._dmc._step_limit  # dm-control's time limit / control timestep (inf: none)
        self.episode_limit: int | None = (
            None
            if self.episode_steps is None and not np.isfinite(limit)
            else self.episode_steps or -(-int(round(limit)) // self.action_repeat)
        )
        """Env steps of an episode: ``episode_steps``, else dm-control's own time limit
        (None: no limit)."""

    @property
    def physics(self):
        """dm-control ``Physics`` of the wrapped task."""
        return self._dmc.physics

    @property
    def physics_state(self) -> NDArray[np.float64]:
        """The noise-free physics state ``[qpos, qvel]``."""
        data = self.physics.data
        return np.concatenate([data.qpos, data.qvel]).astype(np.float64)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None:  # RandomState takes seeds below 2^32; a larger one is hashed
            self._random.seed(
                seed if seed < 2**32 else int(np.random.SeedSequence(seed).generate_state(1)[0])
            )
        ts = self._dmc.reset()
        self._steps = 0
        return self._get_obs(ts.observation), {"physics": self.physics_state}

    def set_physics_state(
        self, values: Mapping[str, float]
    ) -> tuple[NDArray[np.float64], dict[str, Any]]:
        """Set the physics entries named in ``values`` (:attr:`physics_names`, e.g.
        ``{"qpos[hinge]": 3.1, "qvel[hinge]": 0.0}``) and return the observation and ``info``
        of the new state (dm-control's own observation of it); the other entries keep their
        values. Used after :meth:`reset` to start an episode from a given state
        (:func:`mcpilco.envs.reset_state.set_env_state`).

        Raises:
            ValueError: a name that is not one of :attr:`physics_names`.
        """
        state = self.physics_state
        for name, v in values.items():
            if name not in self.physics_names:
                raise ValueError(
                    f"task.eval_init.{name}: not a physics entry of {self.domain}/{self.task} "
                    f"(entries: {', '.join(self.physics_names)})"
                )
            state[self.physics_names.index(name)] = float(v)
        nq = self.physics.model.nq
        with self.physics.reset_context():  # sets the state and recomputes what follows from it
            self.physics.data.qpos[:] = state[:nq]
            self.physics.data.qvel[:] = state[nq:]
        obs = self._get_obs(self._dmc.task.get_observation(self.physics))
        return obs, {"physics": self.physics_state}

    def step(self, action: ArrayLike):
        ts, reward, terminated, truncated = self._advance(action)
        self._steps += 1
        if self.episode_steps is not None and self._steps >= self.episode_steps:
            truncated = not terminated
        info = {"physics": self.physics_state}
        if not np.all(np.isfinite(info["physics"])):
            raise RuntimeError(f"simulation diverged: state {info['physics']}; reset the env")
        return self._get_obs(ts.observation), reward, terminated, truncated, info

    def _advance(self, action: ArrayLike) -> tuple[Any, float, bool, bool]:
        """Hold the validated, clipped ``action`` for ``action_repeat`` dm-control steps (fewer
        when dm-control ends the episode): the last time step, the summed reward, and
        whether dm-control terminated (discount 0) or truncated (its time limit) the
        episode."""
        a = np.clip(self._validate(action), self.action_space.low, self.action_space.high)
        reward, terminated, truncated = 0.0, False, False
        for _ in range(self.action_repeat):
            ts = self._dmc.step(a)
            reward += float(ts.reward or 0.0)
            if ts.last():
                terminated = ts.discount is not None and float(ts.discount) == 0.0
                truncated = not terminated
                break
        return ts, reward, terminated, truncated

    def render(self):
        if self.render_mode == "rgb_array":
            return self.physics.render(height=240, width=320, camera_id=0)
        return None

    def _validate(self, action: ArrayLike) -> NDArray[np.float64]:
        """The action as float64 of the action space's shape; ValueError for a wrong shape or
        a non-finite entry."""
        shape = self.action_space.shape
        try:
            a = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError) as err:
            raise ValueError(f"action must be numeric with shape {shape}, got {action!r}") from err
        if a.shape == () and shape == (1,):
            a = a.reshape(1)
        if a.shape != shape:
            raise ValueError(f"action has shape {a.shape}, expected {shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"action contains NaN or inf: {a}; pass finite values")
        return a

    def _get_obs(self, observation: Any) -> NDArray[np.float64]:
        obs = _flatten(observation)[0]
        if self._obs_noise_std > 0:
            return obs + self._obs_noise_std * self.np_random.standard_normal(obs.shape)
        return obs

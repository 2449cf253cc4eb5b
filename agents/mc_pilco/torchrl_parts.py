"""MC-PILCO's parts as TorchRL objects: the GP world model as a ``TensorDictModule`` and a
TorchRL env that observes a task's state.

Glossary (thesis sections 5.3.1, 5.4.2-5.4.3; symbols as in :mod:`.dynamics`)
----------------------------------------------------------------------------
``x_t``, ``u_t``
    the task's state (``n`` coordinates, any ``n``) and the action.
``x_{t+1} = x_t A^T + Delta_t S^T``
    speed integration, eq. (5.9), of the velocity changes ``Delta_t`` the GPs model.
``E[x_{t+1}]``
    the mean prediction: ``Delta_t = E[Delta^_t]`` (the GP posterior mean, eq. 5.3).
``x_{t+1}`` (a sample)
    ``Delta_t = E[Delta^_t] + sqrt(var[Delta^_t]) eps``, ``eps ~ N(0, I)``: one particle's
    step of the MC-PILCO rollout (reparameterised, so differentiable in ``x_t`` and ``u_t``).
    Both are clipped at the model's bound ``b`` (:class:`.dynamics.SpeedIntegrationDynamics`).

:class:`ParticleWorldModel` reads ``observation`` (the state ``x_t``), ``action`` and,
optionally, ``noise`` (``eps``; drawn when absent) and writes the sampled next state to
``("next", "observation")``, where a TorchRL env writes its next observation, and the mean
to ``("next", "observation_mean")``. It wraps the package's particle dynamics (what
:meth:`.dynamics.GPDynamicsModel.particle_dynamics` returns after a fit); the maths are
those of :mod:`.dynamics`. :class:`~mcpilco.agents.mc_pilco.loss.MCPilcoLoss` takes it in
the place of the plain dynamics module.

:func:`make_torchrl_env` builds a TorchRL env of a task: ``GymEnv`` for a Gymnasium id,
``DMControlEnv`` for a ``dm_control/<domain>-<task>-v0`` id (its observation dict
concatenated in dm-control's key order, the package adapter's order), each action held for
the task's ``action_repeat`` steps, episodes of the task's horizon, and the task's state
``x_t`` written under ``"state"`` by :class:`TaskStateTransform` (the task file's
``obs_indices`` or derived states ``state_from``, read from the observation).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from tensordict.nn import TensorDictModule
from tensordict.utils import NestedKey
from torch import Tensor, nn
from torchrl.data import Unbounded
from torchrl.envs.transforms import Transform

from mcpilco.agents.mc_pilco.dynamics import (
    GPDynamicsModel,
    SpeedIntegrationDynamics,
    sample_clip_integrate_forward,
)
from mcpilco.envs.tasks.spec import TaskSpec

WORLD_MODEL_IN_KEYS: tuple[NestedKey, ...] = ("observation", "action", "noise")
"""Default in_keys of :class:`ParticleWorldModel`: ``x_t``, ``u_t``, ``eps`` (optional)."""

WORLD_MODEL_OUT_KEYS: tuple[NestedKey, ...] = (
    ("next", "observation"),
    ("next", "observation_mean"),
)
"""Default out_keys of :class:`ParticleWorldModel`: the sampled and the mean ``x_{t+1}``."""

STATE_KEY = "state"  # where TaskStateTransform writes the task's state x_t


class GPTransition(nn.Module):
    """``(x_t (..., n), u_t (..., A), eps (..., m) or None) -> (x_{t+1} sample, E[x_{t+1}])``
    of the package's particle dynamics (module glossary); ``eps`` is drawn when None.

    The GP is evaluated once; the sample and the mean are integrated from the same
    ``E[Delta], var[Delta]`` by :func:`.dynamics.sample_clip_integrate_forward`.

    Args:
        dynamics: the particle dynamics of a fitted GP model
            (:meth:`.dynamics.GPDynamicsModel.particle_dynamics`).
    """

    def __init__(self, dynamics: SpeedIntegrationDynamics) -> None:
        super().__init__()
        if not isinstance(dynamics, SpeedIntegrationDynamics):
            raise TypeError(
                "dynamics must be a SpeedIntegrationDynamics (GPDynamicsModel.particle_dynamics()"
                f"), got {type(dynamics).__name__}"
            )
        self.dynamics = dynamics

    @property
    def state_dim(self) -> int:
        """``n``, the task's state size."""
        return self.dynamics.layout.n

    @property
    def noise_dim(self) -> int:
        """``m``, one ``eps`` per GP output."""
        return self.dynamics.layout.output_dim

    def forward(
        self, observation: Tensor, action: Tensor, noise: Tensor | None = None
    ) -> tuple[Tensor, Tensor]:
        n, m = self.state_dim, self.noise_dim
        if observation.shape[-1] != n:
            raise ValueError(
                f"observation must have the task's {n} states in its last dimension, got shape "
                f"{tuple(observation.shape)}"
            )
        dyn = self.dynamics
        mean, var = dyn.delta_distribution(observation, action)
        if noise is None:
            noise = torch.randn_like(mean)
        elif noise.shape[-1] != m:
            raise ValueError(
                f"noise must have one entry per GP output ({m}) in its last dimension, got "
                f"shape {tuple(noise.shape)}"
            )
        bound, dt, layout = dyn.delta_bound, dyn.dt, dyn.layout
        sample, _ = sample_clip_integrate_forward(
            observation, mean, var, noise.to(mean.dtype), bound, dt, layout
        )
        expected, _ = sample_clip_integrate_forward(observation, mean, var, None, bound, dt, layout)
        return sample, expected


class ParticleWorldModel(TensorDictModule):
    """The GP world model as a ``TensorDictModule``: :class:`GPTransition` reading
    ``in_keys`` (``x_t``, ``u_t``, optional ``eps``) and writing ``out_keys`` (the sampled
    and the mean ``x_{t+1}``); module glossary.

    Args:
        dynamics: the particle dynamics of a fitted GP model.
        in_keys: three keys (default :data:`WORLD_MODEL_IN_KEYS`).
        out_keys: two keys (default :data:`WORLD_MODEL_OUT_KEYS`).

    Example::

        model = GPDynamicsModel(task).fit(states, actions, next_states)
        world = ParticleWorldModel.from_model(model)
        td = world(TensorDict({"observation": x, "action": u}, batch_size=[len(x)]))
        td["next", "observation"]  # one sampled step per row
    """

    def __init__(
        self,
        dynamics: SpeedIntegrationDynamics,
        in_keys: Sequence[NestedKey] = WORLD_MODEL_IN_KEYS,
        out_keys: Sequence[NestedKey] = WORLD_MODEL_OUT_KEYS,
    ) -> None:
        if len(in_keys) != 3 or len(out_keys) != 2:
            raise ValueError(
                "ParticleWorldModel needs three in_keys (observation, action, noise) and two "
                f"out_keys (next sample, next mean), got {list(in_keys)} and {list(out_keys)}"
            )
        super().__init__(GPTransition(dynamics), in_keys=list(in_keys), out_keys=list(out_keys))

    @classmethod
    def from_model(
        cls, model: GPDynamicsModel, dtype: torch.dtype = torch.float32, **keys
    ) -> ParticleWorldModel:
        """The world model of a fitted :class:`.dynamics.GPDynamicsModel` (its particle
        dynamics at ``dtype``); ``keys``: ``in_keys`` / ``out_keys``."""
        return cls(model.particle_dynamics(dtype), **keys)

    @property
    def dynamics(self) -> SpeedIntegrationDynamics:
        """The wrapped particle dynamics (what the loss's rollout steps)."""
        return self.module.dynamics


def dmc_domain_task(env_id: str) -> tuple[str, str] | None:
    """``("pendulum", "swingup")`` for ``"dm_control/pendulum-swingup-v0"``; None for an id
    that is not a dm-control one."""
    from mcpilco.envs.dmc import DMC_ID_PREFIX

    if not env_id.startswith(DMC_ID_PREFIX):
        return None
    domain, _, task = env_id[len(DMC_ID_PREFIX) :].removesuffix("-v0").partition("-")
    if not domain or not task:
        raise ValueError(f"env_id {env_id!r}: expected dm_control/<domain>-<task>-v0")
    return domain, task


class TaskStateTransform(Transform):
    """TorchRL transform writing the task's state ``x_t`` (float32; the policy's input) from
    the env's observation, at every step and reset: :meth:`TaskSpec.state_from_obs`.

    Args:
        task: the task; its ``state_from`` entries named by string must be bound to the
            env's entry names first (:meth:`TaskSpec.check_env`, done by
            :func:`make_torchrl_env`). States read from ``info`` are refused: a TorchRL env
            carries its observation only.
        in_key: the observation; out_key: where the state goes.
    """

    def __init__(
        self, task: TaskSpec, in_key: NestedKey = "observation", out_key: NestedKey = STATE_KEY
    ) -> None:
        for name, reader in (task.state_from or {}).items():
            if reader.info is not None:
                raise ValueError(
                    f"state_from.{name}.info: the TorchRL env reads states from the observation "
                    f"only, not from info[{reader.info!r}]; derive {name!r} from observation "
                    "entries"
                )
        super().__init__(in_keys=[in_key], out_keys=[out_key])
        self.task = task

    def _apply_transform(self, obs: Tensor) -> Tensor:
        state = self.task.state_from_obs(obs.detach().cpu().numpy())
        return torch.as_tensor(np.asarray(state), dtype=torch.float32, device=obs.device)

    def _reset(self, tensordict, tensordict_reset):
        return self._call(tensordict_reset)

    def transform_observation_spec(self, observation_spec):
        src = observation_spec[self.in_keys[0]]
        shape = (*src.shape[:-1], self.task.state_dim)
        observation_spec[self.out_keys[0]] = Unbounded(
            shape=shape, dtype=torch.float32, device=src.device
        )
        return observation_spec


def make_torchrl_env(task: TaskSpec, seed: int | None = None, env_kwargs: dict | None = None):
    """A TorchRL env of ``task`` (its ``env_id``): ``GymEnv`` (a Gymnasium id, also
    ``pkg.module:Id``) or ``DMControlEnv`` (``dm_control/<domain>-<task>-v0``; observation
    entries concatenated in dm-control's order under ``"observation"``), each action held
    ``task.action_repeat`` steps (``FrameSkipTransform``), episodes truncated at
    ``task.horizon`` (``StepCounter``), the task's state under :data:`STATE_KEY`
    (:class:`TaskStateTransform`), episode starts marked (``InitTracker``). The task is
    checked against the package's Gymnasium env of the same id first
    (:func:`~mcpilco.agents.common.trials.make_env`; this binds the entry names of derived
    states).
    """
    from torchrl.envs import (
        CatTensors,
        DMControlEnv,
        FrameSkipTransform,
        GymEnv,
        InitTracker,
        StepCounter,
        TransformedEnv,
    )

    from mcpilco.agents.common.trials import make_env, resolve_env_id

    make_env(task.env_id, task.horizon, task, env_kwargs).close()  # checks the task, binds names
    dmc = dmc_domain_task(task.env_id)
    if dmc is not None:
        base = DMControlEnv(*dmc)
        keys = list(base.observation_spec.keys())
        env = TransformedEnv(base, CatTensors(keys, "observation", sort=False))
    else:
        steps = task.horizon * task.action_repeat  # the env's episode length, as make_env's
        env = TransformedEnv(
            GymEnv(resolve_env_id(task.env_id), max_episode_steps=steps, **(env_kwargs or {}))
        )
    if task.action_repeat > 1:
        env.append_transform(FrameSkipTransform(task.action_repeat))
    env.append_transform(StepCounter(max_steps=task.horizon))
    env.append_transform(TaskStateTransform(task))
    env.append_transform(InitTracker())  # the episode starts, which TorchRL's collector asks for
    if seed is not None:
        env.set_seed(int(seed))
    return env

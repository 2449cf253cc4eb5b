"""Adapter around dm-control's ``cartpole``/``swingup``: ``mcpilco/DMCCartpoleSwingUp-v0``.

An external check of the agents on a cart-pole written by others, seen through the same
observation, cost and success conventions as ``mcpilco/CartpoleSwingUp-v0``: the suite's
adapter :class:`~mcpilco.envs.dmc.DMControlEnv` (``dm_control/cartpole-swingup-v0``, which
keeps dm-control's observation and reward) with this env's state, cost and control period.
"""

from __future__ import annotations

import numpy as np
from gymnasium.spaces import Box
from numpy.typing import ArrayLike, NDArray

from mcpilco.envs.cartpole_task import CARTPOLE_TASK, SwingUpScorer
from mcpilco.envs.dmc import DMControlEnv

__all__ = ["DMCCartpoleSwingUpEnv"]


class DMCCartpoleSwingUpEnv(DMControlEnv):
    r"""
    ## Description
    dm-control suite task ``cartpole``/``swingup`` (Tassa et al., 2018) behind the Gymnasium
    API of ``mcpilco/CartpoleSwingUp-v0``. Its physics are dm-control's own, not PILCO's:
    cart 1 kg on a rail limited to |x| <= 1.8 m (slider damping 5e-4), pole a 1 m capsule of
    0.1 kg (hinge damping 2e-6), RK4 with timestep 0.01 s, force = 10 x ctrl. The adapter
    keeps dm-control's model, initial state distribution and physics untouched; only the
    observation, reward, control period and episode length are translated.

    ## Action Space
    `Box(-1, 1, (1,), float32)`, passed unchanged (after clipping to [-1, 1]) to dm-control's
    ``slide`` motor (gear 10, ctrl range [-1, 1]), i.e. a force of ``10 a`` N on the cart.
    Each action is repeated ``action_repeat`` = 5 dm-control control steps of 0.01 s, so the
    control period is 0.05 s as in ``mcpilco/CartpoleSwingUp-v0``. A wrong shape or a NaN/inf
    raises ``ValueError``.

    | Num | Action                   | Min | Max | Name (dm-control XML) | Joint  | Type (Unit)    |
    |-----|--------------------------|-----|-----|-----------------------|--------|----------------|
    | 0   | Force on the cart / 10 N | -1  | 1   | slide                 | slider | Force (x 10 N) |

    ## Observation Space
    `Box(-Inf, Inf, (4,), float64)`: ``[x, x_dot, theta, theta_dot]`` read from
    ``physics.named.data.qpos/qvel`` (not from dm-control's cos/sin observation), plus optional
    Gaussian noise ``obs_noise_std``. dm-control's pole angle ``phi`` is 0 upright and positive
    when the tip moves towards +x; the adapter reports ``theta = pi - phi`` and
    ``theta_dot = -phi_dot``, so theta = 0 hangs down, +-pi is upright, positive theta swings
    the tip towards +x (same as the MuJoCo env), not wrapped. ``info["state"]`` is the
    noise-free state.

    | Num | Observation                   | Min  | Max | Name (dm-control) | Joint | Type (Unit)   |
    |-----|-------------------------------|------|-----|-------------------|-------|---------------|
    | 0   | cart position x               | -Inf | Inf | slider            | slide | position (m)  |
    | 1   | cart velocity x_dot           | -Inf | Inf | slider            | slide | vel. (m/s)    |
    | 2   | pole angle theta = pi - phi   | -Inf | Inf | hinge_1           | hinge | angle (rad)   |
    | 3   | pole ang. velocity -phi_dot   | -Inf | Inf | hinge_1           | hinge | ang. v (rad/s)|

    ## Rewards
    Not dm-control's reward: ``reward = -c(s)`` with the swing-up cost of
    ``mcpilco/CartpoleSwingUp-v0`` (thesis section 5.5.1, defaults l_theta = 1, l_x = 1.5),
    and the same ``info`` keys ``cost``, ``upright``, ``state`` and, at step
    ``episode_steps``, ``success`` (upright over the last 20 steps with |x| < 0.5 m).

    ## Starting State
    dm-control's own swing-up initialisation: slider ~ N(0, 0.01^2), phi ~ pi + N(0, 0.01^2)
    (hanging down), both velocities ~ N(0, 0.01^2); in the adapter's coordinates this is
    ``s_0 ~ N(0, 0.01^2 I)``, the same distribution as the MuJoCo env. dm-control draws it
    from a ``numpy.random.RandomState`` owned by the adapter, reseeded by ``reset(seed=...)``
    (unseeded resets continue its stream).

    ## Episode End
    Never terminates; truncated after ``episode_steps`` = 60 steps (3 s) by the env and by
    ``TimeLimit(max_episode_steps=60)`` at registration. dm-control's own time limit is
    disabled (infinite).

    ## Arguments
    | Parameter       | Type      | Default | Description                                         |
    |-----------------|-----------|---------|-----------------------------------------------------|
    | `obs_noise_std` | **float** | `0.01`  | Std of Gaussian noise added to each observation     |
    | `l_theta`       | **float** | `1.0`   | Cost length scale of the pole angle (rad)           |
    | `l_x`           | **float** | `1.5`   | Cost length scale of the cart position (m)          |
    | `episode_steps` | **int**   | `60`    | Steps per episode                                   |
    | `control_dt`    | **float** | `0.05`  | Control period (s); a multiple of dm-control's 0.01 |

    ## Version History
    * v0: Initial version (dm-control 1.0.x, MuJoCo 3.x).
    """

    def __init__(
        self,
        obs_noise_std: float = CARTPOLE_TASK["obs_noise_std"],
        l_theta: float = CARTPOLE_TASK["l_theta"],
        l_x: float = CARTPOLE_TASK["l_x"],
        episode_steps: int = CARTPOLE_TASK["horizon"],
        control_dt: float = CARTPOLE_TASK["dt"],
        render_mode: str | None = None,
    ) -> None:
        super().__init__(
            "cartpole",
            "swingup",
            episode_steps=episode_steps,
            obs_noise_std=obs_noise_std,
            render_mode=render_mode,
        )
        dmc_dt = self.dt  # one dm-control control step
        repeat = int(round(control_dt / dmc_dt))
        if repeat < 1 or abs(repeat * dmc_dt - control_dt) > 1e-9:
            raise ValueError(
                f"control_dt={control_dt} must be a positive multiple of dm-control's control "
                f"timestep {dmc_dt}"
            )
        self.action_repeat = repeat
        self.dt = repeat * dmc_dt
        self.metadata = {"render_modes": ["rgb_array"], "render_fps": int(round(1.0 / self.dt))}
        self._scorer = SwingUpScorer(l_theta, l_x, episode_steps)
        self.observation_space = Box(-np.inf, np.inf, shape=(4,), dtype=np.float64)

    @property
    def state(self) -> NDArray[np.float64]:
        """True state ``[x, x_dot, theta, theta_dot]`` with ``theta = pi - phi``."""
        qpos, qvel = self.physics.named.data.qpos, self.physics.named.data.qvel
        return np.array(
            [qpos["slider"][0], qvel["slider"][0], np.pi - qpos["hinge_1"][0], -qvel["hinge_1"][0]]
        )

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed, options=options)
        self._scorer.reset()
        state = self.state
        return self._state_obs(state), self._scorer.score(state)[1]

    def step(self, action: ArrayLike):
        self._advance(action)
        state = self.state
        if not np.all(np.isfinite(state)):
            raise RuntimeError(f"simulation diverged: state {state}; reset the env")
        cost, truncated, info = self._scorer.step(state)
        return self._state_obs(state), -cost, False, truncated, info

    def _state_obs(self, state: NDArray[np.float64]) -> NDArray[np.float64]:
        if self._obs_noise_std > 0:
            return state + self._obs_noise_std * self.np_random.standard_normal(4)
        return state.copy()

"""Cart-pole swing-up of PILCO / MC-PILCO in MuJoCo: ``mcpilco/CartpoleSwingUp-v0``.

The task constants (:data:`CARTPOLE_TASK`) and the numpy cost (:func:`cartpole_cost`) live in
:mod:`mcpilco.envs.cartpole_task` and are re-exported here; reading them builds no MuJoCo model.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from gymnasium import utils
from gymnasium.envs.mujoco import MujocoEnv
from gymnasium.spaces import Box
from numpy.typing import ArrayLike, NDArray

from mcpilco.envs.cartpole_task import (
    CARTPOLE_TASK,
    STATE_NAMES,
    SwingUpScorer,
    cartpole_cost,
    is_upright,
    swingup_success,
    validate_action,
    wrap_angle,
)
from mcpilco.envs.display import MUJOCO_OFFSCREEN_MODES, check_render_mode, render_modes

__all__ = [
    "CARTPOLE_TASK",
    "STATE_NAMES",
    "CartpoleSwingUpEnv",
    "cartpole_cost",
    "is_upright",
    "swingup_success",
    "wrap_angle",
]

ASSET_PATH = Path(__file__).resolve().parent / "assets" / "cartpole.xml"
"""MJCF model of the cart-pole (physical parameters documented in the file)."""

FRAME_SKIP = 10
"""Physics steps per env step: 10 x 0.005 s (RK4) = 0.05 s control period."""

DEFAULT_CAMERA_CONFIG = {"trackbodyid": 1, "distance": 2.5, "elevation": 0.0, "azimuth": 90.0}


class CartpoleSwingUpEnv(MujocoEnv, utils.EzPickle):
    r"""
    ## Description
    The cart-pole swing-up benchmark of PILCO (Deisenroth & Rasmussen, 2011) and MC-PILCO
    (Amadio et al., IEEE T-RO 2022; thesis section 5.5.1), simulated in MuJoCo. A cart
    moves on an unbounded horizontal rail; a uniform rod hangs from a hinge on the cart. The
    pole starts hanging down; the goal is to swing it up and balance it with the cart at the
    origin, using a horizontal force of at most 10 N on the cart.

    Physical parameters (``assets/cartpole.xml``): cart mass 0.5 kg; pole 0.5 kg uniform rod
    of length 0.5 m (explicit inertial: centre of mass at 0.25 m, inertia about the pivot
    m l^2 / 3 = 0.041667 kg m^2); viscous friction on the cart 0.1 N s/m; no friction,
    armature or damping on the hinge; gravity 9.81 m/s^2; contacts disabled.
    Physics: RK4 integrator, timestep 0.005 s, ``frame_skip`` = 10, so ``dt`` = 0.05 s.

    ## Action Space
    The action space is a `Box(-1, 1, (1,), float32)`. The action is scaled by the actuator
    gear to the force on the cart, ``u = 10 a`` [N]. Actions outside [-1, 1] are clipped;
    a wrong shape or a NaN/inf raises ``ValueError``.

    | Num | Action                   | Min | Max | Name (XML) | Joint  | Type (Unit)    |
    |-----|--------------------------|-----|-----|------------|--------|----------------|
    | 0   | Force on the cart / 10 N | -1  | 1   | force      | slider | Force (x 10 N) |

    ## Observation Space
    The observation space is a `Box(-Inf, Inf, (4,), float64)`: the state
    ``[x, x_dot, theta, theta_dot]`` plus optional Gaussian measurement noise of standard
    deviation ``obs_noise_std`` on each entry. ``theta`` is 0 with the pole hanging down,
    +-pi upright, positive when the tip swings towards +x, and is NOT wrapped. The noise-free
    state is in ``info["state"]``.

    | Num | Observation                     | Min  | Max | Name (XML) | Joint | Type (Unit)   |
    |-----|---------------------------------|------|-----|------------|-------|---------------|
    | 0   | cart position x                 | -Inf | Inf | slider     | slide | position (m)  |
    | 1   | cart velocity x_dot             | -Inf | Inf | slider     | slide | vel. (m/s)    |
    | 2   | pole angle theta (0 = down)     | -Inf | Inf | hinge      | hinge | angle (rad)   |
    | 3   | pole angular velocity theta_dot | -Inf | Inf | hinge      | hinge | ang. v (rad/s)|

    ## Rewards
    ``reward = -c(s)`` with the saturating swing-up cost of thesis section 5.5.1 on the true
    state ``s`` after the step:

    ``c(s) = 1 - exp(-(|wrap(theta)| - pi)^2 / l_theta^2 - x^2 / l_x^2)``,

    ``wrap`` mapping to [-pi, pi); defaults l_theta = 1 rad and l_x = 1.5 m (thesis: l2 = 1,
    l1 = 1.5). ``info`` holds:

    - ``cost``: c(s) (float);
    - ``upright``: ``|wrap(theta)|`` within 10 degrees of pi (bool);
    - ``state``: the true state ``[x, x_dot, theta, theta_dot]`` (float64 copy);
    - ``success`` (only at step ``episode_steps``): upright at every one of the last 20 steps
      (the last 1 s) with ``|x| < 0.5`` m over those steps (bool).

    ## Starting State
    ``s_0 ~ N(0, 0.01^2 I)``: every coordinate of ``[x, x_dot, theta, theta_dot]`` is drawn
    independently with mean 0 (pole hanging down, cart at rest at the origin) and standard
    deviation ``reset_noise_scale`` = 0.01, from the env's ``np_random``.

    ## Episode End
    ### Termination
    Never (``terminated`` is always False).

    ### Truncation
    After ``episode_steps`` = 60 steps (3 s). The env sets ``truncated`` itself and the
    registration adds ``TimeLimit(max_episode_steps=60)``; pass both ``episode_steps`` and
    ``max_episode_steps`` to ``gym.make`` to change the length.

    ## Arguments
    ```python
    import gymnasium as gym
    import mcpilco.envs  # registers the ids
    env = gym.make("mcpilco/CartpoleSwingUp-v0", obs_noise_std=0.0)
    ```

    | Parameter           | Type  | Default        | Description                              |
    |---------------------|-------|----------------|------------------------------------------|
    | `xml_file`          | str   | `cartpole.xml` | MuJoCo model (default: bundled asset)    |
    | `obs_noise_std`     | float | `0.01`         | Std of Gaussian noise on each obs. entry |
    | `reset_noise_scale` | float | `0.01`         | Std of the initial state around 0        |
    | `l_theta`           | float | `1.0`          | Cost length scale of the pole angle (rad)|
    | `l_x`               | float | `1.5`          | Cost length scale of the cart (m)        |
    | `episode_steps`     | int   | `60`           | Steps per episode (truncation, success)  |
    | `frame_skip`        | int   | `10`           | Physics steps per env step (x 0.005 s)   |

    ## Version History
    * v0: Initial version (MuJoCo 3.x, Gymnasium 1.x).
    """

    metadata = {"render_modes": render_modes(*MUJOCO_OFFSCREEN_MODES)}

    def __init__(
        self,
        xml_file: str | Path = ASSET_PATH,
        obs_noise_std: float = CARTPOLE_TASK["obs_noise_std"],
        reset_noise_scale: float = CARTPOLE_TASK["init_std"],
        l_theta: float = CARTPOLE_TASK["l_theta"],
        l_x: float = CARTPOLE_TASK["l_x"],
        episode_steps: int = CARTPOLE_TASK["horizon"],
        frame_skip: int = FRAME_SKIP,
        default_camera_config: dict[str, float | int] = DEFAULT_CAMERA_CONFIG,
        **kwargs,
    ) -> None:
        utils.EzPickle.__init__(
            self,
            xml_file,
            obs_noise_std,
            reset_noise_scale,
            l_theta,
            l_x,
            episode_steps,
            frame_skip,
            default_camera_config,
            **kwargs,
        )
        if not obs_noise_std >= 0:
            raise ValueError(f"obs_noise_std must be >= 0, got {obs_noise_std}")
        if not reset_noise_scale >= 0:
            raise ValueError(f"reset_noise_scale must be >= 0, got {reset_noise_scale}")
        if int(frame_skip) != frame_skip or frame_skip < 1:
            raise ValueError(f"frame_skip must be a positive integer, got {frame_skip!r}")
        check_render_mode(kwargs.get("render_mode"), MUJOCO_OFFSCREEN_MODES)
        self._obs_noise_std = float(obs_noise_std)
        self._reset_noise_scale = float(reset_noise_scale)
        self._scorer = SwingUpScorer(l_theta, l_x, episode_steps)

        observation_space = Box(low=-np.inf, high=np.inf, shape=(4,), dtype=np.float64)
        MujocoEnv.__init__(
            self,
            str(xml_file),
            int(frame_skip),
            observation_space=observation_space,
            default_camera_config=default_camera_config,
            **kwargs,
        )
        self.metadata = {
            "render_modes": render_modes(*MUJOCO_OFFSCREEN_MODES),
            "render_fps": int(np.round(1.0 / self.dt)),
        }
        self.observation_structure = {name: 1 for name in STATE_NAMES}

    @property
    def state(self) -> NDArray[np.float64]:
        """True state ``[x, x_dot, theta, theta_dot]`` read from the named joints."""
        slider, hinge = self.data.joint("slider"), self.data.joint("hinge")
        return np.array([slider.qpos[0], slider.qvel[0], hinge.qpos[0], hinge.qvel[0]])

    def set_cartpole_state(self, state: ArrayLike) -> None:
        """Set the true state ``[x, x_dot, theta, theta_dot]`` (e.g. for tests or demos)."""
        s = np.asarray(state, dtype=np.float64)
        if s.shape != (4,) or not np.all(np.isfinite(s)):
            raise ValueError(f"state must be 4 finite values [x, x_dot, theta, theta_dot], got {s}")
        qpos, qvel = self.init_qpos.copy(), self.init_qvel.copy()
        qpos[self.model.joint("slider").qposadr[0]] = s[0]
        qvel[self.model.joint("slider").dofadr[0]] = s[1]
        qpos[self.model.joint("hinge").qposadr[0]] = s[2]
        qvel[self.model.joint("hinge").dofadr[0]] = s[3]
        self.set_state(qpos, qvel)

    def step(self, action: ArrayLike):
        a = validate_action(action, self.model.nu)
        self.do_simulation(np.clip(a, -1.0, 1.0), self.frame_skip)
        state = self.state
        if not np.all(np.isfinite(state)):
            raise RuntimeError(f"simulation diverged: state {state}; reset the env")
        cost, truncated, info = self._scorer.step(state)
        if self.render_mode == "human":
            self.render()
        return self._get_obs(), -cost, False, truncated, info

    def reset_model(self) -> NDArray[np.float64]:
        self._scorer.reset()
        noise = self._reset_noise_scale * self.np_random.standard_normal(4)
        self.set_cartpole_state(np.asarray(CARTPOLE_TASK["init_mean"]) + noise)
        return self._get_obs()

    def _get_reset_info(self) -> dict[str, object]:
        return self._scorer.score(self.state)[1]

    def _get_obs(self) -> NDArray[np.float64]:
        obs = self.state
        if self._obs_noise_std > 0:
            obs = obs + self._obs_noise_std * self.np_random.standard_normal(4)
        return obs

"""A user's own env, as a user would write it: a torque-driven pendulum that registers itself
as ``UserPendulum-v0`` when imported (``mcpilco-train --env tests.user_pendulum:UserPendulum-v0``).

State ``(theta, theta_dot)`` with ``theta = 0`` upright; it observes
``[cos theta, sin theta, theta_dot]``, so a task file derives the angle (``state_from``).
Dynamics: ``theta_ddot = 3 g / (2 l) sin(theta) + 3 u / (m l^2)`` (a uniform rod), explicit
Euler with ``dt`` = 0.05 s; ``reset`` draws ``theta ~ U(-a, a)`` with ``a = options["spread"]``
(default pi), at rest.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium.spaces import Box

G, MASS, LENGTH, DT = 9.81, 1.0, 1.0, 0.05  # gravity [m/s^2], rod mass [kg], length [m], step [s]


class UserPendulum(gym.Env):
    """The pendulum of the module docstring; ``max_torque`` [N m] bounds the action."""

    def __init__(self, max_torque: float = 2.0) -> None:
        self.max_torque = float(max_torque)
        self.dt = DT
        self.action_space = Box(-self.max_torque, self.max_torque, shape=(1,), dtype=np.float32)
        self.observation_space = Box(-np.inf, np.inf, shape=(3,), dtype=np.float64)
        self.state = np.zeros(2)

    def _obs(self) -> np.ndarray:
        th, thd = self.state
        return np.array([np.cos(th), np.sin(th), thd])

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        spread = float((options or {}).get("spread", np.pi))
        self.state = np.array([self.np_random.uniform(-spread, spread), 0.0])
        return self._obs(), {}

    def step(self, action):
        a = np.asarray(action, dtype=np.float64).reshape(-1)[0]
        u = float(np.clip(a, -self.max_torque, self.max_torque))
        th, thd = self.state
        thdd = 3 * G / (2 * LENGTH) * np.sin(th) + 3 * u / (MASS * LENGTH**2)
        thd = thd + DT * thdd
        self.state = np.array([th + DT * thd, thd])
        reward = -float(1 - np.cos(self.state[0]))
        return self._obs(), reward, False, False, {}


gym.register(id="UserPendulum-v0", entry_point=UserPendulum, max_episode_steps=200)

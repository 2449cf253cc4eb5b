"""A toy env with an end stop, written in a few lines.

``SlopeCart``: a cart on a sloped track, ``v+ = v + T_s (F u - G)``, ``x+ = x + T_s v+``
(``u in [-1, 1]``, ``F = 4``, the slope's pull ``G = 1`` m/s^2, ``T_s = 0.05`` s), starting
at rest at ``x = 0``; the track ends at ``x = +-1`` (a stop: the cart stays there at rest).
The task declares the track as ``limits``. Registered as ``mcpilco_test/SlopeCart-v0``.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

ENV_ID = "mcpilco_test/SlopeCart-v0"
FORCE, SLOPE, DT, STOP = 4.0, 1.0, 0.05, 1.0  # F [m/s^2], G [m/s^2], T_s [s], the stops +-1 m

TASK = {
    "env_id": ENV_ID,
    "state_names": ["x", "x_dot"],
    "pairs": [["x", "x_dot"]],
    "action_low": [-1.0],
    "action_high": [1.0],
    "dt": DT,
    "horizon": 200,
    "init_mean": [0.0, 0.0],
    "init_std": 0.0,
    "cost": {"terms": [{"state": "x", "target": 0.5, "length_scale": 0.3}]},
    "limits": {"x": [-STOP, STOP]},
    "success": {"window": 20, "bounds": {"x": {"target": 0.5, "tol": 0.1}}},
}


class SlopeCart(gym.Env):
    """The env of the module docstring."""

    def __init__(self) -> None:
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (2,), np.float64)
        self._s = np.zeros(2)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self._s = np.zeros(2)
        return self._s.copy(), {}

    def step(self, action):
        x, v = self._s
        v = v + DT * (FORCE * float(np.clip(action[0], -1.0, 1.0)) - SLOPE)
        x = x + DT * v
        if abs(x) >= STOP:  # the stop: the cart rests against it
            x, v = float(np.sign(x)) * STOP, 0.0
        self._s = np.array([x, v])
        return self._s.copy(), 0.0, False, False, {}


if ENV_ID not in gym.registry:
    gym.register(id=ENV_ID, entry_point=SlopeCart, max_episode_steps=200)

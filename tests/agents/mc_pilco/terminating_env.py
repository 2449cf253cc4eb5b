"""A toy env that ends its episodes early, written in a few lines.

``Drift1D``: a point on a line that drifts forward by ``0.1 + 0.05 u`` per step
(``u in [-1, 1]``), starting at ``p = 0``; the episode ends as soon as ``p > 0.5``, so after
4 to 10 steps whatever the actions. Registered as ``mcpilco_test/Drift1D-v0``.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

ENV_ID = "mcpilco_test/Drift1D-v0"
DRIFT, GAIN, END = 0.1, 0.05, 0.5  # p+ = p + DRIFT + GAIN u; terminated when p > END

TASK = {
    "env_id": ENV_ID,
    "state_names": ["p"],
    "action_low": [-1.0],
    "action_high": [1.0],
    "dt": 0.1,
    "horizon": 20,
    "trial_steps": 30,
    "init_mean": [0.0],
    "init_std": 0.0,
    "cost": {"terms": [{"state": "p", "target": 0.0, "length_scale": 1.0}]},
    "termination": {"p": [-10.0, END]},
    "success": {"full_horizon": True},
}


class Drift1D(gym.Env):
    """The env of the module docstring."""

    def __init__(self) -> None:
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (1,), np.float64)
        self._p = 0.0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self._p = 0.0
        return np.array([self._p]), {}

    def step(self, action):
        self._p += DRIFT + GAIN * float(np.clip(action[0], -1.0, 1.0))
        return np.array([self._p]), -self._p, self._p > END, False, {}


if ENV_ID not in gym.registry:
    gym.register(id=ENV_ID, entry_point=Drift1D, max_episode_steps=20)

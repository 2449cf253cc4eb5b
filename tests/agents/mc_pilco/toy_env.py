"""A toy env written in a few lines, to show that the agent is not tied to the cart-pole.

``PointMass2D``: a unit mass on a plane with light viscous friction, pushed by a force
``u in [-1, 1]^2``; state ``[px, vx, py, vy]``, control period 0.1 s, exact zero-order-hold
discretisation of ``p_dot = v``, ``v_dot = u - b v``. It starts at ``(-1, 0.5)`` at rest and
must reach the origin. Registered as ``mcpilco_test/PointMass2D-v0``.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

ENV_ID = "mcpilco_test/PointMass2D-v0"
DT = 0.1  # control period [s]
FRICTION = 0.2  # viscous friction b [1/s]
START = (-1.0, 0.0, 0.5, 0.0)  # initial state [px, vx, py, vy]

TASK = {
    "env_id": ENV_ID,
    "state_names": ["px", "vx", "py", "vy"],
    "pairs": [["px", "vx"], ["py", "vy"]],
    "action_low": [-1.0, -1.0],
    "action_high": [1.0, 1.0],
    "dt": DT,
    "horizon": 30,
    "init_mean": list(START),
    "init_std": 0.01,
    "cost": {
        "terms": [
            {"state": "px", "target": 0.0, "length_scale": 0.5},
            {"state": "py", "target": 0.0, "length_scale": 0.5},
        ]
    },
    "success": {"window": 5, "bounds": {"px": {"target": 0.0, "tol": 0.1},
                                        "py": {"target": 0.0, "tol": 0.1}}},
}  # fmt: skip


class PointMass2D(gym.Env):
    """The env of the module docstring."""

    def __init__(self) -> None:
        self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (4,), np.float64)
        e = np.exp(-FRICTION * DT)
        # exact ZOH of one axis: [p, v]+ = A [p, v] + B u
        self._A = np.array([[1.0, (1 - e) / FRICTION], [0.0, e]])
        self._B = np.array([(DT - (1 - e) / FRICTION) / FRICTION, (1 - e) / FRICTION])
        self._x = np.zeros(4)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self._x = np.asarray(START) + 0.01 * self.np_random.standard_normal(4)
        return self._x.copy(), {}

    def step(self, action):
        u = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        for axis, k in ((0, 0), (2, 1)):
            self._x[axis : axis + 2] = self._A @ self._x[axis : axis + 2] + self._B * u[k]
        cost = float(self._x[0] ** 2 + self._x[2] ** 2)
        return self._x.copy(), -cost, False, False, {}


if ENV_ID not in gym.registry:
    gym.register(id=ENV_ID, entry_point=PointMass2D, max_episode_steps=30)

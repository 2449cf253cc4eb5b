"""A two-link planar arm behind a PD + gravity controller, in closed form (no simulator).

``TwoLinkTracking``: links of mass ``m_b``, length ``l_b``, centre of mass at ``l_b / 2``,
inertia ``m_b l_b^2 / 12``, in a vertical plane, viscous joint friction ``F_v``. With
``h = m_2 l_1 c_2``::

    M(q) = [[I_1 + I_2 + m_1 c_1^2 + m_2 (l_1^2 + c_2^2 + 2 l_1 c_2 cos q_2),
             I_2 + m_2 (c_2^2 + l_1 c_2 cos q_2)], [., I_2 + m_2 c_2^2]]
    c(q, qd) = h sin q_2 [-(2 qd_1 qd_2 + qd_2^2), qd_1^2]
    g(q) = g0 [(m_1 c_1 + m_2 l_1) cos q_1 + m_2 c_2 cos(q_1 + q_2), m_2 c_2 cos(q_1 + q_2)]
    M qdd + c + g + F_v qd = tau = Kp (q_r - q) + Kd (qd_r - qd) + g(q) + u

The controller runs every substep (RK4, ``SUBSTEPS`` per control period ``DT``), the
correction ``u = action * U_SCALE`` is held over the period. The reference is one sinusoid
per joint (``reset(options={"reference": SumOfSinusoids})``; default :data:`REFERENCE`);
it is fast enough that the PD controller lags it by several hundredths of a radian.
Observation ``[q_1, q_2, qd_1, qd_2, q_r1, q_r2, qd_r1, qd_r2]`` (the UR10 env's layout).
Registered as ``mcpilco_test/TwoLinkTracking-v0``.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from mcpilco.envs.arm_env import SumOfSinusoids

ENV_ID = "mcpilco_test/TwoLinkTracking-v0"
DT = 0.05  # control period [s]
SUBSTEPS = 10  # controller ticks and RK4 steps per control period
HORIZON = 40  # 2 s
MASS, LENGTH, G0 = (1.0, 0.8), (0.5, 0.5), 9.81  # [kg], [m], [m/s^2]
FRICTION = (0.3, 0.2)  # viscous F_v [N m s/rad]
KP, KD = (25.0, 15.0), (4.0, 2.5)  # PD gains [N m/rad], [N m s/rad]
U_SCALE = (4.0, 2.0)  # torque correction per unit action [N m]
REFERENCE = dict(
    centre=[-0.8, 1.0], amplitudes=[[0.5], [0.6]], omegas=[[3.0], [4.0]],
    phases=[[0.0], [1.0]], duration=2.0,
)  # fmt: skip


def sinusoids(ref: dict) -> SumOfSinusoids:
    """The reference of a task's ``reference`` mapping."""
    keys = ("centre", "amplitudes", "omegas", "phases")
    return SumOfSinusoids(*(np.asarray(ref[k], dtype=np.float64) for k in keys), ref["duration"])


def reference_start(ref: dict) -> list[float]:
    """The state ``[q, qd, q_r, qd_r]`` on the reference at ``t = 0``."""
    q, qd, _ = sinusoids(ref)(0.0)
    return [*q, *qd, *q, *qd]


TASK = {
    "env_id": ENV_ID,
    "state_names": ["q1", "q2", "qd1", "qd2", "r1", "r2", "rd1", "rd2"],
    "pairs": [["q1", "qd1"], ["q2", "qd2"], ["r1", "rd1"], ["r2", "rd2"]],
    "joints": ["q1", "q2"],
    "joint_types": "RR",
    "affine_inputs": ["r1", "r2", "rd1", "rd2"],
    "reference": REFERENCE,
    "action_low": [-1.0, -1.0],
    "action_high": [1.0, 1.0],
    "dt": DT,
    "horizon": HORIZON,
    "init_mean": reference_start(REFERENCE),
    "init_std": 0.002,
    "cost": {"terms": [{"state": "q1", "reference": "r1", "length_scale": 0.05},
                       {"state": "q2", "reference": "r2", "length_scale": 0.05}]},
    "success": {"full_horizon": True},
}  # fmt: skip


def dynamics(x: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """``[qd, qdd]`` of the arm at ``x = [q, qd]`` under the joint torques ``tau``."""
    (m1, m2), (l1, l2) = MASS, LENGTH
    c1, c2, i1, i2 = l1 / 2, l2 / 2, m1 * l1**2 / 12, m2 * l2**2 / 12
    q1, q2, qd1, qd2 = x
    h = m2 * l1 * c2
    m11 = i1 + i2 + m1 * c1**2 + m2 * (l1**2 + c2**2) + 2 * h * np.cos(q2)
    m12 = i2 + m2 * c2**2 + h * np.cos(q2)
    m22 = i2 + m2 * c2**2
    cor = h * np.sin(q2) * np.array([-(2 * qd1 * qd2 + qd2**2), qd1**2])
    rhs = tau - cor - gravity(x[:2]) - np.asarray(FRICTION) * x[2:]
    qdd = np.linalg.solve(np.array([[m11, m12], [m12, m22]]), rhs)
    return np.concatenate([x[2:], qdd])


def gravity(q: np.ndarray) -> np.ndarray:
    """``g(q)``, the gravity torques (also the controller's feed-forward)."""
    (m1, m2), (l1, l2) = MASS, LENGTH
    a = m2 * l2 / 2 * np.cos(q[0] + q[1])
    return G0 * np.array([(m1 * l1 / 2 + m2 * l1) * np.cos(q[0]) + a, a])


class TwoLinkTracking(gym.Env):
    """The env of the module docstring."""

    n_joints = 2
    dt = DT

    def __init__(self) -> None:
        self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (8,), np.float64)
        self.reference = None
        self._x, self._t = np.zeros(4), 0.0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        ref = (options or {}).get("reference")
        self.reference = ref if ref is not None else sinusoids(REFERENCE)
        q, qd, _ = self.reference(0.0)
        self._t = 0.0
        self._x = np.concatenate([q + 0.002 * self.np_random.standard_normal(2), qd])
        return self._obs(), {}

    def _obs(self) -> np.ndarray:
        q_r, qd_r, _ = self.reference(self._t)
        return np.concatenate([self._x, q_r, qd_r])

    def _xdot(self, x: np.ndarray, t: float, u: np.ndarray) -> np.ndarray:
        q_r, qd_r, _ = self.reference(t)
        tau = np.asarray(KP) * (q_r - x[:2]) + np.asarray(KD) * (qd_r - x[2:]) + gravity(x[:2])
        return dynamics(x, tau + u)

    def step(self, action):
        u = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0) * np.asarray(U_SCALE)
        h = DT / SUBSTEPS
        for _ in range(SUBSTEPS):
            x, t = self._x, self._t
            k1 = self._xdot(x, t, u)
            k2 = self._xdot(x + h / 2 * k1, t + h / 2, u)
            k3 = self._xdot(x + h / 2 * k2, t + h / 2, u)
            k4 = self._xdot(x + h * k3, t + h, u)
            self._x, self._t = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4), t + h
        obs = self._obs()
        return obs, -float(np.sum((obs[:2] - obs[4:6]) ** 2)), False, False, {}


if ENV_ID not in gym.registry:
    gym.register(id=ENV_ID, entry_point=TwoLinkTracking, max_episode_steps=HORIZON)

"""A planar two-link arm with closed-form inverse dynamics (the independent truth here).

Both hinges turn about the world ``y`` axis, gravity is ``-z``: link ``k`` has mass ``m_k``,
length ``l_k``, centre of mass ``lc_k`` along the link and inertia ``I_k`` about its centre
of mass (about ``y``). With ``V = -g (m1 lc1 s1 + m2 (l1 s1 + lc2 s12))`` (heights are
``-r sin(angle)`` for a rotation about ``+y``) the Euler-Lagrange equations give the
textbook ``M(q) qdd + C(q, qd) qd + g(q)`` below.
"""

from __future__ import annotations

import numpy as np

G = 9.81
M1, M2 = 2.0, 1.5
L1 = 0.6
LC1, LC2 = 0.3, 0.25
I1, I2 = 0.06, 0.04
FV = np.array([0.3, 0.2])  # viscous friction used by the friction test
FC = np.array([0.5, 0.4])  # Coulomb friction


def two_link_mjcf() -> str:
    """MJCF text of the arm (the same numbers as the closed form)."""
    return f"""
<mujoco model="two_link">
  <compiler angle="radian" inertiafromgeom="false"/>
  <option gravity="0 0 -{G}"/>
  <worldbody>
    <body name="link1">
      <joint name="j1" type="hinge" axis="0 1 0"/>
      <inertial pos="{LC1} 0 0" mass="{M1}" diaginertia="0.05 {I1} 0.05"/>
      <body name="link2" pos="{L1} 0 0">
        <joint name="j2" type="hinge" axis="0 1 0"/>
        <inertial pos="{LC2} 0 0" mass="{M2}" diaginertia="0.03 {I2} 0.03"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def two_link_torque(q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
    """Closed-form ``tau (N, 2)`` of the arm for ``(N, 2)`` inputs."""
    c2 = np.cos(q[:, 1])
    s2 = np.sin(q[:, 1])
    c1 = np.cos(q[:, 0])
    c12 = np.cos(q[:, 0] + q[:, 1])
    m11 = I1 + I2 + M1 * LC1**2 + M2 * (L1**2 + LC2**2 + 2 * L1 * LC2 * c2)
    m12 = I2 + M2 * (LC2**2 + L1 * LC2 * c2)
    m22 = I2 + M2 * LC2**2
    h = -M2 * L1 * LC2 * s2
    g1 = -G * ((M1 * LC1 + M2 * L1) * c1 + M2 * LC2 * c12)
    g2 = -G * M2 * LC2 * c12
    tau1 = m11 * qdd[:, 0] + m12 * qdd[:, 1] + h * (2 * qd[:, 0] * qd[:, 1] + qd[:, 1] ** 2) + g1
    tau2 = m12 * qdd[:, 0] + m22 * qdd[:, 1] - h * qd[:, 0] ** 2 + g2
    return np.stack([tau1, tau2], axis=1)


def random_states(n: int, seed: int) -> np.ndarray:
    """``(n, 6)`` inputs ``[q, qd, qdd]`` drawn uniformly."""
    rng = np.random.default_rng(seed)
    q = rng.uniform(-np.pi, np.pi, (n, 2))
    qd = rng.uniform(-2, 2, (n, 2))
    qdd = rng.uniform(-4, 4, (n, 2))
    return np.concatenate([q, qd, qdd], axis=1)


def two_link_data() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Noise-free training (80 rows) and test (50 rows) data ``X, y, X_test, y_test``."""
    X = random_states(80, 0)
    Xt = random_states(50, 1)
    y = two_link_torque(X[:, :2], X[:, 2:4], X[:, 4:])
    yt = two_link_torque(Xt[:, :2], Xt[:, 2:4], Xt[:, 4:])
    return X, y, Xt, yt

"""The cartpole swing-up task, in plain numpy (no MuJoCo, no torch).

Both cartpole environments (:mod:`mcpilco.envs.cartpole` and :mod:`mcpilco.envs.dmc_cartpole`)
score their true state with the functions here, and agents can read :data:`CARTPOLE_TASK`
without building a MuJoCo model. Symbols follow thesis section 5.5.1.

Glossary
--------
``x = [q1, q1_dot, q2, q2_dot]``
    state: cart position ``q1`` [m], cart velocity [m/s], pole angle ``q2`` [rad] (0 hanging
    down, +-pi upright, not wrapped), pole angular velocity [rad/s].
``wrap(q2)``
    ``q2`` mapped to ``[-pi, pi)``.
``c(x) = 1 - exp(-(|wrap(q2)| - pi)^2 / l_theta^2 - q1^2 / l_x^2)``
    swing-up cost in ``[0, 1)``, zero at the upright equilibrium with the cart at the origin
    (thesis section 5.5.1, with ``l1 = l_x = 1.5`` and ``l2 = l_theta = 1``).
upright
    ``|wrap(q2)|`` within 10 degrees of pi.
success
    upright during the whole last second of the episode (the last 20 steps of 0.05 s) with
    ``|q1| < 0.5`` m over those steps (thesis section 5.5.1, plus a bound on the cart).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

STATE_NAMES: tuple[str, ...] = ("x", "x_dot", "theta", "theta_dot")
"""Names of the four state coordinates, in order."""

CARTPOLE_TASK: dict[str, object] = dict(
    dt=0.05,  # control period [s]
    horizon=60,  # steps per episode (3 s)
    u_max=10.0,  # force limit [N]; action a in [-1, 1] gives force u = u_max * a
    l_theta=1.0,  # cost length scale of the pole angle [rad] (thesis 5.5.1: l2 = 1)
    l_x=1.5,  # cost length scale of the cart position [m] (thesis 5.5.1: l1 = 1.5)
    init_mean=(0.0, 0.0, 0.0, 0.0),  # initial state mean
    init_std=0.01,  # initial state std per coordinate: x0 ~ N(0, 1e-4 I)
    obs_noise_std=0.01,  # default measurement noise std on the observation
    upright_tol_deg=10.0,  # |wrap(theta)| within this many degrees of pi counts as upright
    success_window=20,  # steps (1 s) at the episode end that must all be upright
    success_x_max=0.5,  # |x| bound [m] over the success window
    state_names=STATE_NAMES,
    # physical parameters of mcpilco/CartpoleSwingUp-v0 (PILCO / MC-PILCO cart-pole)
    cart_mass=0.5,  # [kg]
    pole_mass=0.5,  # [kg], uniform rod
    pole_length=0.5,  # [m], pivot to tip
    cart_friction=0.1,  # viscous friction on the cart [N s/m]
    gravity=9.81,  # [m/s^2]
)
"""Constants of the swing-up task shared by the cartpole environments and agents."""


def wrap_angle(theta: ArrayLike) -> NDArray[np.float64]:
    """Map angles to ``[-pi, pi)``: ``wrap(theta) = (theta + pi) mod 2 pi - pi``."""
    theta = np.asarray(theta, dtype=np.float64)
    return np.mod(theta + np.pi, 2.0 * np.pi) - np.pi


def cartpole_cost(
    state: ArrayLike,
    l_theta: float = CARTPOLE_TASK["l_theta"],
    l_x: float = CARTPOLE_TASK["l_x"],
) -> NDArray[np.float64] | float:
    """Swing-up cost ``c(x) = 1 - exp(-(|wrap(theta)| - pi)^2 / l_theta^2 - x^2 / l_x^2)``.

    Args:
        state: ``(..., 4)`` array ``[x, x_dot, theta, theta_dot]`` (theta = 0 hanging down).
        l_theta: length scale of the angle term [rad], > 0.
        l_x: length scale of the cart term [m], > 0.

    Returns:
        the cost, shape ``state.shape[:-1]`` (a Python float for a single state), in ``[0, 1)``.
    """
    if not (l_theta > 0 and l_x > 0):
        raise ValueError(f"cost length scales must be > 0, got l_theta={l_theta}, l_x={l_x}")
    state = np.asarray(state, dtype=np.float64)
    if state.ndim == 0 or state.shape[-1] != 4:
        raise ValueError(
            f"state must have shape (..., 4) = [x, x_dot, theta, theta_dot], got {state.shape}"
        )
    x, theta = state[..., 0], state[..., 2]
    d_theta = np.abs(wrap_angle(theta)) - np.pi
    cost = 1.0 - np.exp(-((d_theta / l_theta) ** 2) - (x / l_x) ** 2)
    return float(cost) if cost.ndim == 0 else cost


def is_upright(
    theta: ArrayLike, tol_deg: float = CARTPOLE_TASK["upright_tol_deg"]
) -> NDArray[np.bool_] | bool:
    """True where ``|wrap(theta)|`` is within ``tol_deg`` degrees of pi (pole up)."""
    up = np.abs(wrap_angle(theta)) >= np.pi - math.radians(tol_deg)
    return bool(up) if up.ndim == 0 else up


def swingup_success(
    states: ArrayLike,
    window: int = CARTPOLE_TASK["success_window"],
    x_max: float = CARTPOLE_TASK["success_x_max"],
    tol_deg: float = CARTPOLE_TASK["upright_tol_deg"],
) -> bool:
    """Success of one episode: the last ``window`` states are all upright with ``|x| < x_max``.

    Args:
        states: ``(T, 4)`` true states after each step of the episode, in time order.
        window: number of final states that must satisfy the condition (20 steps = 1 s).
        x_max: bound on ``|x|`` [m] over the window.
        tol_deg: upright tolerance [deg].

    Returns:
        False when fewer than ``window`` states are given.
    """
    states = np.asarray(states, dtype=np.float64)
    if states.ndim != 2 or states.shape[1] != 4:
        raise ValueError(f"states must have shape (T, 4), got {states.shape}")
    if states.shape[0] < window:
        return False
    last = states[-window:]
    return bool(np.all(is_upright(last[:, 2], tol_deg)) and np.all(np.abs(last[:, 0]) < x_max))


class SwingUpScorer:
    """Per-episode bookkeeping of cost, ``upright`` and ``success`` on the true state.

    Shared by the MuJoCo and dm-control cartpole environments so that both report the
    same ``info`` keys with the same definitions.
    """

    def __init__(self, l_theta: float, l_x: float, episode_steps: int) -> None:
        if not (l_theta > 0 and l_x > 0):
            raise ValueError(f"l_theta and l_x must be > 0, got l_theta={l_theta}, l_x={l_x}")
        if int(episode_steps) != episode_steps or episode_steps < 1:
            raise ValueError(f"episode_steps must be a positive integer, got {episode_steps!r}")
        self.l_theta = float(l_theta)
        self.l_x = float(l_x)
        self.episode_steps = int(episode_steps)
        self.reset()

    def reset(self) -> None:
        """Start a new episode."""
        self.steps = 0
        self._window: list[NDArray[np.float64]] = []

    def score(self, state: NDArray[np.float64]) -> tuple[float, dict[str, object]]:
        """Cost and ``info`` entries of a state, without counting a step (used at reset)."""
        cost = cartpole_cost(state, self.l_theta, self.l_x)
        return cost, {"cost": cost, "upright": is_upright(state[2]), "state": state.copy()}

    def step(self, state: NDArray[np.float64]) -> tuple[float, bool, dict[str, object]]:
        """Count one step ending in ``state``; returns ``(cost, truncated, info)``.

        ``truncated`` is True at step ``episode_steps``; ``info["success"]`` is present only
        then.
        """
        self.steps += 1
        self._window.append(state.copy())
        window = CARTPOLE_TASK["success_window"]
        if len(self._window) > window:
            self._window.pop(0)
        cost, info = self.score(state)
        truncated = self.steps >= self.episode_steps
        if self.steps == self.episode_steps:
            info["success"] = swingup_success(np.stack(self._window), window)
        return cost, truncated, info


def validate_action(action: ArrayLike, dim: int) -> NDArray[np.float64]:
    """Check an action at the env boundary and return it as a float64 array of shape (dim,).

    Accepts shape ``(dim,)`` (and a scalar when ``dim == 1``); raises ``ValueError`` naming
    the problem for a wrong shape or a non-finite entry. Values outside ``[-1, 1]`` are
    clipped by the caller.
    """
    try:
        a = np.asarray(action, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise ValueError(f"action must be numeric with shape ({dim},), got {action!r}") from err
    if a.shape == () and dim == 1:
        a = a.reshape(1)
    if a.shape != (dim,):
        raise ValueError(
            f"action has shape {a.shape}, expected ({dim},); pass one value in [-1, 1] per actuator"
        )
    if not np.all(np.isfinite(a)):
        raise ValueError(f"action contains NaN or inf: {a}; pass finite values in [-1, 1]")
    return a

r"""MC-PILCO through a learned kinematic model: reach a target pose with joint increments.

The system of thesis chapter 2: a robot with an ideal joint position controller, seen only
through a camera and fiducial markers. Its learned model is kinematic, not dynamic: the
structure identified from the markers and the forward-kinematics GP of the end marker
(e.g. :class:`~mcpilco.models.kinematics.ChainForwardKinematicsGP`). MC-PILCO optimises a
closed-loop joint-increment policy through it, as it does through GP dynamics on the
cart-pole: particles, the squashed RBF policy with dropout, the expected cumulative cost and
its gradient by backpropagation through the horizon (:class:`ReachingLoss`,
:func:`~.optimize.optimize_policy`).

Glossary (symbols of thesis ch. 2 and 5)
----------------------------------------
``q_t`` (n,)
    joint positions in the model's joint order (``S_q``), the state; revolute joints enter
    the policy as ``(sin, cos)``, prismatic ones as they are.
``u_t = pi_theta(q_t + sigma_obs nu_t)`` in ``[-1, 1]^n``
    the policy's normalised increments.
``q_{t+1} = clip(q_t + Delta o u_t, q_lo, q_hi)``
    the joint controller (:class:`IncrementDynamics`): known, not learned; ``Delta`` the
    largest increment per step of each joint [rad or m].
``(l^, R^) = FK^(q)``
    the learned model's end-marker position and orientation (posterior mean).
``e(q) = ||l^ - l*|| + w_o theta(R^, R*)``
    the pose error of the target ``p* = (l*, R*)``, the geodesic angle
    ``theta = 2 asin(||R^ - R*||_F / (2 sqrt 2))`` weighted by ``w_o`` [m/rad]: the cost of
    :class:`~mcpilco.envs.marker_camera.MarkerCameraEnv` (its reward is ``-e``), on the
    model's prediction.
``c(q) = eps log(1 + e(q) / eps)``
    the cost MC-PILCO minimises (:class:`PoseErrorCost`): ``e`` below ``eps`` (1 cm by
    default), logarithmic above. Summed over the horizon, ``e`` itself weighs a step in
    transit as much as a step at the target, and the optimised policy stops about a
    centimetre short; the logarithm gives the last millimetres the weight of the approach
    (``dc/de = 1 / (1 + e / eps)``). ``eps = None``: ``c = e``.
``J(theta) = sum_{t=1}^{H} 1/M sum_m c(q_t^(m))``
    MC-PILCO's objective (eq. 5.8) over ``H`` steps and ``M`` particles.

The particles start at the measured ``q_0`` with the encoder's noise and see it on their
inputs; the model is the posterior mean, so the particles differ by the policy's dropout and
that noise (a model with a predictive variance would add its own spread through ``eps``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch
from numpy.typing import ArrayLike
from torch import Tensor, nn

from mcpilco.agents.mc_pilco.features import StateLayout
from mcpilco.agents.mc_pilco.optimize import (
    OptimizationResult,
    PolicyOptConfig,
    optimize_policy,
)
from mcpilco.agents.mc_pilco.policy import SquashedRBFPolicy, data_init

__all__ = [
    "IncrementDynamics",
    "PoseErrorCost",
    "ReachingConfig",
    "ReachingLoss",
    "joint_layout",
    "optimise_reaching_policy",
    "rollout_error",
]

ANGLE_EPS = 1e-6  # smoothing of the norms at zero error [m, and Frobenius units]


def joint_layout(joint_types: str) -> StateLayout:
    """State layout of ``q``: revolute joints (``"R"``) as angles, prismatic (``"P"``) plain,
    every coordinate its own change (no velocity pairs)."""
    if not joint_types or set(joint_types) - set("RP"):
        raise ValueError(
            f"joint_types must be a non-empty string of 'R' and 'P', got {joint_types!r}"
        )
    n = len(joint_types)
    return StateLayout(
        n=n,
        plain_idx=tuple(i for i, t in enumerate(joint_types) if t == "P"),
        angle_idx=tuple(i for i, t in enumerate(joint_types) if t == "R"),
        delta_idx=tuple(range(n)),
    )


class IncrementDynamics(nn.Module):
    """``q_{t+1} = clip(q_t + Delta o u_t, q_lo, q_hi)``: an ideal joint position controller
    (module glossary); ``eps`` (the GP dynamics' random input elsewhere) is not used.

    Args:
        increments: ``Delta`` (n,), the largest step of each joint [rad or m].
        q_limits: ``(n, 2)`` joint limits, or None for none.
    """

    def __init__(self, increments: ArrayLike, q_limits: ArrayLike | None = None) -> None:
        super().__init__()
        inc = torch.as_tensor(np.asarray(increments, dtype=np.float64)).reshape(-1)
        if inc.numel() == 0 or not bool((inc > 0).all()):
            raise ValueError(f"increments must be > 0, got {inc.tolist()}")
        self.register_buffer("increments", inc)
        if q_limits is None:
            lo = torch.full_like(inc, -math.inf)
            hi = torch.full_like(inc, math.inf)
        else:
            lim = torch.as_tensor(np.asarray(q_limits, dtype=np.float64))
            if lim.shape != (inc.numel(), 2) or not bool((lim[:, 0] < lim[:, 1]).all()):
                raise ValueError(
                    f"q_limits must be ({inc.numel()}, 2) with low < high, got {tuple(lim.shape)}"
                )
            lo, hi = lim[:, 0], lim[:, 1]
        self.register_buffer("q_low", lo)
        self.register_buffer("q_high", hi)

    def forward(self, q: Tensor, u: Tensor, eps: Tensor | None = None) -> Tensor:
        step = q + self.increments.to(q.dtype) * u
        return torch.maximum(torch.minimum(step, self.q_high.to(q.dtype)), self.q_low.to(q.dtype))


class PoseErrorCost(nn.Module):
    """``c(q) = eps log(1 + e(q) / eps)`` of the pose error ``e(q) = ||l^(q) - l*|| +
    w_o theta(R^(q), R*)`` (module glossary); ``e`` itself when ``log_scale`` is None.

    Args:
        model: the learned kinematics, with ``position_and_rotation(q (..., n)) ->
            (l (..., 3), R (..., 3, 3))`` (e.g.
            :meth:`~mcpilco.models.kinematics.ChainForwardKinematicsGP.predictor`).
        target_position: ``l*`` (3,).
        target_rotation: ``R*`` (3, 3).
        orientation_weight: ``w_o`` [m/rad].
        log_scale: ``eps`` [m], or None for ``c = e``.
    """

    def __init__(
        self,
        model: nn.Module,
        target_position: ArrayLike,
        target_rotation: ArrayLike,
        orientation_weight: float = 0.1,
        log_scale: float | None = None,
    ) -> None:
        super().__init__()
        if log_scale is not None and not log_scale > 0:
            raise ValueError(f"log_scale must be > 0 or None, got {log_scale}")
        self.log_scale = log_scale
        l_star = torch.as_tensor(np.asarray(target_position, dtype=np.float64))
        R_star = torch.as_tensor(np.asarray(target_rotation, dtype=np.float64))
        if l_star.shape != (3,) or R_star.shape != (3, 3):
            raise ValueError(
                f"need target_position (3,) and target_rotation (3, 3), got "
                f"{tuple(l_star.shape)} and {tuple(R_star.shape)}"
            )
        if not orientation_weight >= 0:
            raise ValueError(f"orientation_weight must be >= 0, got {orientation_weight}")
        if not callable(getattr(model, "position_and_rotation", None)):
            raise TypeError("model needs a position_and_rotation(q) method")
        self.model = model
        self.orientation_weight = float(orientation_weight)
        self.register_buffer("l_star", l_star)
        self.register_buffer("R_star", R_star)

    def errors(self, q: Tensor) -> tuple[Tensor, Tensor]:
        """``(||l^ - l*||, theta)`` at ``q`` (..., n), each (...)."""
        l_hat, R_hat = self.model.position_and_rotation(q)
        d_l = l_hat - self.l_star.to(q.dtype)
        pos = torch.sqrt(d_l.pow(2).sum(-1) + ANGLE_EPS**2)
        chord = torch.sqrt((R_hat - self.R_star.to(q.dtype)).pow(2).sum((-2, -1)) + ANGLE_EPS**2)
        theta = 2.0 * torch.asin(torch.clamp(chord / (2.0 * math.sqrt(2.0)), max=1.0))
        return pos, theta

    def forward(self, q: Tensor) -> Tensor:
        pos, theta = self.errors(q)
        e = pos + self.orientation_weight * theta
        if self.log_scale is None:
            return e
        return self.log_scale * torch.log1p(e / self.log_scale)


class ReachingLoss(nn.Module):
    """MC-PILCO's ``J(theta)`` (eq. 5.8) for the kinematic system: ``loss_cost`` and
    ``cost_std`` (``s_J``), as :func:`~.optimize.optimize_policy` reads them.

    The joint trajectories of the ``M`` particles come first (the policy on the noisy
    measured joints, :class:`IncrementDynamics`), then the cost of all ``H M`` states in one
    batched call of the model: the cost depends on the states only, and the model's
    per-call work (a chain of one-joint GPs, each with an iterative projection onto SO(3))
    is then done once per rollout instead of once per step. Each call draws new particles
    ``q_0 ~ N(q0, sigma_0^2 I)``, input noise and dropout masks.
    """

    def __init__(
        self,
        policy: nn.Module,
        dynamics: IncrementDynamics,
        cost: nn.Module,
        horizon: int,
        particles: int,
        q0: Tensor,
        init_std: float,
        obs_noise_std: float,
    ) -> None:
        super().__init__()
        self.policy, self.dynamics, self.cost = policy, dynamics, cost
        self.horizon, self.particles = int(horizon), int(particles)
        self.register_buffer("q0", q0.reshape(-1))
        self.init_std, self.obs_noise_std = float(init_std), float(obs_noise_std)

    def trajectories(self) -> Tensor:
        """``q_1 .. q_H`` of the particles, ``(M, H, n)``."""
        q = self.q0 + self.init_std * torch.randn(
            self.particles, self.q0.numel(), dtype=self.q0.dtype
        )
        steps = []
        for _ in range(self.horizon):
            u = self.policy(q + self.obs_noise_std * torch.randn_like(q)).to(q.dtype)
            q = self.dynamics(q, u)
            steps.append(q)
        return torch.stack(steps, 1)

    def forward(self) -> dict[str, Tensor]:
        per_particle = self.cost(self.trajectories()).sum(1)  # sum_t c(q_t^(m))
        return {"loss_cost": per_particle.mean(), "cost_std": per_particle.detach().std()}


@dataclass
class ReachingConfig:
    """Settings of :func:`optimise_reaching_policy`.

    ``horizon``: ``H`` steps of a trial; ``particles``: ``M``; ``num_basis``: the policy's
    ``n_b``; ``obs_noise_std``: ``sigma_obs`` and the initial spread [rad or m] (the
    encoder noise); ``orientation_weight``: ``w_o`` [m/rad]; ``log_scale``: ``eps`` of the
    cost [m] (None: the pose error itself); ``opt``: Adam's budget and MC-PILCO's dropout
    schedule (its learning-rate and dropout reductions, a shorter patience than the
    cart-pole's: the kinematic rollout is deterministic but for the dropout).
    """

    horizon: int = 20
    particles: int = 8
    num_basis: int = 50  # basis functions: a policy for one start and one target
    obs_noise_std: float = 1e-4  # the env's encoder noise [rad]
    orientation_weight: float = 0.1  # the env's w_o [m/rad]
    log_scale: float | None = 0.01  # eps [m]: 1 cm, the reach the linear cost stops short by
    opt: PolicyOptConfig = field(
        default_factory=lambda: PolicyOptConfig(
            max_steps=1000, min_steps=100, monitor_patience=100, cuda_graph=False
        )
    )

    def __post_init__(self) -> None:
        if self.horizon < 1 or self.particles < 1 or self.num_basis < 1:
            raise ValueError(
                f"horizon, particles and num_basis must be >= 1, got {self.horizon}, "
                f"{self.particles}, {self.num_basis}"
            )
        if not self.obs_noise_std >= 0:
            raise ValueError(f"obs_noise_std must be >= 0, got {self.obs_noise_std}")


def optimise_reaching_policy(
    model: nn.Module,
    joint_types: str,
    q0: ArrayLike,
    target_position: ArrayLike,
    target_rotation: ArrayLike,
    increments: ArrayLike,
    q_data: ArrayLike,
    config: ReachingConfig | None = None,
    policy: SquashedRBFPolicy | None = None,
    q_limits: ArrayLike | None = None,
    seed: int = 0,
) -> tuple[SquashedRBFPolicy, OptimizationResult]:
    """MC-PILCO's policy optimisation from ``q0`` to the target through ``model``.

    Args:
        model: the learned kinematics (:class:`PoseErrorCost`'s ``model``).
        joint_types: ``"R"`` / ``"P"`` per model joint.
        q0: ``(n,)`` measured start configuration.
        target_position, target_rotation: ``l*`` (3,), ``R*`` (3, 3).
        increments: ``Delta`` (n,) of :class:`IncrementDynamics`.
        q_data: ``(N, n)`` configurations of the model's data: a new policy's basis
            functions are spread like their features (:func:`~.policy.data_init`).
        config: :class:`ReachingConfig` (None: its defaults).
        policy: a policy to continue from (e.g. the previous trial's for the same target);
            None: a new one.
        q_limits: ``(n, 2)`` joint limits of the rollout, or None.
        seed: seed of a new policy and of the particles' random numbers.

    Returns:
        ``(policy, result)``: the optimised policy (eval mode) and the optimiser's record.
    """
    cfg = config if config is not None else ReachingConfig()
    layout = joint_layout(joint_types)
    n = layout.n
    q0_t = torch.as_tensor(np.asarray(q0, dtype=np.float64)).reshape(-1)
    if q0_t.numel() != n:
        raise ValueError(f"q0 must have {n} entries (one per joint), got {q0_t.numel()}")
    if policy is None:
        q_data_t = torch.as_tensor(np.asarray(q_data, dtype=np.float64))
        if q_data_t.ndim != 2 or q_data_t.shape[1] != n:
            raise ValueError(f"q_data must be (N, {n}), got {tuple(q_data_t.shape)}")
        features, _, _ = layout.features(q_data_t)
        policy = SquashedRBFPolicy(
            layout, [-1.0] * n, [1.0] * n, num_basis=cfg.num_basis, seed=seed,
            **data_init(features),
        )  # fmt: skip
    elif policy.action_dim != n:
        raise ValueError(f"policy has {policy.action_dim} actions, the arm {n} joints")
    policy = policy.double()
    cost = PoseErrorCost(
        model, target_position, target_rotation, cfg.orientation_weight, cfg.log_scale
    )
    loss = ReachingLoss(
        policy, IncrementDynamics(increments, q_limits), cost, cfg.horizon, cfg.particles,
        q0_t, cfg.obs_noise_std, cfg.obs_noise_std,
    ).double()  # fmt: skip
    gen_state = torch.random.get_rng_state()
    torch.manual_seed(seed)
    try:
        result = optimize_policy(loss, policy, cfg.opt)
    finally:
        torch.random.set_rng_state(gen_state)
    policy.eval()
    return policy, result


def rollout_error(
    policy: nn.Module,
    model: nn.Module,
    q0: ArrayLike,
    target_position: ArrayLike,
    target_rotation: ArrayLike,
    increments: ArrayLike,
    horizon: int,
    orientation_weight: float = 0.1,
    q_limits: ArrayLike | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The deterministic rollout of ``policy`` (eval mode) through the model from ``q0``:
    ``(q (H + 1, n), predicted pose error e(q_t) (H + 1,))`` (:class:`ReachingLoss`'s
    trajectory of one particle without noise)."""
    cost = PoseErrorCost(model, target_position, target_rotation, orientation_weight)
    q0_t = torch.as_tensor(np.asarray(q0, dtype=np.float64)).reshape(1, -1)
    rollout = ReachingLoss(
        policy, IncrementDynamics(increments, q_limits), cost, horizon, 1, q0_t, 0.0, 0.0
    )
    with torch.no_grad():
        q = torch.cat([q0_t, rollout.trajectories()[0]])
        return q.numpy(), cost(q).numpy()

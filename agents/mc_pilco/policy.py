"""Squashed RBF-network policy of MC-PILCO (thesis section 5.5.1; Amadio et al. 2022, eq. (23)).

Glossary
--------
``x``
    the state (observation) of the task, ``n`` coordinates.
``x~ = f(x)``
    policy input: the task's state features (:mod:`.features`): plain coordinates, then
    ``(sin, cos)`` of each angle ("x_ext" in thesis 5.5.1).
``phi_i(x~) = exp(-1/2 ||(x~ - c_i) / l||^2``
    Gaussian basis function ``i = 1..n_b`` with centre ``c_i`` and lengthscales ``l``
    (diagonal, shared by all basis functions, learnable).
``pi_theta(x) = u_mid + u_half tanh(sum_i w_i phi_i(x~) / u_half)``
    the squashed policy, per action coordinate; ``theta = {w, c, l}``; output in the
    action bounds ``(u_mid - u_half, u_mid + u_half)`` (``u_max = u_half`` for symmetric
    bounds, the thesis's form).
linear feedback (optional)
    ``pi_theta(x) = u_mid + u_half tanh((sum_i w_i phi_i(x~) + u_half G^T ((x~ - x~*) / s))
    / u_half)``: a gain matrix ``G`` (F, A) on the features' deviation from a regulation
    point ``x~*``, in units of the feature scales ``s``, added before the squashing; the RBF
    network is then a residual. ``theta = {w, c, l, G}``, ``G = 0`` at initialisation (the
    same ``u`` as without). Why: a task that starts inside the set it must stay in (a
    balance) needs a feedback that is near linear around ``x~*``; from ``w ~ 0`` the RBF
    network can only build it from the few basis functions that happen to lie near
    ``x~*`` (in a box of 6 or more dimensions, hardly any), while ``G`` has a gradient from
    the first step on (classic PILCO balances the double pendulum with a linear policy).
gated linear feedback (optional, a catch)
    ``z = g(x~) u_half G^T ((x~ - x~*) / s)`` with the gate
    ``g(x~) = exp(-1/2 sum_f ((x~_f - x~*_f) / v_f)^2)``, widths ``v`` (F,): the linear term
    acts only near ``x~*`` (``g = 1`` there, ``g -> 0`` far from it) and the RBF network
    alone acts elsewhere. Why: a swing-up must pump energy far from the goal, where a linear
    feedback around the goal would fight the pump, and then hold the goal, which needs the
    same near-linear feedback as a balance; a motor too weak to hold the pole more than a few
    degrees from upright leaves the RBF network (basis functions of width ``l`` ~ 0.7 in
    feature units) no room to build that feedback from its few basis functions near the
    goal. No gate (``v = None``): ``g = 1``, the ungated term of a balance. An angle's
    ``(sin, cos)`` features get the same width: ``(sin psi - sin psi*)^2 + (cos psi -
    cos psi*)^2 = 4 sin^2((psi - psi*) / 2)``, so the gate is ``exp(-(psi - psi*)^2 / (2
    v^2))`` near ``psi*`` and periodic in ``psi``.
dropout
    during policy optimisation, at every call (every simulated time step) each basis
    activation ``phi_i(x~^(m))`` of each particle ``m`` is zeroed with probability ``p`` and the
    others are scaled by ``1/(1-p)``: ``u^(m) = u_max tanh(sum_i d_mi phi_i w_i / u_max)``,
    ``d_mi ~ Bernoulli(1-p) / (1-p)`` i.i.d. over particles, basis functions and time. This is
    the regulariser of MC-PILCO (Amadio et al. 2022, sec. IV-B): every particle sees a
    slightly different policy, so the optimum must be robust to perturbed controls. ``p`` is
    lowered by the monitoring rule (:mod:`mcpilco.agents.mc_pilco.optimize`). Off in
    ``eval()`` mode.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np
import torch
from tensordict.nn import TensorDictModule
from torch import Tensor, nn

from mcpilco.agents.mc_pilco.features import StateLayout
from mcpilco.models.numerics import exp_floor_

SQRT_HALF = math.sqrt(0.5)
"""Default initial lengthscale: ``exp(-1/2 ||(x~ - c)/l||^2)`` with ``l = sqrt(1/2)`` is the
reference code's ``exp(-||x~ - c||^2)`` (unit lengthscales there)."""


class SquashedRBFPolicy(nn.Module):
    """``u = u_mid + u_half tanh(sum_i w_i phi_i(x~) / u_half)`` with ``n_b`` Gaussian basis
    functions over the task's state features.

    Args:
        layout: the task's state layout (:class:`~.features.StateLayout`, or its dict form).
        action_low, action_high: the action bounds (one entry per action).
        num_basis: number of basis functions ``n_b`` (MC-PILCO: 200).
        centers_box: half width ``b`` (one value, or one per plain coordinate) of the box
            ``[-b, b]`` in which the centres of the plain coordinates are initialised
            uniformly; the centres of each angle's ``(sin, cos)`` are ``(sin psi, cos psi)``,
            ``psi ~ U(-pi, pi)`` (on the circle where those features live).
        lengthscale_init: initial lengthscale ``l`` (one value, or one per feature).
        weight_scale: initial weights ``w ~ U(-weight_scale, weight_scale) u_half``.
        dropout: initial dropout probability ``p`` on the activations (training mode only).
        seed: seed of the initialisation (None: torch's global generator).
        center_mean, center_std: (F,) each: draw the centres ``c_i ~ N(center_mean,
            diag(center_std^2))`` in feature space instead of the box (the spread of the
            states the system visits, :func:`data_init`); None: the box.
        linear_ref: (F,) the regulation point ``x~*`` of the linear feedback term (module
            glossary); None: no linear term (the thesis's policy).
        linear_scale: (F,) the feature scales ``s`` of the linear term (None: ones).
        gains_init: (F, A) the gains ``G`` of the linear term at initialisation (None: 0;
            the LQR of a learned model, :mod:`~mcpilco.agents.mc_pilco.regulator`).
        linear_gate: (F,) the gate widths ``v`` of the linear term (module glossary, gated
            linear feedback); None: no gate.

    Shapes:
        ``forward(obs (..., n)) -> action (..., A)``.
    """

    def __init__(
        self,
        layout: StateLayout | dict[str, Any],
        action_low: Sequence[float] = (-1.0,),
        action_high: Sequence[float] = (1.0,),
        num_basis: int = 200,
        centers_box: float | Sequence[float] = math.pi,
        lengthscale_init: float | Sequence[float] = SQRT_HALF,
        weight_scale: float = 0.5,
        dropout: float = 0.25,
        seed: int | None = None,
        center_mean: Sequence[float] | None = None,
        center_std: Sequence[float] | None = None,
        linear_ref: Sequence[float] | None = None,
        linear_scale: Sequence[float] | None = None,
        gains_init: Sequence[Sequence[float]] | None = None,
        linear_gate: Sequence[float] | None = None,
    ) -> None:
        super().__init__()
        if isinstance(layout, dict):
            layout = StateLayout.from_dict(layout)
        if num_basis < 1:
            raise ValueError(f"num_basis must be >= 1, got {num_basis}")
        low = torch.as_tensor(action_low, dtype=torch.float32).reshape(-1)
        high = torch.as_tensor(action_high, dtype=torch.float32).reshape(-1)
        if low.shape != high.shape or not bool((high > low).all()):
            raise ValueError(f"need action_low < action_high, got {low.tolist()}, {high.tolist()}")
        n_plain, F = len(layout.plain_idx), layout.feature_dim
        box = torch.as_tensor(centers_box, dtype=torch.float32).reshape(-1)
        ls = torch.as_tensor(lengthscale_init, dtype=torch.float32).reshape(-1)
        if box.numel() == 1:
            box = box.expand(n_plain).clone()
        if ls.numel() == 1:
            ls = ls.expand(F).clone()
        if box.numel() != n_plain or ls.numel() != F:
            raise ValueError(
                f"centers_box needs 1 or {n_plain} entries (one per plain coordinate) and "
                f"lengthscale_init 1 or {F} (one per feature), got {box.numel()} and {ls.numel()}"
            )
        self.layout = layout
        self.num_basis = int(num_basis)
        self.action_dim = int(low.numel())
        self.input_dim = F
        self.weight_scale = float(weight_scale)
        self.dropout = float(dropout)
        self.register_buffer("action_low", low)
        self.register_buffer("action_high", high)
        self.register_buffer("u_mid", (high + low) / 2)
        self.register_buffer("u_half", (high - low) / 2)
        self.register_buffer("centers_box", box)
        self.register_buffer("lengthscale_init", ls)
        self.center_mean: Tensor | None = None
        self.center_std: Tensor | None = None
        if (center_mean is None) != (center_std is None):
            raise ValueError("center_mean and center_std go together")
        if center_mean is not None:
            self.center_mean = torch.as_tensor(center_mean, dtype=torch.float32).reshape(-1)
            self.center_std = torch.as_tensor(center_std, dtype=torch.float32).reshape(-1)
            if self.center_mean.numel() != F or self.center_std.numel() != F:
                raise ValueError(f"center_mean and center_std need {F} entries (one per feature)")
        self.centers = nn.Parameter(torch.empty(self.num_basis, self.input_dim))
        self.log_lengthscales = nn.Parameter(torch.empty(self.input_dim))
        self.weights = nn.Parameter(torch.empty(self.num_basis, self.action_dim))
        ref, scale, self.gains = _linear_parts(linear_ref, linear_scale, F, self.action_dim)
        self.register_buffer("linear_ref", ref)
        self.register_buffer("linear_scale", scale)
        self.register_buffer("gains_init", None if ref is None else torch.zeros(F, self.action_dim))
        if gains_init is not None:
            if ref is None:
                raise ValueError("gains_init needs linear_ref (the linear term's reference)")
            g = torch.as_tensor(gains_init, dtype=torch.float32)
            if g.shape != self.gains_init.shape:
                raise ValueError(f"gains_init must have shape {tuple(self.gains_init.shape)}")
            self.gains_init.copy_(g)
        self.register_buffer("linear_gate", _gate_widths(linear_gate, ref, F))
        self.reset_parameters(seed)

    @property
    def u_max(self) -> float:
        """The largest ``u_half`` (the output bound of symmetric bounds)."""
        return float(self.u_half.max())

    @torch.no_grad()
    def reset_parameters(self, seed: int | None = None) -> None:
        """(Re-)initialise ``c`` (uniformly in the box, on the circle for ``sin, cos``; or
        from ``N(center_mean, diag(center_std^2))``), ``l`` to its initial value and ``w``
        uniformly in ``+-weight_scale u_half``."""
        gen = None
        if seed is not None:
            gen = torch.Generator().manual_seed(int(seed))
        n_plain, n_ang = len(self.layout.plain_idx), len(self.layout.angle_idx)
        c = torch.rand(self.num_basis, n_plain, generator=gen) * 2.0 - 1.0
        psi = (torch.rand(self.num_basis, n_ang, generator=gen) * 2.0 - 1.0) * math.pi
        sc = torch.stack([psi.sin(), psi.cos()], dim=-1).reshape(self.num_basis, 2 * n_ang)
        if self.center_mean is None:
            self.centers.copy_(torch.cat([c * self.centers_box, sc], 1))
        else:
            z = torch.randn(self.num_basis, self.input_dim, generator=gen)
            self.centers.copy_(self.center_mean + self.center_std * z)
        self.log_lengthscales.copy_(self.lengthscale_init.log())
        w = torch.rand(self.num_basis, self.action_dim, generator=gen) * 2.0 - 1.0
        self.weights.copy_(w * self.weight_scale * self.u_half)
        if self.gains is not None:
            self.gains.copy_(self.gains_init)

    @property
    def linear(self) -> bool:
        """Whether the policy has the linear feedback term (module glossary)."""
        return self.gains is not None

    def settings(self) -> dict[str, Any]:
        """Constructor arguments that define the architecture and initialisation."""
        return {
            "layout": self.layout.to_dict(),
            "action_low": self.action_low.tolist(),
            "action_high": self.action_high.tolist(),
            "num_basis": self.num_basis,
            "centers_box": self.centers_box.tolist(),
            "lengthscale_init": self.lengthscale_init.tolist(),
            "weight_scale": self.weight_scale,
            "dropout": self.dropout,
            "center_mean": None if self.center_mean is None else self.center_mean.tolist(),
            "center_std": None if self.center_std is None else self.center_std.tolist(),
            "linear_ref": None if self.linear_ref is None else self.linear_ref.tolist(),
            "linear_scale": None if self.linear_scale is None else self.linear_scale.tolist(),
            "gains_init": None if self.gains_init is None else self.gains_init.tolist(),
            "linear_gate": _gate_setting(self.linear_gate),
        }

    @torch.no_grad()
    def use_data_init(self, init: dict[str, list[float] | None]) -> None:
        """Take the entries of ``init`` (:func:`data_init`'s centre distribution and initial
        lengthscales; ``linear_scale``, the linear term's feature scales; ``gains_init``, its
        initial gains; ``linear_gate``, its gate widths, at once) for the next
        :meth:`reset_parameters` (and :meth:`settings`)."""
        if init.get("center_mean") is not None:
            self.center_mean = torch.as_tensor(init["center_mean"], dtype=torch.float32)
            self.center_std = torch.as_tensor(init["center_std"], dtype=torch.float32)
        if init.get("lengthscale_init") is not None:
            self.lengthscale_init.copy_(torch.as_tensor(init["lengthscale_init"]))
        if init.get("linear_scale") is not None:
            if self.linear_scale is None:
                raise ValueError("linear_scale needs a policy with a linear term (linear_ref)")
            self.linear_scale.copy_(torch.as_tensor(init["linear_scale"]))
        if init.get("gains_init") is not None:
            if self.gains_init is None:
                raise ValueError("gains_init needs a policy with a linear term (linear_ref)")
            self.gains_init.copy_(torch.as_tensor(init["gains_init"]))
        if init.get("linear_gate") is not None:
            if self.linear_gate is None:
                raise ValueError("linear_gate needs a policy with a linear term (linear_ref)")
            self.linear_gate.copy_(torch.as_tensor(init["linear_gate"]))

    def basis(self, features: Tensor) -> Tensor:
        """Activations ``phi(x~)`` (..., n_b), matmul form of ``||(x~ - c)/l||^2``."""
        lead = features.shape[:-1]
        *_, log_phi = _log_basis(
            features.reshape(1, -1, self.input_dim),
            self.centers.unsqueeze(0),
            self.log_lengthscales.unsqueeze(0),
        )
        return exp_floor_(log_phi).reshape(*lead, self.num_basis)

    def draw_dropout_mask(self, obs: Tensor) -> Tensor | None:
        """The dropout mask ``(1, k, n_b)`` for the ``k`` observations in ``obs (..., n)``
        (:func:`dropout_mask`), or None outside training or at ``p = 0``. ``forward`` draws
        it itself when not given one; drawing it first keeps the random draws out of a
        compiled rollout step (the same masks with and without ``torch.compile``)."""
        drawn = self.draw_dropout_bytes(obs)
        return None if drawn is None else mask_from_bytes(*drawn, obs.dtype)

    def draw_dropout_bytes(self, obs: Tensor) -> tuple[Tensor, int] | None:
        """The random bytes ``b (1, k, n_b)`` and threshold ``t`` of :meth:`draw_dropout_mask`
        (its mask is ``mask_from_bytes(b, t)``; the same random draws), or None when there is
        no dropout."""
        return _draw_bytes(self, (1, obs[..., 0].numel(), self.num_basis), obs.device)

    def forward(self, obs: Tensor, mask: Tensor | None = None) -> Tensor:
        """``u = pi(x~)`` for ``obs (..., n)``; ``mask``: a dropout mask from
        :meth:`draw_dropout_mask` (None: drawn here in training mode)."""
        n = self.layout.n
        if obs.shape[-1] != n:
            raise ValueError(f"observation must have shape (..., {n}), got {tuple(obs.shape)}")
        lead = obs.shape[:-1]
        flat = obs.reshape(1, -1, n)
        if mask is None:
            mask = self.draw_dropout_mask(obs)
        gains = None if self.gains is None else self.gains.unsqueeze(0)
        u = _squashed_rbf(
            flat,
            self.centers.unsqueeze(0),
            self.log_lengthscales.unsqueeze(0),
            self.weights.unsqueeze(0),
            (self.u_mid, self.u_half),
            mask,
            self.layout,
            (gains, self.linear_ref, self.linear_scale, self.linear_gate),
        )
        return u.reshape(*lead, self.action_dim)

    def extra_repr(self) -> str:
        return (
            f"num_basis={self.num_basis}, action_dim={self.action_dim}, linear={self.linear}, "
            f"bounds=({self.action_low.tolist()}, {self.action_high.tolist()}), "
            f"dropout={self.dropout}"
        )


class PolicyPopulation(nn.Module):
    """``K`` candidate :class:`SquashedRBFPolicy` optimised side by side on the same model.

    Why: the particle estimate ``J^`` is non-convex in ``theta``, and from one start the
    optimisation can stall in a local optimum (e.g. a slow pumping that brings the pole up
    only at the end of the horizon). Candidates share the GP model and the rollout: their
    particles are stacked candidate-major, so ``K`` candidates with ``M`` particles each are
    one rollout of ``K M`` particles, and at these sizes a rollout's cost is mostly fixed per
    time step. Each candidate ``k`` has its own ``J^_k`` and gradient (``J^ = sum_k J^_k``:
    parameters are disjoint). After the optimisation the candidate with the lowest ``J^_k``
    is the policy applied to the system; all candidates go on at the next trial.

    Args:
        candidates: the starting policies (same architecture; their initial weight scales may
            differ); their parameters are copied.

    Shapes:
        ``forward(obs (K M, n)) -> (K M, A)``: rows ``k M .. (k + 1) M - 1`` use candidate
        ``k``. Parameters: ``centers (K, n_b, F)``, ``log_lengthscales (K, F)``,
        ``weights (K, n_b, A)``.
    """

    def __init__(self, candidates: Sequence[SquashedRBFPolicy]) -> None:
        super().__init__()
        if not candidates:
            raise ValueError("a population needs at least one candidate policy")
        first = candidates[0]

        def arch(p: SquashedRBFPolicy) -> dict:  # settings less the initial weight scale
            return {k: v for k, v in p.settings().items() if k != "weight_scale"}

        for p in candidates[1:]:
            if arch(p) != arch(first):
                raise ValueError("all candidates must have the same architecture and settings")
        self._settings = first.settings()
        self.num_candidates = len(candidates)
        self.num_basis = first.num_basis
        self.action_dim = first.action_dim
        self.layout = first.layout
        self.register_buffer("u_mid", first.u_mid.clone())
        self.register_buffer("u_half", first.u_half.clone())
        self.dropout = first.dropout
        self.centers = nn.Parameter(torch.stack([p.centers.detach() for p in candidates]))
        self.log_lengthscales = nn.Parameter(
            torch.stack([p.log_lengthscales.detach() for p in candidates])
        )
        self.weights = nn.Parameter(torch.stack([p.weights.detach() for p in candidates]))
        ref, scale, self.gains = _linear_parts(
            first.linear_ref, first.linear_scale, first.input_dim, first.action_dim
        )
        self.register_buffer("linear_ref", ref)
        self.register_buffer("linear_scale", scale)
        self.register_buffer("linear_gate", _gate_widths(first.linear_gate, ref, first.input_dim))
        if self.gains is not None:
            self.gains = nn.Parameter(torch.stack([p.gains.detach() for p in candidates]))

    @property
    def linear(self) -> bool:
        """Whether the candidates have the linear feedback term."""
        return self.gains is not None

    def draw_dropout_mask(self, obs: Tensor) -> Tensor | None:
        """The dropout mask ``(K, M, n_b)`` for ``obs (K M, n)``, or None outside training or
        at ``p = 0`` (as :meth:`SquashedRBFPolicy.draw_dropout_mask`)."""
        drawn = self.draw_dropout_bytes(obs)
        return None if drawn is None else mask_from_bytes(*drawn, obs.dtype)

    def draw_dropout_bytes(self, obs: Tensor) -> tuple[Tensor, int] | None:
        """The random bytes ``(K, M, n_b)`` and threshold of :meth:`draw_dropout_mask` (as
        :meth:`SquashedRBFPolicy.draw_dropout_bytes`)."""
        k = obs[..., 0].numel()
        shape = (self.num_candidates, k // self.num_candidates, self.num_basis)
        return _draw_bytes(self, shape, obs.device)

    def forward(self, obs: Tensor, mask: Tensor | None = None) -> Tensor:
        """``u`` of candidate ``k`` for its ``M`` rows of ``obs (K M, n)``; ``mask`` as in
        :meth:`SquashedRBFPolicy.forward`."""
        n = self.layout.n
        if obs.shape[-1] != n or obs[..., 0].numel() % self.num_candidates:
            raise ValueError(
                f"observation must have shape (K M, {n}) with K = {self.num_candidates} "
                f"candidates, got {tuple(obs.shape)}"
            )
        lead = obs.shape[:-1]
        flat = obs.reshape(self.num_candidates, -1, n)
        if mask is None:
            mask = self.draw_dropout_mask(obs)
        u = _squashed_rbf(
            flat,
            self.centers,
            self.log_lengthscales,
            self.weights,
            (self.u_mid, self.u_half),
            mask,
            self.layout,
            (self.gains, self.linear_ref, self.linear_scale, self.linear_gate),
        )
        return u.reshape(*lead, self.action_dim)

    def candidate(self, k: int) -> SquashedRBFPolicy:
        """Candidate ``k`` as a stand-alone policy (parameters copied)."""
        pol = SquashedRBFPolicy(**self._settings)
        self.copy_to(k, pol)
        return pol

    @torch.no_grad()
    def copy_to(self, k: int, policy: SquashedRBFPolicy) -> None:
        """Write candidate ``k``'s parameters into ``policy``."""
        if not 0 <= k < self.num_candidates:
            raise IndexError(f"candidate {k} out of range 0..{self.num_candidates - 1}")
        policy.centers.copy_(self.centers[k])
        policy.log_lengthscales.copy_(self.log_lengthscales[k])
        policy.weights.copy_(self.weights[k])
        if self.gains is not None:
            policy.gains.copy_(self.gains[k])
            policy.linear_scale.copy_(self.linear_scale)
            policy.gains_init.copy_(torch.as_tensor(self._settings["gains_init"]))
            policy.linear_gate.copy_(self.linear_gate)

    @torch.no_grad()
    def use_data_init(self, init: dict[str, list[float] | None]) -> None:
        """Take the entries of ``init`` (as :meth:`SquashedRBFPolicy.use_data_init`) for the
        candidates of the next :meth:`reset_parameters`; ``linear_scale`` and ``linear_gate``
        at once."""
        self._settings = {**self._settings, **{k: v for k, v in init.items() if v is not None}}
        if init.get("linear_scale") is not None:
            if self.linear_scale is None:
                raise ValueError("linear_scale needs a policy with a linear term (linear_ref)")
            self.linear_scale.copy_(torch.as_tensor(init["linear_scale"]))
        if init.get("linear_gate") is not None:
            if self.linear_gate is None:
                raise ValueError("linear_gate needs a policy with a linear term (linear_ref)")
            self.linear_gate.copy_(torch.as_tensor(init["linear_gate"]))

    @torch.no_grad()
    def reset_parameters(self, seed: int | None = None) -> None:
        """Re-initialise every candidate as :meth:`SquashedRBFPolicy.reset_parameters`."""
        for k in range(self.num_candidates):
            pol = SquashedRBFPolicy(
                **self._settings, seed=None if seed is None else int(seed) + 7919 * k
            )
            self.centers[k] = pol.centers
            self.log_lengthscales[k] = pol.log_lengthscales
            self.weights[k] = pol.weights
            if self.gains is not None:
                self.gains[k] = pol.gains

    def extra_repr(self) -> str:
        return (
            f"num_candidates={self.num_candidates}, num_basis={self.num_basis}, "
            f"linear={self.linear}, "
            f"action_dim={self.action_dim}, dropout={self.dropout}"
        )


def _linear_parts(
    ref: Sequence[float] | Tensor | None,
    scale: Sequence[float] | Tensor | None,
    features: int,
    actions: int,
) -> tuple[Tensor | None, Tensor | None, nn.Parameter | None]:
    """``(x~*, s, G)`` of the linear feedback term: the reference and scales as float32
    tensors (F,) and zero gains (F, A); ``(None, None, None)`` without a reference."""
    if ref is None:
        if scale is not None:
            raise ValueError("linear_scale needs linear_ref (the linear term's reference)")
        return None, None, None
    r = torch.as_tensor(ref, dtype=torch.float32).reshape(-1).clone()
    s = (
        torch.ones(features)
        if scale is None
        else torch.as_tensor(scale, dtype=torch.float32).reshape(-1).clone()
    )
    if r.numel() != features or s.numel() != features:
        raise ValueError(f"linear_ref and linear_scale need {features} entries (one per feature)")
    if not bool((s > 0).all()):
        raise ValueError(f"linear_scale must be > 0, got {s.tolist()}")
    return r, s, nn.Parameter(torch.zeros(features, actions))


def _gate_setting(gate: Tensor | None) -> list[float] | None:
    """The ``linear_gate`` setting of gate widths ``v``: None for no gate (all infinite)."""
    return None if gate is None or bool(torch.isinf(gate).all()) else gate.tolist()


def _gate_widths(
    widths: Sequence[float] | Tensor | None, ref: Tensor | None, features: int
) -> Tensor | None:
    """The gate widths ``v`` of the linear term as a float32 tensor (F,): infinite (``g = 1``,
    no gate) for None; None without a linear term (``ref`` None)."""
    if ref is None:
        if widths is not None:
            raise ValueError("linear_gate needs linear_ref (the linear term's reference)")
        return None
    if widths is None:
        return torch.full((features,), math.inf)
    v = torch.as_tensor(widths, dtype=torch.float32).reshape(-1).clone()
    if v.numel() != features or not bool((v > 0).all()):
        raise ValueError(f"linear_gate needs {features} entries > 0 (one per feature)")
    return v


def _squashed_rbf(
    obs: Tensor,
    centers: Tensor,
    log_l: Tensor,
    w: Tensor,
    bounds: tuple[Tensor, Tensor],
    mask: Tensor | None,
    layout: StateLayout,
    linear: tuple[Tensor | None, Tensor | None, Tensor | None, Tensor | None],
) -> Tensor:
    """The squashed policy of ``K`` policies (:func:`squashed_rbf_forward`'s shapes) with the
    linear feedback term ``z = g(x~) u_half ((x~ - x~*) / s) G`` (``linear = (G (K, F, A),
    x~*, s, v)``; ``G`` None: none; ``v`` None: ``g = 1``) added before the squashing; ``z``
    is differentiated by autograd, the rest by the policy's own backward. Infinite widths (no
    gate) give ``g = exp(0) = 1`` exactly, so the gate is applied without asking its values:
    no host sync in a step that a CUDA graph may capture."""
    gains, ref, scale, gate = linear
    z = None
    if gains is not None:
        feats = layout.features(obs)[0]
        dev = feats - ref.to(feats.dtype)
        z = torch.bmm(dev / scale.to(feats.dtype), gains.to(feats.dtype))
        z = z * bounds[1]
        if gate is not None:
            z = z * torch.exp(-0.5 * (dev / gate.to(feats.dtype)).square().sum(-1, keepdim=True))
    return _SquashedRBF.apply(obs, centers, log_l, w, bounds, mask, layout, z)


DATA_STD_FLOOR = 1e-6  # a feature that spreads less than this over the data counts as constant


def data_init(features: Tensor) -> dict[str, list[float]]:
    """Centre distribution and initial lengthscales of the policy from the features
    ``x~ (N, F)`` of the states a system visits (e.g. its exploration trial).

    ``c_i ~ N(m, diag(s^2))`` with ``m, s`` the features' mean and standard deviation, and
    ``l_j = sqrt(F) s_j``: for ``x~`` and ``c`` both drawn from that spread,
    ``E ||(x~ - c) / l||^2 = sum_j 2 s_j^2 / (F s_j^2) = 2``, so a basis function's typical
    activation is ``exp(-1)`` in any dimension. The box initialisation puts the centres of
    a high-dimensional state (the UR10's 24) so far from the visited states that every
    activation, and the policy's gradient, underflows to zero. A feature constant over the
    data (``s_j < DATA_STD_FLOOR``) gets ``s_j = 1``."""
    f = torch.as_tensor(features, dtype=torch.float64)
    if f.ndim != 2 or f.shape[0] < 2:
        raise ValueError(f"data_init needs features (N >= 2, F), got {tuple(f.shape)}")
    m, s = f.mean(0), f.std(0)
    s = torch.where(s < DATA_STD_FLOOR, torch.ones_like(s), s)
    return {
        "center_mean": m.tolist(),
        "center_std": s.tolist(),
        "lengthscale_init": (math.sqrt(f.shape[1]) * s).tolist(),
    }


def dropout_threshold(p: float) -> int:
    """``t = round(256 (1 - p))``: a byte ``b`` keeps its entry when ``b < t`` (256: keep
    all)."""
    if not 0.0 <= p < 1.0:
        raise ValueError(f"dropout probability must be in [0, 1), got {p}")
    return round(256 * (1.0 - p))


def dropout_bytes(shape: tuple[int, ...], device: torch.device | None = None) -> Tensor:
    """I.i.d. uniform random bytes ``(shape)``, uint8, taken from 64-bit random integers
    (cheaper than one random float per entry)."""
    n = math.prod(shape)
    words = torch.randint(-(2**63), 2**63 - 1, ((n + 7) // 8,), dtype=torch.int64, device=device)
    return words.view(torch.uint8)[:n].view(shape)


def mask_from_bytes(
    b: Tensor, t: int | Tensor, dtype: torch.dtype, scale: float | Tensor | None = None
) -> Tensor:
    """The inverted-dropout mask ``d = 1[b < t] / (t / 256)`` of bytes ``b``, in ``dtype``.

    ``scale``: ``256 / t`` as given (default: computed). A compiled rollout step passes ``t``
    and ``256 / t`` as 0-dim tensors in ``dtype``, so that they are inputs of its graph, not
    constants; their values are those of the Python numbers (the same mask)."""
    scale = 256.0 / t if scale is None else scale
    return b.to(dtype).lt_(t).mul_(scale)  # 0..255 are exact in dtype; faster than (b < t)


def dropout_mask(
    shape: tuple[int, ...], p: float, dtype: torch.dtype, device: torch.device | None = None
) -> Tensor:
    """Inverted-dropout mask ``d = 1[b < t] / (t / 256)`` with ``t = round(256 (1 - p))`` and
    i.i.d. uniform random bytes ``b``: entries are ``Bernoulli(1 - p') / (1 - p')`` with
    ``p'`` = ``p`` rounded to a multiple of 1/256 (exact for MC-PILCO's 0.25 and 0.125), and
    ``E[d] = 1``.

    One random byte per entry (:func:`dropout_bytes`): the rollout needs ``M x n_b`` entries
    at each of the ``H`` steps.
    """
    t = dropout_threshold(p)
    if t >= 256:
        return torch.ones(shape, dtype=dtype, device=device)
    return mask_from_bytes(dropout_bytes(shape, device), t, dtype)


def _draw_bytes(
    policy: SquashedRBFPolicy | PolicyPopulation, shape: tuple[int, ...], device: torch.device
) -> tuple[Tensor, int] | None:
    """``(dropout_bytes(shape), t)`` for the policy's dropout rate, None outside training or
    when ``t = 256`` (nothing dropped)."""
    if not (policy.training and policy.dropout > 0.0):
        return None
    t = dropout_threshold(policy.dropout)
    return None if t >= 256 else (dropout_bytes(shape, device), t)


def _log_basis(feats: Tensor, centers: Tensor, log_l: Tensor) -> tuple[Tensor, ...]:
    """Batched over ``K`` policies: ``a = x~ / l`` (K, k, F), ``b = c / l`` (K, n_b, F),
    ``1 / l`` (K, 1, F) and ``log phi (K, k, n_b) = a b^T - |a|^2/2 - |b|^2/2 =
    -1/2 ||a - b||^2`` (<= 0 up to rounding)."""
    inv_l = torch.exp(-log_l).unsqueeze(1)
    a = feats * inv_l
    b = centers * inv_l
    log_phi = torch.baddbmm((b * b).sum(-1).mul_(-0.5).unsqueeze(1), a, b.transpose(1, 2))
    log_phi.sub_((a * a).sum(-1, keepdim=True).mul_(0.5))
    return a, b, inv_l, log_phi


class PolicyStepSaved(NamedTuple):
    """What :func:`squashed_rbf_backward` needs from :func:`squashed_rbf_forward`, all
    tensors (``K`` policies, ``k`` inputs each): ``a = x~ / l`` (K, k, F), ``b = c / l``
    (K, n_b, F), ``phi`` the (masked) basis (K, k, n_b), ``t = tanh(.)`` (K, k, A), the
    weights ``w``, the angles' ``s = sin``, ``c = cos`` (None without angles), ``inv_l = 1 / l``
    (K, 1, F) and ``u_half``."""

    a: Tensor
    b: Tensor
    phi: Tensor
    t: Tensor
    w: Tensor
    s: Tensor | None
    c: Tensor | None
    inv_l: Tensor
    u_half: Tensor


def squashed_rbf_forward(
    obs: Tensor,
    centers: Tensor,
    log_l: Tensor,
    w: Tensor,
    bounds: tuple[Tensor, Tensor],
    mask: Tensor | None,
    layout: StateLayout,
    z: Tensor | None = None,
) -> tuple[Tensor, PolicyStepSaved]:
    """``u = u_mid + u_half tanh(((D o phi(f(obs))) w + z) / u_half)`` for ``K`` policies at once,
    and what its backward needs (the policy's step protocol: :func:`squashed_rbf_backward`
    is its exact derivative; its autograd node and the chained rollouts of
    :mod:`mcpilco.agents.mc_pilco.fast` both call this pair).

    Shapes: ``obs (K, k, n)``, ``centers c (K, n_b, F)``, ``log l (K, F)``,
    ``w (K, n_b, A)``, ``bounds = (u_mid, u_half)`` (A,) each, ``D (K, k, n_b)`` the dropout
    mask (None: all ones), ``z (K, k, A)`` a pre-activation added before the squashing (the
    linear feedback term; None: none, its gradient is ``g_u (1 - tanh^2)``, the backward's
    ``gs``); ``u (K, k, A)``."""
    u_mid, u_half = bounds
    feats, s, c = layout.features(obs)  # (K, k, F)
    a, b, inv_l, log_phi = _log_basis(feats, centers, log_l)
    phi = exp_floor_(log_phi)  # (K, k, n_b)
    if mask is not None:
        phi.mul_(mask)
    pre = torch.bmm(phi, w)
    if z is not None:
        pre = pre.add_(z)
    t = torch.tanh(pre.div_(u_half))  # (K, k, A)
    return torch.addcmul(u_mid, u_half, t), PolicyStepSaved(a, b, phi, t, w, s, c, inv_l, u_half)


def squashed_rbf_backward(
    saved: PolicyStepSaved,
    g_u: Tensor,
    layout: StateLayout,
    needs: tuple[bool, bool, bool, bool] = (True, True, True, True),
) -> tuple[Tensor | None, Tensor | None, Tensor | None, Tensor | None]:
    """``(dJ/dobs, dJ/dc, dJ/dlog l, dJ/dw)`` from ``g_u = dJ/du`` (K, k, A) and the forward's
    ``saved``; ``needs`` says which of the four are wanted (None for the others).

    Below ``phi`` stands for ``D o phi``, which is also ``d(D o phi) / d log phi``, and the
    products are per policy (batched). With ``a = x~ / l``, ``b = c / l``,
    ``log phi = a b^T - |a|^2/2 - |b|^2/2`` and ``G = dJ/d log phi = ((g_u (1 - tanh^2)) w^T)
    o phi``: ``dJ/da = G b - a o rowsum(G)``, ``dJ/db = G^T a - b o colsum(G)``,
    ``dJ/dw = phi^T (g_u (1 - tanh^2))``, ``dJ/dx~ = dJ/da / l``, ``dJ/dc = dJ/db / l``,
    ``dJ/dlog l = -(sum (dJ/da o a) + sum (dJ/db o b))``; ``x~ -> obs`` through the feature
    map's backward (:meth:`~.features.StateLayout.features_backward`)."""
    a, b, phi, t, w, s, c, inv_l, _ = saved
    need_obs, need_c, need_l, need_w = needs
    gs = g_u * (1.0 - t * t)  # (K, k, A), dJ/d(phi w)
    g_w = torch.bmm(phi.transpose(1, 2), gs) if need_w else None
    g_obs = g_c = g_l = None
    if need_obs or need_c or need_l:
        G = torch.bmm(gs, w.transpose(1, 2)).mul_(phi)  # (K, k, n_b), dJ/d log phi
        Gt = G.transpose(1, 2)
        # (b^T G^T)^T and (a^T G)^T: the wide-output products are faster than G b, G^T a
        g_a = torch.bmm(b.transpose(1, 2), Gt).transpose(1, 2)
        g_a = g_a.addcmul(a, G.sum(2, keepdim=True), value=-1.0)
        g_b = torch.bmm(a.transpose(1, 2), G).transpose(1, 2)
        g_b = g_b.addcmul(b, Gt.sum(2, keepdim=True), value=-1.0)
        if need_l:
            g_l = -((g_a * a).sum(1) + (g_b * b).sum(1))
        if need_c:
            g_c = g_b * inv_l
        if need_obs:
            g_obs = layout.features_backward(g_a * inv_l, s, c)
    return g_obs, g_c, g_l, g_w


class _SquashedRBF(torch.autograd.Function):
    """The policy's step protocol (:func:`squashed_rbf_forward`, :func:`squashed_rbf_backward`)
    as one autograd node per call instead of about fifteen (the rollout calls the policy at
    every time step). ``apply(obs, centers, log_l, w, bounds, mask, layout, z)``, ``z`` the
    pre-activation of the linear term (None: none)."""

    @staticmethod
    def forward(ctx, obs, centers, log_l, w, bounds, mask, layout, z=None):  # noqa: D102
        u, saved = squashed_rbf_forward(obs, centers, log_l, w, bounds, mask, layout, z)
        ctx.save_for_backward(*saved)
        ctx.layout = layout
        return u

    @staticmethod
    def backward(ctx, g_u):  # noqa: D102
        saved = PolicyStepSaved(*ctx.saved_tensors)
        grads = squashed_rbf_backward(saved, g_u, ctx.layout, tuple(ctx.needs_input_grad[:4]))
        out = (*grads, None, None, None)
        if len(ctx.needs_input_grad) == 7:  # called without z
            return out
        return (*out, g_u * (1.0 - saved.t * saved.t) if ctx.needs_input_grad[7] else None)


def make_policy_module(
    policy: SquashedRBFPolicy | PolicyPopulation | None = None, **kwargs
) -> TensorDictModule:
    """Wrap a policy as a ``TensorDictModule`` reading ``"observation"``, writing ``"action"``.

    ``kwargs`` go to :class:`SquashedRBFPolicy` when ``policy`` is None.
    """
    if policy is None:
        policy = SquashedRBFPolicy(**kwargs)
    elif kwargs:
        raise TypeError("pass either a policy or constructor kwargs, not both")
    return TensorDictModule(policy, in_keys=["observation"], out_keys=["action"])


def policy_act(policy: SquashedRBFPolicy) -> Callable[[np.ndarray], np.ndarray]:
    """The action rule ``state -> u`` of ``policy`` on numpy states (evaluation mode, no
    gradients; the policy's device), for :func:`~mcpilco.agents.common.trials.run_episode`."""
    policy.eval()
    device = policy.weights.device

    @torch.no_grad()
    def act(state: np.ndarray) -> np.ndarray:
        x = torch.as_tensor(state, dtype=torch.float32, device=device)[None]
        return policy(x)[0].cpu().numpy()

    return act

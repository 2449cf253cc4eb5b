r"""The rigid-body terms of a serial chain from its joint types, and a regression over them.

Every rigid-body inverse dynamics of a serial chain with joint types ``joint_types`` (R
revolute, P prismatic, base fixed) is the Euler-Lagrange torque of
:math:`L = \tfrac12 \dot q^\top M(q) \dot q - V(q)` (thesis ch. 3):

.. math::

    \tau_a = \sum_b M_{ab}(q)\, \ddot q_b
    + \sum_{b, c} \Big(\frac{\partial M_{ab}}{\partial q_c}
    - \tfrac12 \frac{\partial M_{bc}}{\partial q_a}\Big) \dot q_b \dot q_c
    + \frac{\partial V}{\partial q_a}:

inertia terms linear in :math:`\ddot q`, Coriolis and centrifugal terms quadratic in
:math:`\dot q`, gravity in :math:`q`. With unknown kinematics and inertias, :math:`M` and
:math:`V` are polynomials whose form the chain fixes (composite-rigid-body recursion,
:math:`M_{ij} = S_i^\top X_{i \leftarrow j}^{*} I^c_j S_j` for ``i <= j``):

- :math:`M_{ij}` does not depend on :math:`q_l` for :math:`l \le \min(i, j)`, is of degree
  1 in :math:`q_l` for :math:`\min(i, j) < l \le \max(i, j)` (the transform between the
  two joints enters once) and of degree 2 for :math:`l > \max(i, j)` (the composite inertia
  of the bodies beyond, a congruence);
- :math:`V` is of degree 1 in every joint (each body's position is affine in every
  rotation and translation before it).

Degree ``d`` in a revolute joint: ``1, cos q, sin q`` (``d = 1``) and ``cos 2q, sin 2q``
(``d = 2``); in a prismatic joint: ``1, q, ..., q^d``. The coefficients of these monomials
in :math:`M_{ij}` and :math:`V` are the linear parameters of the chain
(:func:`lagrangian_parameters`); each gives a torque on every joint
(:func:`lagrangian_columns`). Their span lies inside the GIP kernel's (thesis eq. 3.11:
degree <= 2 per joint, affine in :math:`\ddot q` and :math:`\dot q_i \dot q_j`) and holds
every rigid-body torque of the chain, but far fewer functions: 84 parameters for all three
joints of an ``RRR`` arm against 1,250 GIP monomials per joint. One parameter vector serves
every joint, tied by Euler-Lagrange, so a torque on one joint alone (viscous or dry
friction, an offset, a spring) is out of its reach.

:class:`LagrangianEstimator` fits the parameters by Bayesian linear regression on every row
(:class:`~mcpilco.models.gp.blr.BayesianLinearRegression`: float64 normal equations
accumulated in chunks, ``O(n N P^2)``; the prior scale by type-II maximum likelihood).
"""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mcpilco.models.gp.blr import BayesianLinearRegression
from mcpilco.models.inverse_dynamics.base import InverseDynamicsEstimator
from mcpilco.models.inverse_dynamics.inputs import JointStates, as_joint_states
from mcpilco.models.kernels import check_joint_types

FloatArray = NDArray[np.float64]

__all__ = [
    "MAX_RIGID_FEATURES",
    "LagrangianEstimator",
    "lagrangian_columns",
    "lagrangian_parameters",
]

MAX_RIGID_FEATURES = 3000
"""Most parameters of a :class:`LagrangianEstimator` (its ``O(P^2)`` memory per joint,
``O(n N P^2)`` time)."""
MIN_RELATIVE_NOISE = 1e-10
"""Smallest noise variance of a joint in the row weights, relative to its mean square torque
(noise-free torques would otherwise weigh one joint's rows without bound)."""
MAX_PASSES = 60
"""Most passes of :class:`LagrangianEstimator`'s fit, each weighting a joint's rows by the
inverse of its noise variance (and scaling them by its output scale) from the previous
pass."""
PASS_TOLERANCE = 1e-6
"""The passes stop when no output scale or noise variance moves by more than this fraction."""


def _inertia_degree(i: int, j: int, n: int) -> list[int]:
    """Degree of :math:`M_{ij}` in each joint (module docstring)."""
    lo, hi = min(i, j), max(i, j)
    return [0 if l <= lo else (1 if l <= hi else 2) for l in range(n)]


def _monomials(deg: list[int], jt: str) -> list[tuple[int, ...]]:
    """Every monomial of at most degree ``deg[l]`` in joint ``l``: per joint the index of
    its factor (revolute: ``1, cos, sin, cos 2q, sin 2q``; prismatic: the power of ``q``)."""
    opts = [range(2 * d + 1) if c == "R" else range(d + 1) for d, c in zip(deg, jt, strict=True)]
    return list(itertools.product(*opts))


def lagrangian_parameters(joint_types: str) -> list[tuple]:
    """The linear parameters of a serial chain's Lagrangian from its joint types (module
    docstring): ``("M", i, j, monomial)`` (``i <= j``, 0-based: the coefficient of that
    monomial in :math:`M_{ij} = M_{ji}`) and ``("V", monomial)`` (in :math:`V`; its
    constant, which has no torque, left out)."""
    jt = check_joint_types(joint_types)
    n = len(jt)
    out: list[tuple] = []
    for i in range(n):
        for j in range(i, n):
            out += [("M", i, j, m) for m in _monomials(_inertia_degree(i, j, n), jt)]
    out += [("V", m) for m in _monomials([1] * n, jt) if any(m)]
    return out


def _bases(q: FloatArray, jt: str) -> tuple[list[FloatArray], list[FloatArray]]:
    """Per joint the ``(N, 5)`` (revolute) or ``(N, 3)`` (prismatic) factor values and their
    derivatives with respect to that joint's ``q``."""
    values, slopes = [], []
    for b, c in enumerate(jt):
        x = q[:, b]
        one, zero = np.ones_like(x), np.zeros_like(x)
        if c == "R":
            c1, s1, c2, s2 = np.cos(x), np.sin(x), np.cos(2 * x), np.sin(2 * x)
            values.append(np.stack([one, c1, s1, c2, s2], 1))
            slopes.append(np.stack([zero, -s1, c1, -2 * s2, 2 * c2], 1))
        else:
            values.append(np.stack([one, x, x * x], 1))
            slopes.append(np.stack([zero, one, 2 * x], 1))
    return values, slopes


def lagrangian_columns(states: JointStates, params: list[tuple], joint_types: str) -> FloatArray:
    """``(n, N, P)``: the torque of every joint for a unit value of each parameter
    (:func:`lagrangian_parameters`) at ``states``, by Euler-Lagrange (module docstring)."""
    jt = check_joint_types(joint_types)
    n, N = len(jt), states.q.shape[0]
    B, D = _bases(states.q, jt)
    qd, qdd = states.qd, states.qdd
    out = np.zeros((n, N, len(params)))
    for p, par in enumerate(params):
        m = par[-1]
        val = np.ones(N)
        for b in range(n):
            if m[b]:
                val = val * B[b][:, m[b]]
        grad: list[FloatArray | None] = []  # d(monomial)/dq_c
        for c in range(n):
            if m[c] == 0:
                grad.append(None)
                continue
            g = D[c][:, m[c]].copy()
            for b in range(n):
                if b != c and m[b]:
                    g *= B[b][:, m[b]]
            grad.append(g)
        if par[0] == "V":
            for a in range(n):
                if grad[a] is not None:
                    out[a, :, p] += grad[a]
            continue
        _, i, j, _ = par
        entries = [(i, j)] if i == j else [(i, j), (j, i)]  # the entries of M it sets
        for a, b in entries:
            out[a, :, p] += val * qdd[:, b]
            for c in range(n):
                if grad[c] is not None:
                    out[a, :, p] += grad[c] * qd[:, b] * qd[:, c]
        for a in range(n):
            if grad[a] is not None:
                for b, c in entries:
                    out[a, :, p] -= 0.5 * grad[a] * qd[:, b] * qd[:, c]
    return out


class LagrangianEstimator(InverseDynamicsEstimator):
    """Bayesian linear regression of all joints' torques together over the linear
    parameters of the chain's Lagrangian (module docstring), on every row.

    The rows of joint ``a`` are weighted by ``1 / sigma_a`` (its noise from the previous
    pass, :data:`MAX_PASSES`), the columns scaled to unit root mean square, and the prior
    scale and noise fitted by type-II maximum likelihood
    (:class:`~mcpilco.models.gp.blr.BayesianLinearRegression`: float64 normal equations
    accumulated in chunks, ``O(n N P^2)``, the rows never all in memory as features).

    Args:
        joint_types: e.g. ``"RRPR"``.
        chunk: rows per chunk (memory ``n x chunk x P``).
        noise_min: lower bound of the weighted noise variance.
        max_features: refuse a chain with more parameters (``ValueError``).
        output_scales: fit ``y_a = s_a tau_a(theta)`` with a free scale ``s_a`` per joint
            (``s_1 = 1``: the common scale is the parameters'): motor currents are torques
            over per-joint torque constants, ``i_a = tau_a / k_a``, which one parameter vector
            shared by every joint cannot follow otherwise. Off by default: on torque logs
            a free scale takes up part of an effect on its joint (a damping on a 3-joint
            arm was left at 1.6x the noise floor instead of 1.03x).

    Fitted attributes: ``blr_``, ``weights_`` ``(P,)`` (natural units), ``output_scale_``
    ``(n,)``, ``noise_variance_`` ``(n,)`` (units of ``y`` squared), ``n_features_`` (``P``).
    ``predict`` returns the posterior mean and a zero latent variance.

    Raises:
        ValueError: more than ``max_features`` parameters (named, with the count).
    """

    name = "GIP-Lagrangian"

    def __init__(
        self,
        joint_types: str,
        *,
        chunk: int = 2000,
        noise_min: float = 1e-12,
        max_features: int = MAX_RIGID_FEATURES,
        output_scales: bool = False,
    ) -> None:
        self.joint_types = check_joint_types(joint_types)
        super().__init__(len(self.joint_types))
        self.output_scales = bool(output_scales)
        if chunk < 1:
            raise ValueError(f"chunk must be >= 1, got {chunk}")
        self.chunk, self.noise_min = int(chunk), float(noise_min)
        self.params = lagrangian_parameters(self.joint_types)
        if len(self.params) > max_features:
            raise ValueError(
                f"the Lagrangian of joint types {self.joint_types!r} has {len(self.params)} "
                f"parameters (max_features={max_features}); use the Nystroem GIP start "
                "(inducing) for this many joints"
            )
        self.n_features_ = len(self.params)

    def _chunks(self, states: JointStates) -> list[tuple[int, FloatArray]]:
        N = states.q.shape[0]
        return [
            (
                a,
                lagrangian_columns(
                    JointStates(
                        states.q[a : a + self.chunk],
                        states.qd[a : a + self.chunk],
                        states.qdd[a : a + self.chunk],
                    ),
                    self.params,
                    self.joint_types,
                ),
            )
            for a in range(0, N, self.chunk)
        ]

    def _statistics(
        self, states: JointStates, y: FloatArray, normal: bool
    ) -> tuple[FloatArray | None, FloatArray, FloatArray]:
        """Per joint ``A_a = C_a^T C_a`` (with ``normal``), ``b_a = C_a^T y_a``, ``y_a^T y_a``."""
        n, P = len(self.joint_types), self.n_features_
        A = np.zeros((n, P, P)) if normal else None
        b = np.zeros((n, P))
        for a, C in self._chunks(states):
            if A is not None:
                A += np.matmul(C.transpose(0, 2, 1), C)  # batched BLAS
            b += np.einsum("anp,na->ap", C, y[a : a + C.shape[1]])
        return A, b, np.sum(y**2, axis=0)

    def _solve(self, b: FloatArray, yy: FloatArray) -> None:
        """The weighted regression with the output scales (class docstring): passes that
        refit the parameters at the current scales and noise, then each scale (its least
        squares value given the parameters) and each joint's noise."""
        A, d, N = self._A, self.scales_, self._rows
        n = len(self.joint_types)
        var = np.maximum(yy / N, 1e-300)  # first pass: each output's own scale
        scale = np.ones(n)
        for _ in range(MAX_PASSES):
            before = np.concatenate([scale, var])
            blr = BayesianLinearRegression(self.n_features_, 1)
            blr.A[0] = np.einsum("apq,a->pq", A, scale**2 / var) / (d[:, None] * d[None, :])
            blr.b[0] = (b * (scale / var)[:, None]).sum(0) / d
            blr.yy[0] = float(np.sum(yy / var))
            blr.n = N * n
            blr.fit(noise_min=self.noise_min)
            w = blr.weights_[0] / d
            bw, wAw = np.einsum("ap,p->a", b, w), np.einsum("p,apq,q->a", w, A, w)
            if self.output_scales and n > 1:
                scale[1:] = bw[1:] / np.maximum(wAw[1:], 1e-300)
            resid = yy - 2 * scale * bw + scale**2 * wAw
            var = np.maximum(resid / N, MIN_RELATIVE_NOISE * np.maximum(yy / N, 1e-300))
            if np.max(np.abs(np.concatenate([scale, var]) / before - 1.0)) < PASS_TOLERANCE:
                break
        self.blr_, self.weights_, self.noise_variance_ = blr, w, var
        self.output_scale_ = scale

    def _fit(self, states: JointStates, y: FloatArray) -> None:
        A, b, yy = self._statistics(states, y, normal=True)
        self._A, self._rows = A, states.q.shape[0]
        d = np.sqrt(np.clip(np.einsum("app->p", A), 0.0, None) / (self._rows * A.shape[0]))
        self.scales_ = np.where(d > 0, d, 1.0)
        self._solve(b, yy)

    def refit_targets(self, states: Any, y: FloatArray) -> None:
        """The regression refitted on new targets ``y`` at the rows of the fit (the normal
        matrices kept; ``b`` and ``y^T y`` recomputed): a learned start backfitted on the
        output minus fitted effects."""
        if self.n_joints_ is None:
            raise RuntimeError(f"{type(self).__name__} is not fitted; call fit(X, y) first")
        states = as_joint_states(states, self.n_joints_)
        if states.q.shape[0] != self._rows:
            raise ValueError(f"refit_targets needs the {self._rows} rows of the fit")
        _, b, yy = self._statistics(states, np.asarray(y, dtype=np.float64), normal=False)
        self._solve(b, yy)

    def predict_mean(self, X: Any) -> FloatArray:
        """``(N, n)`` posterior mean at ``X`` (a dataset or ``(N, 3n)`` rows)."""
        if self.n_joints_ is None:
            raise RuntimeError(f"{type(self).__name__} is not fitted; call fit(X, y) first")
        states = as_joint_states(X, self.n_joints_)
        return self.output_scale_ * np.concatenate(
            [np.einsum("anp,p->na", C, self.weights_) for _, C in self._chunks(states)]
        )

    def _predict(self, states: JointStates) -> tuple[FloatArray, FloatArray]:
        mean = self.predict_mean(np.concatenate([states.q, states.qd, states.qdd], axis=1))
        return mean, np.zeros_like(mean)

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
import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mcpilco.models.gp.blr import BayesianLinearRegression
from mcpilco.models.inverse_dynamics.base import InverseDynamicsEstimator
from mcpilco.models.inverse_dynamics.inputs import JointStates, as_joint_states
from mcpilco.models.kernels import check_joint_types
from mcpilco.models.stats import mad_std

FloatArray = NDArray[np.float64]

__all__ = [
    "MAX_RIGID_FEATURES",
    "ChainEstimator",
    "LagrangianEstimator",
    "armature_columns",
    "difference_noise",
    "joint_local_columns",
    "chain_columns",
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


GRAVITY = 9.81
"""Magnitude of gravity [m/s^2] in :func:`chain_columns` (its direction is fitted)."""
CHAIN_PARAMETERS = 10
"""Inertial parameters of one body in :func:`chain_columns`: ``m``, ``m c`` (3) and the
inertia about the body frame's origin (6)."""
_SYMMETRIC = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))  # the inertia entries' order


def _axis_rotation(axis: str, angle: Any) -> Any:
    """``(..., 3, 3)`` rotation about ``x`` or ``z`` by ``angle`` (a torch tensor)."""
    import torch

    c, s = torch.cos(angle), torch.sin(angle)
    one, zero = torch.ones_like(c), torch.zeros_like(c)
    if axis == "x":
        rows = ((one, zero, zero), (zero, c, -s), (zero, s, c))
    else:
        rows = ((c, -s, zero), (s, c, zero), (zero, zero, one))
    return torch.stack([torch.stack(r, -1) for r in rows], -2)


def chain_columns(
    kinematics: Any, gravity: Any, joint_types: str, q: Any, qd: Any, qdd: Any
) -> Any:
    r"""``(n, N, 10 n)`` torch tensor: the torque of every joint for a unit value of each
    body's inertial parameters, for the serial chain whose joint ``i`` follows the frame
    ``{i-1}`` by the Denavit-Hartenberg transform
    ``Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)`` (``theta_i = theta0_i + q_i`` for ``R``,
    ``d_i = d0_i + q_i`` for ``P``), ``kinematics`` ``(n, 4)`` rows
    ``(alpha_i, a_i, theta0_i, d0_i)``, gravity of magnitude :data:`GRAVITY` along
    ``-(sin b cos c, sin b sin c, cos b)`` in the base frame (``gravity = (b, c)``).

    Newton-Euler: each body's frame, angular velocity :math:`\omega`, angular acceleration
    :math:`\dot\omega` and origin acceleration :math:`a` (gravity as an upward acceleration
    of the base) forward; body ``k``'s force and moment about its origin are linear in its
    parameters :math:`\pi_k = (m, m c, I_o)` (in its frame, rotated by :math:`R_k`),

    .. math::

        f = m a + \dot\omega \times R\,mc + \omega \times (\omega \times R\,mc),\quad
        n = R I_o R^\top \dot\omega + \omega \times R I_o R^\top \omega + R\,mc \times a,

    and joint ``i`` carries :math:`z_{i-1}^\top \sum_{k \ge i} (n_k + (p_k - p_{i-1})
    \times f_k)` (revolute) or :math:`z_{i-1}^\top \sum_{k \ge i} f_k` (prismatic). Every
    rigid-body torque of a serial chain of these joint types is ``C @ pi`` for some
    kinematics (any two joint axes are related by four DH numbers) and parameters ``pi``.
    Differentiable in ``kinematics`` and ``gravity`` (torch autograd)."""
    import torch

    n, N = len(joint_types), q.shape[0]
    g = torch.stack(
        [
            torch.sin(gravity[0]) * torch.cos(gravity[1]),
            torch.sin(gravity[0]) * torch.sin(gravity[1]),
            torch.cos(gravity[0]),
        ]
    )
    R = torch.eye(3, dtype=q.dtype).expand(N, 3, 3)
    p, w, wd = (torch.zeros(N, 3, dtype=q.dtype) for _ in range(3))
    acc = p + GRAVITY * g
    frames = []
    for j, kind in enumerate(joint_types):
        alpha, a, theta, d = kinematics[j]
        z, axis_point = R[:, :, 2], p
        if kind == "R":
            R = R @ _axis_rotation("z", theta + q[:, j])
            p_new = p + z * d
        else:
            R = R @ _axis_rotation("z", theta.expand(N))
            p_new = p + z * (d + q[:, j : j + 1])
        p_new = p_new + R[:, :, 0] * a
        R = R @ _axis_rotation("x", alpha)
        r = p_new - p
        if kind == "R":
            w_new = w + z * qd[:, j : j + 1]
            wd = wd + torch.cross(w, z * qd[:, j : j + 1], dim=-1) + z * qdd[:, j : j + 1]
            w = w_new
            acc = (
                acc + torch.cross(wd, r, dim=-1) + torch.cross(w, torch.cross(w, r, dim=-1), dim=-1)
            )
        else:
            acc = (
                acc
                + torch.cross(wd, r, dim=-1)
                + torch.cross(w, torch.cross(w, r, dim=-1), dim=-1)
                + 2 * torch.cross(w, z * qd[:, j : j + 1], dim=-1)
                + z * qdd[:, j : j + 1]
            )
        p = p_new
        frames.append((R, p, w, wd, acc, z, axis_point))
    forces, moments = [], []
    for R, _, w, wd, acc, _, _ in frames:
        f, m = [acc], [torch.zeros_like(acc)]
        for e in range(3):
            u = R[:, :, e]
            f.append(torch.cross(wd, u, dim=-1) + torch.cross(w, torch.cross(w, u, dim=-1), dim=-1))
            m.append(torch.cross(u, acc, dim=-1))
        # unit inertia entry E_e (symmetric, entries (i, k) and (k, i)) in the base frame
        # applied to v: R E_e R^T v = R_i (R^T v)_k + R_k (R^T v)_i (once where i = k)
        bwd, bw = (R * wd[:, :, None]).sum(1), (R * w[:, :, None]).sum(1)
        for i, k in _SYMMETRIC:
            Iwd = R[:, :, i] * bwd[:, k : k + 1]
            Iw = R[:, :, i] * bw[:, k : k + 1]
            if i != k:
                Iwd = Iwd + R[:, :, k] * bwd[:, i : i + 1]
                Iw = Iw + R[:, :, k] * bw[:, i : i + 1]
            f.append(torch.zeros_like(acc))
            m.append(Iwd + torch.cross(w, Iw, dim=-1))
        forces.append(torch.stack(f, -1))
        moments.append(torch.stack(m, -1))
    zero = torch.zeros(N, CHAIN_PARAMETERS, dtype=q.dtype)
    cols = []
    for i, kind in enumerate(joint_types):
        z, point = frames[i][5], frames[i][6]
        row = []
        for k in range(n):
            if k < i:
                row.append(zero)
            elif kind == "R":
                lever = (frames[k][1] - point)[:, :, None].expand_as(forces[k])
                moment = moments[k] + torch.cross(lever, forces[k], dim=1)
                row.append(torch.einsum("ni,nic->nc", z, moment))
            else:
                row.append(torch.einsum("ni,nic->nc", z, forces[k]))
        cols.append(torch.cat(row, 1))
    return torch.stack(cols)


def armature_columns(qdd: Any) -> Any:
    r"""``(n, N, n)`` torch tensor: the torque of every joint for a unit armature (rotor
    inertia reflected through the gear, :math:`J_a = J_{m,a} K_{r,a}^2`) on each joint,
    :math:`\tau_a = J_a \ddot q_a` on that joint alone (the thesis's reduced model of a
    geared motor, and MuJoCo's ``armature``). A rotor turning with joint ``a`` on the
    previous body is not one of the chain's bodies: its kinetic energy
    :math:`\tfrac12 J_a \dot q_a^2` adds a constant to :math:`M_{aa}` only, which no body
    of the chain beyond joint 1 gives (a body's inertia about joint ``a``'s axis also loads
    every joint before ``a``)."""
    import torch

    n = qdd.shape[1]
    out = torch.zeros(n, qdd.shape[0], n, dtype=qdd.dtype)
    idx = torch.arange(n)
    out[idx, :, idx] = qdd.T
    return out


CHAIN_RESTARTS = 10
"""Random starts of :class:`ChainEstimator`'s kinematics search, besides the grid's: on a
random 7R arm's log (twists off the quarter-turn grid) about one in five reaches the
global minimum, the others a few local minima at 15-25 times its loss."""
CHAIN_TWISTS = (0.0, math.pi / 2, -math.pi / 2, math.pi)
"""Twists ``alpha_i`` and joint offsets ``theta0_i`` of the grid search: a real arm's axes
are parallel or at right angles, so its DH twists and offsets almost always lie here."""
CHAIN_LENGTHS = tuple(round(0.1 * k, 1) for k in range(-6, 7))
"""Link lengths ``a_i`` and offsets ``d0_i`` of the grid search [m]."""
CHAIN_GRAVITY = (
    (0.0, 0.0),
    (math.pi, 0.0),
    (math.pi / 2, 0.0),
    (math.pi / 2, math.pi / 2),
    (math.pi / 2, math.pi),
    (math.pi / 2, -math.pi / 2),
)
"""Gravity directions ``(b, c)`` of the grid search: along each base axis, either way."""
CHAIN_GRID_STARTS = 6
"""Starts of the grid search's coordinate descent (twists and offsets drawn from
:data:`CHAIN_TWISTS`, lengths zero, gravity along ``-z``)."""
CHAIN_GRID_SWEEPS = 8
"""Most sweeps of one coordinate descent on the grid."""
CHAIN_GRID_ROWS = 1000
"""Rows (evenly spaced) of the grid search's loss (the kinematics fixed: no gradient): on
300 rows of a noisy log (relative loss 0.13 at the true kinematics) the grid's best point
fits the noise below the true kinematics' loss and its descent ends in a wrong minimum."""
CHAIN_GRID_KEEP = 3
"""Best distinct grid points refined by L-BFGS."""
CHAIN_SEARCH_ROWS = 600
"""Rows (evenly spaced) on which :class:`ChainEstimator` refines the starts."""
CHAIN_ITERATIONS = 400
"""Most L-BFGS iterations of one start of the kinematics search."""
CHAIN_REFINE_ROWS = 4000
"""Rows (evenly spaced) on which :class:`ChainEstimator` refines the best start's
kinematics: the search's rows leave the kinematics off by their noise (estimated ``qdd``)."""
CHAIN_REFINE_ITERATIONS = 400
"""Most L-BFGS iterations of the refinement."""
CHAIN_SEARCH_TOLERANCE = 1e-10
"""A start of the search stops once an L-BFGS step changes its loss (in units of each
joint's noise variance: about 1 at the noise floor) by less than this; further steps only
move the kinematics within their noise (the refinement polishes the best start to
``1e-14``)."""
SEARCH_FRICTION_VELOCITY = 0.01
"""Velocity [rad/s or m/s] of the ``tanh`` of the dry-friction column of the kinematics
search's joint-local terms (:func:`joint_local_columns`)."""
SEARCH_REST_VELOCITY = 0.05
"""A joint's rows with ``|qd_a|`` below this [rad/s or m/s] are left out of its part of the
kinematics search's loss: at rest a dry friction's torque is set-valued (anything that
holds the joint), which no column follows."""
NOISE_DIFFERENCE = (1.0, -2.0, 1.0)
"""Second difference whose median absolute value estimates a column's white-noise std
(:func:`difference_noise`; a smooth signal's share is ``O(dt^2)``)."""
MIN_SEARCH_SCALE = 1e-6
"""Smallest weight scale of a joint in the kinematics search, relative to its root mean
square (noise-free torques would otherwise weigh one joint without bound)."""
CHAIN_THREADS = 1
"""Torch threads of :class:`ChainEstimator`'s fit (the count before it restored after): its
matrices are small (``11 n`` parameters, 600-4000 rows), so a second thread gains little
and, on cores shared with other jobs, spent 5-18 times the CPU and 5-18 times the wall
time of one thread (grid evaluations, L-BFGS descents and the refinement of a 7-joint
chain measured both ways)."""
CHAIN_SNAP_ITERATIONS = 400
"""Most L-BFGS iterations of the lengths and gravity after the angles are set to quarter
turns (:meth:`ChainEstimator._snap`)."""
CHAIN_EXACT = 1e-9
"""Relative loss of an exact fit: the search stops early once two starts reach it (noise-free
torques); otherwise every start runs (a local minimum is often found twice, so agreement
between starts does not show the global one)."""


def joint_local_columns(q: Any, qd: Any) -> Any:
    """``(n, N, 2 n)``: on each joint ``a`` alone a viscous ``qd_a`` and a dry friction
    ``tanh(qd_a / v)`` (:data:`SEARCH_FRICTION_VELOCITY`) column (torch tensors): torques
    no chain holds, which :class:`ChainEstimator`'s kinematics search projects out so that
    they do not bend the kinematics (an offset and a spring ``q_a`` are left out: over a
    joint's range they mimic gravity torques, and an effect-free Panda log then named an
    offset)."""
    import torch

    n = qd.shape[1]
    feats = torch.stack([qd, torch.tanh(qd / SEARCH_FRICTION_VELOCITY)], 2)  # (N, n, 2)
    out = torch.zeros(n, qd.shape[0], 2 * n, dtype=qd.dtype)
    for a in range(n):
        out[a, :, 2 * a : 2 * a + 2] = feats[:, a]
    return out


def difference_noise(y: FloatArray) -> FloatArray:
    """``(n,)`` white-noise std of each column of ``y`` ``(N, n)`` (rows in time order), from
    the median absolute second difference (:data:`NOISE_DIFFERENCE`,
    :func:`~mcpilco.models.stats.mad_std`): a smooth signal's curvature adds ``O(dt^2)``, and
    the median ignores the few jumps
    (file boundaries, impacts). Rows out of time order give about the signal's own scale."""
    c = np.asarray(NOISE_DIFFERENCE)
    y = np.asarray(y, dtype=np.float64)
    if y.shape[0] < c.size:
        return np.sqrt(np.mean(y**2, axis=0))
    d = sum(c[k] * y[k : y.shape[0] - c.size + 1 + k] for k in range(c.size))
    return mad_std(d) / math.sqrt(float(np.sum(c**2)))


class ChainEstimator(LagrangianEstimator):
    """Bayesian linear regression of all joints' torques over the inertial parameters of a
    serial chain whose kinematics are fitted too (:func:`chain_columns`) and each joint's
    armature (:func:`armature_columns`): ``11 n`` parameters and ``4 n + 2`` kinematic
    numbers, against the Lagrangian's monomials (:func:`lagrangian_parameters`: 9,947 for 6
    and 49,374 for 7 revolute joints) that span the same torques linearly (a constant in
    :math:`M_{aa}` is one of them). Without the armatures a geared arm's reflected rotor
    inertia (the Panda table's 0.1 kg m^2 on every joint, ten times its wrist links')
    is no torque of the chain: the wrist stays at many times the noise floor.

    The torque is linear in the inertial parameters ``pi`` for fixed kinematics ``kappa``
    (DH numbers and the gravity direction), so the kinematics are searched by variable
    projection: each joint's torques divided by its noise std ``s_a``
    (:func:`difference_noise` of its rows in time order, clipped to at most its root mean
    square), the loss is :math:`\\min_\\pi \\lVert y - C(\\kappa)\\pi \\rVert^2` of these
    whitened torques (``pi`` by ridge least squares inside, differentiated through by torch
    autograd; reported relative to :math:`\\lVert y \\rVert^2`). Whitening weighs each joint
    as the likelihood does: with each joint over its own root mean square instead, a joint
    that carries little more than noise (the Panda's last joint) fills the loss
    and a kinematics that leaves the shoulder at 20-40 times its noise scores as well as
    the arm's own (Panda, 2 x 5 s log). Torques no chain holds are projected out with the
    inertial parameters: a viscous and a dry friction on each joint alone
    (:func:`joint_local_columns`, in the search only: the fitted start leaves them in its
    residual), and a joint's rows at rest (:data:`SEARCH_REST_VELOCITY`: a dry friction's
    set-valued torque) are left out of its part of the loss; otherwise dry friction of
    2-3 N m on two Panda joints bent the kinematics until the other joints stood at 7-49
    times their noise (1.1-1.6 times with them). The problem is
    not convex: from random starts L-BFGS ends in a local minimum most of the time (on the
    Panda's log about 1.4 times the loss at its own kinematics). The search starts where
    real arms lie:

    1. Grid search. ``kappa = (alpha_i, a_i, theta0_i, d0_i)_{i=1..n}, (b, c)`` on the grid
       twists and offsets in :data:`CHAIN_TWISTS` (quarter turns: real arms' axes are
       parallel or perpendicular), lengths in :data:`CHAIN_LENGTHS` (0.1 m steps), gravity
       along a base axis (:data:`CHAIN_GRAVITY`). Coordinate descent over blocks (the
       gravity; per joint its 16 twist-and-offset pairs, its length ``a_i``, its offset
       ``d0_i``), each block set to its best value given the others, sweeps until none
       moves (at most :data:`CHAIN_GRID_SWEEPS`), from ``grid_starts`` random grid points;
       the loss on :data:`CHAIN_GRID_ROWS` rows without gradient (about 14 ms for 7 joints
       on one thread; about 1,000-1,500 evaluations per start, ``grid_evaluations_``).
    2. The :data:`CHAIN_GRID_KEEP` best distinct grid points and ``restarts`` random starts
       (for arms whose axes are at other angles) descended by L-BFGS on ``search_rows``
       rows, keeping the best (fewer starts when two fit exactly, :data:`CHAIN_EXACT`).
    3. The best refined by L-BFGS on ``refine_rows`` rows, where the estimated
       accelerations' noise moves the minimum less.
    4. Quarter turns. Every twist ``alpha_i`` and offset ``theta0_i`` set to the nearest
       multiple of ``pi/2`` and the lengths and gravity descended again; kept when the loss
       rises, in chi-square units (the loss's residual variance taken as the noise's), by
       at most the Bayesian information criterion's ``2 n log N`` for the ``2 n`` angles
       fixed (``N`` residuals). Two 5 s logs do not pin a 7-joint chain's angles: on a
       Panda log with a 1.9 kg payload the refined kinematics fitted the training rows as
       well as the arm's own (twists 0.03-0.43 rad off a quarter turn, offsets up to
       0.7 rad) but left shoulder and elbow at 1.4-1.5 times the noise floor on the
       held-out log; snapped, 1.0-1.2 times, as at the arm's own kinematics. An arm whose
       axes are at other angles keeps its fitted ones (the rise is many times the
       allowance).

    Then the parameters are fitted on every row as :class:`LagrangianEstimator` does (row
    weights, prior scale, noise); :meth:`refit_targets` keeps the kinematics.

    ``per_joint`` (motor currents ``i_a = tau_a / k_a``, each joint in its own units): each
    joint gets its own parameter vector ``pi_a``, in the search and in the regression (one
    Bayesian linear regression per joint), which no per-joint constant can bias; linear,
    where one shared vector with a scale per joint is bilinear. It loses the tie between
    the joints (Euler-Lagrange), so a joint's torque is fitted from its own rows only.

    Args:
        joint_types: e.g. ``"RRRRRRR"``.
        chunk, noise_min: as in :class:`LagrangianEstimator`.
        per_joint: one parameter vector per joint (above).
        restarts: random starts descended besides the grid's (``>= 0``).
        grid_starts: starts of the grid search (``>= 0``; one start of either kind at
            least).
        search_rows: rows of the kinematics search.
        refine_rows: rows of the refinement of the best start (none when not more than
            ``search_rows``).
        seed: seed of the random starts.
        kinematics, gravity: known DH rows ``(n, 4)`` ``(alpha_i, a_i, theta0_i, d0_i)`` and
            gravity direction ``(b, c)`` (:func:`chain_columns`): no search, only the
            inertial parameters are fitted (a robot whose kinematics are known but not its
            inertias; both or neither).
        threads: torch threads of the fit (:data:`CHAIN_THREADS`; the count before it
            restored after; ``None``: leave as is).

    Fitted attributes (besides :class:`LagrangianEstimator`'s): ``kinematics_`` ``(n, 4)``,
    ``gravity_`` ``(2,)``, ``search_scale_`` ``(n,)`` (each joint's ``s_a``),
    ``search_loss_`` (the best relative loss), ``refine_loss_`` (the
    refinement's; NaN without one), ``snapped_`` (the angles set to quarter turns, step 4),
    ``snap_cost_`` (that step's rise over its allowance), ``starts_`` (starts descended),
    ``grid_loss_`` (the grid search's best; NaN without one), ``grid_evaluations_``.
    """

    name = "GIP-chain"

    def __init__(
        self,
        joint_types: str,
        *,
        chunk: int = 2000,
        noise_min: float = 1e-12,
        per_joint: bool = False,
        restarts: int = CHAIN_RESTARTS,
        grid_starts: int = CHAIN_GRID_STARTS,
        search_rows: int = CHAIN_SEARCH_ROWS,
        refine_rows: int = CHAIN_REFINE_ROWS,
        seed: int = 0,
        kinematics: Any = None,
        gravity: Any = None,
        threads: int | None = CHAIN_THREADS,
    ) -> None:
        self.joint_types = check_joint_types(joint_types)
        InverseDynamicsEstimator.__init__(self, len(self.joint_types))
        if threads is not None and threads < 1:
            raise ValueError(f"threads must be >= 1 or None, got {threads}")
        self.threads = threads
        n = len(self.joint_types)
        if (kinematics is None) != (gravity is None):
            raise ValueError("give both kinematics and gravity, or neither")
        self.known = None
        if kinematics is not None:
            kin = np.asarray(kinematics, dtype=np.float64)
            grav = np.asarray(gravity, dtype=np.float64)
            if kin.shape != (n, 4) or grav.shape != (2,):
                raise ValueError(
                    f"kinematics must be ({n}, 4) and gravity (2,); got {kin.shape}, {grav.shape}"
                )
            self.known = (kin, grav)
        if chunk < 1 or min(restarts, grid_starts) < 0 or restarts + grid_starts < 1:
            raise ValueError(
                "need chunk >= 1, restarts >= 0 and grid_starts >= 0 (one start at least); "
                f"got {chunk}, {restarts}, {grid_starts}"
            )
        if search_rows < 2:
            raise ValueError(f"search_rows must be >= 2, got {search_rows}")
        self.chunk, self.noise_min = int(chunk), float(noise_min)
        self.output_scales, self.per_joint = False, bool(per_joint)
        self.restarts, self.search_rows, self.seed = int(restarts), int(search_rows), int(seed)
        self.grid_starts = int(grid_starts)
        self.grid_evaluations_, self.grid_loss_ = 0, math.nan
        self.refine_rows = int(refine_rows)
        self.refine_loss_ = math.nan
        self.snapped_, self.snap_cost_ = False, math.nan
        self.n_features_ = (CHAIN_PARAMETERS + 1) * len(self.joint_types)

    def _columns(self, kinematics: Any, gravity: Any, q: Any, qd: Any, qdd: Any) -> Any:
        """``(n, N, 11 n)``: the bodies' inertial parameters (:func:`chain_columns`) and the
        joints' armatures (:func:`armature_columns`)."""
        import torch

        body = chain_columns(kinematics, gravity, self.joint_types, q, qd, qdd)
        return torch.cat([body, armature_columns(qdd)], 2)

    def _chunks(self, states: JointStates) -> list[tuple[int, FloatArray]]:
        import torch

        kin, grav = torch.as_tensor(self.kinematics_), torch.as_tensor(self.gravity_)
        out = []
        with torch.no_grad():
            for a in range(0, states.q.shape[0], self.chunk):
                parts = (
                    torch.as_tensor(np.ascontiguousarray(x[a : a + self.chunk]))
                    for x in (states.q, states.qd, states.qdd)
                )
                out.append((a, self._columns(kin, grav, *parts).numpy()))
        return out

    def _projection_loss(self, states: JointStates, y: FloatArray, count: int) -> Any:
        """The variable-projection loss of the kinematics on ``count`` evenly spaced rows
        (class docstring): each joint's torques over ``search_scale_``, the inertial
        parameters by ridge least squares inside, differentiated through."""
        import torch

        N, n = states.q.shape[0], len(self.joint_types)
        rows = np.unique(np.round(np.linspace(0, N - 1, min(count, N))).astype(int))
        q, qd, qdd = (torch.as_tensor(x[rows]) for x in (states.q, states.qd, states.qdd))
        scale = self.search_scale_
        moving = torch.as_tensor(np.abs(states.qd[rows]) > SEARCH_REST_VELOCITY).T  # (n, N)
        target = torch.as_tensor((y[rows] / scale).T * moving.numpy()).reshape(-1)
        weight = torch.as_tensor(1.0 / scale)[:, None, None] * moving[:, :, None]
        local = joint_local_columns(q, qd)
        P = self.n_features_ + local.shape[2]
        ridge = 1e-8 * target.numel() * torch.eye(P, dtype=torch.float64)

        def loss(x: Any) -> Any:
            C = self._columns(x[: 4 * n].view(n, 4), x[4 * n :], q, qd, qdd)
            C = torch.cat([C, local], 2)
            if self.per_joint:  # each joint its own parameters: free of its units
                A = C * weight
                A = A / A.detach().pow(2).mean(1, keepdim=True).sqrt().clamp_min(1e-12)
                t = target.view(n, -1, 1)
                H = A.transpose(1, 2) @ A + ridge / n
                pi = torch.linalg.solve(H, A.transpose(1, 2) @ t)
                return (t - A @ pi).pow(2).mean()
            A = (C * weight).reshape(-1, P)
            A = A / A.detach().pow(2).mean(0).sqrt().clamp_min(1e-12)
            pi = torch.linalg.solve(A.T @ A + ridge, A.T @ target)
            return (target - A @ pi).pow(2).mean()

        loss.total = float(target.pow(2).mean().clamp_min(1e-300))  # relative loss = loss / total
        loss.count = int(moving.sum())  # the residuals in the loss (rows at rest left out)
        return loss

    @staticmethod
    def _descend(loss: Any, x0: Any, iterations: int, tolerance: float) -> tuple[float, Any]:
        """L-BFGS (strong Wolfe line search) on ``loss`` from ``x0`` until a step changes the
        loss by less than ``tolerance``: the final loss and point."""
        import torch

        x = x0.detach().clone().requires_grad_(True)
        opt = torch.optim.LBFGS(
            [x],
            max_iter=iterations,
            history_size=50,
            line_search_fn="strong_wolfe",
            tolerance_grad=1e-12,
            tolerance_change=tolerance,
        )

        def closure() -> Any:
            opt.zero_grad()
            value = loss(x)
            value.backward()
            return value

        opt.step(closure)
        with torch.no_grad():
            return float(loss(x)), x.detach().clone()

    def _grid_blocks(self) -> list[Any]:
        """The coordinate blocks of the grid search (class docstring), each a
        function of the current point giving its neighbours in that block: the gravity along
        each base axis either way (:data:`CHAIN_GRAVITY`); per joint every twist-and-offset
        pair (:data:`CHAIN_TWISTS`), every length ``a_i`` and every offset ``d0_i``
        (:data:`CHAIN_LENGTHS`)."""
        import torch

        n = len(self.joint_types)

        def gravity(x: Any) -> list[Any]:
            return [
                torch.cat([x[: 4 * n], torch.tensor(g, dtype=torch.float64)]) for g in CHAIN_GRAVITY
            ]

        def setter(idx: tuple[int, ...], values: Any) -> Any:
            def block(x: Any) -> list[Any]:
                out = []
                for v in values:
                    c = x.clone()
                    c[list(idx)] = torch.tensor(v, dtype=torch.float64)
                    out.append(c)
                return out

            return block

        blocks = [gravity]
        for j in range(n):
            blocks.append(
                setter((4 * j, 4 * j + 2), list(itertools.product(CHAIN_TWISTS, CHAIN_TWISTS)))
            )
            blocks.append(setter((4 * j + 1,), [(v,) for v in CHAIN_LENGTHS]))
            blocks.append(setter((4 * j + 3,), [(v,) for v in CHAIN_LENGTHS]))
        return blocks

    def _grid_search(self, states: JointStates, y: FloatArray) -> list[tuple[float, Any]]:
        """Coordinate descent of the variable-projection loss over the grid of real arms'
        kinematics (class docstring) from :data:`CHAIN_GRID_STARTS` starts, on
        :data:`CHAIN_GRID_ROWS` rows: each neighbour of :meth:`_grid_blocks` that lowers the loss
        is moved to, until a sweep finds none. The distinct end points, best first; the count
        of loss evaluations in ``grid_evaluations_``."""
        import torch

        n = len(self.joint_types)
        loss = self._projection_loss(states, y, CHAIN_GRID_ROWS)
        gen = torch.Generator().manual_seed(self.seed + 1)
        twists = torch.tensor(CHAIN_TWISTS, dtype=torch.float64)
        count, found, blocks = 0, [], self._grid_blocks()
        for _ in range(self.grid_starts):
            pick = torch.randint(len(CHAIN_TWISTS), (n, 2), generator=gen)
            x = torch.zeros(n, 4, dtype=torch.float64)
            x[:, 0], x[:, 2] = twists[pick[:, 0]], twists[pick[:, 1]]
            x = torch.cat([x.reshape(-1), torch.zeros(2, dtype=torch.float64)])
            with torch.no_grad():
                best = float(loss(x))
                count += 1
                for _ in range(CHAIN_GRID_SWEEPS):
                    moved = False
                    for block in blocks:
                        for c in block(x):
                            if torch.equal(c, x):
                                continue
                            value = float(loss(c))
                            count += 1
                            if value < best * (1 - 1e-9):
                                best, x, moved = value, c, True
                    if not moved:
                        break
            if math.isfinite(best) and not any(torch.equal(x, z) for _, z in found):
                found.append((best, x))
        self.grid_evaluations_ = count
        self.grid_loss_ = min((v for v, _ in found), default=math.nan) / loss.total
        return sorted(found, key=lambda t: t[0])

    def _search(self, states: JointStates, y: FloatArray) -> None:
        """The kinematics by variable projection (class docstring): the best
        :data:`CHAIN_GRID_KEEP` points of the grid search and ``restarts`` random starts
        descended by L-BFGS on ``search_rows`` rows, the best refined on ``refine_rows``."""
        import torch

        n = len(self.joint_types)
        rms = np.sqrt(np.maximum(np.mean(y**2, axis=0), 1e-300))
        self.search_scale_ = np.clip(difference_noise(y), MIN_SEARCH_SCALE * rms, rms)
        loss = self._projection_loss(states, y, self.search_rows)
        starts = [x for _, x in self._grid_search(states, y)[:CHAIN_GRID_KEEP]]
        gen = torch.Generator().manual_seed(self.seed)
        for _ in range(self.restarts):
            u = torch.rand(n, 4, generator=gen, dtype=torch.float64) * 2 - 1
            x0 = torch.stack(
                [u[:, 0] * math.pi, u[:, 1] * 0.5, u[:, 2] * math.pi, u[:, 3] * 0.5], 1
            )
            g0 = torch.rand(2, generator=gen, dtype=torch.float64) * torch.tensor(
                [math.pi, 2 * math.pi]
            )
            starts.append(torch.cat([x0.reshape(-1), g0]))
        found: list[tuple[float, Any]] = []
        for x0 in starts:
            value, x = self._descend(loss, x0, CHAIN_ITERATIONS, CHAIN_SEARCH_TOLERANCE)
            if math.isfinite(value):
                found.append((value, x))
            if sum(v < CHAIN_EXACT * loss.total for v, _ in found) >= 2:
                break  # two exact fits (noise-free torques): nothing left to find
        if not found:
            raise ValueError("the kinematics search diverged from every start; check the data")
        value, x = min(found, key=lambda t: t[0])
        self.search_loss_, self.starts_ = value / loss.total, len(found)
        final = loss
        if self.refine_rows > self.search_rows and states.q.shape[0] > self.search_rows:
            refine = self._projection_loss(states, y, self.refine_rows)
            fine, x_fine = self._descend(refine, x, CHAIN_REFINE_ITERATIONS, 1e-14)
            if math.isfinite(fine):
                x, value, final = x_fine, fine, refine
                self.refine_loss_ = fine / refine.total
        x = self._snap(final, x, value)
        self.kinematics_ = x[: 4 * n].view(n, 4).numpy().copy()
        self.gravity_ = x[4 * n :].numpy().copy()

    def _snap(self, loss: Any, x: Any, value: float) -> Any:
        """The kinematics ``x`` (loss ``value``) with every twist ``alpha_i`` and offset
        ``theta0_i`` set to the nearest quarter turn and the lengths and gravity descended
        again (:data:`CHAIN_SNAP_ITERATIONS`), when the loss rises by less than the Bayesian
        information criterion allows for the ``2 n`` angles fixed (class docstring); else
        ``x``. Sets ``snapped_`` and ``snap_cost_`` (the rise over that allowance)."""
        import torch

        n = len(self.joint_types)
        kin = x[: 4 * n].view(n, 4)
        quarter = math.pi / 2
        angles = torch.round(kin[:, [0, 2]] / quarter) * quarter

        def full(z: Any) -> Any:
            k = torch.stack([angles[:, 0], z[:n], angles[:, 1], z[n : 2 * n]], 1)
            return torch.cat([k.reshape(-1), z[2 * n :]])

        z0 = torch.cat([kin[:, 1], kin[:, 3], x[4 * n :]])
        snapped, z = self._descend(lambda z: loss(full(z)), z0, CHAIN_SNAP_ITERATIONS, 1e-14)
        # the loss is a mean of whitened squares: times the count over its own value, the
        # rise in chi-square units (the fit's residual variance as the noise's)
        rise = (snapped - value) / max(value, 1e-300) * loss.count
        allowed = 2 * n * math.log(loss.count)
        self.snap_cost_ = rise / allowed if math.isfinite(rise) else math.inf
        self.snapped_ = bool(self.snap_cost_ <= 1.0)
        return full(z).detach() if self.snapped_ else x

    def _fit(self, states: JointStates, y: FloatArray) -> None:
        import torch

        before = torch.get_num_threads()
        if self.threads is not None:
            torch.set_num_threads(self.threads)
        try:
            if self.known is None:
                self._search(states, y)
            else:
                self.kinematics_, self.gravity_ = (x.copy() for x in self.known)
                self.search_loss_, self.starts_ = math.nan, 0
            super()._fit(states, y)
        finally:
            torch.set_num_threads(before)

    def _solve(self, b: FloatArray, yy: FloatArray) -> None:
        """Shared parameters: :meth:`LagrangianEstimator._solve`; ``per_joint``: one
        Bayesian linear regression per joint on its own rows (``weights_`` ``(n, P)``)."""
        if not self.per_joint:
            return super()._solve(b, yy)
        A, d, N = self._A, self.scales_, self._rows
        n, P = len(self.joint_types), self.n_features_
        blr = BayesianLinearRegression(P, n)
        blr.A[:] = A / (d[:, None] * d[None, :])
        blr.b[:] = b / d
        blr.yy[:] = yy
        blr.n = N
        blr.fit(noise_min=self.noise_min)
        self.blr_, self.weights_ = blr, blr.weights_ / d
        self.noise_variance_, self.output_scale_ = blr.noise_variance, np.ones(n)

    def predict_mean(self, X: Any) -> FloatArray:
        """``(N, n)`` posterior mean at ``X`` (a dataset or ``(N, 3n)`` rows)."""
        if not self.per_joint:
            return super().predict_mean(X)
        if self.n_joints_ is None:
            raise RuntimeError(f"{type(self).__name__} is not fitted; call fit(X, y) first")
        states = as_joint_states(X, self.n_joints_)
        return np.concatenate(
            [np.einsum("anp,ap->na", C, self.weights_) for _, C in self._chunks(states)]
        )

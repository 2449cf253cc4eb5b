"""GP inverse-dynamics estimators: GIP, RBF, parametric prior (PP) and semi-parametric (SP).

One independent GP per joint, batched (:class:`~mcpilco.models.gp.GPRegressor` with
``m = n`` outputs), hyperparameters by maximum marginal likelihood (thesis section 1.3).

=====  ===========================================  =======================================
name   GP input                                     kernel of joint ``b``
=====  ===========================================  =======================================
GIP    ``x_bar = F(q, qd, qdd)`` (eq. 3.8)           ``GIPKernel(joint_types)`` (eq. 3.11)
GIP+F  ``[x_bar, qd_1, sign qd_1, ...]``             GIP + linear on ``[qd_b, sign qd_b]``
RBF    ``x = [q, qd, qdd]``                          ``s_b exp(-||(x - x')/l_b||^2 / 2)``
PP     ``[phi_1, ..., phi_n]`` (nominal regressor)   ``phi_b^T Sigma_b phi_b'`` (eq. 3.6)
SP     ``[q, qd, qdd, phi_1, ..., phi_n]``           PP + RBF on ``[q, qd, qdd]`` (eq. 3.7)
=====  ===========================================  =======================================

Input standardisation: every input column is mapped affinely, ``(x - mu) / s``. For the PP
kernel this keeps the model exact (``tau_b - mean(tau_b) = (phi_b - mean(phi_b))^T w_b``, and
the targets are centred too). For GIP an affine map of each column keeps the polynomial
space spanned by the inhomogeneous MPK factors (degree <= 2 in each ``(cos q_b, sin q_b)``,
affine in ``[qd_v, qdd]``), so the RKHS is unchanged; only the prior weight of the
monomials changes. ``GIPEstimator`` leaves the features unstandardised by default
(``standardize_x=False``): ``cos``/``sin`` are already O(1), and on the SCARA benchmark both
variants reach the noise floor (``mcpilco-bench-inverse-dynamics --gip-std`` reports them
side by side).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gpytorch
import numpy as np
import torch
from numpy.typing import NDArray

from mcpilco.models.gp import GPRegressor
from mcpilco.models.inverse_dynamics.base import InverseDynamicsEstimator
from mcpilco.models.inverse_dynamics.inputs import JointStates, as_joint_states, input_names
from mcpilco.models.inverse_dynamics.kernels import RowLinearKernel
from mcpilco.models.inverse_dynamics.rigid_body import RigidBodyFeatures
from mcpilco.models.kernels import GIPKernel, check_joint_types, gip_feature_names, gip_features

FloatArray = NDArray[np.float64]

__all__ = [
    "GIPEstimator",
    "GIPFrictionEstimator",
    "GPInverseDynamics",
    "NystromGIPEstimator",
    "PPEstimator",
    "RBFEstimator",
    "SPEstimator",
    "rbf_kernel",
]


def rbf_kernel(
    ard_num_dims: int, batch_shape: torch.Size, active_dims: Sequence[int] | None = None
) -> gpytorch.kernels.Kernel:
    """``ScaleKernel(RBFKernel(ARD))`` with batch shape ``batch_shape`` on ``active_dims``."""
    dims = None if active_dims is None else tuple(active_dims)
    rbf = gpytorch.kernels.RBFKernel(
        ard_num_dims=ard_num_dims, batch_shape=batch_shape, active_dims=dims
    )
    return gpytorch.kernels.ScaleKernel(rbf, batch_shape=batch_shape)


class GPInverseDynamics(InverseDynamicsEstimator):
    """Base of the GP estimators: a feature map, a kernel factory, a :class:`GPRegressor`.

    Args:
        n_joints: ``n`` (``None``: from the data).
        standardize_x: standardise the GP inputs (see the module docstring).
        noise_init: initial noise variance (fraction of the output variance).
        noise_min: lower bound of the noise variance (standardised units).
        adam_iters, adam_lr, lbfgs_iters: marginal-likelihood optimisation
            (:meth:`GPRegressor.fit`).
        max_points: condition on at most this many rows (greedy subset) when given.
        hyper_points: when the data have more rows, the hyperparameters are fitted on a
            random subset of this many rows (seeded by ``seed``), then the GP is conditioned
            on all rows (``max_points`` permitting) at those hyperparameters without further
            optimisation: the ``O(N^3)`` cost is paid once instead of at every iteration.
            ``None``: optimise on all rows.
        seed: seed of the ``hyper_points`` subset.
        predict_chunk: rows per posterior call in ``predict`` (memory ``m x chunk x N``).
        progress: tqdm bar during fitting.

    Fitted attributes: ``gp_`` (the :class:`GPRegressor`).
    """

    def __init__(
        self,
        n_joints: int | None = None,
        *,
        standardize_x: bool = True,
        noise_init: float = 1e-2,
        noise_min: float = 1e-8,
        adam_iters: int = 200,
        adam_lr: float = 0.05,
        lbfgs_iters: int = 50,
        max_points: int | None = None,
        hyper_points: int | None = None,
        seed: int = 0,
        predict_chunk: int = 1000,
        progress: bool = False,
    ) -> None:
        super().__init__(n_joints)
        if hyper_points is not None and hyper_points < 2:
            raise ValueError(f"hyper_points must be >= 2 or None, got {hyper_points}")
        if predict_chunk < 1:
            raise ValueError(f"predict_chunk must be >= 1, got {predict_chunk}")
        self.standardize_x = standardize_x
        self.noise_init = noise_init
        self.noise_min = noise_min
        self.adam_iters = adam_iters
        self.adam_lr = adam_lr
        self.lbfgs_iters = lbfgs_iters
        self.max_points = max_points
        self.hyper_points = hyper_points
        self.seed = seed
        self.predict_chunk = int(predict_chunk)
        self.progress = progress
        self.gp_: GPRegressor | None = None

    # subclasses: the GP input and its kernel
    def gp_inputs(self, states: JointStates) -> FloatArray:
        """``(N, d)`` GP input rows for these joint states."""
        raise NotImplementedError

    def kernel(self, batch_shape: torch.Size, n_joints: int) -> gpytorch.kernels.Kernel:
        """The kernel with batch shape ``[n]``."""
        raise NotImplementedError

    def gp_input_names(self, n_joints: int) -> list[str] | None:
        return None

    def new_gp(self, n_joints: int) -> GPRegressor:
        """An unfitted GP with this estimator's kernel, noise settings and names: one output
        ``tau_j`` per joint."""
        n = n_joints
        return GPRegressor(
            lambda batch: self.kernel(batch, n),
            standardize_x=self.standardize_x,
            noise_init=self.noise_init,
            noise_min=self.noise_min,
            input_names=self.gp_input_names(n),
            output_names=[f"tau{j}" for j in range(1, n + 1)],
        )

    def _fit(self, states: JointStates, y: FloatArray) -> None:
        n = states.n_joints
        X = self.gp_inputs(states)
        self.gp_ = self.new_gp(n)
        opt = dict(adam_iters=self.adam_iters, adam_lr=self.adam_lr, lbfgs_iters=self.lbfgs_iters)
        self.hyper_rows_ = None  # rows of the hyperparameter fit (None: all)
        if self.hyper_points is not None and X.shape[0] > self.hyper_points:
            rng = np.random.default_rng(self.seed)
            rows = np.sort(rng.choice(X.shape[0], self.hyper_points, replace=False))
            self.hyper_rows_ = rows
            self.gp_.fit(X[rows], y[rows], progress=self.progress, **opt)
            opt = dict(adam_iters=0, lbfgs_iters=0)  # condition on all rows, keep theta
        self.gp_.fit(X, y, max_points=self.max_points, progress=self.progress, **opt)

    def _predict(self, states: JointStates) -> tuple[FloatArray, FloatArray]:
        X = self.gp_inputs(states)
        means, variances = [], []
        for start in range(0, X.shape[0], self.predict_chunk):  # bounded (m, chunk, N) memory
            mean, var = self.gp_.predict(X[start : start + self.predict_chunk])
            means.append(mean.numpy())
            variances.append(var.numpy())
        return np.concatenate(means), np.concatenate(variances)

    @property
    def noise_variance_(self) -> FloatArray:
        """``(n,)`` fitted noise variance of each joint (units of ``y`` squared)."""
        if self.gp_ is None:
            raise RuntimeError("not fitted")
        return self.gp_.noise_variance.numpy()


class GIPEstimator(GPInverseDynamics):
    """GIP kernel estimator (thesis eq. 3.8 features, eq. 3.11 kernel).

    Args:
        joint_types: e.g. ``"RRPR"``; its length is ``n``.
        standardize_x: default ``False`` (module docstring); other keyword arguments as in
            :class:`GPInverseDynamics`.
    """

    name = "GIP"

    def __init__(self, joint_types: str, *, standardize_x: bool = False, **kwargs: Any) -> None:
        self.joint_types = check_joint_types(joint_types)
        super().__init__(len(self.joint_types), standardize_x=standardize_x, **kwargs)

    def gp_inputs(self, states: JointStates) -> FloatArray:
        t = [torch.as_tensor(a) for a in (states.q, states.qd, states.qdd)]
        return gip_features(*t, self.joint_types).numpy()

    def gp_input_names(self, n_joints: int) -> list[str]:
        return gip_feature_names(self.joint_types)

    def kernel(self, batch_shape: torch.Size, n_joints: int) -> gpytorch.kernels.Kernel:
        return GIPKernel(self.joint_types, batch_shape=batch_shape)


INDUCING_TOLERANCE = 1e-9
"""Eigenvalues of ``K_ZZ`` below this fraction of its largest are dropped from the Nystroem
features (the GIP kernel has finite rank; its null directions carry no function)."""


class NystromGIPEstimator(GIPEstimator):
    r"""The GIP estimator on every row: exact hyperparameters on a subset, then Bayesian
    linear regression over Nystroem features of the fitted kernel.

    1. The GIP GP's hyperparameters (thesis eq. 3.11) are fitted by marginal likelihood on
       ``hyper_points`` rows (seeded random subset; :class:`GIPEstimator`).
    2. ``M = inducing`` rows ``Z`` evenly spaced over the data give, per joint ``b``, the
       features :math:`\phi_b(x) = S^{-1/2} U^\top k_b(Z, x)` with
       :math:`k_b(Z, Z) = U S U^\top` (eigenvalues above :data:`INDUCING_TOLERANCE` times
       the largest), so that :math:`\phi_b(x)^\top \phi_b(x') = k_b(x, Z) k_b(Z, Z)^{+}
       k_b(Z, x')`: the fitted GIP kernel restricted to the span of ``Z``, exact once
       ``M`` reaches the kernel's finite rank.
    3. :class:`~mcpilco.models.gp.blr.BayesianLinearRegression` on **all** rows (standardised
       targets): the kernel's scale and the noise per joint by type-II ML, the posterior in
       weight space, ``O(N M^2)`` time and ``O(M^2)`` memory per joint.

    Args:
        joint_types: e.g. ``"RRPR"``.
        inducing: ``M``.
        hyper_points: rows of the exact hyperparameter fit (``None``: all, ``O(N^3)``).
        chunk: rows per feature chunk.
        **kwargs: as in :class:`GIPEstimator` (``max_points`` is not used).

    Fitted attributes: ``gp_`` (the exact GP of step 1, conditioned on its subset),
    ``blr_``, ``inducing_`` (``Z``), ``hyper_rows_``.
    """

    name = "GIP-Nystroem"

    def __init__(
        self,
        joint_types: str,
        *,
        inducing: int = 1500,
        hyper_points: int | None = 600,
        chunk: int = 4000,
        **kwargs: Any,
    ) -> None:
        if inducing < 1 or chunk < 1:
            raise ValueError(f"inducing and chunk must be >= 1, got {inducing}, {chunk}")
        self.inducing = int(inducing)
        self.chunk = int(chunk)
        super().__init__(joint_types, hyper_points=hyper_points, **kwargs)

    def _fit(self, states: JointStates, y: FloatArray) -> None:
        n = states.n_joints
        X = self.gp_inputs(states)
        N = X.shape[0]
        self.gp_ = self.new_gp(n)
        rows = np.arange(N)
        if self.hyper_points is not None and N > self.hyper_points:
            rng = np.random.default_rng(self.seed)
            rows = np.sort(rng.choice(N, self.hyper_points, replace=False))
        self.hyper_rows_ = rows
        self.gp_.fit(
            X[rows],
            y[rows],
            adam_iters=self.adam_iters,
            adam_lr=self.adam_lr,
            lbfgs_iters=self.lbfgs_iters,
            progress=self.progress,
        )
        pick = np.unique(np.round(np.linspace(0, N - 1, min(self.inducing, N))).astype(int))
        self.inducing_ = X[pick]
        Kzz = self.gp_.prior_covariance(self.inducing_, self.inducing_).numpy()
        self._whiten = []
        for b in range(n):
            S, U = np.linalg.eigh(0.5 * (Kzz[b] + Kzz[b].T))
            keep = S > INDUCING_TOLERANCE * max(float(S[-1]), 1e-300)
            W = np.zeros_like(U)
            W[:, keep] = U[:, keep] / np.sqrt(S[keep])
            self._whiten.append(W)
        self._regress(X, y)

    def _regress(self, X: FloatArray, y: FloatArray) -> None:
        """Step 3 (class docstring) on GP input rows ``X``, and the weights in kernel
        space, ``beta_b = W_b w_b``, so that the mean is ``k_b(x, Z) beta_b`` (``O(M)`` per
        row and joint instead of the features' ``O(M^2)``)."""
        from mcpilco.models.gp.blr import BayesianLinearRegression

        ym = self.gp_.y_mean_.numpy()
        ys = self.gp_.y_scale_.numpy()
        self.blr_ = BayesianLinearRegression(self.inducing_.shape[0], len(self._whiten))
        for a in range(0, X.shape[0], self.chunk):
            self.blr_.add(self._features(X[a : a + self.chunk]), (y[a : a + self.chunk] - ym) / ys)
        self.blr_.fit(noise_min=self.noise_min)
        self._beta = np.stack(
            [W @ w for W, w in zip(self._whiten, self.blr_.weights_, strict=True)]
        )

    def refit_targets(self, states: Any, y: FloatArray) -> None:
        """The regression (step 3) refitted on new targets ``y`` at the same kernel
        hyperparameters and inducing rows (a learned start backfitted on the output minus
        fitted effects)."""
        if self.gp_ is None:
            raise RuntimeError("not fitted")
        states = as_joint_states(states, self.n_joints_)
        self._regress(self.gp_inputs(states), np.asarray(y, dtype=np.float64))

    def _features(self, X: FloatArray) -> FloatArray:
        """``(n, N, M)`` Nystroem features of GP input rows ``X``."""
        K = self.gp_.prior_covariance(self.inducing_, X).numpy()
        return np.stack([K[b].T @ W for b, W in enumerate(self._whiten)])

    def _predict(self, states: JointStates) -> tuple[FloatArray, FloatArray]:
        X = self.gp_inputs(states)
        ym = self.gp_.y_mean_.numpy()
        ys = self.gp_.y_scale_.numpy()
        means, variances = [], []
        for a in range(0, X.shape[0], self.chunk):
            mean, var = self.blr_.predict(self._features(X[a : a + self.chunk]), with_var=True)
            means.append(mean * ys + ym)
            variances.append(var * ys**2)
        return np.concatenate(means), np.concatenate(variances)

    def predict_mean(self, X: Any) -> FloatArray:
        """``(N, n)`` posterior mean only at ``X`` (as in :meth:`predict`), ``O(M)`` per row
        and joint (no variance products)."""
        if self.gp_ is None:
            raise RuntimeError(f"{type(self).__name__} is not fitted; call fit(X, y) first")
        X = self.gp_inputs(as_joint_states(X, self.n_joints_))
        ym = self.gp_.y_mean_.numpy()
        ys = self.gp_.y_scale_.numpy()
        out = []
        for a in range(0, X.shape[0], self.chunk):
            K = self.gp_.prior_covariance(self.inducing_, X[a : a + self.chunk]).numpy()
            out.append(np.einsum("bmn,bm->nb", K, self._beta) * ys + ym)
        return np.concatenate(out)

    @property
    def noise_variance_(self) -> FloatArray:
        """``(n,)`` noise variance of each joint fitted on all rows (units of ``y`` squared)."""
        return self.blr_.noise_variance * self.gp_.y_scale_.numpy() ** 2


class GIPFrictionEstimator(GIPEstimator):
    r"""GIP plus joint friction (beyond thesis ch. 3; the friction features of ch. 4, eq. 4.7).

    .. math::

        k_b(\mathbf x, \mathbf x') = k_{GIP}(\bar{\mathbf x}, \bar{\mathbf x}')
        + \boldsymbol\phi_b^T \Sigma_b\, \boldsymbol\phi_b', \qquad
        \boldsymbol\phi_b = [\dot q_b,\ \operatorname{sign}_\epsilon(\dot q_b)],

    i.e. the GIP's rigid-body function space plus a viscous and a Coulomb coefficient of the
    joint's own friction with a Gaussian prior; ``sign_eps(v) = tanh(v / eps)`` when
    ``coulomb_velocity = eps > 0``, the sign otherwise (as :class:`PPEstimator`). Motor
    currents of a real arm carry this friction, which no polynomial in ``qd`` represents.

    Args:
        joint_types: e.g. ``"RRPR"``.
        coulomb_velocity: ``eps`` [rad/s or m/s] (0: the sign).
        **kwargs: as in :class:`GIPEstimator`.
    """

    name = "GIP+F"

    def __init__(self, joint_types: str, *, coulomb_velocity: float = 0.0, **kwargs: Any) -> None:
        if coulomb_velocity < 0:
            raise ValueError(f"coulomb_velocity must be >= 0, got {coulomb_velocity}")
        self.coulomb_velocity = float(coulomb_velocity)
        super().__init__(joint_types, **kwargs)

    def friction_features(self, qd: FloatArray) -> FloatArray:
        """``(N, 2n)`` rows ``[qd_1, sign(qd_1), ..., qd_n, sign(qd_n)]``."""
        eps = self.coulomb_velocity
        sign = np.tanh(qd / eps) if eps > 0 else np.sign(qd)
        return np.stack([qd, sign], axis=-1).reshape(qd.shape[0], -1)

    def gp_inputs(self, states: JointStates) -> FloatArray:
        return np.concatenate([super().gp_inputs(states), self.friction_features(states.qd)], 1)

    def gp_input_names(self, n_joints: int) -> list[str]:
        fr = [f"{f}(qd{j})" for j in range(1, n_joints + 1) for f in ("", "sign")]
        return super().gp_input_names(n_joints) + fr

    def kernel(self, batch_shape: torch.Size, n_joints: int) -> gpytorch.kernels.Kernel:
        gamma = len(super().gp_input_names(n_joints))
        gip = GIPKernel(self.joint_types, batch_shape=batch_shape, active_dims=tuple(range(gamma)))
        friction = RowLinearKernel(
            n_joints,
            2,
            batch_shape=batch_shape,
            active_dims=tuple(range(gamma, gamma + 2 * n_joints)),
        )
        return gip + friction


class RBFEstimator(GPInverseDynamics):
    """RBF (squared-exponential, ARD) estimator on the raw ``[q, qd, qdd]``."""

    name = "RBF"

    def gp_inputs(self, states: JointStates) -> FloatArray:
        return states.stacked()

    def gp_input_names(self, n_joints: int) -> list[str]:
        return input_names(n_joints)

    def kernel(self, batch_shape: torch.Size, n_joints: int) -> gpytorch.kernels.Kernel:
        return rbf_kernel(3 * n_joints, batch_shape)


class PPEstimator(GPInverseDynamics):
    """Parametric-prior GP (thesis eq. 3.6): linear kernel on the nominal regressor rows.

    Args:
        model: nominal robot (``pinocchio.Model`` or MJCF/URDF path/text).
        blocks: feature blocks of :class:`RigidBodyFeatures` (add ``"viscous"``,
            ``"coulomb"`` for friction).
        coulomb_velocity: smoothing of ``sign(qd)`` (:class:`RigidBodyFeatures`).
        **kwargs: as in :class:`GPInverseDynamics`.

    Attributes:
        features: the :class:`RigidBodyFeatures` (GP input ``features.flat_features``).
    """

    name = "PP"

    def __init__(
        self,
        model: Any,
        blocks: Sequence[str] = ("rigid", "armature"),
        coulomb_velocity: float = 0.0,
        **kwargs: Any,
    ) -> None:
        self.features = RigidBodyFeatures(model, blocks, coulomb_velocity)
        super().__init__(self.features.n_joints, **kwargs)

    def gp_inputs(self, states: JointStates) -> FloatArray:
        return self.features.flat_features(states)

    def kernel(self, batch_shape: torch.Size, n_joints: int) -> gpytorch.kernels.Kernel:
        return RowLinearKernel(n_joints, self.features.n_features, batch_shape=batch_shape)


class SPEstimator(PPEstimator):
    """Semi-parametric GP (thesis eq. 3.7): PP kernel plus an RBF kernel on ``[q, qd, qdd]``.

    Args:
        model, blocks, coulomb_velocity: as in :class:`PPEstimator`.
        rbf_outputscale_init: initial RBF output scale (standardised units): small, so the
            optimisation starts from the parametric model.
        **kwargs: as in :class:`GPInverseDynamics`.
    """

    name = "SP"

    def __init__(
        self,
        model: Any,
        blocks: Sequence[str] = ("rigid", "armature"),
        coulomb_velocity: float = 0.0,
        rbf_outputscale_init: float = 0.1,
        **kwargs: Any,
    ) -> None:
        self.rbf_outputscale_init = rbf_outputscale_init
        super().__init__(model, blocks, coulomb_velocity, **kwargs)

    def gp_inputs(self, states: JointStates) -> FloatArray:
        return np.concatenate([states.stacked(), self.features.flat_features(states)], axis=1)

    def kernel(self, batch_shape: torch.Size, n_joints: int) -> gpytorch.kernels.Kernel:
        raw = 3 * n_joints
        p = self.features.n_features
        pp = RowLinearKernel(
            n_joints, p, batch_shape=batch_shape, active_dims=tuple(range(raw, raw + n_joints * p))
        )
        rbf = rbf_kernel(raw, batch_shape, active_dims=range(raw))
        rbf.outputscale = self.rbf_outputscale_init
        return pp + rbf

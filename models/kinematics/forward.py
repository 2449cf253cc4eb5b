"""Forward kinematics GP with polynomial kernels and a gradient kinematic controller (thesis 2.5).

Glossary (thesis section 2.5; ``N_r`` revolute and ``N_p`` prismatic joints, in chain order)
-----------------------------------------------------------------------------------------
``x = [q_c, q_s, q_p]`` (eq. 2.21)
    ``q_c = cos q_r``, ``q_s = sin q_r`` over the revolute joints, ``q_p`` the prismatic
    joints: :func:`fk_features`.
``k_R(x, x') = prod_b [1, q_cb, q_sb] Sigma_Rb [1, q_cb', q_sb']^T`` (eq. 2.22)
    a product of :class:`~mcpilco.models.kernels.LinearKernel` s, one per revolute joint,
    acting on the columns ``(b, N_r + b)``; the "1" is the linear kernel's offset
    ``sigma^2``. Its RKHS holds the polynomials of Prop. 2.5.1 (i): degree <= 1 in each
    ``(cos q_b, sin q_b)`` pair. Models ``R(1,1), R(2,1), R(3,1), R(3,2), R(3,3)``.
``k_l(x, x') = k_R(x, x') [1, q_p] Sigma_l [1, q_p']^T`` (eq. 2.23)
    one more linear kernel on the prismatic columns (Prop. 2.5.1 (ii)). Models ``x, y, z``.
    Without prismatic joints ``k_l = k_R``; without revolute joints ``k_R`` is the linear
    kernel on ``q_p`` (a superset of the constant rotation).
orientation (eq. 2.20)
    ``gamma = atan2(R21, R11)``, ``beta = atan2(-R31, sqrt(R32^2 + R33^2))``,
    ``alpha = atan2(R32, R33)`` from the five GP means (``R = Rz(gamma) Ry(beta) Rx(alpha)``).
    Near ``beta = +-pi/2`` the five elements barely depend on the remaining degree of freedom
    (``gamma - alpha`` or ``gamma + alpha``): ``R11, R21, R32, R33 -> 0`` and atan2 of their
    errors is arbitrary, so the rotation itself (not only the angles) is lost there.
``rotation_outputs="nine"`` (beyond the thesis, an option)
    one GP with the same ``k_R`` per element of ``R`` (all nine); the mean matrix ``M`` is
    projected onto SO(3) (the nearest rotation, :func:`~mcpilco.models.kinematics.rotations.
    nearest_rotation_torch`) and eq. 2.20 is applied to the projection.
controller (eq. 2.24)
    ``q_des(t + delta) = q_des(t) - nu grad_q e_p``, ``e_p = ||p* - p_hat(q)||`` with
    ``p = [l, w_o o]``: the pose error stacks the position error [m] and the 2 pi-wrapped
    yaw-pitch-roll error [rad] weighted by ``w_o`` [m/rad] (default 0.1: 0.1 rad of
    orientation error costs as much as 1 cm). The gradient is autograd through the GPs'
    cached predictors.
multi-start (beyond the thesis, which names local minima of ``e_p`` and model errors away
    from the data as the controller's limits)
    :func:`multi_start_controller` runs eq. 2.24 from ``q(0)`` and from the training
    configurations whose measured poses are nearest to ``p*`` (:func:`nearest_data_starts`)
    and keeps the reference with the smallest predicted ``e_p``; ``q_limits`` set to the
    joint box of the data keeps ``q_des`` where the GP has seen data.

training design (beyond the thesis, which draws its 100 training samples at random)
    :func:`design_subset` picks the ``k`` training configurations of a trajectory greedily by
    the prior of ``k_l`` (all ``sigma^2 = 1``, ``Sigma = I``, no noise): each pick is the
    configuration the samples chosen so far predict worst, relative to its prior variance
    (greedy D-optimal design of the ``3^{N_r}`` monomials, each configuration's monomial
    vector scaled to unit length). It uses ``q`` alone, never the measured poses.

Each output is one independent GP (``mcpilco.models.gp.GPRegressor``, hyperparameters by
marginal likelihood); only the joint types are known, no kinematic parameter.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray
from torch import Tensor, nn

from mcpilco.models.gp import GPRegressor, KernelFactory, greedy_subset
from mcpilco.models.kernels import LinearKernel
from mcpilco.models.kinematics.rotations import (
    elements_to_ypr_torch,
    nearest_rotation_torch,
    ypr_to_matrix,
    ypr_to_matrix_torch,
)

__all__ = [
    "ControllerResult",
    "FKPredictor",
    "ForwardKinematicsGP",
    "design_subset",
    "fk_features",
    "gradient_kinematic_controller",
    "multi_start_controller",
    "nearest_data_starts",
    "pose_error",
    "position_kernel_factory",
    "rotation_kernel_factory",
    "rotation_elements",
]

FloatArray = NDArray[np.float64]
ROTATION_OUTPUTS = ("R11", "R21", "R31", "R32", "R33")
ALL_ROTATION_OUTPUTS = ("R11", "R12", "R13", "R21", "R22", "R23", "R31", "R32", "R33")
ROTATION_CHOICES = ("five", "nine")
POSITION_OUTPUTS = ("x", "y", "z")


def joint_type_indices(joint_types: str) -> tuple[list[int], list[int]]:
    """The indices of the revolute and of the prismatic joints of ``joint_types`` (a string of
    ``R`` / ``P``); a ``ValueError`` for anything else."""
    if not isinstance(joint_types, str) or not joint_types or set(joint_types) - {"R", "P"}:
        raise ValueError(f"joint_types must be a non-empty string of 'R'/'P', got {joint_types!r}")
    rev = [i for i, c in enumerate(joint_types) if c == "R"]
    pri = [i for i, c in enumerate(joint_types) if c == "P"]
    return rev, pri


def check_joint_positions(q: ArrayLike, joint_types: str) -> FloatArray:
    """``q`` as a float64 ``(N, n)`` array, ``n = len(joint_types)``, all finite (else a
    ``ValueError`` that says what is wrong)."""
    q = np.asarray(q, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != len(joint_types):
        raise ValueError(
            f"q must have shape (N, {len(joint_types)}) for joint_types {joint_types!r}, "
            f"got {q.shape}"
        )
    if not np.isfinite(q).all():
        raise ValueError("q contains NaN or inf; drop those samples before fitting/predicting")
    return q


def fk_features(q: ArrayLike | Tensor, joint_types: str) -> Tensor:
    """``x = [cos q_r, sin q_r, q_p]`` of eq. 2.21; ``q`` ``(..., n)`` -> ``(..., 2 N_r + N_p)``.

    Differentiable (torch in, torch out); numpy input gives a float64 tensor.
    """
    rev, pri = joint_type_indices(joint_types)
    q = q if isinstance(q, Tensor) else torch.as_tensor(np.asarray(q), dtype=torch.float64)
    if q.shape[-1] != len(joint_types):
        raise ValueError(
            f"q must have {len(joint_types)} columns (joint_types {joint_types!r}), got "
            f"{tuple(q.shape)}"
        )
    qr, qp = q[..., rev], q[..., pri]
    return torch.cat([torch.cos(qr), torch.sin(qr), qp], dim=-1)


def rotation_kernel_factory(joint_types: str) -> KernelFactory:
    """Factory of ``k_R`` (eq. 2.22) on the features of :func:`fk_features`."""
    rev, pri = joint_type_indices(joint_types)
    n_r, n_p = len(rev), len(pri)

    def factory(batch_shape: torch.Size) -> LinearKernel:
        if n_r == 0:
            return LinearKernel(n_p, batch_shape=batch_shape, active_dims=tuple(range(n_p)))
        kernel = None
        for b in range(n_r):
            k = LinearKernel(2, batch_shape=batch_shape, active_dims=(b, n_r + b))
            kernel = k if kernel is None else kernel * k
        return kernel

    return factory


def position_kernel_factory(joint_types: str) -> KernelFactory:
    """Factory of ``k_l = k_R [1, q_p]^T Sigma_l [1, q_p]`` (eq. 2.23)."""
    rev, pri = joint_type_indices(joint_types)
    n_r, n_p = len(rev), len(pri)
    k_r = rotation_kernel_factory(joint_types)

    def factory(batch_shape: torch.Size):
        kernel = k_r(batch_shape)
        if n_p == 0 or n_r == 0:
            return kernel
        cols = tuple(range(2 * n_r, 2 * n_r + n_p))
        return kernel * LinearKernel(n_p, batch_shape=batch_shape, active_dims=cols)

    return factory


def design_subset(q: ArrayLike, joint_types: str, k: int) -> NDArray[np.int64]:
    r"""Indices of ``k`` rows of ``q`` to train the FK GP on, picked greedily by prior variance.

    With :math:`S` the rows chosen so far and :math:`x = \phi(q)` the features of
    :func:`fk_features`, the next row is

    .. math::
        i^\star = \arg\max_{i \notin S}\; \frac{k_l(x_i, x_i)
            - k_l(x_i, X_S) K_{l,SS}^{-1} k_l(X_S, x_i)}{k_l(x_i, x_i)},

    the prior of eq. 2.23 with unit hyperparameters (``sigma^2 = 1``, ``Sigma_b = I``) and
    no noise: :func:`~mcpilco.models.gp.greedy_subset`. Each pick multiplies
    ``det(Phi_S Phi_S^T)`` the most, ``Phi`` the monomials of Prop. 2.5.1 (rows scaled to unit
    length; for revolute joints alone the prior variance ``2^{N_r}`` is the same everywhere).
    The picks spread over those monomials, where random draws can fall close together by
    chance. Only ``q`` is used.

    Args:
        q: ``(N, n)`` joint positions in chain order (finite).
        joint_types: e.g. ``"RRRRRR"``.
        k: number of rows, ``1 <= k <= N``.

    Returns:
        ``(k,)`` int64 row indices in selection order, no duplicates.
    """
    joint_type_indices(joint_types)
    q = np.asarray(q, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != len(joint_types) or len(q) == 0:
        raise ValueError(
            f"q must have shape (N >= 1, {len(joint_types)}) for joint_types {joint_types!r}, "
            f"got {q.shape}"
        )
    if not np.isfinite(q).all():
        bad = sorted({int(c) for c in np.nonzero(~np.isfinite(q))[1]})
        raise ValueError(f"q contains NaN or inf in columns {bad}; drop those rows first")
    if not 1 <= k <= len(q):
        raise ValueError(f"k must be in [1, {len(q)}], got {k}")
    kernel = position_kernel_factory(joint_types)(torch.Size([]))
    idx = greedy_subset(fk_features(q, joint_types), kernel, k, noise_variance=0.0)
    return idx.numpy().astype(np.int64)


def rotation_elements(poses: ArrayLike, which: str = "five") -> FloatArray:
    """Rotation elements of poses ``[x, y, z, gamma, beta, alpha]`` ``(N, 6)``.

    ``which="five"``: ``[R11, R21, R31, R32, R33]`` ``(N, 5)`` (thesis 2.5.3); ``"nine"``:
    all of ``R`` row-major ``(N, 9)``.
    """
    if which not in ROTATION_CHOICES:
        raise ValueError(f"which must be one of {ROTATION_CHOICES}, got {which!r}")
    R = ypr_to_matrix(np.asarray(poses, dtype=np.float64)[..., 3:])
    if which == "nine":
        return R.reshape(*R.shape[:-2], 9)
    return np.stack([R[..., 0, 0], R[..., 1, 0], R[..., 2, 0], R[..., 2, 1], R[..., 2, 2]], -1)


class _MaskedOutputs(nn.Module):
    """GP outputs scattered among constant ones: ``(..., d) -> (..., m)`` means.

    Outputs that are constant in the training data (e.g. ``R31`` of a planar arm whose plane
    faces the camera) cannot be learned by a GP (:class:`GPRegressor` rejects them): they are
    stored as constants and predicted as such.
    """

    def __init__(self, predictor: nn.Module | None, varying: Tensor, constants: Tensor) -> None:
        super().__init__()
        self.predictor = predictor
        self.register_buffer("varying", varying)
        self.register_buffer("constants", constants)

    def forward(self, x: Tensor) -> Tensor:
        out = self.constants.to(x.dtype).expand(*x.shape[:-1], -1)
        if self.predictor is None:
            return out
        mean, _ = self.predictor(x)
        out = out.clone()
        out[..., self.varying] = mean.to(x.dtype)
        return out


def _split_constant(Y: FloatArray, tol: float = 1e-10) -> tuple[NDArray[np.bool_], FloatArray]:
    """Mask of the varying columns of ``Y`` and the column means (used for constant ones)."""
    varying = Y.std(0) > tol * (1.0 + np.abs(Y).max(0))
    return varying, Y.mean(0)


class FKPredictor(nn.Module):
    """Differentiable ``q -> (l_hat, o_hat)`` from the two GPs' cached predictors.

    Call: ``position, ypr = pred(q)`` with ``q`` ``(..., n)`` -> ``(..., 3)`` each.
    ``rotation`` gives the five elements of eq. 2.20 (``rotation_outputs="five"``) or all
    nine, which are projected onto SO(3) first (``"nine"``).
    """

    def __init__(
        self,
        joint_types: str,
        rotation: nn.Module,
        position: nn.Module,
        rotation_outputs: str = "five",
    ) -> None:
        super().__init__()
        if rotation_outputs not in ROTATION_CHOICES:
            raise ValueError(
                f"rotation_outputs must be one of {ROTATION_CHOICES}, got {rotation_outputs!r}"
            )
        self.joint_types = joint_types
        self.rotation = rotation
        self.position = position
        self.rotation_outputs = rotation_outputs

    def forward(self, q: Tensor) -> tuple[Tensor, Tensor]:
        x = fk_features(q, self.joint_types)
        elements = self.rotation(x)
        if self.rotation_outputs == "nine":
            elements = five_elements(
                nearest_rotation_torch(elements.reshape(*elements.shape[:-1], 3, 3))
            )
        return self.position(x), elements_to_ypr_torch(elements)


def five_elements(R: Tensor) -> Tensor:
    """``[R11, R21, R31, R32, R33]`` ``(..., 5)`` of rotations ``(..., 3, 3)`` (the elements
    eq. 2.20 reads)."""
    return torch.stack([R[..., 0, 0], R[..., 1, 0], R[..., 2, 0], R[..., 2, 1], R[..., 2, 2]], -1)


class ForwardKinematicsGP:
    """GP model of the forward kinematics ``q -> p^c_M`` knowing only the joint types (2.5.3).

    Args:
        joint_types: joint types along the chain, e.g. ``"RRRRRR"`` (``S_Q`` of the structure
            identification; ``q`` columns must follow the same order, ``S_q``).
        noise_init: initial noise variance (standardised units).
        noise_min: lower bound of the noise variance (standardised units).
        standardize_x: standardise the features (off by default: ``cos q``, ``sin q`` are
            already in ``[-1, 1]``, and the prior of eq. 2.22 is then the thesis's).
        rotation_outputs: ``"five"`` (the thesis: ``R11, R21, R31, R32, R33``, then eq. 2.20)
            or ``"nine"`` (all elements, mean projected onto SO(3), then eq. 2.20; better
            conditioned near ``beta = +-pi/2``, see the module glossary).

    Fitted attributes: ``rotation_gp_`` (the outputs among ``R11..R33`` that vary in the
    data, kernel ``k_R``), ``position_gp_`` (those among ``x, y, z``, kernel ``k_l``);
    ``rotation_varying_`` / ``position_varying_`` masks and ``rotation_constants_`` /
    ``position_constants_`` (outputs constant in the training data are predicted constant).
    """

    def __init__(
        self,
        joint_types: str,
        *,
        noise_init: float = 1e-3,
        noise_min: float = 1e-8,
        standardize_x: bool = False,
        rotation_outputs: str = "five",
    ) -> None:
        joint_type_indices(joint_types)
        if rotation_outputs not in ROTATION_CHOICES:
            raise ValueError(
                f"rotation_outputs must be one of {ROTATION_CHOICES}, got {rotation_outputs!r}"
            )
        self.rotation_outputs = rotation_outputs
        self.joint_types = joint_types
        self.standardize_x = standardize_x
        self.noise_init = noise_init
        self.noise_min = noise_min
        self.rotation_gp_: GPRegressor | None = None
        self.position_gp_: GPRegressor | None = None
        self.outliers_ = np.empty(0, dtype=np.int64)
        self._fitted = False

    def _validate(self, q: ArrayLike, poses: ArrayLike | None = None) -> tuple[Tensor, FloatArray]:
        q = check_joint_positions(q, self.joint_types)
        if poses is None:
            return fk_features(q, self.joint_types), np.empty(0)
        poses = np.asarray(poses, dtype=np.float64)
        if poses.shape != (q.shape[0], 6):
            raise ValueError(
                f"poses must have shape ({q.shape[0]}, 6) with columns [x, y, z, gamma, beta, "
                f"alpha], got {poses.shape}"
            )
        if not np.isfinite(poses).all():
            raise ValueError("poses contain NaN or inf; drop those samples before fitting")
        return fk_features(q, self.joint_types), poses

    def fit(
        self,
        q: ArrayLike,
        poses: ArrayLike,
        *,
        adam_iters: int = 20,
        adam_lr: float = 0.05,
        lbfgs_iters: int = 50,
        progress: bool = False,
        outlier_threshold: float | None = None,
        outlier_rounds: int = 3,
    ) -> ForwardKinematicsGP:
        """Fit the 8 (12 with ``rotation_outputs="nine"``) GPs by marginal likelihood (a
        second call warm-starts).

        With ``outlier_threshold`` (e.g. 4), samples whose leave-one-out score
        :math:`z_i = \\max_b |y_{ib} - \\mu_{-i,b}| / \\sigma_{-i,b}` over the outputs ``b``
        (:meth:`GPRegressor.loo_residuals`) exceeds it are dropped and the GPs refitted,
        up to ``outlier_rounds`` times (gross marker-pose errors: a flipped orientation, a
        wrong depth). ``outliers_`` holds the dropped sample indices.

        Args:
            q: ``(N, n)`` joint positions in chain order.
            poses: ``(N, 6)`` end-marker poses ``[x, y, z, gamma, beta, alpha]`` (camera).
        """
        x, poses = self._validate(q, poses)
        if outlier_threshold is not None and not outlier_threshold > 0:
            raise ValueError(f"outlier_threshold must be > 0 or None, got {outlier_threshold}")
        kw = dict(adam_iters=adam_iters, adam_lr=adam_lr, lbfgs_iters=lbfgs_iters)
        keep = np.ones(len(poses), dtype=bool)
        for _ in range(1 + (outlier_rounds if outlier_threshold is not None else 0)):
            self._fit_gps(x[torch.from_numpy(keep)], poses[keep], progress, kw)
            if outlier_threshold is None:
                break
            bad = self.loo_scores() > outlier_threshold
            if not bad.any():
                break
            keep[np.flatnonzero(keep)[bad]] = False
            if keep.sum() < 3:
                raise ValueError(
                    f"outlier trimming left {int(keep.sum())} samples; raise outlier_threshold"
                )
        self.outliers_ = np.flatnonzero(~keep)
        self._fitted = True
        return self

    def loo_scores(self) -> FloatArray:
        """``(N,)`` largest leave-one-out score ``|residual| / std`` over all outputs of
        each training sample (of the last fit)."""
        scores = None
        for gp in (self.rotation_gp_, self.position_gp_):
            if gp is not None:
                res, std = gp.loo_residuals()
                z = (res / std).abs().amax(dim=1).numpy()
                scores = z if scores is None else np.maximum(scores, z)
        if scores is None:
            raise RuntimeError("no output varies in the data; nothing to score")
        return scores

    def _fit_gps(self, x: Tensor, poses: FloatArray, progress: bool, kw: dict[str, Any]) -> None:
        """One marginal-likelihood fit of the rotation and position GPs on ``(x, poses)``."""
        nine = self.rotation_outputs == "nine"
        for name, Y, factory, names in (
            (
                "rotation",
                rotation_elements(poses, self.rotation_outputs),
                rotation_kernel_factory,
                ALL_ROTATION_OUTPUTS if nine else ROTATION_OUTPUTS,
            ),
            ("position", poses[:, :3], position_kernel_factory, POSITION_OUTPUTS),
        ):
            varying, constants = _split_constant(Y)
            gp = getattr(self, f"{name}_gp_")
            old = getattr(self, f"{name}_varying_", None)
            if gp is None or old is None or not np.array_equal(old, varying):
                gp = None
                if varying.any():
                    gp = GPRegressor(
                        factory(self.joint_types),
                        output_names=[n for n, v in zip(names, varying, strict=True) if v],
                        noise_init=self.noise_init,
                        noise_min=self.noise_min,
                        standardize_x=self.standardize_x,
                    )
            if gp is not None:
                gp.fit(x, Y[:, varying], progress=progress, **kw)
            setattr(self, f"{name}_gp_", gp)
            setattr(self, f"{name}_varying_", varying)
            setattr(self, f"{name}_constants_", constants)

    def _check_fitted(self) -> None:
        if not self._fitted:
            raise RuntimeError("ForwardKinematicsGP is not fitted; call fit(q, poses) first")

    def predict(self, q: ArrayLike) -> FloatArray:
        """Posterior-mean poses ``(n, 6)`` ``[x, y, z, gamma, beta, alpha]`` (eq. 2.20)."""
        pred = self.predictor(torch.float64)
        x, _ = self._validate(q)
        with torch.no_grad():
            position, ypr = pred(x.new_tensor(np.asarray(q, dtype=np.float64)))
        return torch.cat([position, ypr], dim=-1).numpy()

    def _outputs(self, name: str, dtype: torch.dtype) -> _MaskedOutputs:
        gp = getattr(self, f"{name}_gp_")
        predictor = None if gp is None else gp.cached_predictor(dtype, validate=False)
        varying = torch.as_tensor(getattr(self, f"{name}_varying_"))
        constants = torch.as_tensor(getattr(self, f"{name}_constants_"), dtype=dtype)
        return _MaskedOutputs(predictor, varying, constants)

    def predictor(self, dtype: torch.dtype = torch.float64) -> FKPredictor:
        """Differentiable :class:`FKPredictor` over the cached GP predictors."""
        self._check_fitted()
        return FKPredictor(
            self.joint_types,
            self._outputs("rotation", dtype),
            self._outputs("position", dtype),
            self.rotation_outputs,
        )


# ----------------------------------------------------------------------------- controller


ORIENTATION_ERRORS = ("ypr", "chordal")


def pose_error(
    position: Tensor,
    ypr: Tensor,
    target: Tensor,
    orientation_weight: float = 0.1,
    orientation: str = "ypr",
) -> Tensor:
    """``e_p = sqrt(||l* - l||^2 + w_o^2 d_o^2)`` (the norm of eq. 2.24).

    ``orientation="ypr"`` (the thesis): ``d_o = ||wrap(o* - o)||`` on yaw-pitch-roll, which
    is ill-conditioned near ``beta = +-pi/2`` (gimbal lock: ``gamma`` and ``alpha`` are
    then undetermined) and jumps where an angle wraps. ``"chordal"`` (beyond the thesis):
    ``d_o = ||R(o*) - R(o)||_F / sqrt(2)``, smooth everywhere and equal to the rotation
    angle ``theta`` between the two orientations to first order
    (``||R* - R||_F = 2 sqrt(2) sin(theta / 2)``).
    """
    if orientation not in ORIENTATION_ERRORS:
        raise ValueError(f"orientation must be one of {ORIENTATION_ERRORS}, got {orientation!r}")
    d_l = target[..., :3] - position
    if orientation == "ypr":
        d_o = torch.remainder(target[..., 3:] - ypr + torch.pi, 2 * torch.pi) - torch.pi
        sq_o = d_o.pow(2).sum(-1)
    else:
        diff = ypr_to_matrix_torch(target[..., 3:]) - ypr_to_matrix_torch(ypr)
        sq_o = 0.5 * diff.pow(2).sum((-2, -1))
    sq = d_l.pow(2).sum(-1) + orientation_weight**2 * sq_o
    return torch.sqrt(sq + 1e-24)


@dataclass(frozen=True)
class ControllerResult:
    """``q_des`` trajectory ``(steps + 1, n)`` and the predicted errors ``e_p`` ``(steps + 1,)``."""

    q: FloatArray
    predicted_error: FloatArray

    @property
    def q_final(self) -> FloatArray:
        return self.q[-1]


def gradient_kinematic_controller(
    predictor: nn.Module,
    q0: ArrayLike,
    target_pose: ArrayLike,
    *,
    nu: float = 0.5,
    steps: int = 300,
    orientation_weight: float = 0.1,
    backtrack: bool = True,
    q_limits: Sequence[tuple[float, float]] | ArrayLike | None = None,
    orientation: str = "ypr",
) -> ControllerResult:
    """Open-loop reference ``q_des`` driving the predicted end pose to ``target_pose`` (eq. 2.24).

    Args:
        predictor: ``q -> (position, ypr)`` (e.g. :meth:`ForwardKinematicsGP.predictor`).
        q0: ``(n,)`` initial configuration.
        target_pose: ``(6,)`` ``[x, y, z, gamma, beta, alpha]``.
        nu: step size ``nu`` [rad (or m) per unit gradient].
        steps: number of updates ``delta``.
        orientation_weight: ``w_o`` [m/rad] of :func:`pose_error`.
        backtrack: halve the step whenever it would increase the predicted ``e_p`` (and stay
            put), double it back towards ``nu`` after a successful step (beyond the thesis,
            which uses a fixed ``nu``; it removes the chattering of a fixed step near the
            minimum and allows a large ``nu``). ``False`` is plain eq. 2.24.
        q_limits: ``(n, 2)`` joint limits; the reference is clipped to them.
        orientation: orientation error of :func:`pose_error` (``"ypr"``: the thesis).
    """
    q = torch.as_tensor(np.asarray(q0, dtype=np.float64)).clone()
    target = torch.as_tensor(np.asarray(target_pose, dtype=np.float64))
    if target.shape != (6,):
        raise ValueError(f"target_pose must have shape (6,), got {tuple(target.shape)}")
    lo = hi = None
    if q_limits is not None:
        lim = torch.as_tensor(np.asarray(q_limits, dtype=np.float64))
        lo, hi = lim[:, 0], lim[:, 1]

    def error_and_grad(qv: Tensor) -> tuple[float, Tensor]:
        qv = qv.detach().requires_grad_(True)
        pos, ypr = predictor(qv)
        e = pose_error(pos, ypr, target, orientation_weight, orientation)
        (g,) = torch.autograd.grad(e, qv)
        return float(e.detach()), g

    e, g = error_and_grad(q)
    qs, errors = [q.numpy().copy()], [e]
    step = nu
    for _ in range(steps):
        q_new = q - step * g
        if lo is not None:
            q_new = torch.minimum(torch.maximum(q_new, lo), hi)
        e_new, g_new = error_and_grad(q_new)
        if backtrack and e_new > e:
            step *= 0.5
            qs.append(q.numpy().copy())
            errors.append(e)
            continue
        q, e, g = q_new, e_new, g_new
        if backtrack:
            step = min(2.0 * step, nu)
        qs.append(q.numpy().copy())
        errors.append(e)
    return ControllerResult(q=np.array(qs), predicted_error=np.array(errors))


def nearest_data_starts(
    q_data: ArrayLike,
    poses_data: ArrayLike,
    target_pose: ArrayLike,
    k: int,
    orientation_weight: float = 0.1,
    orientation: str = "ypr",
) -> FloatArray:
    """The ``k`` data configurations whose measured poses minimise ``e_p`` to ``target_pose``.

    Args:
        q_data: ``(N, n)`` joint positions of the data (the GP's training inputs).
        poses_data: ``(N, 6)`` measured poses ``[x, y, z, gamma, beta, alpha]``.
        target_pose: ``(6,)`` ``p*``.
        k: number of configurations (``min(k, N)`` are returned), nearest first.
        orientation_weight: ``w_o`` of :func:`pose_error`.
        orientation: orientation error of :func:`pose_error`.

    Returns:
        ``(min(k, N), n)`` joint configurations.
    """
    q_data = np.asarray(q_data, dtype=np.float64)
    poses_data = np.asarray(poses_data, dtype=np.float64)
    if q_data.ndim != 2 or poses_data.shape != (q_data.shape[0], 6):
        raise ValueError(
            f"need q_data (N, n) and poses_data (N, 6), got {q_data.shape} and {poses_data.shape}"
        )
    if not isinstance(k, int | np.integer) or k < 1:
        raise ValueError(f"k must be a positive int, got {k!r}")
    poses = torch.as_tensor(poses_data)
    target = torch.as_tensor(np.asarray(target_pose, dtype=np.float64))
    e = pose_error(poses[:, :3], poses[:, 3:], target, orientation_weight, orientation)
    order = np.argsort(e.numpy(), kind="stable")[:k]
    return q_data[order]


def multi_start_controller(
    predictor: nn.Module,
    q_starts: ArrayLike,
    target_pose: ArrayLike,
    **controller_kwargs,
) -> tuple[ControllerResult, int]:
    """Eq. 2.24 from each row of ``q_starts``; the result with the smallest final ``e_p``.

    Args:
        predictor: ``q -> (position, ypr)``.
        q_starts: ``(S, n)`` initial configurations (row 0 is typically the robot's
            ``q(0)``; the others e.g. from :func:`nearest_data_starts`).
        target_pose: ``(6,)`` ``p*``.
        **controller_kwargs: passed to :func:`gradient_kinematic_controller`.

    Returns:
        ``(result, s)``: the best :class:`ControllerResult` and the index of its start (ties
        go to the earlier start). The robot reaches ``q_starts[s]`` first, then tracks
        ``result.q``.
    """
    q_starts = np.atleast_2d(np.asarray(q_starts, dtype=np.float64))
    if q_starts.ndim != 2 or q_starts.shape[0] == 0:
        raise ValueError(f"q_starts must have shape (S, n) with S >= 1, got {q_starts.shape}")
    results = [
        gradient_kinematic_controller(predictor, q0, target_pose, **controller_kwargs)
        for q0 in q_starts
    ]
    best = int(np.argmin([r.predicted_error[-1] for r in results]))
    return results[best], best

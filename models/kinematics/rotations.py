"""Yaw-pitch-roll angles, rotation matrices and relative marker poses (thesis section 2.2).

Conventions (used by the whole :mod:`mcpilco.models.kinematics` package)
----------------------------------------------------------------------
* A pose is ``p = [x, y, z, gamma, beta, alpha]``: the position ``l`` [m] followed by the
  yaw-pitch-roll angles ``o = [gamma, beta, alpha]`` [rad] with

  .. math:: R = R_z(\\gamma) R_y(\\beta) R_x(\\alpha).

* The inverse map (thesis eq. 2.20, written here with the roles of ``gamma`` and ``alpha`` as
  in the definition of ``R`` above; the printed eq. 2.20 swaps their names):

  .. math::
      \\gamma = \\operatorname{atan2}(R_{21}, R_{11}),\\quad
      \\beta = \\operatorname{atan2}\\big(-R_{31}, \\sqrt{R_{32}^2 + R_{33}^2}\\big),\\quad
      \\alpha = \\operatorname{atan2}(R_{32}, R_{33}),

  so ``gamma, alpha`` lie in ``(-pi, pi]`` and ``beta`` in ``[-pi/2, pi/2]``.
* Relative pose of marker ``b`` seen from marker ``a`` (section 2.3.1):
  ``l^a_b = (R^c_a)^T (l^c_b - l^c_a)`` and ``R^a_b = (R^c_a)^T R^c_b``.

Everything is vectorised over leading dimensions and written with numpy (the structure tests)
or torch (:func:`matrix_to_ypr_torch`, differentiable, for the forward-kinematics GP).
"""

from __future__ import annotations

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "elements_to_ypr_torch",
    "matrix_to_ypr",
    "nearest_rotation",
    "nearest_rotation_torch",
    "relative_poses",
    "rot_x",
    "rot_y",
    "rot_z",
    "wrap_angle",
    "ypr_to_matrix",
    "ypr_to_matrix_torch",
]

FloatArray = NDArray[np.float64]


def wrap_angle(angle: ArrayLike) -> FloatArray:
    """Wrap angles to ``[-pi, pi)``: ``mod(angle + pi, 2 pi) - pi`` (thesis eq. 2.19)."""
    return np.mod(np.asarray(angle, dtype=np.float64) + np.pi, 2.0 * np.pi) - np.pi


def rot_x(angle: ArrayLike) -> FloatArray:
    """Elementary rotations ``Rx(angle)``, shape ``(*angle.shape, 3, 3)``."""
    a = np.asarray(angle, dtype=np.float64)
    c, s, o, z = np.cos(a), np.sin(a), np.ones_like(a), np.zeros_like(a)
    return np.stack([o, z, z, z, c, -s, z, s, c], axis=-1).reshape(*a.shape, 3, 3)


def rot_y(angle: ArrayLike) -> FloatArray:
    """Elementary rotations ``Ry(angle)``, shape ``(*angle.shape, 3, 3)``."""
    a = np.asarray(angle, dtype=np.float64)
    c, s, o, z = np.cos(a), np.sin(a), np.ones_like(a), np.zeros_like(a)
    return np.stack([c, z, s, z, o, z, -s, z, c], axis=-1).reshape(*a.shape, 3, 3)


def rot_z(angle: ArrayLike) -> FloatArray:
    """Elementary rotations ``Rz(angle)``, shape ``(*angle.shape, 3, 3)``."""
    a = np.asarray(angle, dtype=np.float64)
    c, s, o, z = np.cos(a), np.sin(a), np.ones_like(a), np.zeros_like(a)
    return np.stack([c, -s, z, s, c, z, z, z, o], axis=-1).reshape(*a.shape, 3, 3)


def ypr_to_matrix(o: ArrayLike) -> FloatArray:
    """``R = Rz(gamma) Ry(beta) Rx(alpha)`` from ``o = [gamma, beta, alpha]`` ``(..., 3)``."""
    o = np.asarray(o, dtype=np.float64)
    if o.shape[-1:] != (3,):
        raise ValueError(f"yaw-pitch-roll angles need a last axis of size 3, got {o.shape}")
    # the product Rz Ry Rx written out (one stack, no matmuls: used inside least squares)
    R = np.stack(_rz_ry_rx_entries(np.cos(o), np.sin(o)), axis=-1)
    return R.reshape(*o.shape[:-1], 3, 3)


def _rz_ry_rx_entries(c, s) -> list:
    """The 9 entries (row-major) of ``Rz(gamma) Ry(beta) Rx(alpha)`` from ``c = cos(o)``,
    ``s = sin(o)`` with ``o = [gamma, beta, alpha]`` on the last axis (numpy or torch)."""
    cg, cb, ca = (c[..., i] for i in range(3))
    sg, sb, sa = (s[..., i] for i in range(3))
    return [
        cg * cb, cg * sb * sa - sg * ca, cg * sb * ca + sg * sa,
        sg * cb, sg * sb * sa + cg * ca, sg * sb * ca - cg * sa,
        -sb, cb * sa, cb * ca,
    ]  # fmt: skip


def matrix_to_ypr(R: ArrayLike) -> FloatArray:
    """``o = [gamma, beta, alpha]`` of rotation matrices ``(..., 3, 3)`` (eq. 2.20, see above)."""
    R = np.asarray(R, dtype=np.float64)
    if R.shape[-2:] != (3, 3):
        raise ValueError(f"rotation matrices need trailing shape (3, 3), got {R.shape}")
    gamma = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    beta = np.arctan2(-R[..., 2, 0], np.hypot(R[..., 2, 1], R[..., 2, 2]))
    alpha = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    return np.stack([gamma, beta, alpha], axis=-1)


def elements_to_ypr_torch(elements: torch.Tensor) -> torch.Tensor:
    """Eq. 2.20 in torch from the five learned elements ``[R11, R21, R31, R32, R33]``.

    Differentiable; ``elements`` ``(..., 5)`` -> ``(..., 3)`` ``[gamma, beta, alpha]``. The
    elements need not form an exact rotation (GP estimates); atan2 normalises the scale.
    """
    r11, r21, r31, r32, r33 = elements.unbind(-1)
    gamma = torch.atan2(r21, r11)
    beta = torch.atan2(-r31, torch.sqrt(r32**2 + r33**2 + 1e-18))
    alpha = torch.atan2(r32, r33)
    return torch.stack([gamma, beta, alpha], dim=-1)


def nearest_rotation(M: ArrayLike) -> FloatArray:
    """The rotation closest to ``M`` ``(..., 3, 3)`` in the Frobenius norm (SVD).

    .. math:: \\hat R = U \\operatorname{diag}(1, 1, \\det(U V^T)) V^T, \\qquad M = U S V^T,

    the solution of ``min_{R in SO(3)} ||R - M||_F`` (orthogonal Procrustes); for
    ``det M > 0`` it is the orthogonal polar factor of ``M``. Used to turn nine independently
    estimated rotation elements into a rotation.
    """
    M = np.asarray(M, dtype=np.float64)
    if M.shape[-2:] != (3, 3):
        raise ValueError(f"matrices need trailing shape (3, 3), got {M.shape}")
    U, _, Vt = np.linalg.svd(M)
    d = np.sign(np.linalg.det(U @ Vt))
    d = np.where(d == 0, 1.0, d)
    return (U * np.stack([np.ones_like(d), np.ones_like(d), d], -1)[..., None, :]) @ Vt


def nearest_rotation_torch(M: torch.Tensor, iters: int = 12) -> torch.Tensor:
    """Orthogonal polar factor of ``M`` ``(..., 3, 3)`` by the scaled Newton iteration.

    .. math::
        X_0 = M,\\quad X_{k+1} = \\tfrac12\\big(\\zeta_k X_k + \\zeta_k^{-1} X_k^{-T}\\big),
        \\quad \\zeta_k = \\big(\\lVert X_k^{-1}\\rVert_F / \\lVert X_k \\rVert_F\\big)^{1/2}

    (Higham's Frobenius-norm scaling; quadratic convergence). Differentiable with plain
    ops, unlike an SVD, whose backward divides by ``s_i^2 - s_j^2`` and breaks down when
    ``M`` is close to a rotation (all singular values near 1). For ``det M > 0`` the result
    equals :func:`nearest_rotation`; for ``det M < 0`` it is orthogonal with determinant -1
    (no rotation is then uniquely nearest by this route), and a singular ``M`` gives
    non-finite values. A GP mean of the nine elements near its data has ``det M ~ 1``.
    """
    if M.shape[-2:] != (3, 3):
        raise ValueError(f"matrices need trailing shape (3, 3), got {tuple(M.shape)}")
    X = M
    for _ in range(iters):
        Xi = torch.linalg.inv(X)
        zeta = torch.sqrt(torch.linalg.matrix_norm(Xi) / torch.linalg.matrix_norm(X))[
            ..., None, None
        ]
        X = 0.5 * (zeta * X + Xi.mT / zeta)
    return X


def ypr_to_matrix_torch(o: torch.Tensor) -> torch.Tensor:
    """``Rz(gamma) Ry(beta) Rx(alpha)`` in torch (differentiable), ``(..., 3) -> (..., 3, 3)``."""
    R = torch.stack(_rz_ry_rx_entries(torch.cos(o), torch.sin(o)), dim=-1)
    return R.reshape(*o.shape[:-1], 3, 3)


def relative_poses(pose_a: ArrayLike, pose_b: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Relative translation and orientation of marker ``b`` in marker ``a``'s frame.

    Args:
        pose_a: ``(..., 6)`` poses ``[x, y, z, gamma, beta, alpha]`` of marker ``a`` (camera).
        pose_b: ``(..., 6)`` poses of marker ``b``.

    Returns:
        ``l^a_b`` ``(..., 3)`` and ``R^a_b`` ``(..., 3, 3)`` (section 2.3.1).
    """
    pa, pb = np.asarray(pose_a, dtype=np.float64), np.asarray(pose_b, dtype=np.float64)
    Ra_t = np.swapaxes(ypr_to_matrix(pa[..., 3:]), -1, -2)
    Rb = ypr_to_matrix(pb[..., 3:])
    l_ab = np.einsum("...ij,...j->...i", Ra_t, pb[..., :3] - pa[..., :3])
    return l_ab, Ra_t @ Rb

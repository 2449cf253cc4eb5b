"""Synthetic marker-camera data from a numpy Denavit-Hartenberg chain (thesis section 2.6).

A second, MuJoCo-free implementation of the setup of section 2.2, used by the Monte Carlo
benchmark (section 2.6.1) and by the unit tests as independent truth:

* link frames (standard DH, eqs. 2.2-2.3): ``{i} = {i-1} Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``
  with ``theta_i = theta0_i + q_i`` (``R``) or ``d_i = d0_i + q_i`` (``P``); ``{0}`` is the
  base link ``L_1`` whose pose in the camera frame is ``T^c_0``;
* marker ``M_j`` (``j = 0..n``) is rigidly attached to frame ``{j}`` with a constant pose
  ``T^{j}_{M_j}``, so the camera sees ``T^c_{M_j}(q) = T^c_0 A_1(q_1) ... A_j(q_j) T^j_{M_j}``;
* joint trajectories are sums of sinusoids (section 2.6.1: 10 per joint, random amplitudes
  and frequencies).

Markers and joints are returned in chain order; shuffling them is the caller's job.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mcpilco.models.kinematics.rotations import matrix_to_ypr, rot_x, rot_z

__all__ = [
    "SyntheticChain",
    "dh_transforms",
    "homogeneous",
    "pose_from_transform",
    "random_chain",
    "random_rotation",
    "sum_of_sinusoids",
]

FloatArray = NDArray[np.float64]


def homogeneous(R: ArrayLike, t: ArrayLike) -> FloatArray:
    """4x4 transforms from rotations ``(..., 3, 3)`` and translations ``(..., 3)``."""
    R, t = np.asarray(R, dtype=np.float64), np.asarray(t, dtype=np.float64)
    T = np.zeros((*R.shape[:-2], 4, 4))
    T[..., :3, :3], T[..., :3, 3], T[..., 3, 3] = R, t, 1.0
    return T


def pose_from_transform(T: ArrayLike) -> FloatArray:
    """Poses ``[x, y, z, gamma, beta, alpha]`` ``(..., 6)`` of 4x4 transforms ``(..., 4, 4)``."""
    T = np.asarray(T, dtype=np.float64)
    return np.concatenate([T[..., :3, 3], matrix_to_ypr(T[..., :3, :3])], axis=-1)


def random_rotation(rng: np.random.Generator, size: int | None = None) -> FloatArray:
    """Uniformly distributed rotation matrices (QR of a Gaussian matrix, sign-fixed)."""
    shape = () if size is None else (size,)
    A = rng.standard_normal((*shape, 3, 3))
    Q, Rr = np.linalg.qr(A)
    Q = Q * np.sign(np.diagonal(Rr, axis1=-2, axis2=-1))[..., None, :]
    det = np.linalg.det(Q)
    Q[..., :, 0] *= det[..., None]
    return Q


def dh_transforms(dh: FloatArray, joint_types: str, q: FloatArray) -> FloatArray:
    """``A_i(q_i) = Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``: ``q`` ``(T, n) -> (T, n, 4, 4)``.

    ``dh`` is ``(n, 4)`` with columns ``[a, alpha, d0, theta0]``.
    """
    q = np.asarray(q, dtype=np.float64)
    rev = np.array([c == "R" for c in joint_types])
    theta = dh[:, 3] + np.where(rev, q, 0.0)
    d = dh[:, 2] + np.where(rev, 0.0, q)
    Rz = rot_z(theta)
    R = Rz @ rot_x(np.broadcast_to(dh[:, 1], theta.shape))
    t = Rz @ np.stack([np.broadcast_to(dh[:, 0], theta.shape), 0 * theta, 0 * theta], -1)[..., None]
    t = t[..., 0] + np.stack([0 * d, 0 * d, d], axis=-1)
    return homogeneous(R, t)


@dataclass(frozen=True)
class SyntheticChain:
    """An open chain of ``n`` joints (``n + 1`` links) with one marker per link.

    Attributes:
        joint_types: e.g. ``"RRPRRR"``.
        dh: ``(n, 4)`` DH table, columns ``[a, alpha, d0, theta0]``.
        base: ``(4, 4)`` pose ``T^c_0`` of the base frame in the camera frame.
        markers: ``(n + 1, 4, 4)`` constant pose of marker ``j`` in frame ``{j}``.
    """

    joint_types: str
    dh: FloatArray
    base: FloatArray
    markers: FloatArray

    @property
    def n_joints(self) -> int:
        return len(self.joint_types)

    def link_frames(self, q: ArrayLike) -> FloatArray:
        """``T^c_{j}(q)`` for ``j = 0..n``: ``(T, n + 1, 4, 4)`` for ``q`` ``(T, n)``."""
        q = np.atleast_2d(np.asarray(q, dtype=np.float64))
        if q.shape[-1] != self.n_joints:
            raise ValueError(f"q must have {self.n_joints} columns, got shape {q.shape}")
        A = dh_transforms(self.dh, self.joint_types, q)
        frames = np.empty((q.shape[0], self.n_joints + 1, 4, 4))
        frames[:, 0] = self.base
        for j in range(self.n_joints):
            frames[:, j + 1] = frames[:, j] @ A[:, j]
        return frames

    def marker_transforms(self, q: ArrayLike) -> FloatArray:
        """``T^c_{M_j}(q)``, ``(T, n + 1, 4, 4)``."""
        return self.link_frames(q) @ self.markers

    def marker_poses(self, q: ArrayLike) -> FloatArray:
        """Marker poses ``[x, y, z, gamma, beta, alpha]`` in the camera frame, ``(T, n + 1, 6)``."""
        return pose_from_transform(self.marker_transforms(q))


def random_chain(
    n_joints: int,
    rng: np.random.Generator,
    joint_types: str | None = None,
    p_prismatic: float = 0.5,
    link_scale: float = 0.4,
    marker_offset: float = 0.1,
    camera_distance: float = 2.0,
) -> SyntheticChain:
    """A random chain as in the Monte Carlo study of section 2.6.1.

    DH parameters ``a ~ U(-s, s)``, ``d0 ~ U(0, s)``, ``alpha, theta0 ~ U(-pi, pi)`` with
    ``s = link_scale``; markers at a uniformly random orientation and a position
    ``U(-marker_offset, marker_offset)^3`` in their link frame; the base placed at
    ``camera_distance`` along the optical axis (+-0.3 m laterally) with a random orientation.
    """
    if joint_types is None:
        joint_types = "".join(np.where(rng.random(n_joints) < p_prismatic, "P", "R"))
    if len(joint_types) != n_joints or set(joint_types) - {"R", "P"}:
        raise ValueError(f"joint_types must be {n_joints} letters R/P, got {joint_types!r}")
    s = link_scale
    dh = np.column_stack(
        [
            rng.uniform(-s, s, n_joints),
            rng.uniform(-np.pi, np.pi, n_joints),
            rng.uniform(0.0, s, n_joints),
            rng.uniform(-np.pi, np.pi, n_joints),
        ]
    )
    base = homogeneous(random_rotation(rng), [*rng.uniform(-0.3, 0.3, 2), camera_distance])
    markers = homogeneous(
        random_rotation(rng, n_joints + 1),
        rng.uniform(-marker_offset, marker_offset, (n_joints + 1, 3)),
    )
    return SyntheticChain(joint_types=joint_types, dh=dh, base=base, markers=markers)


def sum_of_sinusoids(
    t: ArrayLike,
    n_joints: int,
    rng: np.random.Generator,
    n_sines: int = 10,
    amplitude: float | ArrayLike = 1.0,
    max_frequency: float = 0.5,
) -> FloatArray:
    """``q_k(t) = sum_{s=1}^{n_sines} a_ks sin(2 pi f_ks t + phi_ks)`` (section 2.6.1).

    ``a_ks ~ U(0, A_k / n_sines)`` (so ``|q_k| <= A_k``, ``A_k = amplitude`` per joint),
    ``f_ks ~ U(0, max_frequency)`` [Hz], ``phi_ks ~ U(0, 2 pi)``. Returns ``(len(t), n_joints)``.
    """
    t = np.asarray(t, dtype=np.float64)
    amp = np.broadcast_to(np.asarray(amplitude, dtype=np.float64), (n_joints,))
    a = rng.uniform(0.0, 1.0, (n_joints, n_sines)) * (amp[:, None] / n_sines)
    f = rng.uniform(0.0, max_frequency, (n_joints, n_sines))
    phi = rng.uniform(0.0, 2 * np.pi, (n_joints, n_sines))
    arg = 2 * np.pi * f[None] * t[:, None, None] + phi[None]
    return (a[None] * np.sin(arg)).sum(-1)

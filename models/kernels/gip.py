"""Geometrically inspired polynomial (GIP) kernel for robot inverse dynamics (thesis sec. 3.3).

Glossary (thesis chapter 3):

==============  =====================================================================
symbol          meaning
==============  =====================================================================
``n``           number of joints, ``n = N_r + N_p``
``q, qd, qdd``  joint positions, velocities, accelerations, each ``(..., n)``
``q_c, q_s``    ``cos q_b``, ``sin q_b`` of the revolute joints (in joint order)
``q_p``         positions of the prismatic joints (in joint order)
``qd_v``        all products ``qd_i * qd_j`` with ``i <= j`` (row-major), ``n(n+1)/2``
``x_bar``       ``[q_c, q_s, q_p, qd_v, qdd]`` (eq. 3.8), dimension
                ``gamma = 2 N_r + N_p + n(n+1)/2 + n``
==============  =====================================================================
"""

from __future__ import annotations

import torch
from torch import Tensor

from mcpilco.models.kernels._base import NO_BATCH, DenseKernel
from mcpilco.models.kernels.mpk import MPKernel
from mcpilco.models.kernels.product import linear_product_gram

__all__ = [
    "GIPKernel",
    "check_joint_types",
    "gip_feature_dim",
    "gip_feature_names",
    "gip_features",
]


def check_joint_types(joint_types: str) -> str:
    """Validate a joint-type string such as ``"RRPR"`` (R = revolute, P = prismatic).

    Raises:
        TypeError: if ``joint_types`` is not a string.
        ValueError: if it is empty or holds characters other than ``R`` / ``P``.
    """
    if not isinstance(joint_types, str):
        raise TypeError(
            f"joint_types must be a str such as 'RRPR', got {type(joint_types).__name__}"
        )
    if len(joint_types) == 0:
        raise ValueError("joint_types is empty; give one letter per joint, e.g. 'RRPR'")
    bad = sorted({c for c in joint_types if c not in "RP"})
    if bad:
        raise ValueError(
            f"joint_types {joint_types!r} contains {bad}; use only 'R' (revolute) and "
            "'P' (prismatic), upper case, one letter per joint"
        )
    return joint_types


def gip_feature_dim(joint_types: str) -> int:
    """Dimension :math:`\\gamma = 2N_r + N_p + n(n+1)/2 + n` of :math:`\\bar{\\mathbf x}`."""
    jt = check_joint_types(joint_types)
    n, n_r = len(jt), jt.count("R")
    return 2 * n_r + (n - n_r) + n * (n + 1) // 2 + n


def gip_feature_names(joint_types: str) -> list[str]:
    """Names of the columns of :func:`gip_features` (1-based joint numbers)."""
    jt = check_joint_types(joint_types)
    n = len(jt)
    rev = [b + 1 for b, c in enumerate(jt) if c == "R"]
    pri = [b + 1 for b, c in enumerate(jt) if c == "P"]
    names = [f"cos(q{b})" for b in rev] + [f"sin(q{b})" for b in rev] + [f"q{b}" for b in pri]
    names += [f"qd{i + 1}*qd{j + 1}" for i in range(n) for j in range(i, n)]
    names += [f"qdd{i + 1}" for i in range(n)]
    return names


def gip_features(q: Tensor, qd: Tensor, qdd: Tensor, joint_types: str) -> Tensor:
    r"""The GIP feature map :math:`F: \mathbf x = (q, \dot q, \ddot q) \mapsto \bar{\mathbf x}`
    of thesis eq. (3.8):

    .. math::

        \bar{\mathbf x} = \left[\mathbf q_c,\ \mathbf q_s,\ \mathbf q_p,\ \dot{\mathbf q}_v,\
        \ddot{\mathbf q}\right],\qquad
        \dot{\mathbf q}_v = \{\dot q_i \dot q_j : 1 \le i \le j \le n\}.

    Args:
        q, qd, qdd: ``(..., n)`` tensors (same shape), ``n = len(joint_types)``.
        joint_types: e.g. ``"RRPR"``.

    Returns:
        ``(..., gamma)`` with ``gamma = gip_feature_dim(joint_types)``; column order as in
        :func:`gip_feature_names`.
    """
    jt = check_joint_types(joint_types)
    n = len(jt)
    q, qd, qdd = (torch.as_tensor(t) for t in (q, qd, qdd))
    for name, t in (("q", q), ("qd", qd), ("qdd", qdd)):
        if t.dim() == 0 or t.size(-1) != n:
            raise ValueError(
                f"{name} must have shape (..., {n}) for joint_types {jt!r}, got {tuple(t.shape)}"
            )
    if not (q.shape == qd.shape == qdd.shape):
        raise ValueError(
            f"q, qd, qdd must have the same shape, got {tuple(q.shape)}, {tuple(qd.shape)}, "
            f"{tuple(qdd.shape)}"
        )
    rev = torch.tensor([b for b, c in enumerate(jt) if c == "R"], dtype=torch.long)
    pri = torch.tensor([b for b, c in enumerate(jt) if c == "P"], dtype=torch.long)
    q_r = q.index_select(-1, rev.to(q.device))
    rows, cols = torch.triu_indices(n, n, device=qd.device)
    qd_v = qd.index_select(-1, rows) * qd.index_select(-1, cols)
    parts = [torch.cos(q_r), torch.sin(q_r), q.index_select(-1, pri.to(q.device)), qd_v, qdd]
    return torch.cat(parts, dim=-1)


class GIPKernel(DenseKernel):
    r"""Geometrically inspired polynomial kernel (thesis eq. 3.11) on :math:`\bar{\mathbf x}`.

    .. math::

        k(\bar{\mathbf x}, \bar{\mathbf x}') =
        \prod_{b \in I_r} k^{(2)}_{mpk}\!\left(\mathbf q_{cs_b}, \mathbf q_{cs_b}'\right)
        \prod_{b \in I_p} k^{(2)}_{mpk}\!\left(q_{p_b}, q_{p_b}'\right)\,
        k^{(1)}_{mpk}\!\left(\mathbf q_{av}, \mathbf q_{av}'\right),

    with :math:`\mathbf q_{cs_b} = [\cos q_b, \sin q_b]`, :math:`\mathbf q_{av} =
    [\ddot{\mathbf q}, \dot{\mathbf q}_v]` and :math:`k^{(p)}_{mpk}` the inhomogeneous
    :class:`MPKernel` (eq. 3.10). Its RKHS contains every rigid-body inverse dynamics of a
    robot with these joint types (Proposition 3.3.1): polynomials of degree :math:`\le 2` in
    each joint's position features, and affine in the velocity products and accelerations.

    The kernel acts on :math:`\bar{\mathbf x}` as produced by :func:`gip_features`; each factor
    slices its own columns (the order of the columns of :math:`\mathbf q_{av}` is irrelevant
    since :math:`\Sigma` is diagonal). An outer ``active_dims`` selects the
    :math:`\gamma` columns of :math:`\bar{\mathbf x}` out of a wider input first.

    Args:
        joint_types: e.g. ``"RRPR"`` (R revolute, P prismatic).
        batch_shape, active_dims: as for every GPyTorch kernel.

    Attributes:
        joint_kernels: ``ModuleList`` of degree-2 :class:`MPKernel`, one per joint in joint
            order (2-d for R, 1-d for P).
        dynamics_kernel: the degree-1 :class:`MPKernel` on :math:`[\dot{\mathbf q}_v,
            \ddot{\mathbf q}]`.
    """

    def __init__(
        self,
        joint_types: str,
        batch_shape: torch.Size = NO_BATCH,
        active_dims: tuple[int, ...] | None = None,
    ) -> None:
        jt = check_joint_types(joint_types)
        dim = gip_feature_dim(jt)
        super().__init__(ard_num_dims=dim, batch_shape=batch_shape, active_dims=active_dims)
        self.joint_types = jt
        n, n_r = len(jt), jt.count("R")
        n_p = n - n_r
        kernels, columns = [], []
        i_r = i_p = 0
        for c in jt:
            if c == "R":
                columns.append([i_r, n_r + i_r])
                i_r += 1
            else:
                columns.append([2 * n_r + i_p])
                i_p += 1
            kernels.append(MPKernel(2, len(columns[-1]), batch_shape=self.batch_shape))
        self.joint_kernels = torch.nn.ModuleList(kernels)
        self._joint_columns = columns
        self._dyn_start = 2 * n_r + n_p
        self.dynamics_kernel = MPKernel(1, dim - self._dyn_start, batch_shape=self.batch_shape)

    def _joint_slice(self, x: Tensor, b: int) -> Tensor:
        cols = self._joint_columns[b]
        if len(cols) == 1:
            return x[..., cols[0] : cols[0] + 1]
        return x[..., cols]

    def forward(
        self, x1: Tensor, x2: Tensor, diag: bool = False, last_dim_is_batch: bool = False, **params
    ) -> Tensor:
        self._check_inputs(x1, x2, last_dim_is_batch, self.ard_num_dims)
        if not diag:
            return linear_product_gram(x1, x2, self.linear_factors())
        return self.mpk_product(x1, x2, diag=True)

    def mpk_product(self, x1: Tensor, x2: Tensor, diag: bool = False) -> Tensor:
        """The product of the MPK factors' own forwards, one autograd op per factor (the
        diagonal path; the full Gram matrix goes through the leaner
        :func:`~mcpilco.models.kernels.product.linear_product_gram`)."""
        s = self._dyn_start
        out = self.dynamics_kernel.forward(x1[..., s:], x2[..., s:], diag=diag)
        for b, k in enumerate(self.joint_kernels):
            out = out * k.forward(self._joint_slice(x1, b), self._joint_slice(x2, b), diag=diag)
        return out

    def linear_factors(self) -> list[tuple[slice | list[int], Tensor, Tensor]]:
        """The kernel as a product of linear factors ``(columns, diag Sigma_s, sigma_s^2)``:
        the ``p`` factors of every MPK (joints, then the dynamics MPK), for
        :func:`~mcpilco.models.kernels.product.linear_product_gram`."""
        kernels = [*self.joint_kernels, self.dynamics_kernel]
        columns = [*self._joint_columns, slice(self._dyn_start, None)]
        out = []
        for k, cols in zip(kernels, columns, strict=True):
            cols = (
                slice(cols[0], cols[0] + 1) if isinstance(cols, list) and len(cols) == 1 else cols
            )
            Sigma, sigma2 = k.Sigma_diag, k.sigma2
            out += [(cols, Sigma[..., j, :], sigma2[..., j]) for j in range(k.degree)]
        return out

"""Kernel for the forward dynamics of a rigid arm: configuration RBF times a linear kernel.

Glossary:

==============  =====================================================================
symbol          meaning
==============  =====================================================================
``n``           number of joints (one letter of ``joint_types`` each)
``q, qd, tau``  joint positions, velocities and torques (forces), each ``(..., n)``;
                the kernel input is ``x = [q, qd, tau]``, ``(..., 3n)``
``z(q)``        configuration features: ``[cos q_b, sin q_b]`` for a revolute joint,
                ``q_b`` for a prismatic one
``qd_v``        all products ``qd_i * qd_j`` with ``i <= j`` (row-major), ``n(n+1)/2``
``w``           ``k`` further inputs in which the accelerations are affine at a fixed
                configuration (``num_affine``; e.g. the reference ``[q_ref, qd_ref]`` of
                a PD controller in the loop); the input is then ``[q, qd, tau, w]``
``v``           ``[tau, qd_v, qd, tanh(qd / eps), w]`` (the Coulomb block only with an
                ``eps``), see :func:`rigid_body_feature_names`
==============  =====================================================================
"""

from __future__ import annotations

import torch
from gpytorch.constraints import Interval, Positive
from torch import Tensor

from mcpilco.models.kernels._base import NO_BATCH, DenseKernel, as_parameter_value
from mcpilco.models.kernels.gip import check_joint_types
from mcpilco.models.kernels.linear import LinearKernel

__all__ = [
    "RigidBodyDynamicsKernel",
    "rigid_body_feature_dim",
    "rigid_body_feature_names",
    "rigid_body_features",
]


def rigid_body_feature_dim(joint_types: str, coulomb: bool = False, num_affine: int = 0) -> int:
    """Dimension of :math:`\\mathbf v`: ``n + n(n+1)/2 + n`` (``+ n`` with Coulomb,
    ``+ num_affine``)."""
    n = len(check_joint_types(joint_types))
    return n + n * (n + 1) // 2 + n + (n if coulomb else 0) + int(num_affine)


def rigid_body_feature_names(
    joint_types: str, coulomb: bool = False, num_affine: int = 0
) -> list[str]:
    """Names of the columns of :func:`rigid_body_features` (1-based joint numbers), then
    ``w1 .. wk`` for the ``num_affine`` further affine inputs."""
    n = len(check_joint_types(joint_types))
    names = [f"tau{i + 1}" for i in range(n)]
    names += [f"qd{i + 1}*qd{j + 1}" for i in range(n) for j in range(i, n)]
    names += [f"qd{i + 1}" for i in range(n)]
    if coulomb:
        names += [f"tanh(qd{i + 1}/eps)" for i in range(n)]
    return names + [f"w{i + 1}" for i in range(int(num_affine))]


def rigid_body_features(qd: Tensor, tau: Tensor, coulomb_eps: float | None = None) -> Tensor:
    r"""The velocity / torque features :math:`\mathbf v` in which the forward dynamics is
    affine for a fixed configuration:

    .. math::

        \mathbf v = \left[\boldsymbol\tau,\ \dot{\mathbf q}_v,\ \dot{\mathbf q},\
        \tanh(\dot{\mathbf q} / \epsilon)\right],\qquad
        \dot{\mathbf q}_v = \{\dot q_i \dot q_j : 1 \le i \le j \le n\}.

    Args:
        qd, tau: ``(..., n)``.
        coulomb_eps: :math:`\epsilon > 0` of the smooth sign; ``None`` leaves the block out.

    Returns:
        ``(..., d_v)``, column order as in :func:`rigid_body_feature_names`.

    Raises:
        ValueError: if ``qd`` and ``tau`` differ in shape or are scalars.
    """
    if qd.dim() == 0 or qd.shape != tau.shape:
        raise ValueError(
            f"qd and tau must have the same shape (..., n), got {tuple(qd.shape)} and "
            f"{tuple(tau.shape)}"
        )
    n = qd.size(-1)
    rows, cols = torch.triu_indices(n, n, device=qd.device)
    parts = [tau, qd.index_select(-1, rows) * qd.index_select(-1, cols), qd]
    if coulomb_eps is not None:
        parts.append(torch.tanh(qd / coulomb_eps))
    return torch.cat(parts, dim=-1)


class RigidBodyDynamicsKernel(DenseKernel):
    r"""Structured kernel for the joint accelerations of a rigid arm, on :math:`[q, \dot q,
    \tau]`.

    For a rigid arm the equations of motion give the accelerations

    .. math::

        \ddot{\mathbf q} = M(\mathbf q)^{-1}\left(\boldsymbol\tau
        - C(\mathbf q)\,\dot{\mathbf q}_v - \mathbf g(\mathbf q)
        - F_v \dot{\mathbf q} - F_c \operatorname{sign}(\dot{\mathbf q})\right),

    where :math:`C(\mathbf q)\,\dot{\mathbf q}_v` collects the Coriolis and centripetal terms
    (quadratic in the velocities). For a fixed configuration :math:`\mathbf q` each
    acceleration is therefore affine in :math:`\mathbf v` (:func:`rigid_body_features`; the
    sign is smoothed as :math:`\tanh(\dot q_i / \epsilon)`):
    :math:`\ddot q_k = f_{k0}(\mathbf q) + \sum_j f_{kj}(\mathbf q)\, v_j`. The kernel

    .. math::

        k(\mathbf x, \mathbf x') = k_q(\mathbf q, \mathbf q')\left(\sigma^2 +
        \mathbf v^T \Sigma\, \mathbf v'\right),\qquad
        k_q(\mathbf q, \mathbf q') = \exp\!\left(-\tfrac12 \sum_{b=1}^{n}
        \frac{\lVert z_b(q_b) - z_b(q_b')\rVert^2}{\ell_b^2}\right),

    with :math:`z_b(q) = [\cos q, \sin q]` for a revolute joint (then
    :math:`\lVert z_b(q) - z_b(q')\rVert^2 = 4 \sin^2((q - q')/2)`, a stationary kernel on
    the circle) and :math:`z_b(q) = q` for a prismatic one, has exactly this structure: its
    RKHS is :math:`\{f_0(\mathbf q) + \sum_j f_j(\mathbf q)\, v_j : f_j \in
    \mathcal H_{k_q}\}` (the product of a kernel on :math:`\mathbf q` and the degree-1 MPK
    :math:`\sigma^2 + \mathbf v^T \Sigma \mathbf v'` of :class:`LinearKernel`). The
    velocity / torque factor is exact given :math:`\mathbf q`; only the coefficient
    functions :math:`f_j` are learned from data.

    The configuration factor is an RBF, not the degree-2 MPK on :math:`[\cos q_b, \sin q_b]`
    of :class:`~mcpilco.models.kernels.GIPKernel`: the coefficients come from
    :math:`M(\mathbf q)^{-1} = \operatorname{adj} M(\mathbf q) / \det M(\mathbf q)`, which is
    not a polynomial in :math:`\cos q_b, \sin q_b` (for a planar two-link arm
    :math:`\det M = \alpha - \beta \cos^2 q_2` with constants :math:`\alpha > \beta > 0`),
    whereas inverse dynamics (:math:`\boldsymbol\tau` from :math:`\ddot{\mathbf q}`) is. The
    RBF is universal on the compact configuration space, and the coefficients are smooth
    (analytic) functions of :math:`\mathbf q`, which it approximates from few samples. Each
    joint has its own lengthscale: the accelerations of a planar arm depend on its first
    joint only through gravity, which is of degree one in :math:`\cos q_1, \sin q_1` and is
    matched by a long lengthscale. The overall scale is carried by :math:`\sigma^2` and
    :math:`\Sigma`; an outputscale on :math:`k_q` would be an exactly redundant direction of
    the marginal likelihood and is left out.

    Further inputs :math:`\mathbf w` (``num_affine``) in which the accelerations are affine
    at a fixed configuration join :math:`\mathbf v`. A joint controller in the loop is the
    case in point: with :math:`\boldsymbol\tau = K_p(\mathbf q_r - \mathbf q) + K_d(\dot{
    \mathbf q}_r - \dot{\mathbf q}) + \hat{\mathbf g}(\mathbf q) + \mathbf u` the terms in
    :math:`\mathbf q` and :math:`\dot{\mathbf q}` are already in the span, and the
    reference :math:`\mathbf w = [\mathbf q_r, \dot{\mathbf q}_r]` enters linearly, so the
    input ``[q, qd, u, q_r, qd_r]`` keeps the structure with the correction :math:`\mathbf u`
    in the place of :math:`\boldsymbol\tau`.

    The features are built inside the kernel, so the GP input is the plain
    :math:`[\mathbf q, \dot{\mathbf q}, \boldsymbol\tau]` (a state and an action, as a
    dynamics model sees them) and gradients with respect to it flow through the feature map;
    a precomputed feature map with a product of existing kernels would make every caller,
    and every rollout step, build the features first. The kernel needs the raw coordinates:
    ``q`` in radians for revolute joints (the cosine and sine are taken of it) and ``qd`` in
    its own units (for the smooth sign); fit it with
    ``GPRegressor(..., standardize_x=False)``. (An affine rescaling of ``qd`` and ``tau``
    alone would not change the span of :math:`[1, \mathbf v]` without Coulomb features, but
    a rescaled angle is no longer an angle.)

    Args:
        joint_types: one letter per joint, ``R`` revolute or ``P`` prismatic, e.g. ``"RR"``
            (as for :class:`~mcpilco.models.kernels.GIPKernel`).
        coulomb_eps: width :math:`\epsilon > 0` of the smooth sign
            :math:`\tanh(\dot q_i / \epsilon)` (Coulomb friction features); ``None``
            (default) leaves them out (viscous friction only).
        num_affine: number ``k`` of further inputs ``w`` after ``[q, qd, tau]`` (default 0).
        batch_shape, active_dims: as for every GPyTorch kernel; ``active_dims`` selects the
            ``3n + k`` columns ``[q, qd, tau, w]`` out of a wider input.
        lengthscale_constraint: constraint on :math:`\ell_b` (default ``Positive()``).

    Attributes:
        raw_lengthscale: ``(*batch_shape, 1, n)``, one lengthscale per joint (the revolute
            joints' cosine and sine share it); ``lengthscale`` is the constrained value.
        velocity_kernel: the :class:`LinearKernel` on :math:`\mathbf v`
            (``sigma2`` :math:`= \sigma^2`, ``Sigma_diag`` the diagonal of :math:`\Sigma`,
            columns named by :func:`rigid_body_feature_names`).

    Example:
        >>> k = RigidBodyDynamicsKernel("RR", batch_shape=torch.Size([2]))
        >>> K = k(torch.randn(50, 6)).to_dense()  # (2, 50, 50)
    """

    def __init__(
        self,
        joint_types: str,
        coulomb_eps: float | None = None,
        num_affine: int = 0,
        batch_shape: torch.Size = NO_BATCH,
        active_dims: tuple[int, ...] | None = None,
        lengthscale_constraint: Interval | None = None,
    ) -> None:
        jt = check_joint_types(joint_types)
        if coulomb_eps is not None:
            if isinstance(coulomb_eps, bool) or not isinstance(coulomb_eps, (int, float)):
                raise TypeError(
                    f"coulomb_eps must be a positive float or None, got {coulomb_eps!r}"
                )
            if not coulomb_eps > 0 or coulomb_eps == float("inf"):
                raise ValueError(f"coulomb_eps must be a finite float > 0, got {coulomb_eps}")
            coulomb_eps = float(coulomb_eps)
        if isinstance(num_affine, bool) or not isinstance(num_affine, int) or num_affine < 0:
            raise ValueError(f"num_affine must be an integer >= 0, got {num_affine!r}")
        n = len(jt)
        super().__init__(
            ard_num_dims=3 * n + num_affine, batch_shape=batch_shape, active_dims=active_dims
        )
        self.joint_types = jt
        self.num_joints = n
        self.num_affine = num_affine
        self.coulomb_eps = coulomb_eps
        # joint of each column of z(q): two columns (cos, sin) per revolute joint, one per prismatic
        self._z_joint = [b for b, c in enumerate(jt) for _ in range(2 if c == "R" else 1)]
        self.register_parameter(
            "raw_lengthscale", torch.nn.Parameter(torch.zeros(*self.batch_shape, 1, n))
        )
        self.register_constraint("raw_lengthscale", lengthscale_constraint or Positive())
        self.lengthscale = 1.0
        d_v = rigid_body_feature_dim(jt, coulomb=coulomb_eps is not None, num_affine=num_affine)
        self.velocity_kernel = LinearKernel(d_v, batch_shape=self.batch_shape)
        self.velocity_kernel.Sigma_diag = 1.0 / d_v

    @property
    def lengthscale(self) -> Tensor:
        """Per-joint lengthscales :math:`\\ell_b`, shape ``(*batch_shape, 1, n)``."""
        return self._get("lengthscale")

    @lengthscale.setter
    def lengthscale(self, value: Tensor | float) -> None:
        value = as_parameter_value(value, self.raw_lengthscale, "lengthscale")
        if bool((value <= 0).any()):
            raise ValueError(f"lengthscale must be > 0, got {value.detach().cpu().tolist()}")
        self._set("lengthscale", value)

    def configuration_features(self, q: Tensor) -> Tensor:
        """:math:`z(\\mathbf q)`: ``[cos q_b, sin q_b]`` or ``q_b`` per joint, in joint order."""
        parts = []
        for b, c in enumerate(self.joint_types):
            qb = q[..., b : b + 1]
            parts += [torch.cos(qb), torch.sin(qb)] if c == "R" else [qb]
        return torch.cat(parts, dim=-1)

    def velocity_features(self, qd: Tensor, tau: Tensor) -> Tensor:
        """:math:`\\mathbf v` (:func:`rigid_body_features` with this kernel's ``coulomb_eps``)."""
        return rigid_body_features(qd, tau, self.coulomb_eps)

    def configuration_covar(self, q1: Tensor, q2: Tensor) -> Tensor:
        """:math:`k_q(\\mathbf q, \\mathbf q')`, ``(*batch, n1, n2)``.

        Squared distances in matmul form :math:`\\lVert a\\rVert^2 + \\lVert b\\rVert^2
        - 2 a^T b` on the scaled features :math:`a = z(\\mathbf q) / \\ell`, clamped at zero.
        """
        ls = self.lengthscale.to(q1.dtype)[..., self._z_joint]  # (*batch, 1, d_z)
        a = self.configuration_features(q1) / ls
        b = self.configuration_features(q2) / ls
        sq = a.pow(2).sum(-1, keepdim=True) - 2.0 * (a @ b.mT) + b.pow(2).sum(-1).unsqueeze(-2)
        return torch.exp(-0.5 * sq.clamp_min(0.0))

    def forward(
        self, x1: Tensor, x2: Tensor, diag: bool = False, last_dim_is_batch: bool = False, **params
    ) -> Tensor:
        self._check_inputs(x1, x2, last_dim_is_batch, self.ard_num_dims)
        n = self.num_joints
        sizes = (n, n, n, self.num_affine)
        q1, qd1, tau1, w1 = x1.split(sizes, dim=-1)
        q2, qd2, tau2, w2 = x2.split(sizes, dim=-1)
        v1 = torch.cat([self.velocity_features(qd1, tau1), w1], dim=-1)
        v2 = torch.cat([self.velocity_features(qd2, tau2), w2], dim=-1)
        k_v = self.velocity_kernel.forward(v1, v2, diag=diag)
        if diag:  # k_q(q, q) = 1
            return k_v
        return self.configuration_covar(q1, q2) * k_v

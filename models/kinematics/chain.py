"""Forward kinematics composed along the identified marker chain (beyond the thesis).

The thesis's model (:class:`~mcpilco.models.kinematics.forward.ForwardKinematicsGP`, eqs.
2.22-2.23) maps all ``n`` joints to the end marker directly: on a UR10 its kernels span
``3^6 = 729`` monomials, learned from the end marker's pose alone. The structure
identification (section 2.4) also returns the marker sequence, and every frame measures
every marker. Composing the chain uses both.

Glossary (markers ``M_0 .. M_n`` base to tip, ``S_M``; joint ``q_k`` between ``M_{k-1}`` and
``M_k``, ``S_q``; all poses in the camera frame ``c``)
-----------------------------------------------------------------------------------------
``T^c_{M_n}(q) = T^c_{M_0} G_1(q_1) G_2(q_2) ... G_n(q_n)``
    the end-marker pose as a product of the relative poses of consecutive markers.
``G_k(q_k) = (T^c_{M_{k-1}})^{-1} T^c_{M_k} = [R^{k-1}_k, l^{k-1}_k]``
    marker ``k`` in marker ``k - 1``'s frame. Links are rigid, so it depends on ``q_k``
    alone (eqs. 2.2-2.3; the fact the triplet tests of section 2.3 check). Its 12 elements
    ``y = [l^{k-1}_k, R^{k-1}_k (row-major)]`` are measured by
    :func:`~mcpilco.models.kinematics.rotations.relative_poses`.
``y_o(q_k) ~ GP(0, phi(q_k)^T Sigma_o phi(q_k'))``, ``phi = [1, cos q_k, sin q_k]``
    one GP per element ``o`` with the kernel of eq. 2.22 with one factor (``Sigma_o``
    diagonal: the offset ``sigma^2`` and the ``cos``/``sin`` variances), whose RKHS holds
    ``R^{k-1}_k`` and ``l^{k-1}_k`` exactly (they are ``A + B cos q_k + C sin q_k``). A
    prismatic joint has ``phi = [1, q_k]`` (eq. 2.23). A finite-rank kernel is Bayesian
    linear regression, ``y_o = phi^T w_o + eps``, ``w_o ~ N(0, Sigma_o)``: the evidence
    and the posterior mean ``w_o`` are computed in weight space, ``O(N p^2)`` with ``p <= 3``
    (:class:`~mcpilco.models.gp.linear_gp.JointGP`), hyperparameters ``Sigma_o``,
    ``sigma_n^2`` by type-II maximum likelihood. The mean rotation ``phi^T W_R`` is
    projected onto SO(3) (nearest rotation).
``T^c_{M_0}``
    the base marker's pose, constant. Its position is the mean of the measured positions.
    Its rotation is the nearest rotation to the mean measured matrix (the chordal mean).
frames used
    link ``k`` learns from the frames that show both ``M_{k-1}`` and ``M_k``; the base from
    those showing ``M_0`` (a marker out of view is a row of NaN). ``frames_used_`` counts
    them.

Why it is more accurate on the same frames: it fits ``n`` maps of 3 monomials each, from
12 outputs per frame, instead of one map of ``3^n`` monomials from 6 outputs. So the
measurement noise averages out over far fewer unknowns. Its errors compound along the
chain; each link's error is small.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray
from torch import Tensor, nn

from mcpilco.models.gp.linear_gp import JointGP
from mcpilco.models.kinematics.forward import (
    check_joint_positions,
    five_elements,
    fk_features,
    joint_type_indices,
)
from mcpilco.models.kinematics.rotations import (
    elements_to_ypr_torch,
    nearest_rotation,
    nearest_rotation_torch,
    relative_poses,
    ypr_to_matrix,
)

__all__ = ["ChainFKPredictor", "ChainForwardKinematicsGP", "LinkMean", "fit_link", "link_features"]

FloatArray = NDArray[np.float64]

MIN_FRAMES_PER_LINK = 5
"""Fewest frames showing both markers of a link that :meth:`ChainForwardKinematicsGP.fit`
accepts (each link GP has at most 3 monomials per output)."""


CONSTANT_OUTPUT = 1e-12
"""Relative spread (to ``1 + max |y|``) below which an element is a constant of the link: its
weights are ``[mean, 0, ...]`` instead of a GP fit (e.g. ``R33`` about the marker's ``z``)."""


def link_features(q_k: Tensor, joint_type: str) -> Tensor:
    """``phi(q_k)``: ``[1, cos q_k, sin q_k]`` (``"R"``) or ``[1, q_k]`` (``"P"``), ``(..., 1)``
    -> ``(..., p)``; differentiable."""
    return torch.cat([torch.ones_like(q_k), fk_features(q_k, joint_type)], dim=-1)


def fit_link(q_k: FloatArray, y: FloatArray, joint_type: str, maxiter: int = 200) -> FloatArray:
    """Posterior-mean weights ``W`` ``(p, m)`` of one GP per column of ``y`` ``(N, m)``
    on ``phi(q_k)`` (module glossary), hyperparameters by type-II maximum likelihood."""
    phi = link_features(torch.from_numpy(np.asarray(q_k, dtype=np.float64)[:, None]), joint_type)
    phi = phi.numpy()
    blocks = [phi[:, [j]] for j in range(phi.shape[1])]  # one prior variance per feature
    W = np.zeros((phi.shape[1], y.shape[1]))
    for o in range(y.shape[1]):
        col = y[:, o]
        if np.ptp(col) <= CONSTANT_OUTPUT * (1.0 + np.abs(col).max()):
            W[0, o] = col.mean()
            continue
        gp = JointGP(col, blocks)
        theta, _ = gp.optimise(gp.default_theta(), maxiter=maxiter)
        W[:, o] = gp.weights(theta)[0]
    return W


class LinkMean(nn.Module):
    """``G_k(q_k)``: ``l = phi^T W_l``, ``R = proj_SO(3)(phi^T W_R)`` (module glossary)."""

    def __init__(self, joint_type: str, W: Tensor) -> None:
        super().__init__()
        self.joint_type = joint_type
        self.register_buffer("W", W)

    def position_and_rotation(self, q_k: Tensor) -> tuple[Tensor, Tensor]:
        """``(l (..., 3), R (..., 3, 3))`` for ``q_k`` ``(..., 1)``."""
        y = link_features(q_k, self.joint_type) @ self.W.to(q_k.dtype)
        R = nearest_rotation_torch(y[..., 3:].reshape(*y.shape[:-1], 3, 3))
        return y[..., :3], R


class ChainFKPredictor(nn.Module):
    """Differentiable ``q -> (l_hat, o_hat)`` of the composed chain (module glossary).

    Call: ``position, ypr = pred(q)`` with ``q`` ``(..., n)`` -> ``(..., 3)`` each; like
    :class:`~mcpilco.models.kinematics.forward.FKPredictor`, so the controllers accept it.
    """

    def __init__(self, base_R: Tensor, base_l: Tensor, links: list[LinkMean]) -> None:
        super().__init__()
        self.register_buffer("base_R", base_R)
        self.register_buffer("base_l", base_l)
        self.links = nn.ModuleList(links)

    def position_and_rotation(self, q: Tensor) -> tuple[Tensor, Tensor]:
        """``(l^c_{M_n} (..., 3), R^c_{M_n} (..., 3, 3))`` of ``T^c_{M_0} prod_k G_k(q_k)``."""
        if q.shape[-1] != len(self.links):
            raise ValueError(f"q must have {len(self.links)} columns, got {tuple(q.shape)}")
        lead = q.shape[:-1]
        R = self.base_R.to(q.dtype).expand(*lead, 3, 3)
        l = self.base_l.to(q.dtype).expand(*lead, 3)  # noqa: E741 (l: the thesis's symbol)
        for k, link in enumerate(self.links):
            l_k, R_k = link.position_and_rotation(q[..., k : k + 1])
            l = l + (R @ l_k.unsqueeze(-1)).squeeze(-1)  # noqa: E741
            R = R @ R_k
        return l, R

    def forward(self, q: Tensor) -> tuple[Tensor, Tensor]:
        l, R = self.position_and_rotation(q)  # noqa: E741
        return l, elements_to_ypr_torch(five_elements(R))


class ChainForwardKinematicsGP:
    """FK of the end marker composed from one-joint GPs along the marker chain.

    Args:
        joint_types: joint types along the chain, e.g. ``"RRRRRR"`` (``S_Q``).
        maxiter: L-BFGS-B iterations of each element's evidence maximisation.

    Fitted attributes: ``link_weights_`` (one ``(p, 12)`` posterior-mean weight matrix
    ``W = [W_l, W_R]`` per joint), ``base_R_`` ``(3, 3)`` and ``base_l_`` ``(3,)``
    (``T^c_{M_0}``), ``frames_used_`` (``{"base": N_0, "links": [N_1, ..., N_n]}``, frames
    each part was fitted on).
    """

    def __init__(self, joint_types: str, *, maxiter: int = 200) -> None:
        joint_type_indices(joint_types)
        self.joint_types = joint_types
        self.maxiter = int(maxiter)
        self.link_weights_: list[FloatArray] = []
        self.base_R_: FloatArray | None = None
        self.base_l_: FloatArray | None = None
        self.frames_used_: dict[str, Any] = {}

    @property
    def n_joints(self) -> int:
        return len(self.joint_types)

    def fit(self, q: ArrayLike, marker_poses: ArrayLike):
        """Fit the base pose and the ``n`` link GPs (marginal likelihood each).

        Args:
            q: ``(N, n)`` joint positions in chain order (``S_q``).
            marker_poses: ``(N, n + 1, 6)`` poses ``[x, y, z, gamma, beta, alpha]`` of the
                markers in chain order (``S_M``, base first); a marker out of view is a row
                of NaN, and only the links it belongs to lose that frame.
        """
        q = check_joint_positions(q, self.joint_types)
        P = np.asarray(marker_poses, dtype=np.float64)
        if P.shape != (q.shape[0], self.n_joints + 1, 6):
            raise ValueError(
                f"marker_poses must have shape ({q.shape[0]}, {self.n_joints + 1}, 6) (frames, "
                f"markers base to tip, [x, y, z, gamma, beta, alpha]), got {P.shape}"
            )
        seen = np.isfinite(P).all(-1)  # (N, n + 1)
        partial = np.isnan(P).any(-1) & ~np.isnan(P).all(-1)
        if partial.any() or np.isinf(P).any():
            raise ValueError(
                "a marker pose must be all finite or all NaN (out of view); found "
                f"{int(partial.sum())} partly-NaN and {int(np.isinf(P).any(-1).sum())} "
                "infinite poses"
            )
        counts = [int(seen[:, 0].sum())] + [
            int((seen[:, k] & seen[:, k + 1]).sum()) for k in range(self.n_joints)
        ]
        short = [i for i, c in enumerate(counts) if c < MIN_FRAMES_PER_LINK]
        if short:
            names = ["base marker" if i == 0 else f"link {i} (markers {i - 1}, {i})" for i in short]
            raise ValueError(
                f"too few frames for {', '.join(names)}: {[counts[i] for i in short]} "
                f"(need >= {MIN_FRAMES_PER_LINK} frames showing the markers)"
            )
        base = P[seen[:, 0], 0]
        self.base_l_ = base[:, :3].mean(0)
        self.base_R_ = nearest_rotation(ypr_to_matrix(base[:, 3:]).mean(0))
        weights = []
        for k in range(self.n_joints):
            both = seen[:, k] & seen[:, k + 1]
            l_rel, R_rel = relative_poses(P[both, k], P[both, k + 1])
            y = np.concatenate([l_rel, R_rel.reshape(-1, 9)], axis=-1)  # (N_k, 12)
            weights.append(fit_link(q[both, k], y, self.joint_types[k], self.maxiter))
        self.link_weights_ = weights
        self.frames_used_ = {"base": counts[0], "links": counts[1:]}
        return self

    def _check_fitted(self) -> None:
        if not self.link_weights_:
            raise RuntimeError("ChainForwardKinematicsGP is not fitted; call fit first")

    def predictor(self, dtype: torch.dtype = torch.float64) -> ChainFKPredictor:
        """Differentiable :class:`ChainFKPredictor` over the links' posterior-mean weights."""
        self._check_fitted()
        return ChainFKPredictor(
            torch.as_tensor(self.base_R_, dtype=dtype),
            torch.as_tensor(self.base_l_, dtype=dtype),
            [
                LinkMean(t, torch.as_tensor(W, dtype=dtype))
                for t, W in zip(self.joint_types, self.link_weights_, strict=True)
            ],
        )

    def predict(self, q: ArrayLike) -> FloatArray:
        """Posterior-mean end-marker poses ``(N, 6)`` ``[x, y, z, gamma, beta, alpha]``."""
        q = check_joint_positions(q, self.joint_types)
        with torch.no_grad():
            position, ypr = self.predictor(torch.float64)(torch.from_numpy(q))
        return torch.cat([position, ypr], dim=-1).numpy()

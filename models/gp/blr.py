"""Bayesian linear regression in weight space (primal form), every row at ``O(N F^2)``.

For each output ``j`` with features ``Phi (N, F)`` (shared by all outputs or one matrix per
output) and targets ``y_j (N,)``:

.. math::

    y_j = \\Phi_j w_j + e,\\qquad w_j \\sim \\mathcal N(0, \\lambda_j I),\\qquad
    e \\sim \\mathcal N(0, \\sigma_j^2 I),

i.e. a GP with the finite-rank kernel ``lambda_j phi_j(x)^T phi_j(x')`` (a Nystroem kernel,
an explicit polynomial feature map, ...). Only the sufficient statistics
``A = Phi^T Phi``, ``b = Phi^T y``, ``y^T y`` and ``N`` are kept, accumulated over chunks of
rows (:meth:`BayesianLinearRegression.add`), so the rows never need to be in memory at
once and the cost is linear in ``N``. With ``A = V diag(e) V^T`` and ``c = V^T b`` the
log evidence (thesis eq. 1.9 for this kernel) is, for ``s = sigma^2 / lambda``,

.. math::

    \\log p(y) = -\\tfrac{1}{2\\sigma^2}\\Big(y^\\top y - \\sum_i \\frac{c_i^2}{e_i + s}\\Big)
    - \\tfrac N2 \\log \\sigma^2 - \\tfrac12 \\sum_i \\log\\!\\big(1 + e_i / s\\big)
    - \\tfrac N2 \\log 2\\pi,

``O(F)`` per evaluation after one ``O(F^3)`` eigendecomposition, so ``(lambda, sigma^2)``
are fitted by type-II maximum likelihood (L-BFGS-B on their logarithms) at no cost that
grows with ``N``. The posterior is ``w | y ~ N((A + s I)^{-1} b, sigma^2 (A + s I)^{-1})``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize

FloatArray = NDArray[np.float64]

__all__ = ["BayesianLinearRegression"]

LOG_BOUNDS = (-30.0, 30.0)
"""Bounds of ``log lambda`` and ``log sigma^2`` relative to the target's variance."""
EIG_TOLERANCE = 1e-11
"""Eigenvalues of ``A`` below this fraction of the largest are taken as zero, with their
``c_i``: in exact arithmetic ``b`` lies in the range of ``A``, so there ``c_i`` is round-off,
and ``c_i^2 / (e_i + s)`` would let the evidence grow without bound as ``sigma^2 -> 0``."""


class BayesianLinearRegression:
    """Independent Bayesian linear regressions, one per output, from sufficient statistics.

    Args:
        n_features: ``F``.
        n_outputs: ``m``.

    Usage: :meth:`add` chunks of ``(Phi, Y)`` (``Phi`` ``(N, F)`` shared by the outputs or
    ``(m, N, F)`` one per output; ``Y`` ``(N, m)``), then :meth:`fit`, then :meth:`predict`.
    Fitted attributes: ``log_lambda_``, ``log_noise_`` ``(m,)`` (natural units),
    ``weights_`` ``(m, F)``, ``evidence_`` ``(m,)``.
    """

    def __init__(self, n_features: int, n_outputs: int) -> None:
        if n_features < 1 or n_outputs < 1:
            raise ValueError(
                f"need n_features >= 1 and n_outputs >= 1, got {n_features}, {n_outputs}"
            )
        self.n_features = int(n_features)
        self.n_outputs = int(n_outputs)
        self.A = np.zeros((n_outputs, n_features, n_features))
        self.b = np.zeros((n_outputs, n_features))
        self.yy = np.zeros(n_outputs)
        self.n = 0

    def add(self, Phi: FloatArray, Y: FloatArray) -> None:
        """Accumulate the statistics of a chunk of rows."""
        Y = np.asarray(Y, dtype=np.float64)
        Phi = np.asarray(Phi, dtype=np.float64)
        m, F = self.n_outputs, self.n_features
        if Y.ndim != 2 or Y.shape[1] != m:
            raise ValueError(f"Y must be (N, {m}), got {Y.shape}")
        if Phi.shape[-1] != F or Phi.shape[-2] != Y.shape[0]:
            raise ValueError(f"Phi must be (N, {F}) or ({m}, N, {F}) for N={Y.shape[0]}")
        if not (np.all(np.isfinite(Phi)) and np.all(np.isfinite(Y))):
            raise ValueError("Phi and Y must be finite")
        if Phi.ndim == 2:
            self.A += (Phi.T @ Phi)[None]
            self.b += (Phi.T @ Y).T
        else:
            self.A += np.matmul(Phi.transpose(0, 2, 1), Phi)  # batched BLAS, not einsum
            self.b += np.matmul(Phi.transpose(0, 2, 1), Y.T[:, :, None])[..., 0]
        self.yy += np.sum(Y**2, axis=0)
        self.n += Y.shape[0]

    def _evidence(self, e: FloatArray, c: FloatArray, yy: float, theta: FloatArray) -> float:
        lam, s2 = math.exp(theta[0]), math.exp(theta[1])
        s = s2 / lam
        quad = (yy - float(np.sum(c**2 / (e + s)))) / s2
        logdet = self.n * theta[1] + float(np.sum(np.log1p(e / s)))
        return -0.5 * quad - 0.5 * logdet - 0.5 * self.n * math.log(2 * math.pi)

    def fit(self, noise_min: float = 0.0) -> BayesianLinearRegression:
        """Type-II ML of ``(lambda_j, sigma_j^2)`` per output, then the posterior weights.

        Args:
            noise_min: lower bound on ``sigma_j^2`` (units of ``y`` squared).
        """
        if self.n < 2:
            raise ValueError(f"need at least 2 rows to fit, got {self.n}")
        m, F = self.n_outputs, self.n_features
        self.log_lambda_ = np.zeros(m)
        self.log_noise_ = np.zeros(m)
        self.weights_ = np.zeros((m, F))
        self.evidence_ = np.zeros(m)
        self._eig = []
        for j in range(m):
            A = 0.5 * (self.A[j] + self.A[j].T)
            e, V = np.linalg.eigh(A)
            null = e <= EIG_TOLERANCE * max(float(e[-1]), 1e-300)
            e = np.where(null, 0.0, e)
            c = np.where(null, 0.0, V.T @ self.b[j])
            yy = float(self.yy[j])
            var = max(yy / self.n, 1e-300)
            lo_noise = math.log(max(noise_min, var * 1e-13))
            bounds = [
                (math.log(var) + LOG_BOUNDS[0], math.log(var) + LOG_BOUNDS[1]),
                (max(lo_noise, math.log(var) + LOG_BOUNDS[0]), math.log(var) + 5.0),
            ]
            scale = max(float(np.mean(e)), 1e-300)

            def neg(
                theta: FloatArray, e: FloatArray = e, c: FloatArray = c, yy: float = yy
            ) -> float:
                return -self._evidence(e, c, yy, theta)

            starts = [
                np.array([math.log(var / scale) + k, math.log(var) - 2.0 * k]) for k in (0, 3, 6)
            ]
            best = None
            for x0 in starts:
                x0 = np.clip(x0, [b[0] for b in bounds], [b[1] for b in bounds])
                res = minimize(neg, x0, method="L-BFGS-B", bounds=bounds)
                if best is None or res.fun < best.fun:
                    best = res
            self.log_lambda_[j], self.log_noise_[j] = best.x
            self.evidence_[j] = -float(best.fun)
            s = math.exp(best.x[1] - best.x[0])
            self.weights_[j] = V @ (c / (e + s))
            self._eig.append((e, V, s))
        return self

    @property
    def noise_variance(self) -> FloatArray:
        """``(m,)`` fitted ``sigma_j^2``."""
        return np.exp(self.log_noise_)

    def predict(self, Phi: FloatArray, with_var: bool = False) -> tuple[FloatArray, FloatArray]:
        """Posterior mean ``(N, m)`` and, with ``with_var``, the latent variance ``(N, m)``
        (``sigma^2 phi^T (A + s I)^{-1} phi``); zeros otherwise."""
        Phi = np.asarray(Phi, dtype=np.float64)
        if Phi.ndim == 2:
            mean = Phi @ self.weights_.T
        else:
            mean = np.einsum("jnf,jf->nj", Phi, self.weights_)
        var = np.zeros_like(mean)
        if with_var:
            for j, (e, V, s) in enumerate(self._eig):
                P = (Phi if Phi.ndim == 2 else Phi[j]) @ V
                var[:, j] = math.exp(self.log_noise_[j]) * np.sum(P**2 / (e + s), axis=1)
        return mean, var

"""One joint's GP: a start kernel plus linear kernels on effect blocks, evidence in closed form.

Used by the model diagnosis (:mod:`mcpilco.models.diagnosis`: one joint's residual torque, a
start kernel plus candidate effect blocks) and, without a start kernel, by the kinematic
chain of :mod:`mcpilco.models.kinematics.chain` (one element of a link's relative pose on
``[1, cos q, sin q]``: Bayesian linear regression).

For output joint ``j`` with residual target ``r = y_j - m_j`` (``m_j``: the nominal torque,
or the learned model's constant prior mean), rows ``1..N``:

.. math::

    r \\sim \\mathcal N\\big(0,\\ K\\big),\\qquad
    K = \\alpha K_0 + \\sum_b \\lambda_b \\Phi_b \\Phi_b^\\top + \\sigma^2 I,

``K_0`` the start model's kernel (the GIP kernel of thesis eq. 3.11 at its fitted
hyperparameters; ``0`` for a nominal physics model), ``Phi_b`` the ``(N, p_b)`` block of
effect ``b`` (a linear kernel ``lambda_b phi^T phi'`` on it, i.e. a Gaussian prior
``w_b ~ N(0, lambda_b I)`` on its weights).

Closed form in the eigenbasis ``K_0 = U S U^T`` (``U = I``, ``S = 0`` without a start
kernel), ``D = alpha S + sigma^2 I``, ``Psi = U^T Phi``, ``rho = U^T r``,
``Lambda = diag(lambda)`` per column:

.. math::

    \\log|K| = \\sum \\log D_{ii} + \\log|B|,\\quad
    B = I + \\Lambda^{1/2} \\Psi^\\top D^{-1} \\Psi \\Lambda^{1/2},

    r^\\top K^{-1} r = \\rho^\\top D^{-1}\\rho - c^\\top B^{-1} c,\\quad
    c = \\Lambda^{1/2}\\Psi^\\top D^{-1}\\rho,

    \\log p(r) = -\\tfrac12 r^\\top K^{-1} r - \\tfrac12 \\log|K| - \\tfrac N2 \\log 2\\pi
    \\quad \\text{(thesis eq. 1.9)}.

Cost per evaluation ``O(N P^2)`` (``P`` = columns of all blocks) after one ``O(N^3)``
eigendecomposition per joint: every candidate block and every hyperparameter value is
cheap. The posterior of the block weights (with the start function marginalised) is
``w | r ~ N(Lambda^{1/2} B^{-1} c, Lambda^{1/2} B^{-1} Lambda^{1/2})``.

Everything is computed in standardised units (``r / s_r``, columns ``/ rms``); evidences are
returned in the original units (``- N log s_r``), weights in the original units.
Hyperparameters ``theta = [log alpha (with K_0), log sigma^2, log lambda_1, ...]``
are fitted by type-II maximum likelihood (L-BFGS-B).
"""

from __future__ import annotations

import contextlib
import math
import sys
from collections.abc import Iterator, Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import solve_triangular
from scipy.optimize import minimize

FloatArray = NDArray[np.float64]

__all__ = ["JointGP", "single_thread"]

LOG_ALPHA_BOUNDS = (-12.0, 6.0)
LOG_NOISE_BOUNDS = (-18.0, 3.0)
LOG_LAMBDA_BOUNDS = (-20.0, 12.0)
DEAD_COLUMN = 1e-8
"""A block column whose rms is below this fraction of the block's largest is treated as zero
(columns are scaled to unit rms; rounding noise must not become a regressor)."""


_CONTROLLER: list = []


def _chol(B: FloatArray) -> FloatArray | None:
    """Cholesky factor of the symmetric ``B = I + ...`` (eigenvalues >= 1 in exact
    arithmetic), with a relative jitter up to ``1e-6 trace/P`` against rounding; ``None``
    when it still fails (the caller treats the point as infeasible)."""
    if B.shape[0] == 0:
        return np.zeros((0, 0))
    B = 0.5 * (B + B.T)
    scale = float(np.trace(B)) / B.shape[0]
    for jitter in (0.0, 1e-12, 1e-9, 1e-6):
        try:
            return np.linalg.cholesky(B + jitter * scale * np.eye(B.shape[0]))
        except np.linalg.LinAlgError:
            continue
    return None


@contextlib.contextmanager
def single_thread() -> Iterator[None]:
    """One BLAS thread (threadpoolctl, when installed), and one torch thread when torch is
    loaded: the matrices of the evidence are tiny and BLAS thread start-up would dominate
    them (on a loaded machine, threads that wait for a core multiply the wall time). Also a
    decorator: ``@single_thread()``."""
    torch = sys.modules.get("torch")
    threads = torch.get_num_threads() if torch is not None else None
    try:
        from threadpoolctl import ThreadpoolController
    except ImportError:  # pragma: no cover - optional
        ThreadpoolController = None
    try:
        if torch is not None:
            torch.set_num_threads(1)
        if ThreadpoolController is None:  # pragma: no cover - optional
            yield
            return
        if not _CONTROLLER:
            _CONTROLLER.append(ThreadpoolController())
        with _CONTROLLER[0].limit(limits=1, user_api="blas"):
            yield
    finally:
        if torch is not None:
            torch.set_num_threads(threads)


class JointGP:
    """Evidence and posterior of one joint's GP (module docstring).

    Args:
        r: ``(N,)`` residual target.
        blocks: the effect blocks ``[(N, p_b), ...]``.
        eig: ``(U (N, N), S (N,))`` of ``K_0`` in original units, or ``None``.
        scale: ``s_r``; default the rms of ``r`` (keep it fixed when comparing shifted
            targets so that evidences stay comparable).
    """

    def __init__(
        self,
        r: FloatArray,
        blocks: Sequence[FloatArray],
        eig: tuple[FloatArray, FloatArray] | None = None,
        scale: float | None = None,
        _shared: dict | None = None,
    ) -> None:
        r = np.asarray(r, dtype=np.float64)
        if not np.all(np.isfinite(r)):
            raise ValueError("the residual target has NaN/inf values")
        self.n = r.shape[0]
        self.scale = float(scale) if scale is not None else float(np.sqrt(np.mean(r**2)) or 1.0)
        self.eig = eig
        self.sizes = [int(b.shape[1]) for b in blocks]
        self._shared = _shared if _shared is not None else {}
        if eig is not None:
            U, S = eig
            self.S = np.clip(S, 0.0, None) / self.scale**2
            if "U" not in self._shared:
                self._shared["U"] = U
        self._set_target(r)
        self.col_scale = np.ones(0)
        self.Psi = np.zeros((self.n if eig is not None else 0, 0))
        self._raw_blocks: list[FloatArray] = []
        for b in blocks:
            self._append(np.asarray(b, dtype=np.float64))

    # ------------------------------------------------------------------ construction
    def _set_target(self, r: FloatArray) -> None:
        self._ls = None
        self.r = r / self.scale
        if self.eig is not None:
            self.rho = self._shared["U"].T @ self.r
        else:
            self.rtr = float(self.r @ self.r)

    def _append(self, block: FloatArray) -> None:
        if block.shape[0] != self.n:
            raise ValueError(f"a block has {block.shape[0]} rows, the target {self.n}")
        if not np.all(np.isfinite(block)):
            raise ValueError("an effect block has NaN/inf values")
        rms = np.sqrt(np.mean(block**2, axis=0))
        # a column that is rounding noise next to the block's largest (e.g. a payload
        # parameter that cannot move this joint) is zeroed, not blown up to unit rms
        alive = rms > DEAD_COLUMN * rms.max(initial=0.0)
        rms = np.where(alive, rms, 1.0)
        scaled = np.where(alive, block / rms, 0.0)
        self._raw_blocks.append(scaled)
        self._ls = None
        self.col_scale = np.concatenate([self.col_scale, rms])
        if self.eig is not None:
            self.Psi = np.concatenate([self.Psi, self._shared["U"].T @ scaled], axis=1)

    def with_block(self, block: FloatArray) -> JointGP:
        """A copy with one more block (shares the eigendecomposition)."""
        new = object.__new__(JointGP)
        new.__dict__.update(self.__dict__)
        new.sizes = [*self.sizes, int(block.shape[1])]
        new._raw_blocks = list(self._raw_blocks)
        new._append(np.asarray(block, dtype=np.float64))
        return new

    def with_target(self, r: FloatArray) -> JointGP:
        """A copy with another target (same scale ``s_r``; a shifted output)."""
        new = object.__new__(JointGP)
        new.__dict__.update(self.__dict__)
        new._set_target(np.asarray(r, dtype=np.float64))
        return new

    # ------------------------------------------------------------------ hyperparameters
    @property
    def has_kernel(self) -> bool:
        return self.eig is not None

    @property
    def n_theta(self) -> int:
        return int(self.has_kernel) + 1 + len(self.sizes)

    def default_theta(self, noise: float | None = None) -> FloatArray:
        """``alpha = 1``, ``sigma^2`` = ``noise`` (original units) or 0.1 of the target
        power, ``lambda_b = 1`` (standardised units)."""
        s2 = 0.1 if noise is None else noise / self.scale**2
        head = [0.0] if self.has_kernel else []
        theta = np.array([*head, math.log(max(s2, 1e-12)), *([0.0] * len(self.sizes))])
        return self._clip(theta)

    def bounds(self) -> list[tuple[float, float]]:
        head = [LOG_ALPHA_BOUNDS] if self.has_kernel else []
        return [*head, LOG_NOISE_BOUNDS, *([LOG_LAMBDA_BOUNDS] * len(self.sizes))]

    def _clip(self, theta: FloatArray) -> FloatArray:
        b = np.array(self.bounds())
        return np.clip(theta, b[:, 0], b[:, 1])

    def _unpack(self, theta: FloatArray) -> tuple[float, float, FloatArray]:
        k = 0
        alpha = 0.0
        if self.has_kernel:
            alpha = math.exp(theta[0])
            k = 1
        s2 = math.exp(theta[k])
        lam = np.repeat(np.exp(theta[k + 1 :]), self.sizes) if self.sizes else np.zeros(0)
        return alpha, s2, lam

    def noise_variance(self, theta: FloatArray) -> float:
        """``sigma^2`` in original units."""
        return self._unpack(theta)[1] * self.scale**2

    # ------------------------------------------------------------------ evidence
    def _parts(self, theta: FloatArray) -> tuple[float, float, FloatArray, FloatArray, FloatArray]:
        """With a start kernel: ``(sum log D, rho^T D^-1 rho, sqrt(Lambda), chol(B), c)``
        (without one, :meth:`_ridge` is the stable counterpart)."""
        alpha, s2, lam = self._unpack(theta)
        sl = np.sqrt(lam)
        D = alpha * self.S + s2
        logdet_d = float(np.sum(np.log(D)))
        quad_d = float(np.sum(self.rho**2 / D))
        A = (self.Psi / D[:, None]).T @ self.Psi
        b = self.Psi.T @ (self.rho / D)
        P = sl.shape[0]
        B = np.eye(P) + sl[:, None] * A * sl[None, :]
        L = _chol(B)
        if L is None:
            raise np.linalg.LinAlgError("B is not positive definite even with jitter")
        return logdet_d, quad_d, sl, L, sl * b

    def _least_squares(self) -> tuple[FloatArray, FloatArray, float]:
        """No start kernel: ``Phi = Q R`` (thin QR of the scaled blocks), ``c = Q^T r`` and
        ``|r - Q c|^2``, computed once per target (cached)."""
        if self._ls is None:
            full = np.concatenate(self._raw_blocks, axis=1)
            Q, R = np.linalg.qr(full)
            c = Q.T @ self.r
            rp = self.r - Q @ c
            self._ls = (R, c, float(rp @ rp))
        return self._ls

    def _ridge(self, s2: float, sl: FloatArray) -> tuple[FloatArray, FloatArray, float, float]:
        """No start kernel, stable ridge solve with ``w = sqrt(Lambda) z``, ``z ~ N(0, I)``.

        ``M = [R sqrt(Lambda) / sigma ; I] = Q_2 R_2`` gives ``B = M^T M = R_2^T R_2``,
        ``z = R_2^-1 Q_2^T [c / sigma ; 0]`` and ``|r - Phi w|^2 = |r - Q c|^2 + |c - R w|^2``
        without forming ``Phi^T Phi / sigma^2`` (whose condition number, squared, ruins the
        cancellation in ``r^T K^-1 r`` when the noise is small and the fit close).

        Returns:
            ``(z, B^-1, log|B|, |r - Phi w|^2)``.
        """
        R, c, rp2 = self._least_squares()
        P = sl.shape[0]
        m = R.shape[0]
        sig = math.sqrt(s2)
        # one Householder QR of [M, [c / sigma; 0]]: its R holds R_2 and Q_2^T [c / sigma; 0]
        A = np.zeros((m + P, P + 1))
        A[:m, :P] = R * (sl / sig)[None, :]
        A[m + np.arange(P), np.arange(P)] = 1.0
        A[:m, P] = c / sig
        Ra = np.linalg.qr(A, mode="r")
        R2 = Ra[:P, :P]
        sol = solve_triangular(R2, np.column_stack([Ra[:P, P], np.eye(P)]), check_finite=False)
        z, R2inv = sol[:, 0], sol[:, 1:]
        Binv = R2inv @ R2inv.T
        logdet_b = 2.0 * float(np.sum(np.log(np.abs(np.diag(R2)))))
        e = c - R @ (sl * z)
        return z, Binv, logdet_b, rp2 + float(e @ e)

    def log_evidence(self, theta: FloatArray) -> float:
        """``log p(r | theta)`` in original units (module docstring)."""
        return self.value_and_grad(theta)[0]

    def value_and_grad(self, theta: FloatArray) -> tuple[float, FloatArray]:
        """``log p(r | theta)`` and its gradient w.r.t. ``theta``.

        With ``G = (Lambda^-1 + Psi^T D^-1 Psi)^-1`` and ``mu = G Psi^T D^-1 rho`` (posterior
        mean of the standardised weights), ``a = D^-1 (rho - Psi mu) = K^-1 r``:
        ``dL/dlog lambda_b = (|mu_b|^2 / lambda_b - p_b + tr G_bb / lambda_b) / 2``,
        ``dL/dlog sigma^2 = sigma^2 (|a|^2 - tr K^-1) / 2``,
        ``dL/dlog alpha = alpha (a^T S a - tr(K^-1 S)) / 2`` (Rasmussen & Williams eq. 5.9).
        """
        theta = np.asarray(theta, dtype=np.float64)
        if not self.has_kernel:
            return self._value_and_grad_blocks(theta)
        alpha, s2, lam = self._unpack(theta)
        P = lam.shape[0]
        D = alpha * self.S + s2
        Dinv = 1.0 / D
        logdet_d = float(np.sum(np.log(D)))
        quad_d = float(np.sum(self.rho**2 * Dinv))
        PD = self.Psi * Dinv[:, None]
        A = PD.T @ self.Psi
        v = PD.T @ self.rho
        grad = np.zeros(theta.shape[0])
        k = 1
        if P:
            sl = np.sqrt(lam)
            B = np.eye(P) + sl[:, None] * A * sl[None, :]
            L = _chol(B)
            if L is None:
                return -math.inf, np.zeros(theta.shape[0])
            Linv = np.linalg.inv(L)
            Binv = Linv.T @ Linv
            G = sl[:, None] * Binv * sl[None, :]
            mu = G @ v
            quad = quad_d - float(v @ mu)
            logdet = logdet_d + 2.0 * float(np.sum(np.log(np.diag(L))))
            gdiag = np.diag(G)
            off = 0
            for b, p in enumerate(self.sizes):
                lb = lam[off]
                mb = mu[off : off + p]
                grad[k + 1 + b] = 0.5 * (
                    float(mb @ mb) / lb - p + float(np.sum(gdiag[off : off + p])) / lb
                )
                off += p
        else:
            mu = np.zeros(0)
            G = np.zeros((0, 0))
            quad, logdet = quad_d, logdet_d
        # noise and start-kernel scale
        e = self.rho - self.Psi @ mu if P else self.rho
        a = e * Dinv
        tr_kinv = float(np.sum(Dinv))
        if P:
            A2 = PD.T @ PD
            tr_kinv -= float(np.sum(G * A2))
        grad[k] = 0.5 * s2 * (float(a @ a) - tr_kinv)
        tr_ks = float(np.sum(self.S * Dinv))
        if P:
            AS = (PD * self.S[:, None]).T @ PD
            tr_ks -= float(np.sum(G * AS))
        grad[0] = 0.5 * alpha * (float(np.sum(self.S * a * a)) - tr_ks)
        lml = -0.5 * quad - 0.5 * logdet - 0.5 * self.n * math.log(2 * math.pi)
        return lml - self.n * math.log(self.scale), grad

    def _value_and_grad_blocks(self, theta: FloatArray) -> tuple[float, FloatArray]:
        """:meth:`value_and_grad` without a start kernel, ``K = sigma^2 I + Phi Lambda Phi^T``
        through :meth:`_ridge`: ``r^T K^-1 r = |r - Phi w|^2 / sigma^2 + |z|^2``,
        ``log|K| = N log sigma^2 + log|B|``, ``tr K^-1 = (N - P + tr B^-1) / sigma^2`` and
        ``dL/dlog lambda_b = (|z_b|^2 - p_b + tr (B^-1)_bb) / 2``."""
        _, s2, lam = self._unpack(theta)
        P = lam.shape[0]
        grad = np.zeros(theta.shape[0])
        if P:
            z, Binv, logdet_b, ee = self._ridge(s2, np.sqrt(lam))
            quad = ee / s2 + float(z @ z)
            tr_kinv = (self.n - P + float(np.trace(Binv))) / s2
            bdiag = np.diag(Binv)
            off = 0
            for b, p in enumerate(self.sizes):
                zb = z[off : off + p]
                grad[1 + b] = 0.5 * (float(zb @ zb) - p + float(np.sum(bdiag[off : off + p])))
                off += p
        else:
            logdet_b, ee = 0.0, self.rtr
            quad, tr_kinv = ee / s2, self.n / s2
        grad[0] = 0.5 * s2 * (ee / s2**2 - tr_kinv)
        logdet = self.n * math.log(s2) + logdet_b
        lml = -0.5 * quad - 0.5 * logdet - 0.5 * self.n * math.log(2 * math.pi)
        return lml - self.n * math.log(self.scale), grad

    def optimise(
        self,
        theta0: FloatArray,
        free: Sequence[bool] | None = None,
        starts: Sequence[FloatArray] = (),
        maxiter: int = 200,
    ) -> tuple[FloatArray, float]:
        """Type-II ML over the ``free`` coordinates from ``theta0`` (and extra ``starts``),
        L-BFGS-B with the analytic gradient of :meth:`value_and_grad`.

        Returns:
            ``(theta, log evidence)`` of the best start.
        """
        theta0 = self._clip(np.asarray(theta0, dtype=np.float64))
        free_mask = np.ones(self.n_theta, bool) if free is None else np.asarray(free, bool)
        if not free_mask.any():
            return theta0, self.log_evidence(theta0)
        bounds = [b for b, f in zip(self.bounds(), free_mask, strict=True) if f]
        best = (theta0, self.log_evidence(theta0))
        for start in [theta0, *[self._clip(np.asarray(s, dtype=np.float64)) for s in starts]]:

            def neg(x: FloatArray, start: FloatArray = start) -> tuple[float, FloatArray]:
                th = start.copy()
                th[free_mask] = x
                v, g = self.value_and_grad(th)
                if not math.isfinite(v):
                    return 1e300, np.zeros_like(x)
                return -v, -g[free_mask]

            res = minimize(
                neg,
                start[free_mask],
                jac=True,
                method="L-BFGS-B",
                bounds=bounds,
                options={"maxiter": maxiter},
            )
            th = start.copy()
            th[free_mask] = res.x
            val = -float(res.fun)
            if val > best[1]:
                best = (th, val)
        return best

    # ------------------------------------------------------------------ posterior
    def weights(self, theta: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Posterior mean ``(P,)`` and covariance ``(P, P)`` of all block weights, original
        units (columns not scaled)."""
        theta = np.asarray(theta, dtype=np.float64)
        if not self.sizes:
            return np.zeros(0), np.zeros((0, 0))
        if self.has_kernel:
            _, _, sl, L, c = self._parts(theta)
            Linv = np.linalg.inv(L)
            Binv = Linv.T @ Linv
            mean = sl * (Binv @ c)
        else:
            _, s2, lam = self._unpack(theta)
            sl = np.sqrt(lam)
            z, Binv, _, _ = self._ridge(s2, sl)
            mean = sl * z
        cov = sl[:, None] * Binv * sl[None, :]
        f = self.scale / self.col_scale
        return mean * f, cov * f[:, None] * f[None, :]

    def prior_variance(self, theta: FloatArray) -> FloatArray:
        """``(P,)`` prior variance ``lambda_b`` of every block weight, original units."""
        _, _, lam = self._unpack(np.asarray(theta, dtype=np.float64))
        f = self.scale / self.col_scale
        return lam * f**2

    def information(self, theta: FloatArray) -> FloatArray:
        """``(P, P)`` the data's information on the block weights, original units:
        ``Phi^T (alpha K_0 + sigma^2 I)^-1 Phi``, the curvature of the log-likelihood of the
        weights with the start function marginalised (the posterior precision without the
        prior's ``Lambda^-1``). A direction it does not curve is one the data do not fix."""
        theta = np.asarray(theta, dtype=np.float64)
        if not self.sizes:
            return np.zeros((0, 0))
        alpha, s2, _ = self._unpack(theta)
        if self.has_kernel:
            D = alpha * self.S + s2
            A = (self.Psi / D[:, None]).T @ self.Psi
        else:
            R = self._least_squares()[0]
            A = R.T @ R / s2
        f = self.scale / self.col_scale
        return A / f[:, None] / f[None, :]

    def block_slices(self) -> list[slice]:
        out, k = [], 0
        for p in self.sizes:
            out.append(slice(k, k + p))
            k += p
        return out

    def solve(self, theta: FloatArray, V: FloatArray) -> FloatArray:
        """``K^{-1} V`` in standardised units for ``V (N, m)`` (Woodbury in the eigenbasis)."""
        alpha, s2, lam = self._unpack(theta)
        sl = np.sqrt(lam)
        if self.has_kernel:
            U = self._shared["U"]
            D = alpha * self.S + s2
            W = (U.T @ V) / D[:, None]
            if sl.size:
                _, _, _, L, _ = self._parts(theta)
                T = sl[:, None] * (self.Psi.T @ W)
                T = np.linalg.solve(L.T, np.linalg.solve(L, T))
                W = W - (self.Psi * sl[None, :]) @ T / D[:, None]
            return U @ W
        W = V / s2
        if sl.size:
            full = np.concatenate(self._raw_blocks, axis=1)
            _, Binv, _, _ = self._ridge(s2, sl)
            W = W - (full * sl[None, :]) @ (Binv @ (sl[:, None] * (full.T @ W))) / s2
        return W

    def predict(
        self,
        theta: FloatArray,
        test_blocks: Sequence[FloatArray],
        K0_cross: FloatArray | None = None,
        K0_diag: FloatArray | None = None,
        with_var: bool = True,
        n_test: int | None = None,
    ) -> tuple[FloatArray, FloatArray]:
        """Posterior mean and latent variance of ``r`` at test rows, original units.

        Args:
            test_blocks: the blocks at the test rows (same order and widths).
            K0_cross: ``(N, N*)`` start kernel between training and test rows (original
                units); required with a start kernel.
            K0_diag: ``(N*,)`` its prior variance at the test rows.
            n_test: ``N*`` (needed when there is neither a block nor a start kernel).
        """
        alpha, _, lam = self._unpack(theta)
        if n_test is None:
            n_test = (
                test_blocks[0].shape[0]
                if test_blocks
                else (K0_cross.shape[1] if K0_cross is not None else 0)
            )
        Phis = (
            np.concatenate(test_blocks, axis=1) / self.col_scale
            if test_blocks
            else np.zeros((n_test, 0))
        )
        if not self.has_kernel:
            w_mean, w_cov = self.weights(theta)
            f = self.scale / self.col_scale
            mean = Phis @ (w_mean / f) * self.scale
            var = np.einsum("ij,jk,ik->i", Phis, w_cov / (f[:, None] * f[None, :]), Phis)
            return mean, var * self.scale**2
        if K0_cross is None or K0_diag is None:
            raise ValueError("a start kernel needs K0_cross and K0_diag for prediction")
        train = (
            np.concatenate(self._raw_blocks, axis=1) if self._raw_blocks else np.zeros((self.n, 0))
        )
        k_star = alpha * K0_cross / self.scale**2 + (train * lam[None, :]) @ Phis.T
        beta = self.solve(theta, self.r[:, None])[:, 0]
        mean = k_star.T @ beta * self.scale
        if not with_var:
            return mean, np.zeros(n_test)
        prior = alpha * K0_diag / self.scale**2 + np.einsum("ij,j,ij->i", Phis, lam, Phis)
        var = prior - np.einsum("ij,ij->j", k_star, self.solve(theta, k_star))
        return mean, np.clip(var, 0.0, None) * self.scale**2

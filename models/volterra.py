r"""Volterra series identification with polynomial-kernel GPs (thesis chapter 6).

Glossary (symbols as in the thesis, section 6.2-6.5):

==================  ==========================================================================
symbol              meaning
==================  ==========================================================================
:math:`u_k`         scalar input at time :math:`k`
:math:`m`           system memory (number of past lags); the regressor has :math:`m+1` entries
:math:`\mathbf u_k` lagged input :math:`[u_k, u_{k-1}, \dots, u_{k-m}]^T` (:func:`lag_matrix`)
:math:`r`           Volterra order (highest monomial degree)
:math:`z_k`         noiseless output; :math:`y_k = z_k + e_k`, :math:`e_k\sim N(0,\sigma_n^2)`
PK                  :math:`K^{(r)}_{pk} = \sum_{i=1}^r (\mathbf u^T\Sigma^{(i)}\mathbf u')^i+\rho_0`
                    (6.18)
IPK                 :math:`(1 + \mathbf u^T\Sigma\mathbf u')^r` (6.23)
MPK                 :math:`K^{(r)}_{mpk} = \sum_{i=1}^r \rho_i\prod_{p=1}^i
                    \mathbf u^T\Sigma_p^{(i)}\mathbf u' + \rho_0` (6.24)-(6.25)
SED-MPK             :math:`K^{(r)}_{sed} = \sum_{i=1}^r \rho_i\prod_{p=1}^i
                    \mathbf u^T\Sigma_p^{(i)}\mathbf u' + \rho_0`,
                    :math:`\Sigma_p(i,j)=e^{-\alpha_p|i-j|}e^{-\beta_p(i+j)}` (6.29)-(6.30);
                    tied (6.35): all :math:`\alpha_p=\alpha`, :math:`\beta_p=\beta`
Fit%                :math:`100(1-\|z-\hat z\|_1/\|z-\bar z\|_1)` (section 6.5.1)
==================  ==========================================================================

Convention for the first :math:`m` samples: a data record is assumed to start **from rest**
(:math:`u_k = 0` for :math:`k < 0`), so :func:`lag_matrix` pads with zeros by default and
returns one regressor per sample. The two benchmark systems here (:func:`spinelli_system`,
eq. 6.36, and :func:`wiener_system`, eq. 6.38) are simulated under the same convention, so the
zero-padded regressors are exact for the FIR system (6.36) and exact up to the truncation of the
impulse response after :math:`m` taps for the Wiener system. ``initial="drop"`` instead drops
the first :math:`m` samples (no assumption on the past).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

import numpy as np
import torch
from scipy.signal import lfilter

__all__ = [
    "KINDS",
    "VolterraGP",
    "fit_percent",
    "lag_matrix",
    "SPINELLI_TERMS",
    "spinelli_monomials",
    "spinelli_system",
    "volterra_kernel_factory",
    "wiener_system",
    "WIENER_B",
    "WIENER_A",
]

#: Kernel families accepted by :class:`VolterraGP` and :func:`volterra_kernel_factory`.
KINDS = ("pk", "ipk", "mpk", "sed_mpk", "sed_mpk_tied")

#: Numerator and denominator of :math:`G(q) = 10q^{-1}/(1 - 1.8036q^{-1} + 0.8338q^{-2})`
#: (eq. 6.38, Stoddard and Welsh 2018) in :func:`scipy.signal.lfilter` convention.
WIENER_B = (0.0, 10.0)
WIENER_A = (1.0, -1.8036, 0.8338)


# --------------------------------------------------------------------------------------------
# data: regressors, systems, metric
# --------------------------------------------------------------------------------------------
def _as_signal(u: np.ndarray | torch.Tensor | list[float], name: str = "u") -> np.ndarray:
    """Return ``u`` as a finite 1-D float64 array or raise ``ValueError``."""
    if isinstance(u, torch.Tensor):
        u = u.detach().cpu().numpy()
    arr = np.asarray(u, dtype=np.float64)
    if arr.ndim == 2 and 1 in arr.shape:
        arr = arr.reshape(-1)
    if arr.ndim != 1:
        raise ValueError(
            f"{name} must be a 1-D signal of shape (N,), got shape {arr.shape}; "
            "pass one scalar input sequence"
        )
    if arr.size == 0:
        raise ValueError(f"{name} is empty; pass at least one sample")
    if not np.all(np.isfinite(arr)):
        bad = int(np.flatnonzero(~np.isfinite(arr))[0])
        raise ValueError(f"{name} contains NaN/inf (first at index {bad}); clean the signal")
    return arr


def lag_matrix(
    u: np.ndarray | torch.Tensor | list[float],
    memory: int,
    *,
    initial: Literal["zeros", "drop"] = "zeros",
) -> np.ndarray:
    r"""Lagged-input (regressor) matrix of a scalar signal.

    Row :math:`k` is :math:`\mathbf u_k = [u_k, u_{k-1}, \dots, u_{k-m}]`, :math:`m` =
    ``memory``.

    Args:
        u: input signal, shape ``(N,)``.
        memory: :math:`m \ge 0`, number of past lags.
        initial: ``"zeros"`` (default): the record starts from rest, :math:`u_k = 0` for
            :math:`k<0`; returns ``(N, m+1)``. ``"drop"``: only rows whose lags are all inside
            the record; returns ``(N-m, m+1)``, row ``j`` corresponds to time ``k = j + m``.

    Returns:
        float64 array of shape ``(N, m+1)`` or ``(N-m, m+1)``.
    """
    if isinstance(memory, bool) or not isinstance(memory, int | np.integer) or memory < 0:
        raise ValueError(f"memory must be a non-negative int, got {memory!r}")
    arr = _as_signal(u)
    n = arr.shape[0]
    padded = np.concatenate([np.zeros(memory), arr])
    # column tau holds u_{k - tau}: padded[m + k - tau]
    cols = [padded[memory - tau : memory - tau + n] for tau in range(memory + 1)]
    out = np.stack(cols, axis=1)
    if initial == "zeros":
        return out
    if initial == "drop":
        if n <= memory:
            raise ValueError(
                f"initial='drop' needs more than memory={memory} samples, got N={n}; "
                "use a longer record or initial='zeros'"
            )
        return out[memory:]
    raise ValueError(f"initial must be 'zeros' or 'drop', got {initial!r}")


def fit_percent(z: np.ndarray | torch.Tensor, z_hat: np.ndarray | torch.Tensor) -> float:
    r"""Percentage fit :math:`100\,(1 - \|z-\hat z\|_1 / \|z - \bar z\|_1)` (thesis 6.5.1).

    100 for a perfect prediction, 0 for the constant prediction :math:`\bar z`, negative when
    worse than the mean. ``z`` is the noiseless reference output.
    """
    z_arr = _as_signal(z, "z")
    zh_arr = _as_signal(z_hat, "z_hat")
    if z_arr.shape != zh_arr.shape:
        raise ValueError(f"z has shape {z_arr.shape} but z_hat has shape {zh_arr.shape}")
    denom = np.abs(z_arr - z_arr.mean()).sum()
    if denom == 0.0:
        raise ValueError("z is constant: Fit% is undefined (||z - mean(z)||_1 = 0)")
    return float(100.0 * (1.0 - np.abs(z_arr - zh_arr).sum() / denom))


def spinelli_system(u: np.ndarray | torch.Tensor | list[float]) -> np.ndarray:
    r"""Order-3, memory-6 Volterra system of experiment 1 (thesis eq. 6.36), from rest.

    .. math::
        z_k = u_k + 0.6u_{k-1} + 0.35(u_{k-2}+u_{k-4}) - 0.25u_{k-3}^2 + 0.2(u_{k-5}+u_{k-6})
              + 0.9u_{k-3} + 0.25u_ku_{k-1} + 0.75u_{k-2}^3 - u_{k-1}u_{k-2}
              + 0.5(u_k^2 + u_ku_{k-2} + u_{k-1}u_{k-3})

    with :math:`u_k = 0` for :math:`k<0`. Returns the noiseless output, shape ``(N,)``.
    """
    x = lag_matrix(u, 6)
    u0, u1, u2, u3, u4, u5, u6 = (x[:, i] for i in range(7))
    return (
        u0
        + 0.6 * u1
        + 0.35 * (u2 + u4)
        - 0.25 * u3**2
        + 0.2 * (u5 + u6)
        + 0.9 * u3
        + 0.25 * u0 * u1
        + 0.75 * u2**3
        - u1 * u2
        + 0.5 * (u0**2 + u0 * u2 + u1 * u3)
    )


#: The 14 monomials of system (6.36) with their coefficients: ``(lags, c)`` stands for
#: :math:`c \prod_{\tau \in \text{lags}} u_{k-\tau}` (e.g. ``((2, 2, 2), 0.75)`` is
#: :math:`0.75 u_{k-2}^3`). A second writing of :func:`spinelli_system` (tests compare them).
SPINELLI_TERMS: tuple[tuple[tuple[int, ...], float], ...] = (
    ((0,), 1.0),
    ((1,), 0.6),
    ((2,), 0.35),
    ((3,), 0.9),
    ((4,), 0.35),
    ((5,), 0.2),
    ((6,), 0.2),
    ((3, 3), -0.25),
    ((0, 1), 0.25),
    ((2, 2, 2), 0.75),
    ((1, 2), -1.0),
    ((0, 0), 0.5),
    ((0, 2), 0.5),
    ((1, 3), 0.5),
)


def spinelli_monomials(u: np.ndarray | torch.Tensor | list[float]) -> np.ndarray:
    r"""The regressors :math:`\prod_{\tau} u_{k-\tau}` of :data:`SPINELLI_TERMS`, from rest.

    Returns ``(N, 14)``; ``spinelli_monomials(u) @ c`` with the terms' coefficients ``c`` is
    :func:`spinelli_system` ``(u)``. Least squares on these columns is the oracle of the
    Volterra benchmark: the estimator that knows which monomials (6.36) holds.
    """
    x = lag_matrix(u, 6)
    return np.stack([np.prod(x[:, list(lags)], axis=1) for lags, _ in SPINELLI_TERMS], axis=1)


def wiener_system(u: np.ndarray | torch.Tensor | list[float], order: int) -> np.ndarray:
    r"""Wiener system of experiment 2 (thesis eq. 6.38), from rest.

    .. math::
        x_k = G(q)u_k,\quad G(q) = \frac{10q^{-1}}{1 - 1.8036q^{-1} + 0.8338q^{-2}},\qquad
        z_k = \sum_{i=1}^{r} x_k^i

    (:math:`q^{-1}` the backward shift; poles :math:`0.9018 \pm 0.1535j`, modulus 0.913, so
    the impulse response decays below 0.4% of its peak after 70 taps.)
    """
    if isinstance(order, bool) or not isinstance(order, int | np.integer) or order < 1:
        raise ValueError(f"order must be a positive int, got {order!r}")
    x = lfilter(WIENER_B, WIENER_A, _as_signal(u))
    return sum(x**i for i in range(1, order + 1))


# --------------------------------------------------------------------------------------------
# kernels
# --------------------------------------------------------------------------------------------
KernelFactory = Callable[[torch.Size], "gpytorch.kernels.Kernel"]  # noqa: F821


def volterra_kernel_factory(kind: str, order: int, memory: int) -> KernelFactory:
    r"""Kernel factory (``batch_shape -> gpytorch Kernel``) for a Volterra model of order r.

    ``kind`` (all built by :func:`mcpilco.models.kernels.volterra_kernel`):

    * ``"pk"``: :math:`\sum_{i=1}^r (\mathbf u^T\Sigma^{(i)}\mathbf u')^i + \rho_0` (6.18),
      one diagonal :math:`\Sigma^{(i)}` (ARD) per order.
    * ``"ipk"``: :math:`(1 + \mathbf u^T\Sigma\mathbf u')^r` (6.23), diagonal :math:`\Sigma`,
      offset fixed to 1 as in the thesis.
    * ``"mpk"``: :math:`\sum_{i=1}^r \rho_i k^{(i)}_{mpk} + \rho_0` (6.25), homogeneous
      blocks (6.24) with the hierarchical parametrisation (6.28).
    * ``"sed_mpk"``: :math:`\sum_{i=1}^r \rho_i k^{(i)}_{sed} + \rho_0` (6.30), every factor
      :math:`p` of block :math:`i` with its own :math:`(\alpha_p, \beta_p)` (hierarchical).
    * ``"sed_mpk_tied"``: the special case (6.35) used in the thesis' experiment 2, all
      :math:`\alpha_p = \alpha`, :math:`\beta_p = \beta`:
      :math:`\sum_{i=1}^r \rho_i (\mathbf u^T\Sigma(\alpha,\beta)\mathbf u')^i + \rho_0`
      (:class:`~mcpilco.models.kernels.TiedSEDMPKernel`, :math:`r + 3` hyperparameters).
    """
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    if isinstance(order, bool) or not isinstance(order, int | np.integer) or order < 1:
        raise ValueError(f"order must be a positive int, got {order!r}")
    if isinstance(memory, bool) or not isinstance(memory, int | np.integer) or memory < 0:
        raise ValueError(f"memory must be a non-negative int, got {memory!r}")
    order, memory = int(order), int(memory)

    def factory(batch_shape: torch.Size = torch.Size([])):  # noqa: B008
        from mcpilco.models.kernels import volterra_kernel

        return volterra_kernel(kind, order, memory, batch_shape=batch_shape)

    return factory


# --------------------------------------------------------------------------------------------
# estimator
# --------------------------------------------------------------------------------------------
class VolterraGP:
    r"""GP estimator of a Volterra series of order ``order`` and memory ``memory``.

    ``fit(u, y)`` builds the regressors :math:`\mathbf u_k` with :func:`lag_matrix` (record
    from rest), scales them by one scalar (the training input std, so all lags keep the same
    scale and the polynomial structure is unchanged), standardises :math:`y` with the full
    training set statistics, trains the hyperparameters of the ``kind`` kernel
    (:func:`volterra_kernel_factory`) by exact marginal likelihood (Adam, then L-BFGS) on at
    most ``ml_points`` randomly chosen samples, then conditions the GP on all samples.
    ``predict(u)`` returns the posterior mean of :math:`z` for a new record from rest.

    Args:
        kind: one of :data:`KINDS` (see :func:`volterra_kernel_factory`).
        order: Volterra order :math:`r`.
        memory: system memory :math:`m`.
        ml_points: size of the random subset used for marginal-likelihood training (``None``:
            all samples).
        adam_iters, adam_lr, lbfgs_iters: optimiser budget passed to ``GPRegressor.fit``.
        noise_init: initial noise variance in standardised output units.
        seed: seed of the subset draw.
    """

    def __init__(
        self,
        kind: str,
        order: int,
        memory: int,
        *,
        ml_points: int | None = None,
        adam_iters: int = 200,
        adam_lr: float = 0.05,
        lbfgs_iters: int = 50,
        noise_init: float = 0.1,
        seed: int = 0,
    ) -> None:
        if kind not in KINDS:
            raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
        if ml_points is not None and ml_points < 2:
            raise ValueError(f"ml_points must be >= 2 or None, got {ml_points}")
        self.kind = kind
        self.order = int(order)
        self.memory = int(memory)
        self.ml_points = ml_points
        self.adam_iters = adam_iters
        self.adam_lr = adam_lr
        self.lbfgs_iters = lbfgs_iters
        self.noise_init = noise_init
        self.seed = seed
        self.kernel_factory = volterra_kernel_factory(kind, self.order, self.memory)

    # ---- helpers ---------------------------------------------------------------------------
    def features(self, u: np.ndarray | torch.Tensor | list[float]) -> np.ndarray:
        """Scaled regressors of a record from rest, shape ``(N, memory+1)`` (after fit)."""
        self._check_fitted()
        return lag_matrix(u, self.memory) / self.u_scale_

    def _check_fitted(self) -> None:
        if not hasattr(self, "gp_"):
            raise RuntimeError("VolterraGP is not fitted; call fit(u, y) first")

    # ---- API -------------------------------------------------------------------------------
    def fit(
        self, u: np.ndarray | torch.Tensor | list[float], y: np.ndarray | torch.Tensor
    ) -> VolterraGP:
        """Train hyperparameters by marginal likelihood and condition on ``(u, y)``."""
        from mcpilco.models.gp import GPRegressor

        u_arr = _as_signal(u, "u")
        y_arr = _as_signal(y, "y")
        if u_arr.shape != y_arr.shape:
            raise ValueError(
                f"u has {u_arr.shape[0]} samples but y has {y_arr.shape[0]}; pass one output "
                "sample per input sample"
            )
        self.u_scale_ = float(u_arr.std()) or 1.0
        x = lag_matrix(u_arr, self.memory) / self.u_scale_
        self.y_mean_ = float(y_arr.mean())
        self.y_std_ = float(y_arr.std())
        if self.y_std_ == 0.0:
            raise ValueError("y is constant; nothing to identify")
        ys = (y_arr - self.y_mean_) / self.y_std_

        n = x.shape[0]
        gp = GPRegressor(
            self.kernel_factory,
            standardize_x=False,
            standardize_y=False,
            noise_init=self.noise_init,
        )
        fit_kw = dict(adam_iters=self.adam_iters, adam_lr=self.adam_lr)
        if self.ml_points is not None and n > self.ml_points:
            rng = np.random.default_rng(self.seed)
            idx = np.sort(rng.choice(n, size=self.ml_points, replace=False))
            gp.fit(x[idx], ys[idx], lbfgs_iters=self.lbfgs_iters, **fit_kw)
            # condition on all samples at the trained hyperparameters (no further training)
            gp.fit(x, ys, adam_iters=0, lbfgs_iters=0)
        else:
            gp.fit(x, ys, lbfgs_iters=self.lbfgs_iters, **fit_kw)
        self.gp_ = gp
        return self

    def predict(self, u: np.ndarray | torch.Tensor | list[float]) -> np.ndarray:
        r"""Posterior mean of the noiseless output for a record from rest, shape ``(N,)``.

        Mean only: :math:`\hat z = k(\mathbf U_*, \mathbf U)(K + \sigma_n^2 I)^{-1}\tilde y`
        (rescaled) via ``GPRegressor.predict_mean``, which skips the :math:`L^{-1}` and
        variance products of ``GPRegressor.predict`` (they dominate at N = 3500 and the Fit
        does not need them). :meth:`predict_gp` gives mean and variance.
        """
        self._check_fitted()
        mean = self.gp_.predict_mean(self.features(u))
        mean = mean.detach().cpu().numpy().reshape(-1)
        return self._to_output_units(mean)

    def predict_gp(
        self, u: np.ndarray | torch.Tensor | list[float]
    ) -> tuple[np.ndarray, np.ndarray]:
        """Posterior mean and latent variance of the output via ``GPRegressor.predict``."""
        x = self.features(u)
        mean, var = self.gp_.predict(x)
        mean = self._to_output_units(mean.detach().cpu().numpy().reshape(-1))
        return mean, var.detach().cpu().numpy().reshape(-1) * self.y_std_**2

    def _to_output_units(self, mean: np.ndarray) -> np.ndarray:
        out = mean * self.y_std_ + self.y_mean_
        if not np.all(np.isfinite(out)):
            raise FloatingPointError(
                f"VolterraGP({self.kind}) produced non-finite predictions; the fitted "
                "hyperparameters are degenerate (try more ML iterations or another seed)"
            )
        return out

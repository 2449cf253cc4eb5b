"""Exact multi-output GP regression on GPyTorch (float64, full-batch Cholesky).

Glossary (thesis ch. 5 / standard GP regression; one independent GP per output :math:`b`):

* data :math:`X \\in R^{N \\times d}`, :math:`Y \\in R^{N \\times m}`, standardised per column:
  :math:`\\tilde X = (X - \\mu_x) / s_x`, :math:`\\tilde y_b = (y_b - \\mu_{y,b}) / s_{y,b}`.
* prior :math:`\\tilde y_b \\sim N(0, K_b + \\sigma_{n,b}^2 I)`,
  :math:`K_b = k_b(\\tilde X, \\tilde X)`;
  the kernel comes from ``kernel_factory(torch.Size([m]))`` (batched hyperparameters).
* hyperparameters :math:`\\theta` maximise the exact log marginal likelihood

  .. math::
      \\log p(\\tilde y_b \\mid \\theta) = -\\tfrac12 \\tilde y_b^T (K_b + \\sigma_{n,b}^2 I)^{-1}
      \\tilde y_b - \\tfrac12 \\log\\lvert K_b + \\sigma_{n,b}^2 I \\rvert - \\tfrac N2 \\log 2\\pi

  with Adam, then L-BFGS (strong-Wolfe line search); GPyTorch's solves are forced onto the
  Cholesky path (``max_cholesky_size`` above N, ``fast_computations`` off).
* posterior (see :mod:`mcpilco.models.gp.predictor`) in original units
  :math:`m_b = s_{y,b} \\tilde m_b + \\mu_{y,b}`, :math:`v_b = s_{y,b}^2 \\tilde v_b`.
"""

from __future__ import annotations

import contextlib
import math
import os
import warnings
from collections.abc import Callable, Iterator, Sequence

import gpytorch
import numpy as np
import torch
from linear_operator.utils.errors import NanError, NotPSDError
from torch import Tensor
from tqdm.auto import tqdm

from mcpilco.models.gp.dense import dense_covar, dense_diag
from mcpilco.models.gp.linalg import CHOLESKY_FIX_HINT, JITTER_MAX, JITTER_START, jittered_cholesky
from mcpilco.models.gp.predictor import CachedPredictor
from mcpilco.models.gp.subset import greedy_subset
from mcpilco.models.gp.validation import (
    as_tensor_2d,
    check_finite_columns,
    check_magnitude_columns,
    check_targets_vary,
)
from mcpilco.models.torch_files import atomic_torch_save, load_torch_file

__all__ = ["BatchIndependentExactGP", "GPRegressor", "KernelFactory", "exact_gp_settings"]

KernelFactory = Callable[[torch.Size], gpytorch.kernels.Kernel]
"""Builds the kernel for ``batch_shape=torch.Size([m])`` (one independent GP per output)."""

MAX_CHOLESKY_SIZE = 100_000
"""GPyTorch uses Cholesky (not CG / Lanczos) for all matrices up to this size."""

_FORMAT = "mcpilco.gp.GPRegressor/1"


@contextlib.contextmanager
def _default_dtype(dtype: torch.dtype) -> Iterator[None]:
    """Temporarily set torch's default dtype (so factories build float64 parameters)."""
    previous = torch.get_default_dtype()
    torch.set_default_dtype(dtype)
    try:
        yield
    finally:
        torch.set_default_dtype(previous)


@contextlib.contextmanager
def exact_gp_settings(jitter: float = JITTER_START) -> Iterator[None]:
    """GPyTorch settings for exact inference: Cholesky solves, exact log-det, no fast variances.

    ``jitter`` (absolute, on standardised data where the kernel diagonal is O(1)) is the first
    value GPyTorch's ``psd_safe_cholesky`` adds on a failed Cholesky; it then escalates x10 up to
    ``JITTER_MAX / JITTER_START`` times that, warning each time with the jitter used.
    """
    tries = round(math.log10(JITTER_MAX / JITTER_START)) + 1
    with (
        gpytorch.settings.max_cholesky_size(MAX_CHOLESKY_SIZE),
        gpytorch.settings.fast_computations(
            covar_root_decomposition=False, log_prob=False, solves=False
        ),
        gpytorch.settings.fast_pred_var(False),
        gpytorch.settings.cholesky_jitter(float_value=jitter, double_value=jitter),
        gpytorch.settings.cholesky_max_tries(tries),
    ):
        yield


class BatchIndependentExactGP(gpytorch.models.ExactGP):
    """``m`` independent exact GPs in one batch: zero mean, kernel with batch shape ``[m]``.

    Args:
        train_x: ``(m, N, d)`` standardised inputs (the same rows for every output).
        train_y: ``(m, N)`` standardised targets.
        likelihood: ``GaussianLikelihood(batch_shape=[m])``.
        kernel: kernel with batch shape ``[m]`` (or ``[]`` for shared hyperparameters).
    """

    def __init__(
        self,
        train_x: Tensor,
        train_y: Tensor,
        likelihood: gpytorch.likelihoods.GaussianLikelihood,
        kernel: gpytorch.kernels.Kernel,
    ) -> None:
        super().__init__(train_x, train_y, likelihood)
        self.mean_module = gpytorch.means.ZeroMean(batch_shape=train_y.shape[:-1])
        self.covar_module = kernel

    def forward(self, x: Tensor) -> gpytorch.distributions.MultivariateNormal:
        return gpytorch.distributions.MultivariateNormal(self.mean_module(x), self.covar_module(x))


class GPRegressor:
    """Exact GP regression with several outputs, standardisation, and a cached predictor.

    Args:
        kernel_factory: ``kernel_factory(torch.Size([m])) -> Kernel``; hyperparameters carry
            batch shape ``[m]`` (one independent GP per output). Its initial values are the
            starting point of the first fit (in standardised units).
        standardize_x: standardise each input column (zero mean, unit std; constant columns
            are only centred).
        standardize_y: standardise each output column.
        noise_init: initial noise variance :math:`\\sigma_n^2` (standardised units when
            ``standardize_y``, i.e. a fraction of the output variance).
        noise_min: lower bound on :math:`\\sigma_n^2` (same units); raise it if the Cholesky
            fails.
        input_names: names of the ``d`` input columns (used in error messages).
        output_names: names of the ``m`` output columns.

    Fitted attributes (after :meth:`fit`): ``model_`` (:class:`BatchIndependentExactGP`),
    ``x_mean_``, ``x_scale_`` ``(d,)``, ``y_mean_``, ``y_scale_`` ``(m,)``, ``train_x_`` /
    ``train_y_`` (the rows the GP is conditioned on, original units), ``subset_indices_``
    (rows of the last fit's data kept by ``max_points``, or None).
    """

    def __init__(
        self,
        kernel_factory: KernelFactory,
        *,
        standardize_x: bool = True,
        standardize_y: bool = True,
        noise_init: float = 1e-2,
        noise_min: float = 1e-8,
        input_names: Sequence[str] | None = None,
        output_names: Sequence[str] | None = None,
    ) -> None:
        if not callable(kernel_factory):
            raise TypeError("kernel_factory must be callable: batch_shape -> gpytorch Kernel")
        if not noise_min >= 0:
            raise ValueError(f"noise_min must be >= 0, got {noise_min}")
        if not noise_init > noise_min:
            raise ValueError(
                f"noise_init ({noise_init}) must be larger than noise_min ({noise_min})"
            )
        self.kernel_factory = kernel_factory
        self.standardize_x = bool(standardize_x)
        self.standardize_y = bool(standardize_y)
        self.noise_init = float(noise_init)
        self.noise_min = float(noise_min)
        self.input_names = list(input_names) if input_names is not None else None
        self.output_names = list(output_names) if output_names is not None else None
        self.model_: BatchIndependentExactGP | None = None
        self.subset_indices_: Tensor | None = None
        self._predictor64: CachedPredictor | None = None
        self._mean_predictor64: CachedPredictor | None = None

    # ------------------------------------------------------------------ properties
    @property
    def input_dim(self) -> int:
        """Number of input columns ``d``."""
        self._check_fitted()
        return int(self.x_mean_.shape[0])

    @property
    def output_dim(self) -> int:
        """Number of outputs ``m``."""
        self._check_fitted()
        return int(self.y_mean_.shape[0])

    @property
    def noise_variance(self) -> Tensor:
        """``(m,)`` fitted noise variance :math:`\\sigma_{n,b}^2` in original units."""
        self._check_fitted()
        noise = self.model_.likelihood.noise.detach().reshape(-1)
        return noise.expand(self.output_dim) * self.y_scale_**2

    # ------------------------------------------------------------------ validation
    def _check_fitted(self) -> None:
        if self.model_ is None:
            raise RuntimeError("this GPRegressor is not fitted yet; call fit(X, Y) first")

    def _as_inputs(self, X: np.ndarray | Tensor) -> Tensor:
        """Validate test inputs: 2-D, ``d`` columns, finite -> float64."""
        x, _ = as_tensor_2d(X, "X")
        d = self.input_dim
        if x.shape[1] != d:
            raise ValueError(
                f"X must have shape (n, {d}) (the training input dimension), got {tuple(x.shape)}"
            )
        check_finite_columns(x, "X", self.input_names)
        check_magnitude_columns(x, "X", self.input_names)
        return x

    def _validate_training_data(
        self, X: np.ndarray | Tensor, Y: np.ndarray | Tensor
    ) -> tuple[Tensor, Tensor]:
        x, _ = as_tensor_2d(X, "X")
        y, _ = as_tensor_2d(Y, "Y", allow_1d=True)
        if x.shape[0] != y.shape[0]:
            raise ValueError(
                f"X and Y must have the same number of rows, got X {tuple(x.shape)} and "
                f"Y {tuple(y.shape)}"
            )
        if self.input_names is not None and len(self.input_names) != x.shape[1]:
            raise ValueError(
                f"input_names has {len(self.input_names)} names but X has {x.shape[1]} "
                f"columns (shape {tuple(x.shape)})"
            )
        if self.output_names is not None and len(self.output_names) != y.shape[1]:
            raise ValueError(
                f"output_names has {len(self.output_names)} names but Y has {y.shape[1]} "
                f"columns (shape {tuple(y.shape)})"
            )
        check_finite_columns(x, "X", self.input_names)
        check_finite_columns(y, "Y", self.output_names)
        check_magnitude_columns(x, "X", self.input_names)
        check_magnitude_columns(y, "Y", self.output_names)
        check_targets_vary(y, self.output_names)
        return x, y

    # ------------------------------------------------------------------ standardisation
    def _standardize_x(self, x: Tensor) -> Tensor:
        return (x - self.x_mean_) / self.x_scale_

    def _standardize_y(self, y: Tensor) -> Tensor:
        return (y - self.y_mean_) / self.y_scale_

    def _set_standardization(self, x: Tensor, y: Tensor) -> None:
        d, m = x.shape[1], y.shape[1]
        if self.standardize_x:
            self.x_mean_ = x.mean(0)
            std = x.std(0, correction=0) if x.shape[0] > 1 else torch.zeros(d, dtype=x.dtype)
            self.x_scale_ = torch.where(std > 0, std, torch.ones_like(std))
        else:
            self.x_mean_ = torch.zeros(d, dtype=x.dtype)
            self.x_scale_ = torch.ones(d, dtype=x.dtype)
        if self.standardize_y:
            self.y_mean_ = y.mean(0)
            std = y.std(0, correction=0)
            self.y_scale_ = torch.where(std > 0, std, torch.ones_like(std))
        else:
            self.y_mean_ = torch.zeros(m, dtype=y.dtype)
            self.y_scale_ = torch.ones(m, dtype=y.dtype)

    # ------------------------------------------------------------------ model building
    def _build_model(self, xs: Tensor, ys: Tensor) -> BatchIndependentExactGP:
        """Fresh model on standardised data ``xs (N, d)``, ``ys (N, m)``."""
        m = ys.shape[1]
        batch = torch.Size([m])
        # float64 default so that values set inside the factory are not rounded to float32
        with _default_dtype(torch.float64):
            kernel = self.kernel_factory(batch)
            if not isinstance(kernel, gpytorch.kernels.Kernel):
                raise TypeError(
                    f"kernel_factory must return a gpytorch Kernel, got {type(kernel).__name__}"
                )
            likelihood = gpytorch.likelihoods.GaussianLikelihood(
                batch_shape=batch,
                noise_constraint=gpytorch.constraints.GreaterThan(self.noise_min),
            )
            likelihood.noise = torch.full((m, 1), self.noise_init, dtype=torch.float64)
            model = BatchIndependentExactGP(
                xs.expand(m, *xs.shape), ys.T.contiguous(), likelihood, kernel
            ).to(torch.float64)
        return model

    def _condition_on(self, xs: Tensor, ys: Tensor, warm: bool) -> None:
        """Set the training data of ``model_`` (reusing its hyperparameters when ``warm``)."""
        m = ys.shape[1]
        if warm and self.model_ is not None:
            self.model_.set_train_data(xs.expand(m, *xs.shape), ys.T.contiguous(), strict=False)
        else:
            self.model_ = self._build_model(xs, ys)
        self._predictor64 = None
        self._mean_predictor64 = None

    def _can_warm_start(self, d: int, m: int) -> bool:
        if self.model_ is None:
            return False
        return self.x_mean_.shape[0] == d and self.y_mean_.shape[0] == m

    # ------------------------------------------------------------------ fit
    def fit(
        self,
        X: np.ndarray | Tensor,
        Y: np.ndarray | Tensor,
        *,
        adam_iters: int = 200,
        adam_lr: float = 0.05,
        lbfgs_iters: int = 50,
        max_points: int | None = None,
        progress: bool = False,
    ) -> GPRegressor:
        """Fit hyperparameters by exact marginal likelihood (Adam, then L-BFGS).

        A second call warm-starts from the current hyperparameters when ``d`` and ``m`` match
        (the standardisation constants are recomputed from the new data).

        Args:
            X: ``(N, d)`` inputs, numpy or torch (converted to float64).
            Y: ``(N, m)`` or ``(N,)`` targets.
            adam_iters: Adam steps (0 to skip).
            adam_lr: Adam learning rate.
            lbfgs_iters: L-BFGS iterations (0 to skip).
            max_points: if ``N > max_points``, condition on ``max_points`` rows chosen by
                :func:`greedy_subset` (largest posterior variance first). Without a warm start
                the hyperparameters for the selection come from a first fit on a random subset
                of ``max_points`` rows.
            progress: show a tqdm progress bar.

        Returns:
            self.

        Raises:
            ValueError: bad data (names the column or shape), or the Cholesky fails even with
                jitter (the message suggests the fix).
        """
        x, y = self._validate_training_data(X, Y)
        n, d = x.shape
        m = y.shape[1]
        if max_points is not None and max_points < 1:
            raise ValueError(f"max_points must be a positive int or None, got {max_points}")
        warm = self._can_warm_start(d, m)
        self._set_standardization(x, y)
        xs, ys = self._standardize_x(x), self._standardize_y(y)
        self.subset_indices_ = None
        if max_points is not None and n > max_points:
            if not warm:
                gen = torch.Generator().manual_seed(0)
                rand = torch.randperm(n, generator=gen)[:max_points].sort().values
                self._condition_on(xs[rand], ys[rand], warm=False)
                self._train(adam_iters, adam_lr, lbfgs_iters, progress, "GP fit (random subset)")
                warm = True
            idx = greedy_subset(
                xs,
                self.model_.covar_module,
                max_points,
                noise_variance=self.model_.likelihood.noise.detach().reshape(-1),
            )
            idx = idx.sort().values
            self.subset_indices_ = idx
            x, y, xs, ys = x[idx], y[idx], xs[idx], ys[idx]
        self._condition_on(xs, ys, warm=warm)
        self.train_x_, self.train_y_ = x, y
        self._train(adam_iters, adam_lr, lbfgs_iters, progress, "GP fit")
        return self

    def _loss(self, mll: gpytorch.mlls.ExactMarginalLogLikelihood) -> Tensor:
        model = self.model_
        out = model(*model.train_inputs)
        return -mll(out, model.train_targets).sum()

    def _train(
        self, adam_iters: int, adam_lr: float, lbfgs_iters: int, progress: bool, desc: str
    ) -> None:
        model = self.model_
        model.train()
        mll = gpytorch.mlls.ExactMarginalLogLikelihood(model.likelihood, model)
        params = [p for p in model.parameters() if p.requires_grad]
        if not params or adam_iters + lbfgs_iters == 0:
            model.eval()
            return
        bar = tqdm(total=adam_iters + lbfgs_iters, desc=desc, disable=not progress, leave=False)
        try:
            with exact_gp_settings():
                if adam_iters > 0:
                    opt = torch.optim.Adam(params, lr=adam_lr)
                    for _ in range(adam_iters):
                        opt.zero_grad(set_to_none=True)
                        loss = self._loss(mll)
                        if not torch.isfinite(loss):
                            raise ValueError(
                                "the negative log marginal likelihood became non-finite "
                                f"during Adam; lower adam_lr (now {adam_lr}) or "
                                f"{CHOLESKY_FIX_HINT}"
                            )
                        loss.backward()
                        opt.step()
                        bar.update(1)
                        bar.set_postfix(nlml=f"{loss.item():.4g}")
                if lbfgs_iters > 0:
                    self._run_lbfgs(mll, params, lbfgs_iters, bar)
        except (NotPSDError, NanError) as err:
            raise ValueError(
                f"Cholesky of K + sigma_n^2 I failed during training ({err}). "
                f"To fix: {CHOLESKY_FIX_HINT}."
            ) from err
        finally:
            bar.close()
            model.eval()
            self._predictor64 = None
            self._mean_predictor64 = None

    def _run_lbfgs(
        self,
        mll: gpytorch.mlls.ExactMarginalLogLikelihood,
        params: list[torch.nn.Parameter],
        iters: int,
        bar: tqdm,
    ) -> None:
        """L-BFGS with strong-Wolfe line search; reverts to the previous state on failure."""
        model = self.model_
        before = {k: v.clone() for k, v in model.state_dict().items()}
        with torch.no_grad():
            loss_before = float(self._loss(mll))
        opt = torch.optim.LBFGS(
            params, lr=1.0, max_iter=iters, line_search_fn="strong_wolfe", history_size=20
        )

        def closure() -> Tensor:
            opt.zero_grad(set_to_none=True)
            loss = self._loss(mll)
            if torch.isfinite(loss):
                loss.backward()
            if bar.n < bar.total:
                bar.update(1)
            bar.set_postfix(nlml=f"{loss.item():.4g}")
            return loss

        failed = None
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", gpytorch.utils.warnings.NumericalWarning)
                opt.step(closure)
            with torch.no_grad():
                loss_after = float(self._loss(mll))
            if not math.isfinite(loss_after) or loss_after > loss_before + 1e-9 * abs(loss_before):
                failed = f"nlml {loss_before:.6g} -> {loss_after:.6g}"
        except (NotPSDError, NanError, RuntimeError) as err:
            failed = str(err)
        if failed is not None:
            model.load_state_dict(before)
            warnings.warn(
                f"L-BFGS did not improve the marginal likelihood ({failed}); kept the Adam "
                "hyperparameters",
                RuntimeWarning,
                stacklevel=3,
            )

    # ------------------------------------------------------------------ inference
    def _standardized_train(self) -> tuple[Tensor, Tensor, Tensor]:
        """``(x (N, d), y (m, N), noise (m,))`` in standardised units."""
        model = self.model_
        xs = model.train_inputs[0][0]
        ys = model.train_targets
        noise = model.likelihood.noise.detach().reshape(-1).expand(ys.shape[0])
        return xs, ys, noise

    def cached_predictor(
        self,
        dtype: torch.dtype = torch.float32,
        *,
        validate: bool = True,
        with_variance: bool = True,
    ) -> CachedPredictor:
        """Extract a :class:`CachedPredictor` (dense, differentiable w.r.t. the test inputs).

        Args:
            dtype: float32 (rollouts) or float64.
            validate: finiteness checks on every call (set False in hot loops).
            with_variance: False gives a mean-only predictor (no :math:`L^{-1}`).
        """
        self._check_fitted()
        xs, ys, noise = self._standardized_train()
        return CachedPredictor.from_data(
            self.model_.covar_module,
            xs,
            ys,
            noise,
            x_mean=self.x_mean_,
            x_scale=self.x_scale_,
            y_mean=self.y_mean_,
            y_scale=self.y_scale_,
            dtype=dtype,
            validate=validate,
            with_variance=with_variance,
        )

    @torch.no_grad()
    def predict_mean(self, X: np.ndarray | Tensor) -> Tensor:
        """Posterior mean only, ``(n, m)`` float64 in original units.

        Skips :math:`L^{-1}` and the variance products of :meth:`predict`, which dominate for
        large N when only the mean is needed.
        """
        self._check_fitted()
        x = self._as_inputs(X)
        if self._mean_predictor64 is None:
            self._mean_predictor64 = self.cached_predictor(torch.float64, with_variance=False)
        return self._mean_predictor64(x)[0]

    @torch.no_grad()
    def predict(self, X: np.ndarray | Tensor, include_noise: bool = False) -> tuple[Tensor, Tensor]:
        """Posterior mean and variance in original units.

        Args:
            X: ``(n, d)`` test inputs.
            include_noise: add the noise variance (predictive variance of an observation).

        Returns:
            ``(mean, var)``, each ``(n, m)`` float64.
        """
        self._check_fitted()
        x = self._as_inputs(X)
        if self._predictor64 is None:
            self._predictor64 = self.cached_predictor(torch.float64, validate=True)
        mean, var = self._predictor64(x)
        if include_noise:
            var = var + self._predictor64.noise_variance
        return mean, var

    @torch.no_grad()
    def predict_gpytorch(
        self, X: np.ndarray | Tensor, include_noise: bool = False
    ) -> tuple[Tensor, Tensor]:
        """Reference path: GPyTorch's own posterior ``model(x)`` in eval mode, original units.

        Slow (LinearOperator machinery on every call); for tests and benchmarks.
        """
        self._check_fitted()
        x = self._standardize_x(self._as_inputs(X))
        model = self.model_
        model.eval()
        m = self.output_dim
        with exact_gp_settings():
            post = model(x.expand(m, *x.shape))
            if include_noise:
                post = model.likelihood(post)
            mean, var = post.mean, post.variance
        return mean.T * self.y_scale_ + self.y_mean_, var.T * self.y_scale_**2

    def _train_cholesky(self) -> tuple[Tensor, Tensor]:
        """Cholesky factor ``L (m, N, N)`` of :math:`K = K_f + \\sigma_n^2 I` on the
        standardised training inputs, and the standardised targets ``(m, N)``."""
        xs, ys, noise = self._standardized_train()
        m, n = ys.shape
        xb = xs.expand(m, *xs.shape)
        K = dense_covar(self.model_.covar_module, xb, xb).expand(m, n, n) + torch.diag_embed(
            noise.reshape(m, 1).expand(m, n)
        )
        L, _ = jittered_cholesky(K)
        return L, ys

    @torch.no_grad()
    def loo_residuals(self) -> tuple[Tensor, Tensor]:
        """Leave-one-out residuals of the training targets at the fitted hyperparameters.

        Rasmussen & Williams (2006) eq. 5.12, with :math:`K = K_f + \\sigma_n^2 I`:

        .. math::

           y_i - \\mu_{-i} = \\frac{[K^{-1} y]_i}{[K^{-1}]_{ii}}, \\qquad
           \\sigma_{-i}^2 = \\frac{1}{[K^{-1}]_{ii}}

        (the predictive distribution of :math:`y_i` from the other :math:`N - 1` points,
        noise included). Returns ``(residual, std)``, each ``(N, m)`` float64 in original
        units; ``residual / std`` is a standard normal score under the model.
        """
        self._check_fitted()
        L, ys = self._train_cholesky()
        K_inv = torch.cholesky_inverse(L)
        d = K_inv.diagonal(dim1=-2, dim2=-1)  # (m, N)
        alpha = (K_inv @ ys.unsqueeze(-1)).squeeze(-1)
        scale = self.y_scale_.reshape(-1, 1)
        return (alpha / d * scale).T, (d.rsqrt() * scale).T

    @torch.no_grad()
    def log_marginal_likelihood(self) -> Tensor:
        """``(m,)`` exact log marginal likelihood of each output column, original units.

        :math:`\\log p(y_b) = \\log p(\\tilde y_b) - N \\log s_{y,b}` (change of variables from
        the standardised targets); computed densely with a Cholesky factorisation.
        """
        self._check_fitted()
        L, ys = self._train_cholesky()
        n = ys.shape[1]
        alpha = torch.cholesky_solve(ys.unsqueeze(-1), L).squeeze(-1)
        logdet_half = L.diagonal(dim1=-2, dim2=-1).log().sum(-1)
        lml = -0.5 * (ys * alpha).sum(-1) - logdet_half - 0.5 * n * math.log(2 * math.pi)
        return lml - n * self.y_scale_.log()

    def prior_variance(self, X: np.ndarray | Tensor) -> Tensor:
        """``(n, m)`` prior variance :math:`s_{y,b}^2 k_b(x, x)` in original units."""
        self._check_fitted()
        x = self._standardize_x(self._as_inputs(X))
        m = self.output_dim
        with torch.no_grad():
            k = dense_diag(self.model_.covar_module, x.expand(m, *x.shape))
        return k.expand(m, x.shape[0]).T * self.y_scale_**2

    def prior_covariance(self, X1: np.ndarray | Tensor, X2: np.ndarray | Tensor) -> Tensor:
        """``(m, N1, N2)`` prior covariance :math:`k_b(x, x')` of every output in standardised
        output units (times ``y_scale_**2`` for the original units), dense."""
        self._check_fitted()
        x1 = self._standardize_x(self._as_inputs(X1))
        x2 = self._standardize_x(self._as_inputs(X2))
        m = self.output_dim
        with torch.no_grad():
            return dense_covar(
                self.model_.covar_module, x1.expand(m, *x1.shape), x2.expand(m, *x2.shape)
            )

    # ------------------------------------------------------------------ persistence
    def save(self, path: str | os.PathLike) -> None:
        """Write hyperparameters (state_dict), training data and constants to ``path``
        (atomically, tensors and plain data only)."""
        self._check_fitted()
        xs, ys, _ = self._standardized_train()
        payload = {
            "format": _FORMAT,
            "config": {
                "standardize_x": self.standardize_x,
                "standardize_y": self.standardize_y,
                "noise_init": self.noise_init,
                "noise_min": self.noise_min,
                "input_names": self.input_names,
                "output_names": self.output_names,
            },
            "state_dict": self.model_.state_dict(),
            "train_x_std": xs.clone(),
            "train_y_std": ys.T.clone(),
            "train_x": self.train_x_.clone(),
            "train_y": self.train_y_.clone(),
            "x_mean": self.x_mean_,
            "x_scale": self.x_scale_,
            "y_mean": self.y_mean_,
            "y_scale": self.y_scale_,
            "subset_indices": self.subset_indices_,
        }
        atomic_torch_save(payload, path)

    @classmethod
    def load(cls, path: str | os.PathLike, kernel_factory: KernelFactory) -> GPRegressor:
        """Rebuild a GP saved by :meth:`save` (same ``kernel_factory`` structure required).

        Raises:
            FileNotFoundError: no file at ``path``.
            ValueError: the file is empty, damaged, unsafe or not a GP file (names it).
        """
        remedy = "restore it, or fit the GP again (a run: start it again with --overwrite)"
        payload = load_torch_file(path, "GP file", remedy)
        if not isinstance(payload, dict) or payload.get("format") != _FORMAT:
            raise ValueError(
                f"GP file {path} is not a GPRegressor file written by GPRegressor.save; {remedy}"
            )
        gp = cls(kernel_factory, **payload["config"])
        gp.x_mean_, gp.x_scale_ = payload["x_mean"], payload["x_scale"]
        gp.y_mean_, gp.y_scale_ = payload["y_mean"], payload["y_scale"]
        gp.train_x_, gp.train_y_ = payload["train_x"], payload["train_y"]
        gp.subset_indices_ = payload["subset_indices"]
        gp.model_ = gp._build_model(payload["train_x_std"], payload["train_y_std"])
        try:
            gp.model_.load_state_dict(payload["state_dict"])
        except RuntimeError as err:
            raise ValueError(
                f"the kernel built by kernel_factory does not match the saved one: {err}"
            ) from err
        gp.model_.eval()
        return gp

    def __repr__(self) -> str:
        if self.model_ is None:
            return "GPRegressor(unfitted)"
        return (
            f"GPRegressor(N={self.train_x_.shape[0]}, d={self.input_dim}, "
            f"m={self.output_dim}, kernel={type(self.model_.covar_module).__name__})"
        )

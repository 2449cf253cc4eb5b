"""Exact multi-output GP regression on GPyTorch and a cached predictor for rollouts.

* :class:`GPRegressor` -- one independent exact GP per output (batched), float64,
  standardisation, marginal-likelihood training (Adam then L-BFGS), save / load.
* :class:`CachedPredictor` -- dense, differentiable posterior mean / variance for rollouts.
* :class:`FusedRBFMPKPredictor` -- the same posterior for RBF (+ MPK) kernels with the
  hyperparameters baked into a few large ops (the MC-PILCO rollout hot path).
* :class:`~mcpilco.models.gp.linear_gp.JointGP` -- GP with linear kernels on feature blocks
  (plus an optional fixed kernel), evidence and posterior in weight space, ``O(N P^2)``.
* :func:`greedy_subset` -- subset of data by largest posterior variance (pivoted Cholesky).
* :func:`dense_covar` / :func:`dense_diag` -- evaluate a GPyTorch kernel tree with dense ops.
"""

from mcpilco.models.gp.dense import dense_covar, dense_diag
from mcpilco.models.gp.fused import FusedRBFMPKPredictor
from mcpilco.models.gp.linalg import jittered_cholesky
from mcpilco.models.gp.predictor import CachedPredictor
from mcpilco.models.gp.regressor import (
    BatchIndependentExactGP,
    GPRegressor,
    KernelFactory,
    exact_gp_settings,
)
from mcpilco.models.gp.subset import greedy_subset

__all__ = [
    "BatchIndependentExactGP",
    "CachedPredictor",
    "FusedRBFMPKPredictor",
    "GPRegressor",
    "KernelFactory",
    "dense_covar",
    "dense_diag",
    "exact_gp_settings",
    "greedy_subset",
    "jittered_cholesky",
]

"""greedy_subset: isolated points first, no duplicates, variance bound, numpy cross-check."""

from __future__ import annotations

import gpytorch
import numpy as np
import pytest

from mcpilco.models.gp import GPRegressor, greedy_subset

from .conftest import rbf_factory


def _rbf(lengthscale: float):
    k = gpytorch.kernels.RBFKernel().double()
    k.lengthscale = lengthscale
    return k


def numpy_posterior_variance(X, S, lengthscale, noise=0.0):
    """Posterior variance at every row of X given noisy observations at rows S (numpy)."""
    k = lambda a, b: np.exp(-0.5 * (a[:, None, 0] - b[None, :, 0]) ** 2 / lengthscale**2)
    Kss = k(X[S], X[S]) + (noise + 1e-12) * np.eye(len(S))
    Kxs = k(X, X[S])
    return 1.0 - np.einsum("ij,ji->i", Kxs, np.linalg.solve(Kss, Kxs.T))


def test_isolated_points_are_selected_early() -> None:
    rng = np.random.default_rng(0)
    cluster = rng.normal(0.0, 0.05, size=(200, 1))
    isolated = np.array([[-5.0], [3.0], [7.0], [-9.0]])
    X = np.concatenate([cluster, isolated])  # isolated rows: 200..203
    idx = greedy_subset(X, _rbf(0.5), 6)
    assert set(range(200, 204)) <= set(idx[:5].tolist())


def test_no_duplicates_even_with_repeated_rows() -> None:
    X = np.repeat(np.linspace(0, 1, 10)[:, None], 5, axis=0)  # every row five times
    idx = greedy_subset(X, _rbf(0.3), 30)
    assert len(idx) == 30 and len(set(idx.tolist())) == 30
    # the ten distinct locations come first
    assert len(np.unique(X[idx[:10].numpy(), 0])) == 10


def test_variance_small_everywhere_after_k_picks_and_matches_numpy() -> None:
    X = np.linspace(-3, 3, 500)[:, None]
    idx, var = greedy_subset(X, _rbf(0.8), 15, return_variance=True)
    ref = numpy_posterior_variance(X, idx.numpy(), 0.8)
    np.testing.assert_allclose(var.numpy(), ref, atol=1e-8)
    assert ref.max() < 1e-3


def test_noise_aware_variance_matches_numpy() -> None:
    rng = np.random.default_rng(1)
    X = rng.uniform(-2, 2, size=(100, 1))
    idx, var = greedy_subset(X, _rbf(0.5), 12, noise_variance=0.1, return_variance=True)
    ref = numpy_posterior_variance(X, idx.numpy(), 0.5, noise=0.1)
    np.testing.assert_allclose(var.numpy(), ref, atol=1e-8)


def test_batched_kernel_and_gp_input() -> None:
    rng = np.random.default_rng(2)
    X = rng.uniform(-2, 2, size=(80, 2))
    Y = np.stack([np.sin(X[:, 0]), X[:, 1] ** 2], 1)
    gp = GPRegressor(rbf_factory(2)).fit(X, Y, adam_iters=10, lbfgs_iters=0)
    idx, var = greedy_subset(X, gp, 20, return_variance=True)
    assert var.shape == (2, 80)
    assert len(set(idx.tolist())) == 20
    with pytest.raises(ValueError, match="between 1 and N=80"):
        greedy_subset(X, gp, 81)

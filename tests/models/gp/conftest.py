"""Shared fixtures for the GP-core tests: small synthetic data sets and kernel factories."""

from __future__ import annotations

import gpytorch
import numpy as np
import pytest
import torch


def rbf_factory(d: int, lengthscale: float | None = None, outputscale: float | None = None):
    """``ScaleKernel(RBFKernel(ard_num_dims=d))`` factory, optionally with fixed initial values."""

    def factory(batch_shape: torch.Size) -> gpytorch.kernels.Kernel:
        k = gpytorch.kernels.ScaleKernel(
            gpytorch.kernels.RBFKernel(ard_num_dims=d, batch_shape=batch_shape),
            batch_shape=batch_shape,
        )
        if lengthscale is not None:
            k.base_kernel.lengthscale = lengthscale
        if outputscale is not None:
            k.outputscale = outputscale
        return k

    return factory


@pytest.fixture(autouse=True)
def _one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture
def data_2out() -> tuple[np.ndarray, np.ndarray]:
    """60 points in 3-D with two smooth noisy outputs on different scales."""
    rng = np.random.default_rng(0)
    X = rng.uniform(-2, 2, size=(60, 3))
    Y = np.stack([np.sin(X[:, 0]) + 0.3 * X[:, 1], 10.0 + 5.0 * np.cos(X[:, 1] * X[:, 2])], axis=1)
    Y += 0.05 * rng.standard_normal(Y.shape) * np.array([1.0, 5.0])
    return X, Y

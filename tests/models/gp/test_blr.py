"""Bayesian linear regression from sufficient statistics against the dense GP it equals."""

import math

import numpy as np
import pytest

from mcpilco.models.gp.blr import BayesianLinearRegression


def dense_evidence(Phi: np.ndarray, y: np.ndarray, lam: float, s2: float) -> float:
    """log N(y; 0, lam Phi Phi^T + s2 I) by a dense Cholesky (the GP's dual form)."""
    K = lam * Phi @ Phi.T + s2 * np.eye(y.size)
    L = np.linalg.cholesky(K)
    a = np.linalg.solve(L, y)
    return -0.5 * a @ a - np.sum(np.log(np.diag(L))) - 0.5 * y.size * math.log(2 * math.pi)


@pytest.fixture
def data() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    Phi = rng.normal(size=(120, 8))
    w = rng.normal(size=(8, 2))
    Y = Phi @ w + 0.1 * rng.normal(size=(120, 2))
    return Phi, Y


def test_evidence_mean_and_variance_equal_the_dense_gp(data) -> None:
    Phi, Y = data
    blr = BayesianLinearRegression(8, 2)
    for a in range(0, 120, 50):  # chunks add up to the whole
        blr.add(Phi[a : a + 50], Y[a : a + 50])
    blr.fit()
    Xs = np.random.default_rng(1).normal(size=(5, 8))
    mean, var = blr.predict(Xs, with_var=True)
    for j in range(2):
        lam, s2 = math.exp(blr.log_lambda_[j]), math.exp(blr.log_noise_[j])
        assert blr.evidence_[j] == pytest.approx(dense_evidence(Phi, Y[:, j], lam, s2), rel=1e-9)
        K = lam * Phi @ Phi.T + s2 * np.eye(120)
        ks = lam * Xs @ Phi.T
        np.testing.assert_allclose(mean[:, j], ks @ np.linalg.solve(K, Y[:, j]), rtol=1e-7)
        dense_var = lam * np.sum(Xs**2, 1) - np.einsum("ij,ji->i", ks, np.linalg.solve(K, ks.T))
        np.testing.assert_allclose(var[:, j], dense_var, rtol=1e-6)
        # type-II ML: the evidence is at a maximum in (log lambda, log sigma^2)
        for d in ([0.05, 0.0], [0.0, 0.05], [-0.05, 0.0], [0.0, -0.05]):
            moved = dense_evidence(Phi, Y[:, j], lam * math.exp(d[0]), s2 * math.exp(d[1]))
            assert moved <= blr.evidence_[j] + 1e-6
    assert np.sqrt(blr.noise_variance) == pytest.approx([0.1, 0.1], rel=0.2)


def test_per_output_features_and_bad_shapes(data) -> None:
    Phi, Y = data
    shared = BayesianLinearRegression(8, 2)
    shared.add(Phi, Y)
    per = BayesianLinearRegression(8, 2)
    per.add(np.stack([Phi, Phi]), Y)
    np.testing.assert_allclose(per.A, shared.A)
    np.testing.assert_allclose(per.b, shared.b)
    with pytest.raises(ValueError, match="Y must be"):
        shared.add(Phi, Y[:, :1])
    with pytest.raises(ValueError, match="at least 2 rows"):
        BayesianLinearRegression(8, 2).fit()

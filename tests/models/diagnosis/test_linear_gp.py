"""JointGP against a dense Gaussian log-density and dense GP posterior (independent maths)."""

import numpy as np
import pytest
from scipy.stats import multivariate_normal

from mcpilco.models.diagnosis.linear_gp import JointGP


def _problem(with_kernel: bool):
    rng = np.random.default_rng(0)
    N = 50
    X = rng.normal(size=(N, 3))
    K0 = (X @ X.T + 1.0) ** 2
    blocks = [rng.normal(size=(N, 2)), 3.0 * rng.normal(size=(N, 1))]
    r = 2.0 * rng.normal(size=N)
    eig = None
    if with_kernel:
        S, U = np.linalg.eigh(K0)
        eig = (U, S)
    gp = JointGP(r, blocks, eig=eig)
    theta = gp.default_theta() + 0.3 * rng.normal(size=gp.n_theta)
    alpha, s2, lam = gp._unpack(theta)
    Phi = np.concatenate(blocks, axis=1)
    K = (alpha * K0 if with_kernel else 0.0) + (Phi * lam * gp.scale**2 / gp.col_scale**2) @ Phi.T
    K = K + s2 * gp.scale**2 * np.eye(N)
    return gp, theta, K, r, X, blocks, alpha, lam


@pytest.mark.parametrize("with_kernel", [False, True])
def test_evidence_gradient_and_posterior_match_dense(with_kernel):
    gp, theta, K, r, X, blocks, alpha, lam = _problem(with_kernel)
    ref = multivariate_normal(np.zeros(r.size), K).logpdf(r)
    value, grad = gp.value_and_grad(theta)
    assert value == pytest.approx(ref, rel=1e-10)
    eye = np.eye(theta.size)
    num = [
        (gp.log_evidence(theta + 1e-6 * e) - gp.log_evidence(theta - 1e-6 * e)) / 2e-6 for e in eye
    ]
    np.testing.assert_allclose(grad, num, atol=1e-5)
    # posterior at test rows vs dense GP formulas
    rng = np.random.default_rng(1)
    Xs = rng.normal(size=(4, 3))
    tb = [rng.normal(size=(4, 2)), rng.normal(size=(4, 1))]
    Ph = np.concatenate(blocks, 1) / gp.col_scale
    Phs = np.concatenate(tb, 1) / gp.col_scale
    K0x = (X @ Xs.T + 1.0) ** 2
    K0d = np.diag((Xs @ Xs.T + 1.0) ** 2)
    kst = (alpha * K0x if with_kernel else 0.0) + (Ph * lam) @ Phs.T * gp.scale**2
    kss = (alpha * K0d if with_kernel else 0.0) + np.einsum(
        "ij,j,ij->i", Phs, lam, Phs
    ) * gp.scale**2
    mean_ref = kst.T @ np.linalg.solve(K, r)
    var_ref = kss - np.einsum("ij,ij->j", kst, np.linalg.solve(K, kst))
    if with_kernel:
        mean, var = gp.predict(theta, tb, K0_cross=K0x, K0_diag=K0d)
    else:
        mean, var = gp.predict(theta, tb)
    np.testing.assert_allclose(mean, mean_ref, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(var, var_ref, rtol=1e-6, atol=1e-9)


def test_weights_recover_a_linear_effect():
    rng = np.random.default_rng(2)
    x = rng.normal(size=(400, 1))
    r = 3.0 * x[:, 0] + 0.1 * rng.normal(size=400)
    gp = JointGP(r, [x])
    theta, _ = gp.optimise(gp.default_theta())
    mean, cov = gp.weights(theta)
    assert mean[0] == pytest.approx(3.0, abs=4 * np.sqrt(cov[0, 0]))
    assert np.sqrt(gp.noise_variance(theta)) == pytest.approx(0.1, rel=0.15)

"""JointGP against a dense Gaussian log-density and dense GP posterior (independent maths)."""

import numpy as np
import pytest
from scipy.stats import multivariate_normal

from mcpilco.models.gp.linear_gp import JointGP


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


def _svd_log_evidence(r: np.ndarray, Phi: np.ndarray, s2: float, lam: float) -> float:
    """log N(r; 0, s2 I + lam Phi Phi^T) from the SVD of Phi (stable for any s2, lam)."""
    U, S, _ = np.linalg.svd(Phi, full_matrices=False)
    keep = S > 1e-12 * S[0]
    U, S = U[:, keep], S[keep]
    d = s2 + lam * S**2
    c = U.T @ r
    rp = r - U @ c
    quad = float(np.sum(c**2 / d)) + float(rp @ rp) / s2
    logdet = float(np.sum(np.log(d))) + (r.size - S.size) * np.log(s2)
    return -0.5 * (quad + logdet + r.size * np.log(2 * np.pi))


def test_evidence_is_exact_at_low_noise_with_a_dependent_column():
    """A block with an exactly dependent column (a payload regressor on a wrist joint is like
    this) and a target explained to 1e-3 of its size: the evidence must match an SVD-based
    second implementation over the whole (noise, prior variance) box, so that type-II ML
    finds the true noise (forming Phi^T Phi / sigma^2 would give spurious maxima)."""
    rng = np.random.default_rng(3)
    N = 2000
    F = rng.normal(size=(N, 4)) * np.array([1.0, 10.0, 0.1, 3.0])
    block = np.column_stack([F, F[:, 0] - 2.0 * F[:, 2]])  # column 5 depends on 1 and 3
    noise = 1e-2
    r = F @ np.array([3.0, 0.5, -40.0, 2.0]) + noise * rng.normal(size=N)
    gp = JointGP(r, [block])
    Phi_s, r_s = block / gp.col_scale, r / gp.scale
    for log_s2 in (-18.0, -16.0, -14.0, -12.0):
        for log_lam in (0.0, 5.0, 10.0, 12.0):
            ref = _svd_log_evidence(r_s, Phi_s, np.exp(log_s2), np.exp(log_lam))
            ref -= N * np.log(gp.scale)
            got = gp.log_evidence(np.array([log_s2, log_lam]))
            assert got == pytest.approx(ref, rel=1e-6, abs=1e-3), (log_s2, log_lam)
    theta, _ = gp.optimise(gp.default_theta(), starts=[np.array([-16.0, 10.0])])
    assert np.sqrt(gp.noise_variance(theta)) == pytest.approx(noise, rel=0.1)
    w, _ = gp.weights(theta)
    assert np.sqrt(np.mean((r - block @ w) ** 2)) == pytest.approx(noise, rel=0.1)


@pytest.mark.parametrize("with_kernel", [False, True])
def test_information_and_prior_variance_match_dense(with_kernel):
    """``information`` is ``Phi^T (alpha K_0 + sigma^2 I)^-1 Phi`` and, with the prior
    precision ``Lambda^-1``, the inverse of the posterior covariance of the weights."""
    gp, theta, K, r, X, blocks, alpha, lam = _problem(with_kernel)
    Phi = np.concatenate(blocks, axis=1)
    s2 = gp.noise_variance(theta)
    K0 = (X @ X.T + 1.0) ** 2
    noise_k = (alpha * K0 if with_kernel else 0.0) + s2 * np.eye(r.size)
    info_ref = Phi.T @ np.linalg.solve(noise_k, Phi)
    np.testing.assert_allclose(gp.information(theta), info_ref, rtol=1e-8)
    prior = gp.prior_variance(theta)
    np.testing.assert_allclose(prior, lam * gp.scale**2 / gp.col_scale**2, rtol=1e-12)
    _, cov = gp.weights(theta)
    np.testing.assert_allclose(
        np.linalg.inv(cov), info_ref + np.diag(1.0 / prior), rtol=1e-6, atol=1e-8
    )

"""Tests of the Volterra identification pieces against hand-computed / analytic truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mcpilco.models.volterra import (
    SPINELLI_TERMS,
    VolterraGP,
    fit_percent,
    lag_matrix,
    spinelli_monomials,
    spinelli_system,
    wiener_system,
)

pytestmark = pytest.mark.usefixtures("one_torch_thread")  # tiny GP fits


# ---------------------------------------------------------------------------- lag_matrix
def test_lag_matrix_zero_initial_conditions_by_hand():
    u = [1.0, 2.0, 3.0, 4.0]
    expected = np.array(
        [
            [1.0, 0.0, 0.0],
            [2.0, 1.0, 0.0],
            [3.0, 2.0, 1.0],
            [4.0, 3.0, 2.0],
        ]
    )
    np.testing.assert_array_equal(lag_matrix(u, 2), expected)


def test_lag_matrix_drop_keeps_full_rows_only():
    u = np.array([1.0, 2.0, 3.0, 4.0])
    np.testing.assert_array_equal(lag_matrix(u, 2, initial="drop"), [[3, 2, 1], [4, 3, 2]])
    np.testing.assert_array_equal(lag_matrix(u, 0), u[:, None])


@pytest.mark.parametrize(
    ("u", "memory", "kw", "match"),
    [
        (np.ones((3, 2)), 1, {}, "1-D"),
        ([1.0, np.nan], 1, {}, "NaN"),
        ([1.0, 2.0], -1, {}, "memory"),
        ([1.0, 2.0], 2, {"initial": "drop"}, "more than memory"),
        ([1.0, 2.0], 1, {"initial": "pad"}, "initial"),
        ([], 1, {}, "empty"),
    ],
)
def test_lag_matrix_rejects_bad_input(u, memory, kw, match):
    with pytest.raises(ValueError, match=match):
        lag_matrix(u, memory, **kw)


# ---------------------------------------------------------------------------- fit_percent
def test_fit_percent_perfect_and_mean_prediction():
    z = np.array([1.0, -2.0, 3.5, 0.5, 7.0])
    assert fit_percent(z, z) == pytest.approx(100.0)
    assert fit_percent(z, np.full_like(z, z.mean())) == pytest.approx(0.0, abs=1e-12)
    # hand value: z = [0, 2], mean 1, ||z - mean||_1 = 2; z_hat = [0, 1] -> error 1 -> 50 %
    assert fit_percent([0.0, 2.0], [0.0, 1.0]) == pytest.approx(50.0)


def test_fit_percent_rejects_constant_and_mismatched():
    with pytest.raises(ValueError, match="constant"):
        fit_percent(np.ones(4), np.zeros(4))
    with pytest.raises(ValueError, match="shape"):
        fit_percent(np.arange(4.0), np.arange(3.0))


# ---------------------------------------------------------------------------- systems
def test_spinelli_system_impulse_response_by_hand():
    """Unit impulse in (6.36): only terms of a single lag survive; u^2 = u^3 = 1."""
    u = np.zeros(9)
    u[0] = 1.0
    expected = [1 + 0.5, 0.6, 0.35 + 0.75, -0.25 + 0.9, 0.35, 0.2, 0.2, 0.0, 0.0]
    np.testing.assert_allclose(spinelli_system(u), expected, atol=1e-14)


def test_spinelli_monomials_with_their_coefficients_give_the_system():
    """Two writings of (6.36): the term table times its monomials equals the formula."""
    u = np.random.default_rng(0).normal(0.0, 2.0, 300)
    coefs = np.array([c for _, c in SPINELLI_TERMS])
    phi = spinelli_monomials(u)
    assert phi.shape == (300, 14)
    np.testing.assert_allclose(phi @ coefs, spinelli_system(u), rtol=1e-12, atol=1e-12)
    assert len({lags for lags, _ in SPINELLI_TERMS}) == 14  # no monomial listed twice


def test_spinelli_system_cross_terms_by_hand():
    """u = [1, 1, 0, ...]: at k = 1, lags u_k = u_{k-1} = 1 -> every (u0, u1) term."""
    u = np.array([1.0, 1.0, 0.0, 0.0])
    z = spinelli_system(u)
    # k=1: u0=u1=1: u0 + 0.6u1 + 0.25u0u1 + 0.5u0^2 = 1 + 0.6 + 0.25 + 0.5
    assert z[1] == pytest.approx(2.35)
    # k=2: u1=u2=1: 0.6 + 0.35 + 0.75 - 1 = 0.7
    assert z[2] == pytest.approx(0.7)
    # k=3: u2=u3=1: 0.35 - 0.25 + 0.9 + 0.75 + 0.5 u0u2(0) + 0.5 u1u3(0) = 1.75
    assert z[3] == pytest.approx(1.75)


def test_wiener_impulse_response_matches_difference_equation_and_closed_form():
    """r = 1: z = G(q)u, x_k = 1.8036 x_{k-1} - 0.8338 x_{k-2} + 10 u_{k-1}."""
    n = 80
    u = np.zeros(n)
    u[0] = 1.0
    h = wiener_system(u, 1)
    # first taps by hand from the difference equation
    h0 = 0.0
    h1 = 10.0
    h2 = 1.8036 * 10.0
    h3 = 1.8036 * 18.036 - 0.8338 * 10.0
    h4 = 1.8036 * h3 - 0.8338 * 18.036
    np.testing.assert_allclose(h[:5], [h0, h1, h2, h3, h4], rtol=1e-12)
    assert h3 == pytest.approx(24.1917296)
    # closed form for complex poles rho e^{+-j theta}: h_k = 10 rho^(k-1) sin(k theta)/sin(theta)
    rho = math.sqrt(0.8338)
    theta = math.acos(1.8036 / (2.0 * rho))
    k = np.arange(1, n)
    np.testing.assert_allclose(
        h[1:], 10.0 * rho ** (k - 1) * np.sin(k * theta) / math.sin(theta), rtol=1e-9, atol=1e-12
    )


def test_wiener_system_is_polynomial_of_linear_part():
    rng = np.random.default_rng(0)
    u = rng.standard_normal(50)
    x = wiener_system(u, 1)
    np.testing.assert_allclose(wiener_system(u, 3), x + x**2 + x**3, rtol=1e-12)
    with pytest.raises(ValueError, match="order"):
        wiener_system(u, 0)


# ---------------------------------------------------------------------------- estimator
def _small_system(u: np.ndarray) -> np.ndarray:
    """Order 2, memory 2: z_k = u_k - 0.5 u_{k-1} u_{k-2} + 0.3 u_k^2 + 0.2 u_{k-2}."""
    x = lag_matrix(u, 2)
    return x[:, 0] - 0.5 * x[:, 1] * x[:, 2] + 0.3 * x[:, 0] ** 2 + 0.2 * x[:, 2]


def test_mpk_identifies_small_noiseless_volterra_system():
    rng = np.random.default_rng(1)
    u_train, u_test = rng.standard_normal(200), rng.standard_normal(300)
    est = VolterraGP("mpk", order=2, memory=2, adam_iters=20, lbfgs_iters=20, noise_init=1e-3)
    est.fit(u_train, _small_system(u_train))
    assert fit_percent(_small_system(u_test), est.predict(u_test)) > 99.0


def test_volterra_gp_validates_inputs():
    with pytest.raises(ValueError, match="kind"):
        VolterraGP("rbf", order=2, memory=2)
    est = VolterraGP("mpk", order=2, memory=2)
    with pytest.raises(ValueError, match="samples"):
        est.fit(np.zeros(10), np.zeros(9))
    with pytest.raises(RuntimeError, match="not fitted"):
        est.predict(np.zeros(5))


def test_mean_only_prediction_matches_gp_regressor_predict():
    rng = np.random.default_rng(2)
    u = rng.standard_normal(120)
    y = _small_system(u) + 0.05 * rng.standard_normal(120)
    est = VolterraGP("sed_mpk", order=2, memory=2, adam_iters=5, lbfgs_iters=0).fit(u, y)
    u_test = rng.standard_normal(40)
    mean, var = est.predict_gp(u_test)
    np.testing.assert_allclose(est.predict(u_test), mean, rtol=1e-8, atol=1e-8)
    assert np.all(var >= 0)


def _small_wiener(u: np.ndarray) -> np.ndarray:
    """x_k = sum_{tau=0}^{9} 0.7^tau u_{k-tau}, z_k = x_k + 0.5 x_k^2 + 0.2 x_k^3 (from rest)."""
    x = lag_matrix(u, 9) @ (0.7 ** np.arange(10))
    return x + 0.5 * x**2 + 0.2 * x**3


def test_tied_sed_mpk_identifies_small_wiener_system():
    """The tied SED-MPK (6.35) prior (smooth, exponentially decaying lags shared by every
    order) fits a Wiener system with a decaying impulse response from 300 samples."""
    rng = np.random.default_rng(5)
    u_train, u_test = rng.standard_normal(300), rng.standard_normal(300)
    y = _small_wiener(u_train) + 1e-2 * rng.standard_normal(300)
    est = VolterraGP("sed_mpk_tied", order=3, memory=9, adam_iters=0, lbfgs_iters=20)
    est.fit(u_train, y)
    assert fit_percent(_small_wiener(u_test), est.predict(u_test)) > 99.5
    kernel = est.gp_.model_.covar_module
    assert sum(p.numel() for p in kernel.parameters()) == 3 + 3  # alpha, beta, rho_0..rho_3

"""GP and NN estimators on the closed-form two-link arm; input validation of fit/predict."""

from __future__ import annotations

import numpy as np
import pytest

from mcpilco.models.inverse_dynamics import (
    GIPEstimator,
    GIPFrictionEstimator,
    NNEstimator,
    PPEstimator,
    RBFEstimator,
    SPEstimator,
    gmse,
    nmse,
)
from mcpilco.models.robot_data import make_dataset
from tests.models.inverse_dynamics.two_link import (
    random_states,
    two_link_data,
    two_link_mjcf,
    two_link_torque,
)

FAST = dict(adam_iters=30, lbfgs_iters=10)


def test_pp_with_the_true_model_predicts_the_closed_form() -> None:
    X, y, Xt, yt = two_link_data()
    pp = PPEstimator(two_link_mjcf(), blocks=("rigid",), **FAST).fit(X, y)
    mean, var = pp.predict(Xt)
    assert mean.shape == var.shape == yt.shape
    np.testing.assert_allclose(mean, yt, atol=1e-5 * np.abs(yt).max(), rtol=0)
    assert np.all(var >= 0)


def test_sp_with_the_true_model_predicts_the_closed_form() -> None:
    X, y, Xt, yt = two_link_data()
    sp = SPEstimator(two_link_mjcf(), blocks=("rigid",), **FAST).fit(X, y)
    mean, _ = sp.predict(Xt)
    assert np.all(nmse(yt, mean) < 1e-6)


def test_gip_learns_the_arm_from_data_alone() -> None:
    """GIP knows only the joint types; RBF with the same data and budget is far worse."""
    rng = np.random.default_rng(5)
    X = random_states(150, 2)
    y = two_link_torque(X[:, :2], X[:, 2:4], X[:, 4:]) + 1e-3 * rng.standard_normal((150, 2))
    Xt = random_states(100, 3)
    yt = two_link_torque(Xt[:, :2], Xt[:, 2:4], Xt[:, 4:])
    gip = GIPEstimator("RR", **FAST).fit(X, y)
    mean, var = gip.predict(Xt)
    err_gip = nmse(yt, mean)
    assert np.all(err_gip < 1e-3), err_gip
    rbf = RBFEstimator(**FAST).fit(X, y)
    err_rbf = nmse(yt, rbf.predict(Xt)[0])
    assert np.all(err_rbf > 10 * err_gip), (err_rbf, err_gip)
    assert gip.noise_variance_.shape == (2,)


def test_gip_with_friction_learns_arm_plus_joint_friction() -> None:
    """Closed-form arm plus viscous and Coulomb friction per joint: GIP+F reaches the noise,
    the plain GIP (no polynomial in qd represents sign(qd)) does not."""
    rng = np.random.default_rng(7)
    Fv, Fc = np.array([0.3, 0.2]), np.array([0.8, 0.5])

    def torque(X: np.ndarray) -> np.ndarray:
        rigid = two_link_torque(X[:, :2], X[:, 2:4], X[:, 4:])
        return rigid + Fv * X[:, 2:4] + Fc * np.sign(X[:, 2:4])

    X, Xt = random_states(200, 4), random_states(200, 6)
    y = torque(X) + 1e-3 * rng.standard_normal((200, 2))
    yt = torque(Xt)
    err_f = nmse(yt, GIPFrictionEstimator("RR", **FAST).fit(X, y).predict(Xt)[0])
    err_gip = nmse(yt, GIPEstimator("RR", **FAST).fit(X, y).predict(Xt)[0])
    assert np.all(err_f < 1e-4), err_f
    assert np.all(err_gip > 30 * err_f), (err_gip, err_f)
    with pytest.raises(ValueError, match="coulomb_velocity"):
        GIPFrictionEstimator("RR", coulomb_velocity=-1.0)


def test_nn_fits_and_returns_no_variance() -> None:
    X = random_states(400, 4)
    y = two_link_torque(X[:, :2], X[:, 2:4], X[:, 4:])
    nn = NNEstimator(hidden=64, max_epochs=60, patience=20, batch_size=64, lr=3e-3).fit(X, y)
    mean, var = nn.predict(X[:100])
    assert var is None and mean.shape == (100, 2)
    assert np.all(nmse(y[:100], mean) < 0.2)
    assert 1 <= nn.epochs_ <= 60


def test_fit_accepts_a_robot_dataset() -> None:
    X, y, _, _ = two_link_data()
    ds = make_dataset(dict(t=np.arange(80) * 0.01, q=X[:, :2], qd=X[:, 2:4], qdd=X[:, 4:], tau=y))
    pp = PPEstimator(two_link_mjcf(), blocks=("rigid",), **FAST).fit(ds)  # y from ds.tau
    np.testing.assert_allclose(pp.predict(ds)[0], y, atol=1e-5 * np.abs(y).max())


@pytest.mark.parametrize(
    ("X", "y", "match"),
    [
        (np.zeros((10, 5)), np.zeros((10, 2)), "3n columns"),
        (np.zeros(10), np.zeros((10, 2)), "2-D"),
        (np.zeros((10, 6)), np.zeros((9, 2)), r"shape \(10, 2\)"),
        (np.zeros((10, 6)), np.zeros((10, 3)), r"shape \(10, 2\)"),
        (np.zeros((0, 6)), np.zeros((0, 2)), "no rows"),
        (np.zeros((10, 6)), None, "y is None"),
    ],
)
def test_fit_rejects_mismatched_shapes(X, y, match) -> None:
    with pytest.raises(ValueError, match=match):
        RBFEstimator(**FAST).fit(X, y)


def test_fit_names_the_bad_column() -> None:
    X, y, _, _ = two_link_data()
    X = X.copy()
    X[7, 3] = np.nan  # qd2
    with pytest.raises(ValueError, match="row 7.*'qd2'"):
        NNEstimator().fit(X, y)
    y = y.copy()
    y[3, 1] = np.inf
    with pytest.raises(ValueError, match="row 3.*tau2"):
        NNEstimator().fit(two_link_data()[0], y)


def test_gip_checks_the_joint_count_and_predict_checks_fitting() -> None:
    X, y, _, _ = two_link_data()
    with pytest.raises(ValueError, match=r"shape \(N, 9\)"):
        GIPEstimator("RRP").fit(X, y)
    with pytest.raises(RuntimeError, match="not fitted"):
        GIPEstimator("RR").predict(X)


def test_metrics_match_hand_computation() -> None:
    y = np.array([[1.0, 0.0], [3.0, 2.0]])
    p = np.array([[2.0, 0.0], [3.0, 1.0]])
    np.testing.assert_allclose(nmse(y, p), [0.5 / 1.0, 0.5 / 1.0])
    assert gmse(y, p) == pytest.approx(0.5 + 0.5)
    with pytest.raises(ValueError, match="shapes differ"):
        nmse(y, p[:1])


def test_nystrom_gip_uses_every_row() -> None:
    """Hyperparameters on 60 rows, the regression on all 1500: the error against the closed
    form falls to about ``sigma sqrt(F / N)`` (F = 150 GIP monomials of an RR arm), well
    below the exact GP conditioned on the 60 rows alone."""
    from mcpilco.models.inverse_dynamics import NystromGIPEstimator

    rng = np.random.default_rng(7)
    sigma = 0.05
    X = random_states(1500, 8)
    y = two_link_torque(X[:, :2], X[:, 2:4], X[:, 4:]) + sigma * rng.standard_normal((1500, 2))
    Xt = random_states(300, 9)
    yt = two_link_torque(Xt[:, :2], Xt[:, 2:4], Xt[:, 4:])
    nys = NystromGIPEstimator("RR", inducing=300, hyper_points=60, **FAST).fit(X, y)
    mean, var = nys.predict(Xt)
    rmse = np.sqrt(np.mean((mean - yt) ** 2, axis=0))
    assert np.all(rmse < 0.5 * sigma), rmse
    assert np.all(var >= 0) and var.shape == yt.shape
    np.testing.assert_allclose(nys.predict_mean(Xt), mean, rtol=1e-6, atol=1e-9)
    assert np.sqrt(nys.noise_variance_) == pytest.approx([sigma, sigma], rel=0.15)
    rows = nys.hyper_rows_
    sub = GIPEstimator("RR", **FAST).fit(X[rows], y[rows])
    rmse_sub = np.sqrt(np.mean((sub.predict(Xt)[0] - yt) ** 2, axis=0))
    assert np.all(rmse < 0.5 * rmse_sub), (rmse, rmse_sub)
    # the regression refitted on other targets at the same hyperparameters
    nys.refit_targets(X, 2.0 * y)
    np.testing.assert_allclose(nys.predict_mean(Xt), 2.0 * mean, rtol=0.05, atol=0.05)

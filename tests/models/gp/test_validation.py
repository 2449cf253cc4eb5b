"""Bad input raises ValueError naming the column or shape; jitter escalation; never NaN."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mcpilco.models.gp import GPRegressor, jittered_cholesky

from .conftest import rbf_factory

FIT = dict(adam_iters=0, lbfgs_iters=0)


@pytest.fixture
def xy():
    rng = np.random.default_rng(0)
    return rng.normal(size=(20, 3)), rng.normal(size=(20, 2))


def gp(**kw) -> GPRegressor:
    return GPRegressor(rbf_factory(3), **kw)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_input_names_the_column(xy, bad) -> None:
    X, Y = xy
    X[4, 1] = bad
    with pytest.raises(ValueError, match=r"X\[:, 1\].*row 4"):
        gp().fit(X, Y, **FIT)
    with pytest.raises(ValueError, match=r"'velocity'"):
        gp(input_names=["position", "velocity", "torque"]).fit(X, Y, **FIT)


def test_non_finite_target_names_the_column(xy) -> None:
    X, Y = xy
    Y[7, 1] = np.nan
    with pytest.raises(ValueError, match=r"Y\[:, 1\]"):
        gp().fit(X, Y, **FIT)
    with pytest.raises(ValueError, match=r"'qdd'"):
        gp(output_names=["qd", "qdd"]).fit(X, Y, **FIT)


def test_constant_target_names_the_column(xy) -> None:
    X, Y = xy
    Y[:, 0] = 3.0
    with pytest.raises(ValueError, match=r"'qd' \(Y\[:, 0\]\) is constant"):
        gp(output_names=["qd", "qdd"]).fit(X, Y, **FIT)
    with pytest.raises(ValueError, match=r"Y\[:, 0\] is constant"):
        gp().fit(X, Y, **FIT)


def test_mismatched_lengths(xy) -> None:
    X, Y = xy
    with pytest.raises(ValueError, match=r"same number of rows.*\(20, 3\).*\(19, 2\)"):
        gp().fit(X, Y[:-1], **FIT)


def test_wrong_dimensionality(xy) -> None:
    X, Y = xy
    with pytest.raises(ValueError, match=r"X must be 2-D.*shape \(20,\)"):
        gp().fit(X[:, 0], Y, **FIT)
    with pytest.raises(ValueError, match=r"X must be 2-D.*\(2, 10, 3\)"):
        gp().fit(X.reshape(2, 10, 3), Y, **FIT)
    with pytest.raises(ValueError, match=r"Y must be 1-D \(N,\) or 2-D.*\(20, 2, 1\)"):
        gp().fit(X, Y[..., None], **FIT)


def test_empty_data() -> None:
    with pytest.raises(ValueError, match=r"X is empty.*\(0, 3\)"):
        gp().fit(np.zeros((0, 3)), np.zeros((0, 1)), **FIT)


def test_names_must_match_columns(xy) -> None:
    X, Y = xy
    with pytest.raises(ValueError, match="input_names has 2 names but X has 3 columns"):
        gp(input_names=["a", "b"]).fit(X, Y, **FIT)
    with pytest.raises(ValueError, match="output_names has 1 names but Y has 2 columns"):
        gp(output_names=["a"]).fit(X, Y, **FIT)


def test_predict_validates_inputs(xy) -> None:
    X, Y = xy
    model = gp(input_names=["p", "v", "u"]).fit(X, Y, **FIT)
    with pytest.raises(ValueError, match=r"X must have shape \(n, 3\).*\(5, 2\)"):
        model.predict(np.zeros((5, 2)))
    with pytest.raises(ValueError, match=r"X must be 2-D"):
        model.predict(np.zeros(3))
    bad = np.zeros((5, 3))
    bad[2, 2] = np.nan
    with pytest.raises(ValueError, match=r"'u' \(X\[:, 2\]\)"):
        model.predict(bad)
    with pytest.raises(RuntimeError, match="not fitted"):
        gp().predict(X)


def test_jitter_escalation_warns_on_duplicated_inputs_with_tiny_noise() -> None:
    X = np.repeat(np.linspace(0, 1, 80)[:, None], 2, axis=0)  # every input twice
    y = np.sin(3 * X[:, 0])
    model = GPRegressor(
        rbf_factory(1, lengthscale=1.0), standardize_x=False, noise_init=1e-15, noise_min=0.0
    ).fit(X, y, **FIT)
    with pytest.warns(RuntimeWarning, match=r"relative jitter of \d\.\de-\d\d"):
        mean, var = model.predict(X[:5])
    assert torch.isfinite(mean).all() and torch.isfinite(var).all()


def test_cholesky_failure_error_suggests_the_fix() -> None:
    A = -torch.eye(4, dtype=torch.float64)  # not PSD: no jitter up to 1e-3 can help
    with pytest.raises(ValueError, match="duplicate.*noise_min.*standardize"):
        jittered_cholesky(A)
    L, eps = jittered_cholesky(torch.eye(3, dtype=torch.float64) * 2.0)
    assert eps == 0.0
    torch.testing.assert_close(L, torch.eye(3, dtype=torch.float64) * 2.0**0.5)


def test_constructor_arguments_are_checked() -> None:
    with pytest.raises(ValueError, match="noise_init"):
        GPRegressor(rbf_factory(1), noise_init=1e-9, noise_min=1e-8)
    with pytest.raises(TypeError, match="callable"):
        GPRegressor("rbf")

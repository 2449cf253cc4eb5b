"""Values whose squares overflow float64 are rejected naming the column and row."""

from __future__ import annotations

import numpy as np
import pytest

from mcpilco.models.gp import GPRegressor

from .conftest import rbf_factory


@pytest.mark.parametrize(
    "where, value, message",
    [
        ("Y", 1e200, r"Y\[:, 0\] holds 1e\+200 at row 7"),
        ("X", 1e300, r"'speed' \(X\[:, 1\]\) holds 1e\+300 at row 7"),
    ],
)
def test_overflowing_values_are_named(where, value, message):
    rng = np.random.default_rng(0)
    X, Y = rng.normal(size=(20, 2)), rng.normal(size=(20, 1))
    (Y if where == "Y" else X)[7, 1 if where == "X" else 0] = value
    gp = GPRegressor(rbf_factory(2), input_names=["pos", "speed"])
    with pytest.raises(ValueError, match=message):
        gp.fit(X, Y, adam_iters=2, lbfgs_iters=0)


def test_prediction_inputs_beyond_the_limit_are_rejected():
    rng = np.random.default_rng(1)
    X = rng.normal(size=(15, 1))
    gp = GPRegressor(rbf_factory(1)).fit(X, np.sin(X), adam_iters=5, lbfgs_iters=0)
    with pytest.raises(ValueError, match=r"X\[:, 0\] holds -1e\+160 at row 1"):
        gp.predict(np.array([[0.0], [-1e160]]))
    mean, var = gp.predict(np.array([[1e149]]))  # far but representable: the prior
    assert np.isfinite(mean.numpy()).all() and np.isfinite(var.numpy()).all()
    residual, std = gp.loo_residuals()
    assert np.isfinite(residual.numpy()).all() and np.isfinite(std.numpy()).all()

"""GPRegressor against independent truth: closed-form numpy posterior, known hyperparameters."""

from __future__ import annotations

import math

import gpytorch
import numpy as np
import pytest
import torch

from mcpilco.models.gp import GPRegressor, exact_gp_settings

from .conftest import rbf_factory


def numpy_gp_posterior(X, y, Xs, lengthscale, outputscale, noise):
    """Closed-form GP posterior (zero mean, SE kernel) written directly in numpy."""

    def k(a, b):
        d2 = ((a[:, None, :] - b[None, :, :]) / lengthscale) ** 2
        return outputscale * np.exp(-0.5 * d2.sum(-1))

    K = k(X, X) + noise * np.eye(len(X))
    Ks = k(Xs, X)
    mean = Ks @ np.linalg.solve(K, y)
    var = outputscale - np.einsum("ij,ji->i", Ks, np.linalg.solve(K, Ks.T))
    lml = -0.5 * y @ np.linalg.solve(K, y) - 0.5 * np.linalg.slogdet(K)[1]
    lml -= 0.5 * len(X) * math.log(2 * math.pi)
    return mean, var, lml


def _fixed_gp(X, y, lengthscale, outputscale, noise) -> GPRegressor:
    """An RBF GP with the given hyperparameters, no standardisation and no training."""
    return GPRegressor(
        rbf_factory(X.shape[1], lengthscale=torch.tensor(lengthscale), outputscale=outputscale),
        standardize_x=False,
        standardize_y=False,
        noise_init=noise,
    ).fit(X, y, adam_iters=0, lbfgs_iters=0)


def test_posterior_equals_closed_form_without_standardisation() -> None:
    rng = np.random.default_rng(1)
    X = rng.uniform(-1, 1, size=(25, 2))
    y = np.sin(3 * X[:, 0]) * X[:, 1]
    Xs = rng.uniform(-1.5, 1.5, size=(30, 2))
    ls, os_, noise = np.array([0.4, 0.7]), 1.3, 0.02
    gp = _fixed_gp(X, y, ls, os_, noise)
    mean, var = gp.predict(Xs)
    ref_mean, ref_var, ref_lml = numpy_gp_posterior(X, y, Xs, ls, os_, noise)
    assert mean.shape == var.shape == (30, 1)
    np.testing.assert_allclose(mean[:, 0].numpy(), ref_mean, rtol=1e-9, atol=1e-10)
    np.testing.assert_allclose(var[:, 0].numpy(), ref_var, rtol=1e-8, atol=1e-10)
    _, var_noisy = gp.predict(Xs, include_noise=True)
    np.testing.assert_allclose(var_noisy[:, 0].numpy(), ref_var + noise, rtol=1e-8)
    np.testing.assert_allclose(gp.log_marginal_likelihood().numpy(), [ref_lml], rtol=1e-10)
    np.testing.assert_allclose(gp.noise_variance.numpy(), [noise], rtol=1e-10)


def test_loo_residuals_equal_posteriors_without_each_point() -> None:
    """Eq. 5.12 of Rasmussen & Williams against N closed-form posteriors on N - 1 points."""
    rng = np.random.default_rng(3)
    X = rng.uniform(-1, 1, size=(20, 2))
    y = np.cos(2 * X[:, 0]) + X[:, 1] ** 2 + 0.05 * rng.standard_normal(20)
    y[7] += 1.5  # an outlier: its LOO score stands out
    ls, os_, noise = np.array([0.5, 0.8]), 1.1, 0.01
    gp = _fixed_gp(X, y, ls, os_, noise)
    res, std = gp.loo_residuals()
    assert res.shape == std.shape == (20, 1)
    for i in range(20):
        keep = np.arange(20) != i
        mean, var, _ = numpy_gp_posterior(X[keep], y[keep], X[i : i + 1], ls, os_, noise)
        np.testing.assert_allclose(res[i, 0].item(), y[i] - mean[0], rtol=1e-8, atol=1e-10)
        np.testing.assert_allclose(std[i, 0].item() ** 2, var[0] + noise, rtol=1e-8)
    score = (res / std).abs()[:, 0].numpy()
    assert score.argmax() == 7


def test_posterior_in_original_units_with_standardisation() -> None:
    rng = np.random.default_rng(2)
    X = rng.uniform(-1, 1, size=(30, 2)) * np.array([10.0, 0.1]) + np.array([5.0, -3.0])
    y = 100.0 + 20.0 * np.sin(X[:, 0] / 3) + 50 * X[:, 1]
    Xs = rng.uniform(-1, 1, size=(20, 2)) * np.array([10.0, 0.1]) + np.array([5.0, -3.0])
    ls, os_, noise = np.array([0.8, 1.2]), 0.9, 0.01
    gp = GPRegressor(
        rbf_factory(2, lengthscale=torch.tensor(ls), outputscale=os_), noise_init=noise
    ).fit(X, y, adam_iters=0, lbfgs_iters=0)
    mx, sx = X.mean(0), X.std(0)
    my, sy = y.mean(), y.std()
    ref_mean, ref_var, ref_lml = numpy_gp_posterior(
        (X - mx) / sx, (y - my) / sy, (Xs - mx) / sx, ls, os_, noise
    )
    mean, var = gp.predict(Xs)
    np.testing.assert_allclose(mean[:, 0].numpy(), my + sy * ref_mean, rtol=1e-9)
    np.testing.assert_allclose(var[:, 0].numpy(), sy**2 * ref_var, rtol=1e-7, atol=1e-9)
    # the mean-only path (no L^-1) gives the same closed-form mean
    np.testing.assert_allclose(gp.predict_mean(Xs)[:, 0].numpy(), my + sy * ref_mean, rtol=1e-9)
    np.testing.assert_allclose(gp.noise_variance.numpy(), [noise * sy**2], rtol=1e-10)
    # change of variables: log p(y) = log p(y_std) - N log s_y
    np.testing.assert_allclose(
        gp.log_marginal_likelihood().numpy(), [ref_lml - len(y) * math.log(sy)], rtol=1e-10
    )


def test_training_recovers_known_noise_and_lengthscale() -> None:
    """Sample from a GP prior with known hyperparameters; ML-II recovers them roughly."""
    rng = np.random.default_rng(3)
    n, ls, os_, noise = 300, 0.3, 1.0, 0.01
    X = rng.uniform(-2, 2, size=(n, 1))
    K = os_ * np.exp(-0.5 * (X - X.T) ** 2 / ls**2) + 1e-10 * np.eye(n)
    f = np.linalg.cholesky(K) @ rng.standard_normal(n)
    y = f + math.sqrt(noise) * rng.standard_normal(n)
    gp = GPRegressor(rbf_factory(1), standardize_x=False, standardize_y=False, noise_init=0.1)
    gp.fit(X, y, adam_iters=100, adam_lr=0.05, lbfgs_iters=50)
    kern = gp.model_.covar_module
    assert 0.5 * noise < float(gp.noise_variance[0]) < 2.0 * noise
    assert 0.7 * ls < float(kern.base_kernel.lengthscale.detach().reshape(-1)[0]) < 1.4 * ls
    assert 0.25 * os_ < float(kern.outputscale.detach().reshape(-1)[0]) < 4.0 * os_


def test_training_increases_marginal_likelihood(data_2out) -> None:
    X, Y = data_2out
    gp = GPRegressor(rbf_factory(3)).fit(X, Y, adam_iters=0, lbfgs_iters=0)
    before = gp.log_marginal_likelihood()
    gp.fit(X, Y, adam_iters=40, lbfgs_iters=20)
    after = gp.log_marginal_likelihood()
    assert (after > before + 1.0).all()


def test_log_marginal_likelihood_matches_gpytorch(data_2out) -> None:
    X, Y = data_2out
    gp = GPRegressor(rbf_factory(3)).fit(X, Y, adam_iters=20, lbfgs_iters=0)
    model = gp.model_
    model.train()
    mll = gpytorch.mlls.ExactMarginalLogLikelihood(model.likelihood, model)
    with torch.no_grad(), exact_gp_settings():
        ref = mll(model(*model.train_inputs), model.train_targets) * len(X)
    model.eval()
    ref = ref - len(X) * gp.y_scale_.log()
    torch.testing.assert_close(gp.log_marginal_likelihood(), ref, rtol=1e-10, atol=1e-8)


def test_multi_output_batch_equals_separate_fits(data_2out) -> None:
    """Adam is element-wise, so the batched fit must equal one fit per output column."""
    X, Y = data_2out
    Xs = np.random.default_rng(4).uniform(-2, 2, size=(15, 3))
    kw = dict(adam_iters=30, lbfgs_iters=0)
    joint = GPRegressor(rbf_factory(3)).fit(X, Y, **kw)
    mean, var = joint.predict(Xs)
    for j in range(2):
        single = GPRegressor(rbf_factory(3)).fit(X, Y[:, j], **kw)
        m1, v1 = single.predict(Xs)
        torch.testing.assert_close(mean[:, j : j + 1], m1, rtol=1e-8, atol=1e-8)
        torch.testing.assert_close(var[:, j : j + 1], v1, rtol=1e-7, atol=1e-10)
        torch.testing.assert_close(joint.noise_variance[j : j + 1], single.noise_variance)


def test_lbfgs_phase_runs_and_progress_bar(data_2out, capsys) -> None:
    X, Y = data_2out
    gp = GPRegressor(rbf_factory(3)).fit(X, Y, adam_iters=5, lbfgs_iters=10, progress=True)
    mean, var = gp.predict(X[:5])
    assert torch.isfinite(mean).all() and (var >= 0).all()


def test_refit_warm_starts_from_current_hyperparameters(data_2out) -> None:
    X, Y = data_2out
    gp = GPRegressor(rbf_factory(3)).fit(X[:40], Y[:40], adam_iters=40, lbfgs_iters=10)
    ls = gp.model_.covar_module.base_kernel.lengthscale.detach().clone()
    model = gp.model_
    gp.fit(X, Y, adam_iters=0, lbfgs_iters=0)  # no training: hyperparameters carried over
    assert gp.model_ is model
    torch.testing.assert_close(gp.model_.covar_module.base_kernel.lengthscale.detach(), ls)
    assert gp.train_x_.shape == (60, 3)
    fresh = GPRegressor(rbf_factory(3)).fit(X, Y, adam_iters=0, lbfgs_iters=0)
    assert not torch.allclose(fresh.model_.covar_module.base_kernel.lengthscale, ls)


def test_save_load_roundtrip_gives_identical_predictions(tmp_path, data_2out) -> None:
    X, Y = data_2out
    gp = GPRegressor(rbf_factory(3), output_names=["a", "b"]).fit(
        X, Y, adam_iters=20, lbfgs_iters=5
    )
    Xs = np.random.default_rng(5).uniform(-2, 2, size=(10, 3))
    mean, var = gp.predict(Xs)
    path = tmp_path / "gp.pt"
    gp.save(path)
    loaded = GPRegressor.load(path, rbf_factory(3))
    m2, v2 = loaded.predict(Xs)
    assert torch.equal(mean, m2) and torch.equal(var, v2)
    assert loaded.output_names == ["a", "b"]
    torch.testing.assert_close(loaded.noise_variance, gp.noise_variance, rtol=0, atol=0)
    p1, p2 = gp.cached_predictor(torch.float32), loaded.cached_predictor(torch.float32)
    x = torch.as_tensor(Xs, dtype=torch.float32)
    assert torch.equal(p1(x)[0], p2(x)[0])


def test_load_rejects_mismatched_kernel(tmp_path, data_2out) -> None:
    X, Y = data_2out
    gp = GPRegressor(rbf_factory(3)).fit(X, Y, adam_iters=0, lbfgs_iters=0)
    gp.save(tmp_path / "gp.pt")

    def other(batch_shape):
        return gpytorch.kernels.LinearKernel(batch_shape=batch_shape)

    with pytest.raises(ValueError, match="does not match"):
        GPRegressor.load(tmp_path / "gp.pt", other)


def test_max_points_conditions_on_greedy_subset() -> None:
    rng = np.random.default_rng(6)
    X = rng.uniform(-3, 3, size=(400, 2))
    y = np.sin(X[:, 0]) * np.cos(X[:, 1]) + 0.02 * rng.standard_normal(400)
    gp = GPRegressor(rbf_factory(2)).fit(X, y, adam_iters=30, lbfgs_iters=5, max_points=80)
    assert gp.train_x_.shape == (80, 2)
    idx = gp.subset_indices_
    assert len(set(idx.tolist())) == 80
    np.testing.assert_array_equal(gp.train_x_.numpy(), X[idx.numpy()])
    Xt = rng.uniform(-2.5, 2.5, size=(200, 2))
    mean, _ = gp.predict(Xt)
    truth = np.sin(Xt[:, 0]) * np.cos(Xt[:, 1])
    assert np.sqrt(np.mean((mean[:, 0].numpy() - truth) ** 2)) < 0.1


def test_exact_cholesky_path_at_n5000() -> None:
    """One marginal-likelihood evaluation at N=5000 via GPyTorch equals the dense Cholesky."""
    rng = np.random.default_rng(7)
    n = 5000
    X = rng.uniform(-3, 3, size=(n, 1))
    y = np.sin(2 * X[:, 0]) + 0.1 * rng.standard_normal(n)
    gp = GPRegressor(rbf_factory(1), noise_init=0.05).fit(X, y, adam_iters=0, lbfgs_iters=0)
    model = gp.model_
    model.train()
    mll = gpytorch.mlls.ExactMarginalLogLikelihood(model.likelihood, model)
    with torch.no_grad(), exact_gp_settings():
        ref = mll(model(*model.train_inputs), model.train_targets) * n - n * gp.y_scale_.log()
    model.eval()
    # CG / Lanczos would differ by ~1e-3 relative; the exact Cholesky path agrees to ~1e-12.
    torch.testing.assert_close(gp.log_marginal_likelihood(), ref, rtol=1e-9, atol=1e-6)

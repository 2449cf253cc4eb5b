"""CachedPredictor against GPyTorch's own posterior, float32 accuracy, gradients, shapes."""

from __future__ import annotations

import gpytorch
import numpy as np
import pytest
import torch

from mcpilco.models.gp import CachedPredictor, GPRegressor

from .conftest import rbf_factory

K = gpytorch.kernels


def composite_factory(batch_shape: torch.Size) -> gpytorch.kernels.Kernel:
    """RBF on two dims + linear on the third, times a constant: exercises the tree walker."""
    rbf = K.ScaleKernel(
        K.RBFKernel(ard_num_dims=2, batch_shape=batch_shape, active_dims=[0, 1]),
        batch_shape=batch_shape,
    )
    lin = K.LinearKernel(batch_shape=batch_shape, active_dims=[2])
    return (rbf + lin) * K.ConstantKernel(batch_shape=batch_shape)


@pytest.fixture(scope="module")
def fitted() -> dict[str, GPRegressor]:
    rng = np.random.default_rng(0)
    X = rng.uniform(-2, 2, size=(60, 3))
    Y = np.stack([np.sin(X[:, 0]) + 0.3 * X[:, 2], 10.0 + 5.0 * np.cos(X[:, 1] * X[:, 0])], axis=1)
    Y += 0.05 * rng.standard_normal(Y.shape)
    # N = 200: L^{-1} is split into several column panels (the panel product path)
    X2 = rng.uniform(-2, 2, size=(200, 3))
    Y2 = np.stack([np.sin(2 * X2[:, 0]) * X2[:, 1], np.cos(X2[:, 2] + X2[:, 0])], axis=1)
    Y2 += 0.01 * rng.standard_normal(Y2.shape)
    return {
        "rbf": GPRegressor(rbf_factory(3)).fit(X, Y, adam_iters=30, lbfgs_iters=10),
        "composite": GPRegressor(composite_factory).fit(X, Y, adam_iters=30, lbfgs_iters=0),
        "rbf_n200": GPRegressor(rbf_factory(3)).fit(X2, Y2, adam_iters=15, lbfgs_iters=0),
    }


def _test_points(n: int = 40, seed: int = 1) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    return torch.rand(n, 3, generator=gen, dtype=torch.float64) * 5 - 2.5


@pytest.mark.parametrize("name", ["rbf", "composite", "rbf_n200"])
def test_float64_predictor_matches_gpytorch_posterior(fitted, name) -> None:
    gp = fitted[name]
    x = _test_points()
    ref_mean, ref_var = gp.predict_gpytorch(x)
    pred = gp.cached_predictor(torch.float64)
    if name == "rbf_n200":
        assert pred.linv.num_panels > 1
    mean, var = pred(x)
    assert mean.dtype == var.dtype == torch.float64
    torch.testing.assert_close(mean, ref_mean, rtol=0, atol=1e-8)
    torch.testing.assert_close(var, ref_var, rtol=0, atol=1e-8)
    _, ref_noisy = gp.predict_gpytorch(x, include_noise=True)
    torch.testing.assert_close(var + pred.noise_variance, ref_noisy, rtol=0, atol=1e-8)


def test_float32_predictor_close_to_float64(fitted) -> None:
    gp = fitted["rbf"]
    x = _test_points()
    m64, v64 = gp.cached_predictor(torch.float64)(x)
    pred32 = gp.cached_predictor(torch.float32)
    m32, v32 = pred32(x.float())
    assert m32.dtype == v32.dtype == pred32.noise_variance.dtype == torch.float32
    # relative to the output scale (mean) and to the prior variance (variance)
    y_scale = gp.y_scale_
    prior = gp.prior_variance(x)
    assert ((m32.double() - m64).abs() / y_scale).max() < 1e-4
    assert ((v32.double() - v64).abs() / prior).max() < 1e-4


def test_predictor_gradcheck_wrt_inputs(fitted) -> None:
    for name in ("rbf", "composite", "rbf_n200"):
        pred = fitted[name].cached_predictor(torch.float64)
        x = _test_points(4, seed=2).requires_grad_(True)
        assert torch.autograd.gradcheck(pred, (x,), eps=1e-6, atol=1e-6)


@pytest.mark.parametrize("name", ["rbf", "rbf_n200"])
def test_predictor_gradient_matches_gpytorch_autograd(fitted, name) -> None:
    """d mean / dx and d var / dx agree with autograd through GPyTorch's posterior."""
    gp = fitted[name]
    x = _test_points(5, seed=3)
    pred = gp.cached_predictor(torch.float64)
    x1 = x.clone().requires_grad_(True)
    mean, var = pred(x1)
    g1 = torch.autograd.grad((mean * torch.tensor([1.0, -2.0])).sum() + var.sum(), x1)[0]
    x2 = x.clone().requires_grad_(True)
    xs = gp._standardize_x(x2)
    model = gp.model_
    with gpytorch.settings.fast_pred_var(False), gpytorch.settings.max_cholesky_size(10**5):
        post = model(xs.expand(2, *xs.shape))
        m_ref = post.mean.T * gp.y_scale_ + gp.y_mean_
        v_ref = post.variance.T * gp.y_scale_**2
    g2 = torch.autograd.grad((m_ref * torch.tensor([1.0, -2.0])).sum() + v_ref.sum(), x2)[0]
    torch.testing.assert_close(g1, g2, rtol=1e-6, atol=1e-8)


def test_arbitrary_leading_dims(fitted) -> None:
    pred = fitted["rbf"].cached_predictor(torch.float32)
    x = _test_points(24).float()
    mean, var = pred(x)
    mean3, var3 = pred(x.reshape(2, 3, 4, 3))
    assert mean3.shape == var3.shape == (2, 3, 4, 2)
    torch.testing.assert_close(mean3.reshape(24, 2), mean)
    torch.testing.assert_close(var3.reshape(24, 2), var)
    m1, v1 = pred(x[0])
    assert m1.shape == (2,)
    torch.testing.assert_close(m1, mean[0])


def test_predictor_call_path_is_plain_tensors(fitted) -> None:
    """No LinearOperator in the call path: outputs are plain tensors; module holds buffers."""
    pred = fitted["composite"].cached_predictor(torch.float32)
    assert isinstance(pred, CachedPredictor) and isinstance(pred, torch.nn.Module)
    mean, var = pred(_test_points(3).float())
    assert type(mean) is torch.Tensor and type(var) is torch.Tensor
    assert not any(p.requires_grad for p in pred.parameters())
    names = {n for n, _ in pred.named_buffers()}
    assert {"alpha", "train_x", "x_mean", "x_scale", "y_mean", "y_scale"} <= names
    assert {f"linv.panel{j}" for j in range(pred.linv.num_panels)} <= names


def test_predictor_rejects_wrong_dimension_and_nan(fitted) -> None:
    pred = fitted["rbf"].cached_predictor(torch.float32)
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        pred(torch.zeros(5, 4))
    with pytest.raises(ValueError, match="NaN"):
        pred(torch.tensor([[0.0, float("nan"), 0.0]]))
    pred.validate = False
    pred(torch.zeros(5, 3))  # hot path still works


def test_predict_matches_cached_predictor_and_variance_nonnegative(fitted) -> None:
    gp = fitted["rbf"]
    x = _test_points()
    mean, var = gp.predict(x.numpy())
    m2, v2 = gp.cached_predictor(torch.float64)(x)
    torch.testing.assert_close(mean, m2)
    torch.testing.assert_close(var, v2)
    assert (var >= 0).all()
    far = torch.full((1, 3), 50.0, dtype=torch.float64)  # far away: prior variance, prior mean
    m_far, v_far = gp.predict(far)
    torch.testing.assert_close(v_far, gp.prior_variance(far), rtol=1e-8, atol=0)
    torch.testing.assert_close(m_far, gp.y_mean_.reshape(1, 2), rtol=1e-8, atol=1e-8)

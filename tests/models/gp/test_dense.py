"""dense_covar / dense_diag against GPyTorch's own (lazy) kernel evaluation."""

from __future__ import annotations

import gpytorch
import pytest
import torch

from mcpilco.models.gp import dense_covar, dense_diag

K = gpytorch.kernels
B = torch.Size([2])


def _randomize(kernel: gpytorch.kernels.Kernel, seed: int) -> gpytorch.kernels.Kernel:
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in kernel.parameters():
            p.copy_(torch.randn(p.shape, generator=gen, dtype=p.dtype) * 0.5)
    return kernel.double()


KERNELS = {
    "scale_rbf_ard_batch": lambda: K.ScaleKernel(
        K.RBFKernel(ard_num_dims=4, batch_shape=B), batch_shape=B
    ),
    "rbf_plus_linear_active": lambda: (
        K.ScaleKernel(K.RBFKernel(ard_num_dims=2, batch_shape=B, active_dims=[0, 2]), batch_shape=B)
        + K.LinearKernel(batch_shape=B, active_dims=[1, 3])
    ),
    "product_with_constant": lambda: (
        K.RBFKernel(batch_shape=B, active_dims=[3])
        * K.ConstantKernel(batch_shape=B)
        * K.ScaleKernel(K.RBFKernel(ard_num_dims=4, batch_shape=B), batch_shape=B)
    ),
    "nested_scale_of_sum": lambda: K.ScaleKernel(
        K.AdditiveKernel(
            K.RBFKernel(batch_shape=B, active_dims=[0]), K.LinearKernel(batch_shape=B)
        ),
        batch_shape=B,
    ),
    "matern_fallback": lambda: K.ScaleKernel(
        K.MaternKernel(nu=2.5, ard_num_dims=4, batch_shape=B), batch_shape=B
    ),
    "unbatched_rbf": lambda: K.ScaleKernel(K.RBFKernel(ard_num_dims=4)),
}


@pytest.mark.parametrize("name", sorted(KERNELS))
def test_dense_covar_matches_gpytorch(name: str) -> None:
    kernel = _randomize(KERNELS[name](), seed=len(name))
    gen = torch.Generator().manual_seed(1)
    x1 = torch.randn(2, 7, 4, generator=gen, dtype=torch.float64)
    x2 = torch.randn(2, 5, 4, generator=gen, dtype=torch.float64)
    with torch.no_grad():
        ref = kernel(x1, x2).to_dense()
        ref_sym = kernel(x1, x1).to_dense()
        ref_diag = kernel(x1, x1, diag=True)
        got = dense_covar(kernel, x1, x2)
        got_sym = dense_covar(kernel, x1, x1)
        got_diag = dense_diag(kernel, x1)
    torch.testing.assert_close(got.expand_as(ref), ref, rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(got_sym.expand_as(ref_sym), ref_sym, rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(got_diag.expand_as(ref_diag), ref_diag, rtol=1e-10, atol=1e-12)
    assert isinstance(got, torch.Tensor) and type(got) is torch.Tensor


def test_dense_covar_broadcasts_unbatched_inputs_over_kernel_batch() -> None:
    kernel = _randomize(KERNELS["scale_rbf_ard_batch"](), seed=3)
    x = torch.randn(6, 4, dtype=torch.float64)
    got = dense_covar(kernel, x, x)
    assert got.shape == (2, 6, 6)
    ref = kernel(x.expand(2, 6, 4)).to_dense()
    torch.testing.assert_close(got, ref.detach(), rtol=1e-10, atol=1e-12)


def test_dense_rbf_is_differentiable_wrt_hyperparameters() -> None:
    kernel = _randomize(KERNELS["scale_rbf_ard_batch"](), seed=4)
    x = torch.randn(2, 5, 4, dtype=torch.float64)
    dense_covar(kernel, x, x).sum().backward()
    assert kernel.base_kernel.raw_lengthscale.grad is not None
    assert torch.isfinite(kernel.base_kernel.raw_lengthscale.grad).all()


def test_scaled_rbf_grad_path_equals_inplace_path_and_zero_outputscale_is_finite() -> None:
    """With and without autograd (the latter clamps and exps in place) the values agree with
    GPyTorch; an outputscale of exactly 0 gives a matrix of at most the smallest normal float
    (the documented floor) and finite input gradients."""
    kernel = _randomize(KERNELS["scale_rbf_ard_batch"](), seed=5)
    gen = torch.Generator().manual_seed(2)
    x1 = torch.randn(2, 6, 4, generator=gen, dtype=torch.float64)
    x2 = torch.randn(2, 3, 4, generator=gen, dtype=torch.float64).requires_grad_(True)
    with torch.no_grad():
        ref = kernel(x1, x2).to_dense()
        nograd = dense_covar(kernel, x1, x2)
    withgrad = dense_covar(kernel, x1, x2)
    assert withgrad.requires_grad
    torch.testing.assert_close(nograd, ref, rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(withgrad.detach(), ref, rtol=1e-10, atol=1e-12)
    with torch.no_grad():
        kernel.raw_outputscale.fill_(-800.0)  # softplus underflows to exactly 0
    assert float(kernel.outputscale.detach().abs().max()) == 0.0
    zero = dense_covar(kernel, x1, x2)
    assert 0.0 <= float(zero.detach().min())
    # exp(log tiny) rounds to tiny up to a few ulps
    assert float(zero.detach().max()) <= torch.finfo(torch.float64).tiny * (1 + 1e-12)
    (g,) = torch.autograd.grad(zero.sum(), x2)
    assert torch.isfinite(g).all()

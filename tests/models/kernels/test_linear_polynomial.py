"""Linear, PK and IPK kernels against explicit per-pair loops."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mcpilco.models.kernels import LinearKernel, PolynomialKernel


def loop_kernel(x, y, offset, w, power):
    out = np.empty((len(x), len(y)))
    for i, a in enumerate(x):
        for j, b in enumerate(y):
            out[i, j] = (offset + sum(w[t] * a[t] * b[t] for t in range(len(w)))) ** power
    return out


def test_linear_kernel_formula():
    rng = np.random.default_rng(0)
    x, y = rng.normal(size=(6, 3)), rng.normal(size=(4, 3))
    k = LinearKernel(3).double()
    k.sigma2 = 0.7
    k.Sigma_diag = torch.tensor([0.5, 2.0, 0.1], dtype=torch.float64)
    K = k(torch.from_numpy(x), torch.from_numpy(y)).to_dense().detach().numpy()
    np.testing.assert_allclose(K, loop_kernel(x, y, 0.7, [0.5, 2.0, 0.1], 1), rtol=1e-12)


@pytest.mark.parametrize(("degree", "homogeneous"), [(1, True), (2, True), (3, False), (4, False)])
def test_polynomial_kernel_formula(degree, homogeneous):
    rng = np.random.default_rng(degree)
    x, y = rng.normal(size=(5, 2)), rng.normal(size=(3, 2))
    w = [0.3, 1.4]
    k = PolynomialKernel(degree, 2, homogeneous=homogeneous).double()
    k.Sigma_diag = torch.tensor(w, dtype=torch.float64)
    offset = 0.0
    if not homogeneous:
        k.sigma2 = offset = 0.9
    K = k(torch.from_numpy(x), torch.from_numpy(y)).to_dense().detach().numpy()
    np.testing.assert_allclose(K, loop_kernel(x, y, offset, w, degree), rtol=1e-12)


def test_homogeneous_pk_has_no_sigma2_parameter():
    k = PolynomialKernel(2, 3, homogeneous=True)
    assert [n for n, _ in k.named_parameters()] == ["raw_Sigma_diag"]
    assert (k.sigma2 == 0).all()
    with pytest.raises(AttributeError):
        k.sigma2 = 1.0


def test_last_dim_is_batch_is_rejected_with_a_hint():
    k = LinearKernel(2)
    with pytest.raises(NotImplementedError, match="active_dims"):
        k.forward(torch.randn(3, 2), torch.randn(3, 2), last_dim_is_batch=True)


@pytest.mark.parametrize(
    "make",
    [
        lambda: LinearKernel(3),
        lambda: PolynomialKernel(2, 3, homogeneous=False),
    ],
)
def test_float64_kernel_on_float32_inputs_returns_float32(make):
    """Hyperparameters are cast to the input dtype (float32 cached predictors)."""
    k = make().double()
    x = torch.randn(5, 3)
    K32 = k(x).to_dense()
    assert K32.dtype == torch.float32
    torch.testing.assert_close(K32.double(), k(x.double()).to_dense(), rtol=1e-5, atol=1e-5)


def test_ipk_with_fixed_offset_is_thesis_6_23_and_trains_only_sigma():
    """``fixed_sigma2=1``: (1 + x^T Sigma x')^p, no offset parameter, setter refused."""
    rng = np.random.default_rng(7)
    x, y = rng.normal(size=(5, 3)), rng.normal(size=(4, 3))
    w = [0.2, 0.6, 1.1]
    k = PolynomialKernel(3, 3, homogeneous=False, fixed_sigma2=1.0).double()
    k.Sigma_diag = torch.tensor(w, dtype=torch.float64)
    assert [n for n, _ in k.named_parameters()] == ["raw_Sigma_diag"]
    K = k(torch.from_numpy(x), torch.from_numpy(y)).to_dense().detach().numpy()
    np.testing.assert_allclose(K, loop_kernel(x, y, 1.0, w, 3), rtol=1e-12)
    with pytest.raises(AttributeError, match="fixed"):
        k.sigma2 = 2.0
    with pytest.raises(ValueError, match="homogeneous=False"):
        PolynomialKernel(2, 3, homogeneous=True, fixed_sigma2=1.0)
    with pytest.raises(ValueError, match="fixed_sigma2"):
        PolynomialKernel(2, 3, homogeneous=False, fixed_sigma2=-1.0)

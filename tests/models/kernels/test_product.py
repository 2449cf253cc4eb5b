"""Blocked product-of-linear-kernels Gram matrix against plain autograd (second implementation)."""

from __future__ import annotations

import pytest
import torch

import mcpilco.models.kernels.product as product
from mcpilco.models.kernels import GIPKernel
from mcpilco.models.kernels.product import linear_product_gram

F64 = torch.float64


def naive_gram(x1, x2, factors):
    """The same product with one full-size autograd op per factor."""
    out = None
    for cols, w, s in factors:
        f = s[..., None, None] + (x1[..., cols] * w.unsqueeze(-2)) @ x2[..., cols].mT
        out = f if out is None else out * f
    return out


def make_factors(batch: tuple[int, ...], gen: torch.Generator):
    def leaf(*shape):
        return torch.rand(*shape, generator=gen, dtype=F64).requires_grad_()

    return [
        ([0, 3], leaf(*batch, 2), leaf(*batch)),  # non-contiguous columns
        (slice(4, 8), leaf(*batch, 4), leaf(*batch)),
        (slice(1, 2), leaf(1, 1), torch.zeros(1, dtype=F64, requires_grad=True)),  # homogeneous
    ]


@pytest.mark.parametrize("block", [7, 1 << 18])  # many row blocks / one block
@pytest.mark.parametrize("x_batch", [(), (3,)])
def test_value_and_gradients_match_autograd(monkeypatch, block, x_batch):
    monkeypatch.setattr(product, "BLOCK_ELEMENTS", block)
    gen = torch.Generator().manual_seed(0)
    x1 = torch.randn(*x_batch, 9, 8, generator=gen, dtype=F64, requires_grad=True)
    x2 = torch.randn(*x_batch, 5, 8, generator=gen, dtype=F64, requires_grad=True)
    factors = make_factors((3,), gen)
    leaves = [x1, x2] + [t for f in factors for t in f[1:]]
    a, b = linear_product_gram(x1, x2, factors), naive_gram(x1, x2, factors)
    assert a.shape == b.shape == (3, 9, 5)
    torch.testing.assert_close(a, b, rtol=1e-13, atol=1e-13)
    G = torch.randn(a.shape, generator=gen, dtype=F64)
    ga = torch.autograd.grad((a * G).sum(), leaves)
    gb = torch.autograd.grad((b * G).sum(), leaves)
    for u, v in zip(ga, gb, strict=True):
        assert u.shape == v.shape
        torch.testing.assert_close(u, v, rtol=1e-12, atol=1e-12)


def test_gradcheck(monkeypatch):
    monkeypatch.setattr(product, "BLOCK_ELEMENTS", 10)
    gen = torch.Generator().manual_seed(1)
    x1 = torch.randn(4, 8, generator=gen, dtype=F64, requires_grad=True)
    x2 = torch.randn(3, 8, generator=gen, dtype=F64, requires_grad=True)
    factors = make_factors((2,), gen)
    cols = [c for c, _, _ in factors]
    params = tuple(t for f in factors for t in f[1:])

    def fn(a, b, *p):
        return linear_product_gram(a, b, [(c, p[2 * i], p[2 * i + 1]) for i, c in enumerate(cols)])

    assert torch.autograd.gradcheck(fn, (x1, x2, *params))


def test_gip_kernel_equals_product_of_its_mpks():
    """GIPKernel's blocked Gram matrix equals the product of its MPK factors' own forwards."""
    gen = torch.Generator().manual_seed(2)
    k = GIPKernel("RPRR", batch_shape=torch.Size([2])).double()
    with torch.no_grad():
        for p in k.parameters():
            p.add_(0.5 * torch.randn(p.shape, generator=gen, dtype=F64))
    x = torch.randn(30, k.ard_num_dims, generator=gen, dtype=F64)
    s = k._dyn_start
    ref = k.dynamics_kernel.forward(x[:, s:], x[:, s:])
    for b, kb in enumerate(k.joint_kernels):
        ref = ref * kb.forward(k._joint_slice(x, b), k._joint_slice(x, b))
    got = k.forward(x, x)
    torch.testing.assert_close(got, ref, rtol=1e-12, atol=1e-12)
    G = torch.randn(got.shape, generator=gen, dtype=F64)
    g_got = torch.autograd.grad((got * G).sum(), list(k.parameters()))
    g_ref = torch.autograd.grad((ref * G).sum(), list(k.parameters()))
    for u, v in zip(g_got, g_ref, strict=True):
        torch.testing.assert_close(u, v, rtol=1e-10, atol=1e-12)


def test_no_factor_is_an_error():
    x = torch.zeros(2, 3)
    with pytest.raises(ValueError, match="at least one factor"):
        linear_product_gram(x, x, [])

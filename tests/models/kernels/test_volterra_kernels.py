"""Volterra kernels of order r: each spans the monomials of degree <= r of the lagged inputs."""

from __future__ import annotations

import math

import pytest
import torch
from gpytorch.kernels import AdditiveKernel

from mcpilco.models.kernels import VOLTERRA_KINDS, volterra_kernel


@pytest.mark.parametrize("kind", VOLTERRA_KINDS)
def test_spans_all_monomials_up_to_the_order(kind):
    order, memory = 3, 2
    k = volterra_kernel(kind, order, memory).double()
    u = torch.randn(80, memory + 1, generator=torch.Generator().manual_seed(0)).double()
    K = k(u).to_dense().detach()
    assert torch.linalg.matrix_rank(K, rtol=1e-10).item() == math.comb(memory + 1 + order, order)


@pytest.mark.parametrize("kind", ["pk", "mpk", "sed_mpk"])
def test_structure_is_a_sum_over_degrees_plus_constant(kind):
    k = volterra_kernel(kind, 4, 5, batch_shape=torch.Size([2]))
    assert isinstance(k, AdditiveKernel) and len(k.kernels) == 5
    u = torch.randn(7, 6)
    assert k(u).to_dense().shape == (2, 7, 7)


def test_unknown_kind_raises():
    with pytest.raises(ValueError, match="sed_mpk"):
        volterra_kernel("rbf", 2, 3)

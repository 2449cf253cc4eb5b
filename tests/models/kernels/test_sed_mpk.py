"""SED-MPK: Sigma_s entry by entry, PSD, kernel as explicit double sums, hierarchy."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from mcpilco.models.kernels import SEDMPKernel, sed_matrix

ALPHA = [0.2, 0.5, 1.3]
BETA = [0.05, 0.05, 0.4]


def make_kernel(memory: int = 4) -> SEDMPKernel:
    k = SEDMPKernel(3, memory).double()
    k.alpha = torch.tensor(ALPHA, dtype=torch.float64)
    k.beta = torch.tensor(BETA, dtype=torch.float64)
    return k


def test_sigma_matches_formula_entry_by_entry():
    m = 4
    Sigma = make_kernel(m).Sigma.detach()
    assert Sigma.shape == (3, m + 1, m + 1)
    for s in range(3):
        for i in range(m + 1):
            for j in range(m + 1):
                expected = math.exp(-ALPHA[s] * abs(i - j)) * math.exp(-BETA[s] * (i + j))
                assert Sigma[s, i, j].item() == pytest.approx(expected, rel=1e-10)


@pytest.mark.parametrize(("alpha", "beta"), [(0.0, 0.0), (0.01, 0.3), (2.0, 0.0), (5.0, 1.0)])
def test_sigma_is_psd(alpha, beta):
    S = sed_matrix(torch.tensor(alpha, dtype=torch.float64), torch.tensor(beta).double(), 30)
    eig = torch.linalg.eigvalsh(S)
    assert eig.min() >= -1e-12 * S.trace()


def test_kernel_matches_explicit_double_sums():
    m = 3
    k = make_kernel(m)
    S = k.Sigma.detach().numpy()
    rng = np.random.default_rng(0)
    u, v = rng.normal(size=(5, m + 1)), rng.normal(size=(4, m + 1))
    expected = np.ones((5, 4))
    for a in range(5):
        for b in range(4):
            for s in range(3):
                expected[a, b] *= sum(
                    S[s, i, j] * u[a, i] * v[b, j] for i in range(m + 1) for j in range(m + 1)
                )
    K = k(torch.from_numpy(u), torch.from_numpy(v)).to_dense().detach().numpy()
    np.testing.assert_allclose(K, expected, rtol=1e-11)


def test_degree_p_kernel_spans_monomials_of_degree_p():
    m, p = 2, 2  # monomials of degree exactly 2 in 3 lags: 6
    k = SEDMPKernel(p, m).double()
    u = torch.randn(60, m + 1, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    K = k(u).to_dense().detach()
    assert torch.linalg.matrix_rank(K, rtol=1e-10).item() == math.comb(m + p, p)


@pytest.mark.parametrize("seed", range(4))
def test_alpha_beta_non_decreasing_and_sigma_non_increasing(seed):
    k = SEDMPKernel(4, 6, batch_shape=torch.Size([2]))
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in k.parameters():
            p.copy_(3 * torch.randn(p.shape, generator=g))
    assert k.alpha.shape == (2, 4) and k.beta.shape == (2, 4)
    assert (k.alpha.diff(dim=-1) >= 0).all() and (k.alpha > 0).all()
    assert (k.beta.diff(dim=-1) >= 0).all() and (k.beta > 0).all()
    assert (k.Sigma.diff(dim=-3) <= 1e-7).all()  # entrywise Sigma_1 >= Sigma_2 >= ...


def test_ordering_survives_optimisation_steps():
    k = SEDMPKernel(2, 3).double()
    opt = torch.optim.Adam(k.parameters(), lr=0.3)
    for _ in range(20):
        opt.zero_grad()
        loss = (k.alpha[0] - 3.0) ** 2 + (k.alpha[1] - 0.01) ** 2 + (k.beta[0] - 2.0) ** 2
        loss.backward()
        opt.step()
        assert (k.alpha.diff() >= 0).all() and (k.beta.diff() >= 0).all()


def test_setters_reject_decreasing_values_and_bad_memory():
    k = SEDMPKernel(2, 3)
    with pytest.raises(ValueError, match="non-decreasing"):
        k.alpha = torch.tensor([1.0, 0.5])
    with pytest.raises(ValueError, match="memory"):
        SEDMPKernel(2, -1)
    with pytest.raises(ValueError, match="last dimension 4"):
        k.forward(torch.randn(3, 5), torch.randn(3, 5))


def test_float64_kernel_on_float32_inputs_returns_float32():
    k = make_kernel(3)
    u = torch.randn(5, 4)
    K32 = k(u).to_dense()
    assert K32.dtype == torch.float32
    torch.testing.assert_close(K32.double(), k(u.double()).to_dense(), rtol=1e-5, atol=1e-5)

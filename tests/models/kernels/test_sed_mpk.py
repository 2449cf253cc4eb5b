"""SED-MPK: Sigma_s entry by entry, PSD, kernel as explicit double sums, hierarchy."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from mcpilco.models.kernels import SEDMPKernel, TiedSEDMPKernel, sed_matrix, volterra_kernel

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


# ------------------------------------------------------------------------- tied SED-MPK (6.35)
def make_tied(order: int = 3, memory: int = 4, alpha: float = 0.3, beta: float = 0.1):
    k = TiedSEDMPKernel(order, memory).double()
    k.alpha, k.beta = alpha, beta
    k.rho = torch.tensor([0.7, 0.2, 0.05, 0.01][:order], dtype=torch.float64)
    k.rho0 = 0.4
    return k


def test_tied_kernel_matches_explicit_formula():
    """rho_0 + sum_i rho_i (sum_{a,b} e^{-alpha|a-b|} e^{-beta(a+b)} u_a v_b)^i, by loops."""
    m, alpha, beta = 3, 0.3, 0.1
    k = make_tied(3, m, alpha, beta)
    rho = [0.7, 0.2, 0.05]
    rng = np.random.default_rng(3)
    u, v = rng.normal(size=(4, m + 1)), rng.normal(size=(5, m + 1))
    expected = np.empty((4, 5))
    for a in range(4):
        for b in range(5):
            base = sum(
                math.exp(-alpha * abs(i - j) - beta * (i + j)) * u[a, i] * v[b, j]
                for i in range(m + 1)
                for j in range(m + 1)
            )
            expected[a, b] = 0.4 + sum(rho[i] * base ** (i + 1) for i in range(3))
    K = k(torch.from_numpy(u), torch.from_numpy(v)).to_dense().detach().numpy()
    np.testing.assert_allclose(K, expected, rtol=1e-11)


def test_tied_kernel_coefficient_similarity_is_eq_6_35():
    """Order 2: (u^T S v)^2 = sum_{tau, tau'} P(tau, tau') u_tau1 u_tau2 v_tau'1 v_tau'2 with
    P = exp(-alpha ||tau - tau'||_1) exp(-beta ||tau + tau'||_1) (thesis eq. 6.35)."""
    m, alpha, beta = 2, 0.4, 0.15
    k = TiedSEDMPKernel(2, m).double()
    k.alpha, k.beta = alpha, beta
    k.rho = torch.tensor([0.0, 1.0], dtype=torch.float64).clamp_min(1e-300)
    k.rho0 = 1e-300
    rng = np.random.default_rng(4)
    u, v = rng.normal(size=m + 1), rng.normal(size=m + 1)
    lags = [(a, b) for a in range(m + 1) for b in range(m + 1)]
    total = 0.0
    for t in lags:
        for s in lags:
            d = abs(t[0] - s[0]) + abs(t[1] - s[1])
            p = math.exp(-alpha * d - beta * (t[0] + s[0] + t[1] + s[1]))
            total += p * u[t[0]] * u[t[1]] * v[s[0]] * v[s[1]]
    K = k(torch.from_numpy(u[None]), torch.from_numpy(v[None])).to_dense().item()
    assert K == pytest.approx(total, rel=1e-10)


@pytest.mark.parametrize("order", [1, 3, 5])
def test_tied_kernel_equals_general_sed_mpk_with_equal_parameters(order):
    """Second implementation: the general Volterra SED-MPK (one SEDMPKernel per order, each with
    its own hierarchical alpha_p, beta_p) with every alpha_p = alpha, beta_p = beta."""
    m, alpha, beta = 5, 0.25, 0.08
    tied = make_tied(order, m, alpha, beta) if order <= 4 else TiedSEDMPKernel(order, m).double()
    tied.alpha, tied.beta = alpha, beta
    general = volterra_kernel("sed_mpk", order, m).double()
    for i, term in enumerate(general.kernels[:-1]):
        term.base_kernel.alpha = torch.full((i + 1,), alpha, dtype=torch.float64)
        term.base_kernel.beta = torch.full((i + 1,), beta, dtype=torch.float64)
        term.outputscale = tied.rho[i].detach()
    general.kernels[-1].constant = tied.rho0.detach()
    rng = np.random.default_rng(order)
    u = torch.from_numpy(rng.normal(size=(9, m + 1)))
    v = torch.from_numpy(rng.normal(size=(6, m + 1)))
    # zero increments map to 1e-12 in the general kernel, hence rtol 1e-8
    torch.testing.assert_close(
        tied(u, v).to_dense(), general(u, v).to_dense(), rtol=1e-8, atol=1e-12
    )
    torch.testing.assert_close(tied(u, diag=True), general(u, diag=True), rtol=1e-8, atol=1e-12)
    n_tied = sum(p.numel() for p in tied.parameters())
    n_general = sum(p.numel() for p in general.parameters())
    assert n_tied == order + 3 and n_general == order * (order + 1) + order + 1


def test_tied_kernel_initial_orders_have_equal_prior_variance():
    """Default rho_i = 1 / ((r+1) tr(Sigma)^i): for u ~ N(0, I), E[(u^T S u)^i] ~ tr(S)^i up to
    moment factors, so each order's prior variance is O(1/(r+1)) on unit-variance inputs."""
    k = TiedSEDMPKernel(3, 70).double()
    trace = float(k.Sigma.detach().diagonal().sum())
    expected = torch.tensor([1 / (4 * trace**i) for i in (1, 2, 3)], dtype=torch.float64)
    torch.testing.assert_close(k.rho.detach(), expected, rtol=1e-5, atol=0)  # float32 init
    assert k.rho0.item() == pytest.approx(0.25)
    assert k.alpha.item() == pytest.approx(0.1) and k.beta.item() == pytest.approx(0.05)


def test_tied_kernel_validates_arguments():
    with pytest.raises(ValueError, match="memory"):
        TiedSEDMPKernel(2, -1)
    with pytest.raises(ValueError, match="order"):
        TiedSEDMPKernel(0, 3)
    with pytest.raises(ValueError, match="last dimension 4"):
        TiedSEDMPKernel(2, 3).forward(torch.randn(3, 5), torch.randn(3, 5))

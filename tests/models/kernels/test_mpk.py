"""MPK: monomial span (independent feature-map expansion), rank, hierarchical ordering."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import torch

from mcpilco.models.kernels import LinearKernel, MPKernel

# --- independent truth: expand prod_s (c_s + sum_j w_sj x_j x'_j) by hand --------------------


def monomial_exponents(d: int, max_degree: int, min_degree: int = 0) -> list[tuple[int, ...]]:
    """All exponent vectors alpha in N^d with min_degree <= |alpha| <= max_degree."""
    return [
        a
        for a in itertools.product(range(max_degree + 1), repeat=d)
        if min_degree <= sum(a) <= max_degree
    ]


def expanded_monomial_weights(offsets: np.ndarray, weights: np.ndarray) -> dict:
    """Weights W_alpha with prod_s (c_s + sum_j w_sj x_j y_j) = sum_alpha W_alpha x^alpha y^alpha.

    Each factor s contributes either its offset c_s (choice -1) or the term w_sj x_j y_j
    (choice j); a choice tuple over the p factors yields the monomial whose exponent counts
    how often each j was chosen. Summing the products of the chosen coefficients over all
    choice tuples gives W_alpha.
    """
    p, d = weights.shape
    out: dict[tuple[int, ...], float] = {}
    for choice in itertools.product(range(-1, d), repeat=p):
        coef, alpha = 1.0, [0] * d
        for s, j in enumerate(choice):
            if j < 0:
                coef *= offsets[s]
            else:
                coef *= weights[s, j]
                alpha[j] += 1
        out[tuple(alpha)] = out.get(tuple(alpha), 0.0) + coef
    return out


def monomial_features(x: np.ndarray, exponents: list[tuple[int, ...]]) -> np.ndarray:
    return np.stack([np.prod(x ** np.array(a), axis=1) for a in exponents], axis=1)


def ordered_levels(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """Random positive values non-increasing along axis 0 (reverse cumsum of increments)."""
    inc = rng.uniform(0.1, 1.0, size=shape)
    return np.flip(np.cumsum(np.flip(inc, 0), 0), 0).copy()


@pytest.mark.parametrize(
    ("degree", "d", "homogeneous"), [(2, 3, False), (3, 2, False), (2, 3, True)]
)
def test_mpk_equals_explicit_monomial_feature_map(degree, d, homogeneous):
    rng = np.random.default_rng(degree * 10 + d)
    Sigma = ordered_levels(rng, (degree, d))
    offsets = np.zeros(degree) if homogeneous else ordered_levels(rng, (degree,))
    k = MPKernel(degree, d, homogeneous=homogeneous).double()
    k.Sigma_diag = torch.from_numpy(Sigma)
    if not homogeneous:
        k.sigma2 = torch.from_numpy(offsets)
    W = expanded_monomial_weights(offsets, Sigma)
    exps = monomial_exponents(d, degree, min_degree=degree if homogeneous else 0)
    assert set(a for a, w in W.items() if w != 0) == set(exps)
    x, y = rng.normal(size=(9, d)), rng.normal(size=(7, d))
    expected = (
        monomial_features(x, exps) @ np.diag([W[a] for a in exps]) @ monomial_features(y, exps).T
    )
    K = k(torch.from_numpy(x), torch.from_numpy(y)).to_dense().detach().numpy()
    np.testing.assert_allclose(K, expected, rtol=1e-11, atol=1e-11)


@pytest.mark.parametrize(
    ("degree", "d", "homogeneous"),
    [(1, 4, False), (2, 3, False), (3, 2, False), (2, 3, True), (3, 3, True)],
)
def test_gram_rank_equals_number_of_monomials(degree, d, homogeneous):
    n_monomials = math.comb(d + degree, degree)
    if homogeneous:
        n_monomials = math.comb(d + degree - 1, degree)
    k = MPKernel(degree, d, homogeneous=homogeneous).double()
    x = torch.randn(80, d, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    K = k(x).to_dense().detach()
    assert torch.linalg.matrix_rank(K, rtol=1e-10).item() == n_monomials


def test_mpk_is_product_of_linear_kernels_with_effective_parameters():
    k = MPKernel(3, 4).double()
    with torch.no_grad():
        for p in k.parameters():
            p.normal_(generator=torch.Generator().manual_seed(1))
    x = torch.randn(10, 4, dtype=torch.float64)
    expected = torch.ones(10, 10, dtype=torch.float64)
    for s in range(3):
        lin = LinearKernel(4).double()
        lin.sigma2 = k.sigma2[s : s + 1].detach()
        lin.Sigma_diag = k.Sigma_diag[s].detach()
        expected = expected * lin(x).to_dense()
    torch.testing.assert_close(k(x).to_dense(), expected)


def assert_non_increasing(levels: torch.Tensor, dim: int) -> None:
    diffs = levels.diff(dim=dim)
    assert (diffs <= 0).all(), levels


@pytest.mark.parametrize("seed", range(5))
def test_effective_parameters_non_increasing_for_random_raw_values(seed):
    k = MPKernel(4, 3, batch_shape=torch.Size([2]))
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in k.parameters():
            p.copy_(3 * torch.randn(p.shape, generator=g))
    assert k.Sigma_diag.shape == (2, 4, 3) and k.sigma2.shape == (2, 4)
    assert_non_increasing(k.Sigma_diag, dim=-2)
    assert_non_increasing(k.sigma2, dim=-1)
    assert (k.Sigma_diag[..., -1, :] > 0).all() and (k.sigma2[..., -1] > 0).all()


def test_ordering_survives_optimisation_steps_that_push_against_it():
    """A loss that wants Sigma_2 > Sigma_1 cannot break the ordering: it is structural."""
    k = MPKernel(2, 3).double()
    opt = torch.optim.Adam(k.parameters(), lr=0.3)
    for _ in range(30):
        opt.zero_grad()
        S, c = k.Sigma_diag, k.sigma2
        loss = ((S[0] - 0.1) ** 2).sum() + ((S[1] - 5.0) ** 2).sum() + (c[0] - 0.1) ** 2
        loss = loss + (c[1] - 5.0) ** 2
        loss.backward()
        opt.step()
        assert_non_increasing(k.Sigma_diag.detach(), dim=-2)
        assert_non_increasing(k.sigma2.detach(), dim=-1)


def test_ordering_after_marginal_likelihood_step():
    torch.manual_seed(0)
    x = torch.randn(40, 3, dtype=torch.float64)
    y = x[:, 0] ** 2 - x[:, 1] * x[:, 2] + 0.1 * torch.randn(40, dtype=torch.float64)
    k = MPKernel(2, 3).double()
    opt = torch.optim.Adam(k.parameters(), lr=0.5)
    for _ in range(5):
        opt.zero_grad()
        K = k(x).to_dense() + 0.01 * torch.eye(40, dtype=torch.float64)
        L = torch.linalg.cholesky(K)
        nll = 0.5 * y @ torch.cholesky_solve(y[:, None], L)[:, 0] + L.diagonal().log().sum()
        nll.backward()
        opt.step()
    assert_non_increasing(k.Sigma_diag.detach(), dim=-2)
    assert_non_increasing(k.sigma2.detach(), dim=-1)


def test_setters_round_trip_and_reject_wrong_order():
    k = MPKernel(3, 2).double()
    S = torch.tensor([[3.0, 2.0], [2.0, 2.0], [0.5, 1.0]], dtype=torch.float64)
    k.Sigma_diag = S
    k.sigma2 = torch.tensor([1.0, 0.5, 0.25], dtype=torch.float64)
    torch.testing.assert_close(k.Sigma_diag, S, atol=1e-10, rtol=1e-10)
    torch.testing.assert_close(k.Sigma_increment[2], S[2])
    with pytest.raises(ValueError, match="non-increasing"):
        k.Sigma_diag = torch.tensor([[1.0, 1.0], [2.0, 1.0], [0.5, 0.5]])
    with pytest.raises(ValueError, match="non-increasing"):
        k.sigma2 = torch.tensor([0.1, 0.5, 0.2])


def test_homogeneous_mpk_has_no_offsets():
    k = MPKernel(2, 3, homogeneous=True)
    assert not hasattr(k, "raw_sigma2_increment")
    assert (k.sigma2 == 0).all()
    with pytest.raises(AttributeError):
        k.sigma2 = 1.0


@pytest.mark.parametrize(
    ("kwargs", "error"),
    [
        ({"degree": 0, "ard_num_dims": 2}, ValueError),
        ({"degree": 2.0, "ard_num_dims": 2}, TypeError),
        ({"degree": 2, "ard_num_dims": 0}, ValueError),
    ],
)
def test_invalid_constructor_arguments(kwargs, error):
    with pytest.raises(error):
        MPKernel(**kwargs)


def test_wrong_input_dimension_raises_value_error_naming_the_shape():
    k = MPKernel(2, 3)
    with pytest.raises(ValueError, match=r"\(5, 4\)"):
        k.forward(torch.randn(5, 4), torch.randn(5, 4))


def test_float64_kernel_on_float32_inputs_returns_float32():
    k = MPKernel(2, 3).double()
    x = torch.randn(5, 3)
    K32 = k(x).to_dense()
    assert K32.dtype == torch.float32
    torch.testing.assert_close(K32.double(), k(x.double()).to_dense(), rtol=1e-5, atol=1e-5)


def test_state_dict_round_trip():
    k = MPKernel(2, 3, batch_shape=torch.Size([2]))
    with torch.no_grad():
        for p in k.parameters():
            p.normal_()
    k2 = MPKernel(2, 3, batch_shape=torch.Size([2]))
    k2.load_state_dict(k.state_dict())
    x = torch.randn(4, 3)
    torch.testing.assert_close(k2(x).to_dense(), k(x).to_dense())

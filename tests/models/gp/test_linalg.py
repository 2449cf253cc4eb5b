"""LowerTriangularBlocks (panel-blocked triangular product) against the dense matmul."""

from __future__ import annotations

import pytest
import torch

from mcpilco.models.gp.linalg import LowerTriangularBlocks


def _lower(shape: tuple[int, ...], n: int, seed: int, dtype=torch.float64) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    return torch.randn(*shape, n, n, generator=gen, dtype=dtype).tril()


@pytest.mark.parametrize(
    ("n", "panel_width"),
    [(1, 64), (5, 2), (63, 64), (64, 64), (65, 64), (97, 16), (200, 64), (257, 32), (130, 1)],
)
def test_block_product_equals_dense_product(n: int, panel_width: int) -> None:
    M = _lower((2,), n, seed=n)
    B = torch.randn(2, n, 9, generator=torch.Generator().manual_seed(n + 1), dtype=M.dtype)
    tri = LowerTriangularBlocks(M, panel_width=panel_width)
    assert tri.num_panels == max(1, round(n / panel_width))
    dense = M @ B  # second implementation: the plain dense matmul
    torch.testing.assert_close(tri.matmul(B), dense, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(tri.sq_col_norms(B), dense.pow(2).sum(-2), rtol=1e-12, atol=1e-12)
    # the zero upper half is not stored (beyond the diagonal blocks of the panels)
    stored = sum(b[0].numel() for b in tri.panels)
    assert stored <= n * n
    if tri.num_panels > 1:
        assert stored < n * n
    # dense() gives M back exactly; the panels' bounds tile 0..N
    assert torch.equal(tri.dense(), M)
    assert [s for s, _ in tri.bounds] == [0, *(e for _, e in tri.bounds[:-1])]
    assert tri.bounds[-1][1] == n


def test_block_product_unbatched_float32_and_broadcast_rhs() -> None:
    M = _lower((), 150, seed=3, dtype=torch.float32)
    tri = LowerTriangularBlocks(M, panel_width=40)
    B = torch.randn(3, 150, 7, generator=torch.Generator().manual_seed(4))
    got = tri.sq_col_norms(B)
    assert got.shape == (3, 7) and got.dtype == torch.float32
    ref = (M.double() @ B.double()).pow(2).sum(-2)
    torch.testing.assert_close(got.double(), ref, rtol=1e-4, atol=1e-4)


def test_sq_col_norms_gradient_is_analytic() -> None:
    """d/dB sum_c w_c ||M b_c||^2 = 2 M^T M B diag(w), checked against that formula."""
    M = _lower((2,), 90, seed=5)
    tri = LowerTriangularBlocks(M, panel_width=20)
    B = torch.randn(2, 90, 6, dtype=torch.float64, generator=torch.Generator().manual_seed(6))
    w = torch.linspace(-1.0, 2.0, 6, dtype=torch.float64)
    B.requires_grad_(True)
    (tri.sq_col_norms(B) * w).sum().backward()
    expected = 2.0 * M.transpose(-1, -2) @ M @ B.detach() * w
    torch.testing.assert_close(B.grad, expected, rtol=1e-11, atol=1e-11)
    small = B[:, :, :2].detach().requires_grad_()
    assert torch.autograd.gradcheck(tri.sq_col_norms, (small,))
    assert torch.autograd.gradgradcheck(tri.sq_col_norms, (small,))


def test_block_product_broadcasts_batch_both_ways() -> None:
    """Unbatched B against a batched M and the reverse; gradients keep B's shape."""
    M = _lower((2,), 70, seed=7)
    B = torch.randn(70, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(8))
    B.requires_grad_(True)
    tri = LowerTriangularBlocks(M, panel_width=16)
    out = tri.matmul(B)
    torch.testing.assert_close(out, M @ B.detach(), rtol=1e-12, atol=1e-12)
    out.sum().backward()
    torch.testing.assert_close(B.grad, M.transpose(-1, -2).sum(0) @ torch.ones_like(B))
    tri1 = LowerTriangularBlocks(M[0], panel_width=16)
    B2 = torch.randn(4, 70, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(9))
    torch.testing.assert_close(tri1.matmul(B2), M[0] @ B2, rtol=1e-12, atol=1e-12)


def test_block_product_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match=r"shape \(\.\.\., N, N\)"):
        LowerTriangularBlocks(torch.zeros(3, 4))
    with pytest.raises(ValueError, match="lower triangular"):
        LowerTriangularBlocks(torch.ones(4, 4))
    with pytest.raises(ValueError, match="panel_width"):
        LowerTriangularBlocks(torch.eye(4), panel_width=0)
    tri = LowerTriangularBlocks(torch.eye(4))
    with pytest.raises(ValueError, match=r"\(\.\.\., 4, n\)"):
        tri.sq_col_norms(torch.zeros(5, 2))


def test_multiply_adds_counts_the_stored_triangle():
    """Width-1 panels hold exactly the lower triangle, N(N+1)/2 entries; one panel holds the
    full square; in between the count lies between the two."""
    L = torch.tril(torch.randn(2, 30, 30, dtype=torch.float64))
    n = 7
    assert LowerTriangularBlocks(L, panel_width=1).multiply_adds(n) == 30 * 31 // 2 * n
    assert LowerTriangularBlocks(L, panel_width=64).multiply_adds(n) == 30 * 30 * n
    assert 30 * 31 // 2 * n < LowerTriangularBlocks(L, panel_width=8).multiply_adds(n) < 900 * n

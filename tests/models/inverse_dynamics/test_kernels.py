"""RowLinearKernel: the PP kernel of output b uses row b only (checked against numpy)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mcpilco.models.inverse_dynamics import RowLinearKernel


def test_gram_matrix_is_phi_b_sigma_b_phi_b() -> None:
    torch.manual_seed(0)
    n, p = 3, 4
    k = RowLinearKernel(n, p, batch_shape=torch.Size([n])).double()
    k.Sigma_diag = torch.rand(n, p, dtype=torch.float64) + 0.1
    x1 = torch.randn(7, n * p, dtype=torch.float64)
    x2 = torch.randn(5, n * p, dtype=torch.float64)
    K = k(x1, x2).to_dense()
    assert K.shape == (n, 7, 5)
    S = k.Sigma_diag.detach().numpy()
    a, b = x1.numpy().reshape(7, n, p), x2.numpy().reshape(5, n, p)
    for r in range(n):
        expected = (a[:, r] * S[r]) @ b[:, r].T
        np.testing.assert_allclose(K[r].detach().numpy(), expected, rtol=1e-12, atol=1e-12)
    with torch.no_grad():
        diag = k(x1, x1, diag=True)
        full = k(x1, x1).to_dense()
    torch.testing.assert_close(diag, torch.diagonal(full, dim1=-2, dim2=-1))
    eig = torch.linalg.eigvalsh(k(x1, x1).to_dense().detach())
    assert bool((eig > -1e-10).all())


def test_active_dims_pick_the_rows_out_of_a_wider_input() -> None:
    n, p = 2, 3
    k = RowLinearKernel(n, p, batch_shape=torch.Size([n]), active_dims=tuple(range(6, 12)))
    x = torch.randn(4, 12, dtype=torch.float64)
    K_wide = k.double()(x).to_dense()
    k2 = RowLinearKernel(n, p, batch_shape=torch.Size([n])).double()
    torch.testing.assert_close(K_wide, k2(x[:, 6:]).to_dense())


def test_needs_one_batch_element_per_row() -> None:
    with pytest.raises(ValueError, match="batch_shape"):
        RowLinearKernel(3, 2)

"""Shared contract every kernel of ``mcpilco.models.kernels`` must satisfy.

Subclass :class:`KernelContract` in a ``Test*`` class, set ``input_dim`` and implement
``make_kernel``; pytest collects the inherited ``test_*`` methods for each subclass.
"""

from __future__ import annotations

import gpytorch
import pytest
import torch
from gpytorch.kernels import Kernel, RBFKernel

N_POINTS = 24
EMPTY = torch.Size([])


def dense(k: Kernel, x1: torch.Tensor, x2: torch.Tensor | None = None, **kw) -> torch.Tensor:
    """Evaluate a kernel to a dense tensor."""
    out = k(x1, x2, **kw)
    return out.to_dense() if hasattr(out, "to_dense") else out


def randomize_raw(kernel: Kernel, seed: int, scale: float = 0.7) -> Kernel:
    """Set every raw hyperparameter to N(0, scale^2) values (generic, non-default values)."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in kernel.parameters():
            p.copy_(scale * torch.randn(p.shape, generator=g, dtype=p.dtype))
    return kernel


def copy_parameters(src: Kernel, dst: Kernel, index: int | None = None) -> None:
    """Copy raw parameters by name (optionally the ``index``-th batch member of ``src``)."""
    dst_params = dict(dst.named_parameters())
    with torch.no_grad():
        for name, p in src.named_parameters():
            dst_params[name].copy_(p if index is None else p[index])


class KernelContract:
    """Base test case: symmetry, PSD, diag, batch, dtype, gradients, active_dims, + and *."""

    input_dim: int

    def make_kernel(
        self, batch_shape: torch.Size = EMPTY, active_dims: tuple[int, ...] | None = None
    ) -> Kernel:
        raise NotImplementedError

    def make_inputs(self, n: int, seed: int, dtype: torch.dtype = torch.float64) -> torch.Tensor:
        g = torch.Generator().manual_seed(seed)
        return torch.randn(n, self.input_dim, generator=g, dtype=torch.float64).to(dtype)

    def kernel64(self, seed: int = 0, **kw) -> Kernel:
        return randomize_raw(self.make_kernel(**kw), seed).double()

    # ---------------------------------------------------------------------------------------
    def test_is_gpytorch_kernel_with_constrained_raw_parameters(self):
        k = self.make_kernel()
        assert isinstance(k, Kernel)
        names = [n for n, _ in k.named_parameters()]
        assert names, "kernel has no hyperparameters"
        assert all(n.split(".")[-1].startswith("raw_") for n in names), names

    def test_symmetric_and_cross_shape(self):
        k = self.kernel64()
        x, y = self.make_inputs(N_POINTS, 1), self.make_inputs(7, 2)
        K = dense(k, x)
        assert K.shape == (N_POINTS, N_POINTS)
        torch.testing.assert_close(K, K.mT, rtol=1e-12, atol=1e-12)
        Kxy = dense(k, x, y)
        assert Kxy.shape == (N_POINTS, 7)
        torch.testing.assert_close(Kxy, dense(k, y, x).mT, rtol=1e-12, atol=1e-12)
        assert torch.isfinite(K).all()

    @pytest.mark.parametrize("seed", [0, 1, 2])
    def test_positive_semidefinite(self, seed):
        k = self.kernel64(seed)
        K = dense(k, self.make_inputs(N_POINTS, 10 + seed))
        eig = torch.linalg.eigvalsh(K)
        assert eig.min() >= -1e-8 * K.diagonal().sum(), (eig.min(), K.diagonal().sum())

    def test_diag_matches_full(self):
        k = self.kernel64()
        x = self.make_inputs(N_POINTS, 3)
        d = dense(k, x, diag=True)
        assert d.shape == (N_POINTS,)
        torch.testing.assert_close(d, dense(k, x).diagonal(), rtol=1e-10, atol=1e-12)

    def test_batch_shape_matches_independent_kernels(self):
        bs = torch.Size([3])
        kb = self.kernel64(seed=5, batch_shape=bs)
        x = self.make_inputs(N_POINTS, 4)
        xb = torch.stack([self.make_inputs(N_POINTS, 20 + i) for i in range(3)])
        K, Kb, Db = dense(kb, x), dense(kb, xb), dense(kb, xb, diag=True)
        assert K.shape == (3, N_POINTS, N_POINTS) and Kb.shape == K.shape
        assert Db.shape == (3, N_POINTS)
        for i in range(3):
            ki = self.make_kernel().double()
            copy_parameters(kb, ki, index=i)
            torch.testing.assert_close(K[i], dense(ki, x), rtol=1e-10, atol=1e-12)
            torch.testing.assert_close(Kb[i], dense(ki, xb[i]), rtol=1e-10, atol=1e-12)
            torch.testing.assert_close(Db[i], dense(ki, xb[i], diag=True), rtol=1e-10, atol=1e-12)
        assert not torch.allclose(K[0], K[1]), "batch members should have their own parameters"

    def test_float32_and_float64(self):
        k64 = self.kernel64()
        k32 = self.make_kernel().float()
        copy_parameters(k64, k32)
        x = self.make_inputs(N_POINTS, 6)
        K64 = dense(k64, x)
        K32 = dense(k32, x.float())
        assert K64.dtype == torch.float64 and K32.dtype == torch.float32
        assert torch.isfinite(K32).all()
        scale = K64.abs().max()
        torch.testing.assert_close(K32.double() / scale, K64 / scale, rtol=0, atol=1e-5)

    def test_finite_gradients(self):
        k = self.kernel64(seed=3)
        x = self.make_inputs(N_POINTS, 7).requires_grad_(True)
        y = self.make_inputs(5, 8)
        loss = dense(k, x, y).pow(2).mean() + dense(k, x, diag=True).mean()
        loss.backward()
        assert torch.isfinite(x.grad).all() and x.grad.abs().sum() > 0
        grads = [p.grad for p in k.parameters()]
        assert all(g is not None and torch.isfinite(g).all() for g in grads)
        assert sum(g.abs().sum() for g in grads) > 0

    def test_active_dims_selects_columns(self):
        d = self.input_dim
        k_act = self.kernel64(seed=4, active_dims=tuple(range(1, d + 1)))
        k = self.make_kernel().double()
        copy_parameters(k_act, k)
        x = self.make_inputs(N_POINTS, 9)
        g = torch.Generator().manual_seed(0)
        wide = torch.cat([torch.randn(N_POINTS, 1, generator=g, dtype=x.dtype), x], -1)
        wide = torch.cat([wide, torch.randn(N_POINTS, 2, generator=g, dtype=x.dtype)], -1)
        torch.testing.assert_close(dense(k_act, wide), dense(k, x), rtol=1e-12, atol=1e-12)
        torch.testing.assert_close(
            dense(k_act, wide, diag=True), dense(k, x, diag=True), rtol=1e-12, atol=1e-12
        )

    def test_sum_and_product_composition(self):
        k = self.kernel64(seed=6)
        rbf = RBFKernel().double()
        x = self.make_inputs(N_POINTS, 11)
        K, R = dense(k, x), dense(rbf, x)
        torch.testing.assert_close(dense(k + rbf, x), K + R, rtol=1e-12, atol=1e-12)
        torch.testing.assert_close(dense(k * rbf, x), K * R, rtol=1e-12, atol=1e-12)
        torch.testing.assert_close(dense(k * k, x, diag=True), K.diagonal() ** 2)

    def test_non_lazy_evaluation(self):
        k = self.kernel64()
        x = self.make_inputs(N_POINTS, 12)
        with gpytorch.settings.lazily_evaluate_kernels(False):
            K = dense(k, x)
        torch.testing.assert_close(K, dense(k, x))

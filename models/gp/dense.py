"""Dense evaluation of GPyTorch kernel trees with plain torch ops.

GPyTorch evaluates kernels lazily (``LazyEvaluatedKernelTensor``) and wraps results in
``LinearOperator`` objects. That machinery is convenient for training but costs tens of
microseconds of Python per call, which dominates the particle rollouts of MC-PILCO (thesis
chapter 5: 400 particles, one posterior call per time step, with backward). This module walks a
kernel tree and evaluates it with dense tensors only:

* ``ScaleKernel``: :math:`\\theta_s\\, k_{base}(x, x')`;
* ``AdditiveKernel``: :math:`\\sum_i k_i(x, x')`; ``ProductKernel``: :math:`\\prod_i k_i(x, x')`;
* ``RBFKernel``: :math:`\\exp(-\\tfrac12 \\lVert (x - x') / \\ell \\rVert^2)`, squared distances in
  matmul form :math:`\\lVert a\\rVert^2 + \\lVert b\\rVert^2 - 2 a b^T` clamped at 0;
* ``ConstantKernel``: :math:`c`; gpytorch ``LinearKernel``: :math:`v\\, x^T x'`;
* any other kernel: its own ``forward`` (the project's kernels in :mod:`mcpilco.models.kernels`
  all return dense tensors), densified with ``to_dense`` if it returns a ``LinearOperator``.

``active_dims`` are applied exactly where GPyTorch applies them: in ``Kernel.__call__``.
``ScaleKernel`` calls ``base_kernel.forward`` (it copies the base kernel's ``active_dims`` onto
itself at construction), so the base kernel's ``active_dims`` are not applied a second time.
"""

from __future__ import annotations

import gpytorch
import torch
from linear_operator import to_dense
from torch import Tensor

from mcpilco.models.numerics import exp_floor, exp_floor_arg

__all__ = ["dense_covar", "dense_diag", "rbf_sq_dist"]


def rbf_sq_dist(a: Tensor, b: Tensor) -> Tensor:
    """Squared Euclidean distances in matmul form, clamped at zero.

    :math:`D_{ij} = \\lVert a_i\\rVert^2 + \\lVert b_j\\rVert^2 - 2 a_i^T b_j`, one batched matmul
    instead of an ``(n, N, d)`` broadcast difference.

    Args:
        a: ``(..., n, d)``.
        b: ``(..., N, d)``.

    Returns:
        ``(..., n, N)``.
    """
    a2 = a.pow(2).sum(-1, keepdim=True)
    b2 = b.pow(2).sum(-1, keepdim=True)
    d = (a2 - 2.0 * (a @ b.transpose(-1, -2))) + b2.transpose(-1, -2)
    return d.clamp_min(0.0)


def _scaled_rbf(outputscale: Tensor, lengthscale: Tensor, x1: Tensor, x2: Tensor) -> Tensor:
    """Fused :math:`\\theta_s \\exp(-\\tfrac12 \\lVert (x - x')/\\ell \\rVert^2)` from ONE matmul.

    With :math:`a = x / (\\sqrt2\\,\\ell)`, :math:`b = x' / (\\sqrt2\\,\\ell)` the exponent
    :math:`\\log\\theta_s - \\lVert a_i\\rVert^2 - \\lVert b_j\\rVert^2 + 2 a_i^T b_j = u_i^T w_j`
    is the product of the augmented rows

    .. math::
        u_i = [a_i,\\ 1,\\ \\log\\theta_s - \\lVert a_i\\rVert^2], \\qquad
        w_j = [2 b_j,\\ -\\lVert b_j\\rVert^2,\\ 1],

    so the ``(n, N)`` exponent is written once by the matmul; then
    :math:`\\exp(\\min(\\max(u_i^T w_j, \\log \\mathrm{tiny}), \\log\\theta_s))` (the min is the
    clamp of the squared distance at zero; the max keeps ``exp`` on its fast path, see
    :mod:`mcpilco.models.numerics`). Without a gradient to record, the clamps and the exp act
    in place. An outputscale of exactly 0 is floored at the smallest normal float so that no
    ``-inf`` enters the matmul (whose backward would turn ``0 * inf`` into NaN); the result is
    then that float (up to the rounding of ``exp(log tiny)``).
    """
    scale = lengthscale.mul(2.0**0.5).reciprocal()  # (*batch, 1, d)
    a = x1 * scale
    b = x2 * scale
    log_os = outputscale.clamp_min(torch.finfo(outputscale.dtype).tiny).log()[..., None, None]
    batch = torch.broadcast_shapes(a.shape[:-2], b.shape[:-2], log_os.shape[:-2])
    a = a.expand(*batch, *a.shape[-2:])
    b = b.expand(*batch, *b.shape[-2:])
    ones_a = a.new_ones(*a.shape[:-1], 1)
    ones_b = b.new_ones(*b.shape[:-1], 1)
    u = torch.cat([a, ones_a, log_os - a.pow(2).sum(-1, keepdim=True)], dim=-1)
    w = torch.cat([2.0 * b, -b.pow(2).sum(-1, keepdim=True), ones_b], dim=-1)
    arg = u @ w.transpose(-1, -2)
    floor = exp_floor_arg(arg.dtype)  # keeps exp on its fast path (mcpilco.models.numerics)
    if torch.is_grad_enabled() and arg.requires_grad:
        return torch.minimum(arg.clamp(min=floor), log_os).exp()
    return arg.clamp_(min=arg.new_tensor(floor), max=log_os).exp_()  # one pass


def _select(kernel: gpytorch.kernels.Kernel, x: Tensor) -> Tensor:
    dims = kernel.active_dims
    if dims is None:
        return x
    return x.index_select(-1, dims.to(x.device))


def dense_covar(
    kernel: gpytorch.kernels.Kernel,
    x1: Tensor,
    x2: Tensor,
    *,
    diag: bool = False,
    apply_active_dims: bool = True,
) -> Tensor:
    """Evaluate ``kernel(x1, x2)`` densely (plain torch ops, no ``LinearOperator``).

    Args:
        kernel: a GPyTorch kernel tree (see the module docstring for the handled node types).
        x1: ``(..., n, d)`` inputs; leading dims broadcast with the kernel's ``batch_shape``.
        x2: ``(..., N, d)`` inputs.
        diag: return :math:`k(x1_i, x2_i)` of shape ``(..., n)`` instead of the full matrix
            (requires ``n == N``).
        apply_active_dims: apply ``kernel.active_dims`` first (as ``Kernel.__call__`` does).

    Returns:
        ``(..., n, N)`` (or ``(..., n)`` with ``diag=True``), differentiable w.r.t. the inputs
        and the hyperparameters.
    """
    if apply_active_dims:
        x1 = _select(kernel, x1)
        x2 = _select(kernel, x2)
    kernels = gpytorch.kernels
    if isinstance(kernel, kernels.ScaleKernel):
        if type(kernel.base_kernel) is kernels.RBFKernel and not diag:
            return _scaled_rbf(kernel.outputscale, kernel.base_kernel.lengthscale, x1, x2)
        base = dense_covar(kernel.base_kernel, x1, x2, diag=diag, apply_active_dims=False)
        scale = kernel.outputscale
        scale = scale.unsqueeze(-1) if diag else scale.unsqueeze(-1).unsqueeze(-1)
        return base * scale
    if isinstance(kernel, kernels.AdditiveKernel):
        out = dense_covar(kernel.kernels[0], x1, x2, diag=diag)
        for k in kernel.kernels[1:]:
            out = out + dense_covar(k, x1, x2, diag=diag)
        return out
    if isinstance(kernel, kernels.ProductKernel):
        out = dense_covar(kernel.kernels[0], x1, x2, diag=diag)
        for k in kernel.kernels[1:]:
            out = out * dense_covar(k, x1, x2, diag=diag)
        return out
    if type(kernel) is kernels.RBFKernel:
        ls = kernel.lengthscale  # (*batch, 1, d)
        a = x1 / ls
        b = x2 / ls
        if diag:
            return exp_floor(-0.5 * (a - b).pow(2).sum(-1))
        return exp_floor(-0.5 * rbf_sq_dist(a, b))
    if type(kernel) is kernels.ConstantKernel:
        c = kernel.constant  # (*batch, 1)
        if diag:
            return c * x1.new_ones(x1.shape[:-1])
        return c.unsqueeze(-1) * x1.new_ones(*x1.shape[:-1], x2.shape[-2])
    if type(kernel) is kernels.LinearKernel:
        v = kernel.variance  # (*batch, 1, 1)
        if diag:
            return v.squeeze(-1) * (x1 * x2).sum(-1)
        return v * (x1 @ x2.transpose(-1, -2))
    return to_dense(kernel.forward(x1, x2, diag=diag))


def dense_diag(kernel: gpytorch.kernels.Kernel, x: Tensor) -> Tensor:
    """Prior variance :math:`k(x_i, x_i)`, shape ``(..., n)``, evaluated densely."""
    return dense_covar(kernel, x, x, diag=True)

"""Memory-lean Gram matrix of a product of diagonal linear kernels (GIP, MPK factors).

A GIP kernel (thesis eq. 3.11) on a 6-joint arm is a product of ``F = 13`` linear factors,

.. math::

    K = \\prod_{f=1}^{F} K_f, \\qquad
    K_f = \\sigma_f^2 + X^{(1)}_{C_f}\\, \\operatorname{diag}(\\mathbf w_f)\\,
    X^{(2)\\,T}_{C_f},

where :math:`C_f` are the input columns of factor :math:`f` (``[cos q_b, sin q_b]`` of joint
``b``, or ``[qd_v, qdd]``). Plain autograd keeps all :math:`F` factors and :math:`F - 1`
partial products, each ``(batch, N, N)``, for the backward pass: at ``N = 2000`` with 6
outputs that is about 7 GB, and the backward streams twice as many full-size products
through memory.

:func:`linear_product_gram` evaluates :math:`K` and its vector-Jacobian products in blocks
of rows and saves only the inputs. With :math:`G = \\partial L / \\partial K` and the
products of the other factors :math:`E_f = G \\odot \\prod_{g \\ne f} K_g` (a prefix
product times a suffix product, no division by a factor that may vanish):

.. math::

    \\frac{\\partial L}{\\partial \\sigma_f^2} = \\sum_{n,m} (E_f)_{nm}, \\quad
    \\frac{\\partial L}{\\partial w_{fj}} = \\sum_n X^{(1)}_{nj} (E_f X^{(2)}_{C_f})_{nj},
    \\quad
    \\frac{\\partial L}{\\partial X^{(1)}_{C_f}} \\mathrel{+}= (E_f X^{(2)}_{C_f})
    \\operatorname{diag}(\\mathbf w_f), \\quad
    \\frac{\\partial L}{\\partial X^{(2)}_{C_f}} \\mathrel{+}= (E_f^T X^{(1)}_{C_f})
    \\operatorname{diag}(\\mathbf w_f).

The backward recomputes the factors of one block of rows at a time, so the extra memory is
``O(F * batch * rows * N)`` for a block, not for the whole matrix.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

__all__ = ["linear_product_gram"]

#: elements of one ``(batch, rows, N)`` block in the backward pass (about 2 MB in float64)
BLOCK_ELEMENTS = 1 << 18


def _factor(x1c: Tensor, x2c: Tensor, w: Tensor, s: Tensor) -> Tensor:
    """:math:`\\sigma^2 + X_1 \\operatorname{diag}(w) X_2^T`, ``(*batch, n, m)``."""
    return torch.matmul(x1c * w.unsqueeze(-2), x2c.mT).add_(s[..., None, None])


def _sum_to(t: Tensor, shape: torch.Size) -> Tensor:
    """Sum ``t`` over the dimensions that were broadcast from ``shape``."""
    if t.shape == shape:
        return t
    lead = t.dim() - len(shape)
    t = t.sum(dim=tuple(range(lead))) if lead > 0 else t
    dims = tuple(i for i, n in enumerate(shape) if n == 1 and t.shape[i] != 1)
    return t.sum(dim=dims, keepdim=True) if dims else t


def _row_blocks(x1: Tensor, x2: Tensor, ws: Sequence[Tensor]) -> list[tuple[int, int]]:
    """Row ranges of ``x1`` whose ``(batch, rows, m)`` blocks hold about ``BLOCK_ELEMENTS``."""
    shape = torch.broadcast_shapes(x1.shape[:-2], x2.shape[:-2], *(w.shape[:-1] for w in ws))
    n, m = x1.shape[-2], x2.shape[-2]
    rows = max(1, min(n, BLOCK_ELEMENTS // max(shape.numel() * m, 1)))
    return [(r0, min(n, r0 + rows)) for r0 in range(0, n, rows)]


class _LinearProductGram(torch.autograd.Function):
    @staticmethod
    def forward(ctx, x1: Tensor, x2: Tensor, columns: tuple, *params: Tensor) -> Tensor:
        ws, ss = params[0::2], params[1::2]
        x2cs = [x2[..., cols] for cols in columns]
        blocks = _row_blocks(x1, x2, ws)
        out = None
        for r0, r1 in blocks:
            x1r = x1[..., r0:r1, :]
            block = None
            for cols, x2c, w, s in zip(columns, x2cs, ws, ss, strict=True):
                f = _factor(x1r[..., cols], x2c, w, s)
                block = f if block is None else block.mul_(f)
            if len(blocks) == 1:
                out = block
            else:
                if out is None:
                    out = block.new_empty(block.shape[:-2] + (x1.shape[-2], x2.shape[-2]))
                out[..., r0:r1, :] = block
        ctx.columns = columns
        ctx.save_for_backward(x1, x2, *params)
        return out

    @staticmethod
    @once_differentiable
    def backward(ctx, grad: Tensor):
        x1, x2, *params = ctx.saved_tensors
        ws, ss = params[0::2], params[1::2]
        columns = ctx.columns
        need_x1, need_x2 = ctx.needs_input_grad[0], ctx.needs_input_grad[1]
        g_w: list[Tensor | None] = [None] * len(ws)
        g_s: list[Tensor | None] = [None] * len(ss)
        like = dict(dtype=grad.dtype, device=grad.device)
        g_x1 = torch.zeros(grad.shape[:-1] + x1.shape[-1:], **like) if need_x1 else None
        g_x2 = torch.zeros(grad.shape[:-2] + x2.shape[-2:], **like) if need_x2 else None
        x2cs = [x2[..., cols] for cols in columns]
        for r0, r1 in _row_blocks(x1, x2, ws):
            x1r = x1[..., r0:r1, :]
            x1cs = [x1r[..., cols] for cols in columns]
            factors = [_factor(a, b, w, s) for a, b, w, s in zip(x1cs, x2cs, ws, ss, strict=True)]
            suffix: list[Tensor | None] = [None] * len(factors)  # prod_{g > f} K_g
            for f in range(len(factors) - 2, -1, -1):
                nxt = factors[f + 1]
                suffix[f] = nxt if suffix[f + 1] is None else nxt * suffix[f + 1]
            prefix = grad[..., r0:r1, :]  # G * prod_{g < f} K_g
            for f, (cols, x1c, x2c, w) in enumerate(zip(columns, x1cs, x2cs, ws, strict=True)):
                e = prefix if suffix[f] is None else prefix * suffix[f]
                ex2 = torch.matmul(e, x2c)  # (*b, rows, |C_f|)
                gw = (ex2 * x1c).sum(-2)
                g_w[f] = gw if g_w[f] is None else g_w[f] + gw
                gs = e.sum((-2, -1))
                g_s[f] = gs if g_s[f] is None else g_s[f] + gs
                if need_x1:
                    g_x1[..., r0:r1, cols] += ex2 * w.unsqueeze(-2)
                if need_x2:
                    g_x2[..., cols] += torch.matmul(e.mT, x1c) * w.unsqueeze(-2)
                if f + 1 < len(factors):
                    prefix = prefix * factors[f]
        out_params = []
        for w, s, gw, gs in zip(ws, ss, g_w, g_s, strict=True):
            out_params += [_sum_to(gw, w.shape), _sum_to(gs, s.shape)]
        gx1 = _sum_to(g_x1, x1.shape) if need_x1 else None
        gx2 = _sum_to(g_x2, x2.shape) if need_x2 else None
        return (gx1, gx2, None, *out_params)


def linear_product_gram(
    x1: Tensor,
    x2: Tensor,
    factors: Sequence[tuple[slice | list[int], Tensor, Tensor]],
) -> Tensor:
    """Gram matrix :math:`\\prod_f (\\sigma_f^2 + X^{(1)}_{C_f} \\operatorname{diag}(w_f)
    X^{(2)T}_{C_f})` with a memory-lean backward (module docstring).

    Args:
        x1: ``(..., n, d)``.
        x2: ``(..., m, d)``.
        factors: ``(columns, w, sigma2)`` per factor: ``columns`` a slice or list of column
            indices of the inputs, ``w`` ``(*batch, |columns|)`` the diagonal of
            :math:`\\Sigma_f`, ``sigma2`` ``(*batch,)`` the offset :math:`\\sigma_f^2`
            (zeros for a homogeneous factor). ``batch`` broadcasts against the inputs'.

    Returns:
        ``(*batch, n, m)``; differentiable w.r.t. ``x1``, ``x2`` and every ``w``, ``sigma2``.
    """
    if len(factors) == 0:
        raise ValueError("linear_product_gram needs at least one factor")
    columns = tuple(c for c, _, _ in factors)
    params: list[Tensor] = []
    for _, w, s in factors:
        params += [w.to(x1.dtype), s.to(x1.dtype)]
    return _LinearProductGram.apply(x1, x2, columns, *params)

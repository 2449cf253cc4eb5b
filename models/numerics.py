"""Small numerical helpers shared by the GP core and the agents.

``exp`` of a very negative argument is slow on CPU: PyTorch's vectorised ``exp`` leaves its
fast path when the result underflows below the smallest normal float
(:math:`x < \\log(\\mathrm{tiny}) \\approx -87.3` in float32, :math:`-708.4` in float64), and
is then many times slower per element. A GP with short lengthscales, or an RBF policy, puts
most entries of its kernel matrix there, which slows a whole MC-PILCO optimisation step.
:func:`exp_floor_` clamps the argument at
:math:`\\log(\\mathrm{tiny})` first, so such entries become the smallest normal float
(1.2e-38 in float32, 2.2e-308 in float64) instead of 0 or a subnormal: a change below any
tolerance the kernels or the policy can see, for one cheap clamp.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

__all__ = ["exp_floor", "exp_floor_", "exp_floor_arg"]


def exp_floor_arg(dtype: torch.dtype) -> float:
    """:math:`\\lceil \\log(\\mathrm{tiny}) \\rceil` of ``dtype``, rounded up to a multiple of
    0.5: ``-87.0`` for float32, ``-708.0`` for float64 (the exp of it is a normal float)."""
    return math.ceil(2.0 * math.log(torch.finfo(dtype).tiny)) / 2.0


def exp_floor_(x: Tensor) -> Tensor:
    """In place :math:`x \\leftarrow \\exp(\\max(x, \\log \\mathrm{tiny}))`; returns ``x``.

    For tensors that need no gradient (or inside custom autograd functions whose backward uses
    the result). Entries below the floor become :math:`\\approx` the smallest normal float.
    """
    return x.clamp_(min=exp_floor_arg(x.dtype)).exp_()


def exp_floor(x: Tensor) -> Tensor:
    """Out of place :math:`\\exp(\\max(x, \\log \\mathrm{tiny}))`, differentiable (zero gradient
    below the floor, where the exact gradient is below the smallest normal float too)."""
    return x.clamp(min=exp_floor_arg(x.dtype)).exp()

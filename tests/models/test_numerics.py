"""exp with a floored argument: equal to exp where it does not underflow, normal floats below."""

import math

import pytest
import torch

from mcpilco.models.numerics import exp_floor, exp_floor_, exp_floor_arg


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_floor_is_log_of_a_normal_float(dtype: torch.dtype) -> None:
    tiny = torch.finfo(dtype).tiny
    f = exp_floor_arg(dtype)
    assert f >= math.log(tiny)  # exp(f) is a normal float ...
    assert f - 0.5 < math.log(tiny)  # ... and the floor is within half a unit of log(tiny)
    assert float(torch.tensor(f, dtype=dtype).exp()) >= tiny


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_exp_floor_matches_math_exp(dtype: torch.dtype) -> None:
    x = torch.tensor([-1e6, -1000.0, -750.0, -100.0, -87.0, -20.0, -1.0, 0.0, 3.0], dtype=dtype)
    f = exp_floor_arg(dtype)
    expect = torch.tensor([math.exp(max(float(v), f)) for v in x], dtype=dtype)
    torch.testing.assert_close(exp_floor(x), expect, rtol=1e-6, atol=0.0)
    y = x.clone()
    assert exp_floor_(y) is y
    torch.testing.assert_close(y, expect, rtol=1e-6, atol=0.0)
    # no zeros and no subnormals, even far below the floor
    assert bool((y >= torch.finfo(dtype).tiny).all())


def test_exp_floor_gradient() -> None:
    x = torch.tensor([-1e4, -2.0, 0.5], dtype=torch.float64, requires_grad=True)
    exp_floor(x).sum().backward()
    torch.testing.assert_close(x.grad, torch.tensor([0.0, math.exp(-2.0), math.exp(0.5)]).double())

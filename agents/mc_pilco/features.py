"""State layout and angle features in torch, derived from a :class:`~.task.TaskSpec`.

``f(x) = [x_plain, sin x_a1, cos x_a1, sin x_a2, cos x_a2, ...]`` (``x_plain``: the coordinates
that are not angles, in state order). The GP input is ``[f(x), u]`` and the policy input is
``f(x)``. :class:`StateLayout` holds the index sets; :meth:`StateLayout.features` and
:meth:`StateLayout.features_backward` are the map and its analytic vector-Jacobian product,
``dJ/dx_a = dJ/dsin_a cos x_a - dJ/dcos_a sin x_a``, used by the autograd functions of the
policy and the GP inputs (one autograd node each).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import torch
from torch import Tensor


@dataclass(frozen=True)
class StateLayout:
    """Index sets of a state of ``n`` coordinates.

    Attributes:
        n: state size.
        plain_idx: coordinates entering ``f(x)`` as they are.
        angle_idx: coordinates entering through ``(sin, cos)``.
        position_idx, velocity_idx: the speed-integration pairs, eq. (5.9).
        delta_idx: coordinates in no pair, predicted as their own change.
        oscillators: ``(position index, velocity index, omega, centre)`` per known reference
            joint: states that follow a known harmonic oscillator (a sinusoidal reference,
            the exosystem of a tracking task), propagated exactly instead of predicted
            (:func:`~mcpilco.agents.mc_pilco.dynamics.speed_integration`).
    """

    n: int
    plain_idx: tuple[int, ...]
    angle_idx: tuple[int, ...]
    position_idx: tuple[int, ...] = ()
    velocity_idx: tuple[int, ...] = ()
    delta_idx: tuple[int, ...] = ()
    oscillators: tuple[tuple[int, int, float, float], ...] = ()

    def __post_init__(self) -> None:
        if sorted(self.plain_idx + self.angle_idx) != list(range(self.n)):
            raise ValueError(
                f"plain_idx {self.plain_idx} and angle_idx {self.angle_idx} must split "
                f"range({self.n})"
            )
        covered = self.position_idx + self.velocity_idx + self.delta_idx + self.oscillator_idx
        if sorted(covered) != list(range(self.n)):
            raise ValueError(
                f"pairs {list(zip(self.position_idx, self.velocity_idx, strict=False))}, "
                f"delta_idx {self.delta_idx} and oscillators {self.oscillator_idx} must cover "
                f"range({self.n}) once"
            )

    @classmethod
    def from_task(cls, task: Any) -> StateLayout:
        """The layout of a :class:`~.task.TaskSpec`."""
        return cls(
            n=task.state_dim,
            plain_idx=task.plain_idx,
            angle_idx=task.angle_idx,
            position_idx=task.position_idx,
            velocity_idx=task.velocity_idx,
            delta_idx=task.delta_idx,
            oscillators=task.oscillators,
        )

    @property
    def oscillator_idx(self) -> tuple[int, ...]:
        """The coordinates of the known oscillators (positions and velocities): no GP output."""
        return tuple(i for p, v, _, _ in self.oscillators for i in (p, v))

    @property
    def feature_dim(self) -> int:
        return len(self.plain_idx) + 2 * len(self.angle_idx)

    @property
    def output_idx(self) -> tuple[int, ...]:
        """Coordinates whose change the GP predicts: pair velocities, then unpaired ones."""
        return self.velocity_idx + self.delta_idx

    @property
    def output_dim(self) -> int:
        return len(self.output_idx)

    def to_dict(self) -> dict[str, Any]:
        d = {k: list(v) if isinstance(v, tuple) else v for k, v in vars(self).items()}
        d["oscillators"] = [list(o) for o in self.oscillators]
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> StateLayout:
        d = {k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}
        oscillators = tuple(
            (int(p), int(v), float(w), float(c)) for p, v, w, c in d.get("oscillators", ())
        )
        return cls(**{**d, "oscillators": oscillators})

    def features(self, x: Tensor) -> tuple[Tensor, Tensor | None, Tensor | None]:
        """``f(x)`` (..., F) and the ``sin, cos`` of the angles (kept for the backward)."""
        plain = take(x, self.plain_idx)
        if not self.angle_idx:
            return plain, None, None
        ang = take(x, self.angle_idx)
        s, c = torch.sin(ang), torch.cos(ang)
        sc = torch.stack([s, c], dim=-1).flatten(-2)
        return torch.cat([plain, sc], dim=-1), s, c

    def features_backward(self, g: Tensor, s: Tensor | None, c: Tensor | None) -> Tensor:
        """``dJ/dx`` (..., n) from ``dJ/df`` (..., F)."""
        p = len(self.plain_idx)
        parts = [None] * self.n
        for k, i in enumerate(self.plain_idx):
            parts[i] = g[..., k]
        for k, i in enumerate(self.angle_idx):
            g_s, g_c = g[..., p + 2 * k], g[..., p + 2 * k + 1]
            parts[i] = g_s * c[..., k] - g_c * s[..., k]
        return torch.stack(parts, dim=-1)


def take(x: Tensor, idx: tuple[int, ...]) -> Tensor:
    """``x[..., idx]`` for fixed indices, built from views of ``x`` (a slice for a run of
    consecutive indices, else a stack of columns) instead of an index tensor: no tensor is
    made from host memory, so the selection also runs inside a CUDA graph capture."""
    idx = tuple(idx)
    if not idx:
        return x[..., :0]
    if idx == tuple(range(idx[0], idx[0] + len(idx))):
        return x[..., idx[0] : idx[0] + len(idx)]
    return torch.stack([x[..., i] for i in idx], dim=-1)


class GPInputsSaved(NamedTuple):
    """What :func:`gp_inputs_backward` needs: the angles' ``sin`` and ``cos`` (None without
    angles)."""

    s: Tensor | None
    c: Tensor | None


def gp_inputs_forward(
    state: Tensor, action: Tensor, layout: StateLayout
) -> tuple[Tensor, GPInputsSaved]:
    """``x~ = [f(x), u]``: (..., n), (..., A) -> (..., F + A), and what its backward needs (the
    GP inputs' step protocol, with :func:`gp_inputs_backward`)."""
    f, s, c = layout.features(state)
    return torch.cat([f, action], dim=-1), GPInputsSaved(s, c)


def gp_inputs_backward(
    saved: GPInputsSaved, g: Tensor, layout: StateLayout
) -> tuple[Tensor, Tensor]:
    """``(dJ/dx, dJ/du)`` from ``g = dJ/dx~`` (..., F + A)."""
    F = layout.feature_dim
    return layout.features_backward(g[..., :F], saved.s, saved.c), g[..., F:]


class _GPInputs(torch.autograd.Function):
    """:func:`gp_inputs_forward` and :func:`gp_inputs_backward` as one autograd node."""

    @staticmethod
    def forward(ctx, state: Tensor, action: Tensor, layout: StateLayout) -> Tensor:  # noqa: D102
        out, saved = gp_inputs_forward(state, action, layout)
        ctx.save_for_backward(*saved)
        ctx.layout = layout
        return out

    @staticmethod
    def backward(ctx, g: Tensor) -> tuple[Tensor, Tensor, None]:  # noqa: D102
        return (*gp_inputs_backward(GPInputsSaved(*ctx.saved_tensors), g, ctx.layout), None)


def gp_inputs(state: Tensor, action: Tensor, layout: StateLayout) -> Tensor:
    """The GP input ``x~ = [f(x), u]`` (differentiable, analytic backward)."""
    return _GPInputs.apply(state, action, layout)

"""Saturating cost of a task in torch (thesis section 5.5.1; Amadio et al. 2022, sec. V-VI).

Glossary
--------
``c(x) = 1 - exp(-sum_j d_j(x)^2 / l_j^2)``
    the cost on the task's cost terms ``j`` (state coordinate ``x_j``, target ``x*_j``, length
    scale ``l_j``), in ``[0, 1)``;
``d_j = x_j - x*_j``
    for a plain coordinate;
``d_j = wrap(x_j - x*_j)``
    for an angle in mode ``"wrap"`` (the angle mapped to ``[-pi, pi)``; derivative 1 almost
    everywhere);
``d_j = x_j - x_r - x*_j``
    for a term that tracks another state ``x_r`` (``refs``; wrapped for an angle in mode
    ``"wrap"``), e.g. a joint and its reference;
``d_j = |x_j| - |x*_j|``
    for an angle in mode ``"abs"``: MC-PILCO's unwrapped cart-pole cost (Amadio et al. 2022,
    sec. V-A), where every full rotation increases ``|x_j|``, so spinning the pole through
    the target is not rewarded (with a wide ``l_j`` and the wrapped angle a spinning policy
    gets a low average cost);
``c_b(x) = sum_k sigma((x_k - hi_k) / s_k) + sigma((lo_k - x_k) / s_k)``
    a barrier at the declared limits ``[lo_k, hi_k]`` of states ``x_k`` (``sigma`` the
    logistic function, ``s_k`` its width: ``c_b`` is 1/2 at a limit, 0.05 at ``3 s_k`` inside
    it), added to ``c``. It grows whatever the other terms, so it also acts while ``c`` is
    saturated (the pole hanging during a swing-up), and it keeps the particles, which a GP of
    the free motion lets pass through a stop, inside the reachable range;
``J = sum_t E[c(x_t)]``
    expected cumulative cost, eq. (5.1); its Monte Carlo estimate is eq. (5.8)
    (:mod:`mcpilco.agents.mc_pilco.loss`).

The numpy evaluation cost of the same spec is :meth:`.task.TaskSpec.cost`; the tests check
that the two agree.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import torch
from torch import Tensor, nn

from mcpilco.envs.tasks.spec import ANGLE_MODES

MODE_PLAIN, MODE_WRAP, MODE_ABS = 0, 1, 2
"""Distance kinds of a term: plain difference, wrapped angle, ``|x| - |x*|``."""


class SaturatingCost(nn.Module):
    """``c(x) = 1 - exp(-sum_j d_j(x)^2 / l_j^2)`` (module glossary).

    Args:
        state_dim: ``n``, the state size.
        idx: state index of each term.
        targets: ``x*_j``.
        length_scales: ``l_j`` (> 0).
        modes: per term, 0 plain, 1 wrapped angle, 2 ``|x| - |x*|`` (see the constants).
        refs: per term, the index of the state it tracks (``d_j = x_j - x_r - x*_j``), or -1;
            None: no term tracks a state.
        barriers: ``(k, lo_k, hi_k, s_k)`` per barrier ``c_b`` (module glossary): state index,
            limits and width (> 0); None: none.

    Shapes:
        ``forward(state (..., n)) -> cost (...)``.
    """

    def __init__(
        self,
        state_dim: int,
        idx: Sequence[int],
        targets: Sequence[float],
        length_scales: Sequence[float],
        modes: Sequence[int],
        refs: Sequence[int] | None = None,
        barriers: Sequence[tuple[int, float, float, float]] | None = None,
    ) -> None:
        super().__init__()
        if not (len(idx) == len(targets) == len(length_scales) == len(modes)) or not idx:
            raise ValueError("idx, targets, length_scales and modes need one entry per term")
        if not all(ls > 0 and math.isfinite(ls) for ls in length_scales):
            raise ValueError(f"cost length scales must be > 0, got {list(length_scales)}")
        if not all(0 <= i < state_dim for i in idx):
            raise ValueError(f"cost term indices {list(idx)} out of range for {state_dim} states")
        self.state_dim = int(state_dim)
        self.idx = tuple(int(i) for i in idx)
        self.targets = tuple(float(t) for t in targets)
        self.length_scales = tuple(float(v) for v in length_scales)
        self.modes = tuple(int(m) for m in modes)
        self.refs = tuple(-1 for _ in idx) if refs is None else tuple(int(r) for r in refs)
        if len(self.refs) != len(self.idx) or not all(-1 <= r < state_dim for r in self.refs):
            raise ValueError(f"refs needs one index in -1..{state_dim - 1} per term, got {refs}")
        if any(r >= 0 and m == MODE_ABS for r, m in zip(self.refs, self.modes, strict=True)):
            raise ValueError("a term with a reference state takes mode plain or wrap, not abs")
        self.barriers = tuple(
            (int(k), float(lo), float(hi), float(w)) for k, lo, hi, w in (barriers or ())
        )
        for k, lo, hi, w in self.barriers:
            if not (0 <= k < state_dim and lo < hi and w > 0 and math.isfinite(lo + hi + w)):
                raise ValueError(
                    f"a barrier needs a state index in 0..{state_dim - 1}, finite lo < hi and "
                    f"a width > 0, got {(k, lo, hi, w)}"
                )

    @property
    def tracks(self) -> bool:
        """Whether a term tracks another state (``refs``)."""
        return any(r >= 0 for r in self.refs)

    @classmethod
    def from_task(
        cls,
        task: Any,
        length_scales: Mapping[str, float] | None = None,
        angle_mode: str | None = None,
        limit_widths: Mapping[str, float] | None = None,
    ) -> SaturatingCost:
        """The cost of ``task``'s terms; ``length_scales`` (by state name) and ``angle_mode``
        (for every angle term) replace the task's values, e.g. for the optimised cost;
        ``limit_widths`` (by state name) adds a barrier of that width at the task's limits of
        each named state."""
        limit_widths = dict(limit_widths or {})
        no_limits = sorted(set(limit_widths) - set(task.limits))
        if no_limits:
            raise ValueError(
                f"cost limit widths for {no_limits}, which have no limits in the task "
                f"(limits: {sorted(task.limits)})"
            )
        length_scales = dict(length_scales or {})
        unknown = set(length_scales) - {t.state for t in task.cost_terms}
        if unknown:
            raise ValueError(
                f"cost length scales for {sorted(unknown)}, which have no cost term in the "
                f"task (terms: {[t.state for t in task.cost_terms]})"
            )
        if angle_mode is not None and angle_mode not in ANGLE_MODES:
            raise ValueError(f"angle_mode must be one of {ANGLE_MODES}, got {angle_mode!r}")
        modes = []
        for t in task.cost_terms:
            if t.state not in task.angles:
                modes.append(MODE_PLAIN)
            else:
                mode = angle_mode or t.angle_mode
                modes.append(MODE_WRAP if mode == "wrap" or t.reference else MODE_ABS)
        return cls(
            task.state_dim,
            [task.index(t.state) for t in task.cost_terms],
            [t.target for t in task.cost_terms],
            [float(length_scales.get(t.state, t.length_scale)) for t in task.cost_terms],
            modes,
            [-1 if t.reference is None else task.index(t.reference) for t in task.cost_terms],
            [(task.index(k), *task.limits[k], float(w)) for k, w in limit_widths.items()],
        )

    def forward(self, state: Tensor) -> Tensor:
        if state.shape[-1] != self.state_dim:
            raise ValueError(
                f"state must have shape (..., {self.state_dim}), got {tuple(state.shape)}"
            )
        return _SaturatingCostFn.apply(state, self)

    def extra_repr(self) -> str:
        return (
            f"idx={self.idx}, targets={self.targets}, length_scales={self.length_scales}, "
            f"modes={self.modes}"
            + (f", refs={self.refs}" if self.tracks else "")
            + (f", barriers={self.barriers}" if self.barriers else "")
        )


def _distance(v: Tensor, target: float, mode: int) -> tuple[Tensor, Tensor | None]:
    """``d`` and ``dd/dv`` (None: 1) of one term."""
    if mode == MODE_PLAIN:
        return v - target, None
    if mode == MODE_WRAP:
        return torch.remainder(v - target + math.pi, 2.0 * math.pi) - math.pi, None
    return v.abs() - abs(target), torch.sign(v)


class SaturatingCostSaved(NamedTuple):
    """What :func:`saturating_cost_backward` needs: ``E`` (...), ``d_j`` per term, ``d'_j``
    per ``abs`` term (the others have ``d'_j = 1``) and ``dc_b/dx_k`` per barrier."""

    E: Tensor
    ds: tuple[Tensor, ...]
    slopes: tuple[Tensor, ...]
    dbar: tuple[Tensor, ...]

    def flat(self) -> tuple[Tensor, ...]:
        """All tensors in one tuple (for ``save_for_backward``)."""
        return (self.E, *self.ds, *self.slopes, *self.dbar)

    @classmethod
    def from_flat(cls, tensors: tuple[Tensor, ...], cost: SaturatingCost) -> SaturatingCostSaved:
        """The inverse of :meth:`flat` for ``cost``'s terms and barriers."""
        k, n_slopes = len(cost.idx), sum(m == MODE_ABS for m in cost.modes)
        E, *rest = tensors
        return cls(E, tuple(rest[:k]), tuple(rest[k : k + n_slopes]), tuple(rest[k + n_slopes :]))


def saturating_cost_forward(
    state: Tensor, cost: SaturatingCost
) -> tuple[Tensor, SaturatingCostSaved]:
    """``c = 1 - E + c_b`` (...) of ``state (..., n)``, ``E = exp(-sum_j (d_j / l_j)^2)``, and
    what its backward needs (the cost's step protocol, with :func:`saturating_cost_backward`).
    """
    s = None
    ds, slopes = [], []
    for i, target, ls, mode, r in zip(
        cost.idx, cost.targets, cost.length_scales, cost.modes, cost.refs, strict=True
    ):
        v = state[..., i] if r < 0 else state[..., i] - state[..., r]
        d, slope = _distance(v, target, mode)
        term = (d / ls) ** 2
        s = term if s is None else s + term
        ds.append(d)
        if slope is not None:
            slopes.append(slope)
    E = torch.exp(-s)
    c = 1.0 - E
    dbar = []  # dc_b / dx_k per barrier
    for k, lo, hi, w in cost.barriers:
        a = torch.sigmoid((state[..., k] - hi) / w)
        b = torch.sigmoid((lo - state[..., k]) / w)
        c = c + (a + b)
        dbar.append((a * (1.0 - a) - b * (1.0 - b)) / w)
    return c, SaturatingCostSaved(E, tuple(ds), tuple(slopes), tuple(dbar))


def saturating_cost_backward(saved: SaturatingCostSaved, g: Tensor, cost: SaturatingCost) -> Tensor:
    """``dJ/dx`` (..., n) from ``g = dJ/dc`` (...): ``dc/dx_j = 2 E d_j d'_j / l_j^2`` with
    ``d'_j = 1`` (plain, wrap) or ``sign(x_j)`` (``abs``; ``sign(0) = 0``, the subgradient of
    ``abs`` in torch), and the same with the opposite sign on the tracked state ``x_r`` of a
    term that has one; each barrier adds ``dc_b/dx_k = (a (1 - a) - b (1 - b)) / s_k``,
    ``a = sigma((x_k - hi_k) / s_k)``, ``b = sigma((lo_k - x_k) / s_k)``."""
    E, ds, slopes = saved.E, saved.ds, iter(saved.slopes)
    gE2 = 2.0 * g * E
    cols = [None] * cost.state_dim
    for j, (i, ls, r, mode) in enumerate(
        zip(cost.idx, cost.length_scales, cost.refs, cost.modes, strict=True)
    ):
        gj = gE2 * ds[j] / (ls * ls)
        if mode == MODE_ABS:
            gj = gj * next(slopes)
        cols[i] = gj if cols[i] is None else cols[i] + gj
        if r >= 0:
            cols[r] = -gj if cols[r] is None else cols[r] - gj
    for (i, *_), db in zip(cost.barriers, saved.dbar, strict=True):
        cols[i] = g * db if cols[i] is None else cols[i] + g * db
    zero = torch.zeros_like(E)
    return torch.stack([zero if c is None else c for c in cols], dim=-1)


class _SaturatingCostFn(torch.autograd.Function):
    """:func:`saturating_cost_forward` and :func:`saturating_cost_backward` as one autograd
    node."""

    @staticmethod
    def forward(ctx, state: Tensor, cost: SaturatingCost) -> Tensor:  # noqa: D102
        c, saved = saturating_cost_forward(state, cost)
        ctx.save_for_backward(*saved.flat())
        ctx.cost = cost
        return c

    @staticmethod
    def backward(ctx, g: Tensor) -> tuple[Tensor, None]:  # noqa: D102
        saved = SaturatingCostSaved.from_flat(ctx.saved_tensors, ctx.cost)
        return saturating_cost_backward(saved, g, ctx.cost), None

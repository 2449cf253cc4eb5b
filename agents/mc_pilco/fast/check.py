"""The check of a fast rollout against the eager one: the same loss, the same random
numbers, ``J^`` and ``dJ^/dtheta`` of both compared before the optimisation uses the fast one
(:func:`~mcpilco.agents.mc_pilco.fast.select.use_fast_rollout`)."""

from __future__ import annotations

from typing import Any

import torch

COMPILE_CHECK_RTOL = 0.1
"""Largest relative difference a fast rollout may show against the eager one in
:func:`check_against_eager`: ``|J_f - J_e| / |J_e|`` and ``||g_f - g_e|| / ||g_e||`` (2-norm
over all policy parameters together). A wrong gradient gives about 1 (a gradient cut through
time gives 0.97 in the tests); a false alarm only costs speed (the eager rollout runs)."""

COMPILE_CHECK_HORIZON = 10
"""Time steps of that check (at most the loss's horizon). Over a long horizon the float32
policy gradient can be chaotic (particles near an unstable equilibrium amplify rounding, so
two correct float32 implementations may differ by tens of percent); over 10 steps they agree
to about 1e-4, and every part of the step, forward and backward, still runs."""


def passes(check: dict[str, float] | None) -> bool:
    """Whether the figures of :func:`check_against_eager` are within
    :data:`COMPILE_CHECK_RTOL` (NaN fails; None, no check, passes)."""
    return check is None or (check["J_rel"] <= COMPILE_CHECK_RTOL >= check["grad_rel"])


def check_against_eager(
    loss: Any, seed: int = 0, horizon: int | None = COMPILE_CHECK_HORIZON
) -> dict[str, float]:
    """``J^`` and ``dJ^/dtheta`` of the loss's fast rollout and of its eager rollout over the
    first ``horizon`` steps (None: the loss's horizon) from the same random numbers (torch
    seeded with ``seed`` inside a forked random state, so the caller's stream is untouched):
    ``{"J_rel": |J_f - J_e| / |J_e|, "grad_rel": ||g_f - g_e|| / ||g_e||}`` (``g`` all policy
    parameters' gradients, one vector; 0 where both are 0). The policy runs in training
    mode, with its dropout masks, as in the optimisation (its mode is restored after). The
    first call of a fresh compiled step compiles it."""
    fast = loss.fast_rollout
    if fast == (None, None):
        raise ValueError("the loss has no fast rollout: call use_fast_rollout first")
    params = [p for p in loss.parameters() if p.requires_grad]
    dev = loss.init_mean.device
    results = []
    full_horizon = loss.horizon
    loss.horizon = full_horizon if horizon is None else min(int(horizon), full_horizon)
    policy = loss.policy_module
    was_training = policy.training
    policy.train()
    try:
        with torch.random.fork_rng(devices=[dev] if dev.type == "cuda" else []):
            for engine, step_fn in ((None, None), fast):
                loss.set_fast_rollout(engine, step_fn)
                torch.manual_seed(seed)
                J = loss()["loss_cost"]
                grads = (
                    torch.autograd.grad(J, params, allow_unused=True)
                    if J.requires_grad and params
                    else [None] * len(params)
                )
                vec = [
                    (torch.zeros_like(p) if g is None else g.detach()).flatten()
                    for g, p in zip(grads, params, strict=True)
                ]
                results.append((J.detach(), torch.cat(vec or [J.new_zeros(0)])))
    finally:
        loss.set_fast_rollout(*fast)
        loss.horizon = full_horizon
        policy.train(was_training)
    (J_e, g_e), (J_f, g_f) = results

    def rel(diff: float, scale: float) -> float:
        return 0.0 if diff == 0 else diff / scale if scale > 0 else float("inf")

    return {
        "J_rel": rel((J_f - J_e).abs().item(), J_e.abs().item()),
        "grad_rel": rel((g_f - g_e).norm().item(), g_e.norm().item()),
    }


__all__ = ["COMPILE_CHECK_HORIZON", "COMPILE_CHECK_RTOL", "check_against_eager", "passes"]

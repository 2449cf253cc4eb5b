"""Exploration that respects declared end stops: on a cart whose track ends in stops (the
task's ``limits``), held random actions drive it into a stop; braked by
:class:`~mcpilco.agents.common.trials.LimitGuard`, which is told nothing of the cart's
law, the cart never reaches either stop."""

from __future__ import annotations

import numpy as np

from mcpilco.agents.common.trials import LimitGuard, exploration_episodes, make_env
from mcpilco.envs.tasks.spec import TaskSpec
from tests.agents.common import end_stop_env
from tests.agents.common.end_stop_env import ENV_ID, FORCE, SLOPE, STOP, TASK

SEEDS = range(12)
HOLD = 10  # each random push held 0.5 s: long enough to reach a stop


def _explore(seed: int, guard: LimitGuard | None) -> list[dict]:
    task = TaskSpec.from_dict(TASK)
    env = make_env(ENV_ID, task.horizon, task)
    try:
        return exploration_episodes(
            env, np.random.default_rng(seed), seed, task.horizon, task, HOLD, guard=guard
        )
    finally:
        env.close()


def test_unguarded_exploration_hits_the_stop():
    """The premise: without the guard, held random pushes reach a stop on most seeds."""
    assert end_stop_env.SlopeCart  # the env module registers the id
    hits = [np.any(np.abs(_explore(s, None)[0]["states"][:, 0]) >= STOP) for s in SEEDS]
    assert sum(hits) >= len(SEEDS) // 2


def test_guarded_exploration_never_reaches_a_stop():
    """With the guard the true state stays strictly inside the track on every seed and the
    guard braked on each (it had to). The actions are the unguarded run's random draws
    except the two probe pulses (+1, -1) at the start and the braked steps, each a full
    push."""
    task = TaskSpec.from_dict(TASK)
    for seed in SEEDS:
        guard = LimitGuard(task)
        (ep,) = _explore(seed, guard)
        x = ep["states"][:, 0]
        assert np.all(np.abs(x) < STOP), (seed, x.min(), x.max())
        assert guard.interventions > 0 and guard.probes == 2
        u = ep["actions"][:, 0]
        np.testing.assert_array_equal(u[:2], [1.0, -1.0])
        (free,) = _explore(seed, None)
        changed = np.flatnonzero(u[2:] != free["actions"][2:, 0]) + 2
        assert 0 < len(changed) <= guard.interventions
        np.testing.assert_array_equal(np.abs(u[changed]), 1.0)  # full pushes


def test_guard_learns_the_cart_law():
    """The online fit of ``Delta v = b u + c`` recovers the env's own ``T_s F`` and
    ``-T_s G`` (noise-free data away from the stops)."""
    task = TaskSpec.from_dict(TASK)
    guard = LimitGuard(task)
    _explore(0, guard)
    b, c = guard.coef[:, 0]
    np.testing.assert_allclose([b, c], [task.dt * FORCE, -task.dt * SLOPE], rtol=1e-6)


def test_guard_without_bounds_passes_actions_through():
    """A task that declares no limits gets the random actions unchanged."""
    task = TaskSpec.from_dict({k: v for k, v in TASK.items() if k != "limits"})
    guard = LimitGuard(task)
    u = np.array([0.7])
    assert guard.bounds == [] and guard(np.array([0.99, 5.0]), u) is not None
    np.testing.assert_array_equal(guard(np.array([0.99, 5.0]), u), u)


def test_trainer_explores_within_the_limits_and_records_the_braking(tmp_path):
    """MC-PILCO's exploration trial on the cart brakes by default (``explore_limits:
    limits``) and its record counts the braked steps; ``none`` explores freely; another
    value is refused naming the field."""
    import pytest

    from mcpilco.agents.common.records import TrialRecord
    from mcpilco.agents.mc_pilco import MCPilcoConfig
    from mcpilco.agents.mc_pilco.trainer import Trainer

    for mode in ("limits", "none"):
        cfg = MCPilcoConfig(
            env_id=ENV_ID, task=TASK, num_trials=0, num_basis=5, explore_hold=HOLD,
            explore_limits=mode, seed=3,
        )  # fmt: skip
        trainer = Trainer(cfg, tmp_path / mode, progress=False, log=None, write_rrd=False)
        trainer.set_up()
        rec = TrialRecord(index=0, kind="exploration")
        try:
            (ep,) = trainer.explore(rec)
        finally:
            trainer.env.close()
            trainer.run_folder.close()
        if mode == "limits":
            assert rec.explore_braked > 0 and np.all(np.abs(ep["states"][:, 0]) < STOP)
        else:
            assert rec.explore_braked is None
    with pytest.raises(ValueError, match="explore_limits"):
        MCPilcoConfig(env_id=ENV_ID, task=TASK, explore_limits="yes")

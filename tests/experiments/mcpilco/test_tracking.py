"""The tracking benchmark's figures: the controller-alone baseline against the two-link arm
run by hand, the per-trial means, ratios and halved counts against hand-computed values,
and the report files."""

from __future__ import annotations

import numpy as np
import pytest

from mcpilco.agents.common.trials import make_env, run_episode, trial_seed
from mcpilco.agents.mc_pilco import MCPilcoConfig, TaskSpec
from mcpilco.experiments.mcpilco.tracking import (
    controller_alone,
    overall,
    tracking_part,
    tracking_section,
    write_tracking_report,
)
from mcpilco.experiments.results import read_result
from tests.agents.mc_pilco.arm_env import ENV_ID, TASK


def test_controller_alone_is_the_zero_correction_episode():
    """The baseline of trial k is the episode of reset seed ``trial_seed(seed, k)`` with a
    zero torque correction; its RMS per joint equals sqrt(mean (q - q_r)^2) computed here from
    the states."""
    cfg = MCPilcoConfig(env_id=ENV_ID, task=TASK)
    got = controller_alone(cfg, seed=4, trials=2)
    task = TaskSpec.from_dict(TASK)
    env = make_env(ENV_ID, task.horizon, task)
    for k, rms in enumerate(got, start=1):
        ep = run_episode(env, lambda _x: np.zeros(2), trial_seed(4, k), task.horizon, task)
        s = ep["states"][1:]
        want = np.sqrt(np.mean((s[:, :2] - s[:, 4:6]) ** 2, axis=0))
        np.testing.assert_allclose([rms["q1"], rms["q2"]], want, rtol=1e-12)
    assert got[0] != got[1]  # another reset seed, another initial state


def test_tracking_section_means_ratios_and_halved_counts(tmp_path, monkeypatch):
    """Two seeds, two policy trials, baselines fixed: means, ratios to the baseline, the
    worst ratio and the number of seeds with every joint at most half the baseline's."""
    alone, ideal = {"q1": 0.04, "q2": 0.02}, {"q1": 0.004, "q2": 0.004}
    monkeypatch.setattr(
        "mcpilco.experiments.mcpilco.tracking.controller_alone",
        lambda config, seed, trials, feedforward=False: [ideal if feedforward else alone] * trials,
    )

    def run(seed, rms):
        recs = [{"kind": "exploration", "experience_s": 2.0}]
        recs += [
            {"kind": "policy", "experience_s": 2.0 * (k + 2), "tracking_rms": r}
            for k, r in enumerate(rms)
        ]
        return {"seed": seed, "records": recs, "seconds": 1.0}

    runs = [
        run(1, [{"q1": 0.03, "q2": 0.02}, {"q1": 0.01, "q2": 0.01}]),
        run(0, [{"q1": 0.01, "q2": 0.005}, {"q1": 0.02, "q2": 0.012}]),
    ]
    section = {"config": {}, "seeds": [0, 1], "jobs": 1, "wall_s_per_run": 1.0}
    out = tracking_section(MCPilcoConfig(env_id=ENV_ID, task=TASK), runs, section)
    assert out["joints"] == ["q1", "q2"]
    first, second = out["tracking"]
    np.testing.assert_allclose(first["rms_mean"], [0.02, 0.0125])
    np.testing.assert_allclose(first["ratio_mean"], [(0.75 + 0.25) / 2, (1.0 + 0.25) / 2])
    np.testing.assert_allclose(first["ratio_worst"], [0.75, 1.0])
    assert first["seeds_halved"] == 1  # seed 0 only
    np.testing.assert_allclose(first["feedforward_ratio"], [0.1, 0.2])
    assert first["feedforward_halved"] == 2
    assert second["seeds_halved"] == 1  # seed 1 (0.25, 0.5); seed 0 has q2 at 0.6
    assert [s["seed"] for s in out["tracking_per_seed"]] == [0, 1]
    tot = overall(out, 0)  # all joints: sqrt(mean_j rms_j^2) per seed
    a0, a1, alone_all = np.sqrt(6.25e-5), np.sqrt(6.5e-4), np.sqrt(1e-3)
    assert tot["rms"] == pytest.approx((a0 + a1) / 2)
    assert tot["ratio"] == pytest.approx((a0 + a1) / 2 / alone_all)
    assert tot["alone"] == pytest.approx(alone_all) and tot["halved"] == 1
    out["config"] = MCPilcoConfig(env_id=ENV_ID, task=TASK).to_dict()
    write_tracking_report({"runs": {"arm": out}}, tmp_path)
    md = (tmp_path / "mcpilco_tracking.md").read_text()
    assert "| controller alone | 40.0 | 20.0 | - |" in md
    assert "| known-model feed-forward | 4.0 (0.10) | 4.0 (0.20) | 2 / 2 |" in md
    assert "| 4 s (policy 1) | 20.0 (0.50) | 12.5 (0.62) | 1 / 2 (feed-forward 2) |" in md
    assert read_result(tmp_path / "mcpilco_tracking.json").payload()["runs"]["arm"]["joints"]
    assert (tmp_path / "mcpilco_tracking.png").stat().st_size > 0


def test_tracking_part_refuses_a_task_without_a_reference(tmp_path):
    from tests.agents.mc_pilco.toy_env import ENV_ID as TOY_ID
    from tests.agents.mc_pilco.toy_env import TASK as TOY_TASK

    cfg = MCPilcoConfig(env_id=TOY_ID, task=TOY_TASK)
    with pytest.raises(ValueError, match="tracks no reference state"):
        tracking_part({TOY_ID: cfg}, [0], None, tmp_path, tmp_path)


def test_task_detector_is_trained_on_the_tasks_motion_and_alarms_on_a_push(tmp_path):
    """:func:`train_task_detector` on two collision-free UR10 tracking episodes: the file
    loads as a 6-joint detector for 8 ms samples; on a third, pushed episode of the task
    (80 N for 0.6 s) it alarms inside the push and nowhere before it."""
    from mcpilco.agents.common.trials import make_env, run_episode
    from mcpilco.agents.mc_pilco import load_config
    from mcpilco.agents.mc_pilco.filters import CollisionFilter, contact_steps
    from mcpilco.envs.arm_env import Push
    from mcpilco.experiments.mcpilco.tracking import train_task_detector
    from mcpilco.models.collision import CollisionDetector

    cfg = load_config("mcpilco/UR10-v0")
    path = train_task_detector(cfg, tmp_path / "det.pt", episodes=2, gp_points=200)
    det = CollisionDetector.load(path)
    assert det.n_joints == 6 and det.sample_time == pytest.approx(0.008)
    task = cfg.task_spec()
    push = Push(2.0, 0.6, 3, (0.0, 80.0, 0.0), 0.05)
    env = make_env(task.env_id, task.horizon, task, {"disturbances": [push]})
    ep = run_episode(env, lambda _x: np.zeros(6), 7, task.horizon, task, record_info=True)
    marked = CollisionFilter(det, 6, 0.008, margin=0).excluded(ep["infos"])
    contact = contact_steps(ep["infos"])
    first = int(np.argmax(contact))
    assert marked[contact].any() and not marked[: first - 1].any(), np.flatnonzero(marked)

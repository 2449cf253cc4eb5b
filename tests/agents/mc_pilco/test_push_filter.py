"""The push filter of MC-PILCO's dynamics data (``agents/mc_pilco/filters.py``): a collision
detector trained on a short collision-free UR10 log marks the transitions of an episode in
which the env pushed the arm (the env's own ``contact`` flag is the truth), and
``transitions`` leaves them out; bad detectors are refused with the field named."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from mcpilco.agents.common.trials import make_env, run_episode, transitions
from mcpilco.agents.mc_pilco import TaskSpec
from mcpilco.agents.mc_pilco.filters import CollisionFilter, contact_steps, dilate
from mcpilco.envs.arm_builder import dh_forward_kinematics
from mcpilco.envs.arm_data import rollout
from mcpilco.envs.arm_env import UR10_HOME, Push, UR10Env
from mcpilco.experiments.collision.nominal import nominal_model
from mcpilco.models.collision import train_detector
from mcpilco.models.robot_data import save_dataset

SCHEMA = ("t", "q", "qd", "qdd", "tau", "i", "i_cmd", "e_q", "e_qd", "contact")


def test_dilate_spreads_each_mark_by_the_margin():
    m = np.array([0, 0, 0, 1, 0, 0, 0, 0, 1], dtype=bool)
    np.testing.assert_array_equal(dilate(m, 0), m)
    np.testing.assert_array_equal(dilate(m, 1), [0, 0, 1, 1, 1, 0, 0, 1, 1])
    np.testing.assert_array_equal(dilate(m, 2), [0, 1, 1, 1, 1, 1, 1, 1, 1])


def test_bad_detectors_are_refused(tmp_path):
    with pytest.raises(FileNotFoundError, match="push_filter: no collision-detector file"):
        CollisionFilter(tmp_path / "none.pt", 6, 0.008)
    fake = SimpleNamespace(n_joints=6, sample_time=0.008)
    with pytest.raises(ValueError, match="the detector is for 6 joints, the task has 2"):
        CollisionFilter(fake, 2, 0.008)
    with pytest.raises(ValueError, match="made for samples of 0.008 s, the env samples every"):
        CollisionFilter(fake, 6, 0.002)
    with pytest.raises(ValueError, match="margin"):
        CollisionFilter(fake, 6, 0.008, margin=-1)
    with pytest.raises(ValueError, match="lacks"):
        CollisionFilter(fake, 6, 0.008).alarms([{"q": 0.0}])


@pytest.fixture(scope="module")
def detector(tmp_path_factory):
    """A PP detector (rigid-body regressor + friction; 2-sample persistence) from 12 s of
    collision-free UR10 motion of the tracking task: its reference, three resets, random
    torque corrections (the motion the filter will watch)."""
    tmp = tmp_path_factory.mktemp("det")
    task = TaskSpec.for_env("mcpilco/UR10-v0")
    ref = task.reset_options()["reference"]
    env = UR10Env()
    rng = np.random.default_rng(0)
    logs = [
        rollout(env, ref, seed=s, duration=4.0, policy=lambda _o: rng.uniform(-0.5, 0.5, 6))
        for s in range(3)
    ]
    free = {k: np.concatenate([g[k] for g in logs]) for k in SCHEMA}
    free["t"] = np.arange(len(free["t"])) * env.dt
    save_dataset(free, tmp / "free.csv")
    return train_detector(
        tmp / "free.csv", nominal_model("ur10"), estimator="PP", gp_points=300,
        hyper_points=150, adam_iters=20, lbfgs_iters=5, persistence=2,
    )  # fmt: skip


def test_filter_marks_the_pushed_transitions_of_a_tracking_episode(detector):
    """The UR10 tracking task with one 80 N push on link 4 from 1.5 s to 2.3 s: every
    transition the env reports a contact in is marked, and at most the margin's transitions
    around the push besides; ``transitions`` leaves exactly the marked ones out."""
    task = TaskSpec.for_env("mcpilco/UR10-v0")
    p = dh_forward_kinematics(UR10Env().arm, np.array(UR10_HOME))[:3, 3]
    radial = p[:2] / np.linalg.norm(p[:2])
    push = Push(1.5, 0.8, 4, tuple((80.0 * np.array([-radial[1], radial[0], 0.0])).tolist()), 0.05)
    env = make_env(task.env_id, task.horizon, task, {"disturbances": [push]})
    ep = run_episode(env, lambda _x: np.zeros(6), 3, task.horizon, task, record_info=True)
    env.close()
    filt = CollisionFilter(detector, 6, task.dt / task.action_repeat, margin=1)
    marked = filt.excluded(ep["infos"])
    contact = contact_steps(ep["infos"])
    assert contact.sum() in (20, 21)  # 0.8 s of 40 ms control steps, by the grid
    assert marked[contact].all()
    assert (marked & ~dilate(contact, 1)).sum() == 0, np.flatnonzero(marked & ~contact)
    s, a, s1 = transitions([{"obs": ep["obs"], "actions": ep["actions"], "filtered": marked}])
    assert len(a) == task.horizon - marked.sum()
    np.testing.assert_array_equal(s, ep["obs"][:-1][~marked])


def test_runs_leave_the_filtered_transitions_out_and_count_them(detector, tmp_path):
    """run_mcpilco on the UR10 task (short: 1.2 s horizon, one policy trial) with a push in
    each episode and ``push_filter``: the records count the pushed and the filtered
    transitions, the GP of the policy trial saw the exploration's transitions less the
    filtered ones, and the plot arrays mark them."""
    from mcpilco.agents.common.checkpoint import load_checkpoint
    from mcpilco.agents.mc_pilco import MCPilcoConfig, PolicyOptConfig, run_mcpilco

    path = tmp_path / "det.pt"
    detector.save(path)
    push = Push(0.4, 0.4, 4, (0.0, 80.0, 0.0), 0.05)
    cfg = MCPilcoConfig(
        env_id="mcpilco/UR10-v0", horizon=30, num_trials=1, num_particles=10, num_basis=20,
        max_points=None, gp_adam_iters=10, gp_lbfgs_iters=0, torch_threads=1,
        env_kwargs={"disturbances": [push]}, push_filter=str(path), policy_init="data",
        opt=PolicyOptConfig(max_steps=3, min_steps=1),
    )  # fmt: skip
    summary = run_mcpilco(cfg, tmp_path / "run", progress=False, log=None, write_rrd=False)
    explore, policy = summary.records
    for rec in (explore, policy):
        assert rec["n_contact"] >= 10 and rec["n_filtered_contact"] == rec["n_contact"]
        assert rec["n_filtered"] <= rec["n_contact"] + 2
    assert policy["n_data"] == 30 - explore["n_filtered"]
    arrays = load_checkpoint(tmp_path / "run" / "checkpoint.pt")["arrays"]
    assert int(np.sum(arrays[1]["excluded"])) == policy["n_filtered"]
    assert int(np.sum(arrays[1]["contact"])) == policy["n_contact"]

"""A joint held still by dry friction: no effect is named on it and the verdict says
"not enough data", naming the joint and what to record.

Independent truth: logs of :func:`mcpilco.envs.robot_logs.simulate_log` with MuJoCo
``frictionloss`` on joint 3 of a 3-joint arm; the simulator's true joint velocities say
whether the joint moved (3 N m of friction against a motor of 2 N m: the true ``|qd_3|``
stays below 1e-3 rad/s on 99 % of the samples; at 1 N m and the generator's servo the joint
sticks and slips).
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest

from mcpilco.envs.arm_builder import arm_to_xml
from mcpilco.envs.arms import random_arm
from mcpilco.envs.robot_logs import HiddenEffect, simulate_log
from mcpilco.experiments.diagnosis.scoring import verdict_category
from mcpilco.models.diagnosis import (
    DiagnosisModel,
    NominalStart,
    as_trajectories,
    at_rest,
    auto_improve,
    held_still,
)
from mcpilco.models.diagnosis.analysis import HELD_STILL_SHARE
from mcpilco.models.robot_data import from_frame

DURATION = 4.0
WEAK_LIMIT = 2.0  # N m: a motor on joint 3 weaker than its 3 N m of friction


@pytest.fixture(scope="module")
def arm():
    return random_arm(3, seed=1, joint_types="RRR").rigid()


def logs(arm, friction: float, weak: bool = False):
    """Training log (seed 0), held-out log (seed 1) and the true velocities of both; with
    ``weak``, joint 3's motor gives at most :data:`WEAK_LIMIT`."""
    if weak:
        joints = list(arm.joints)
        joints[2] = dataclasses.replace(joints[2], torque_limit=WEAK_LIMIT)
        arm = dataclasses.replace(arm, joints=tuple(joints))
    effect = [HiddenEffect("frictionloss", 3, friction, 0.0)]
    sims = [simulate_log(arm, effect, duration=DURATION, seed=s) for s in (0, 1)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        trajs = [
            as_trajectories([from_frame(s.table, source=f"log{i}")]) for i, s in enumerate(sims)
        ]
    return trajs[0], trajs[1], [s.truth.qd for s in sims]


def diagnose_logs(arm, train, test):
    model = DiagnosisModel(NominalStart(arm_to_xml(arm, friction=False))).fit(train)
    return auto_improve(model, test, max_steps=3)


def test_held_still_reads_each_joints_share_of_rows_at_rest():
    rest = np.zeros((100, 3), dtype=bool)
    rest[:, 2] = True
    rest[: int(100 * HELD_STILL_SHARE) - 1, 1] = True  # just below the share
    assert held_still(rest.mean(axis=0)) == [3]


def test_a_joint_held_by_dry_friction_is_not_enough_data(arm):
    train, test, true_qd = logs(arm, 3.0, weak=True)
    for qd in true_qd:  # the truth: joint 3 never moved, joints 1-2 did
        assert np.mean(np.abs(qd[:, 2]) < 1e-3) > 0.99
        assert np.mean(np.abs(qd[:, :2]) < 1e-3) < 0.05
    # what the data can tell from encoder positions alone
    assert held_still(at_rest(train).mean(axis=0)) == [3]
    versions, diags = diagnose_logs(arm, train, test)
    assert [e.joint for e in versions[-1].effects if e.joint == 3] == []
    verdict = diags[-1].verdict()
    assert verdict_category(verdict) == "not enough data"
    assert "joint 3 did not move" in verdict and "record logs in which joint 3 moves" in verdict
    unmoved = [c for c in diags[0].candidates if c.unmoved is not None]
    assert unmoved and all(c.outputs == [3] for c in unmoved)


def test_a_joint_that_sticks_and_slips_still_gets_its_friction_named(arm):
    train, test, true_qd = logs(arm, 1.0)
    assert 0.2 < np.mean(np.abs(true_qd[0][:, 2]) >= 1e-3) < 0.8  # the truth: it moves
    assert 3 not in held_still(at_rest(train).mean(axis=0))
    versions, diags = diagnose_logs(arm, train, test)
    named = diags[0].best
    assert named is not None and named.effect.joint == 3
    assert named.effect.key in ("coulomb", "stribeck")
    assert verdict_category(diags[-1].verdict()) != "not enough data"

"""Dry friction at the noise floor: on the joints coupled to a joint with dry friction, the
rows around its stick phases, where estimated ``qd``/``qdd`` are biased by the friction's
own jump, are held set-valued (:func:`~mcpilco.models.diagnosis.analysis.friction_kinks`);
on the sticking joint itself, the smoothing width ``eps`` is the sharpest the data allow.

Independent truth: MuJoCo's ``frictionloss`` (a dry-friction constraint of known level) in
logs of :func:`mcpilco.envs.robot_logs.simulate_log`, and the simulator's true velocities.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pandas as pd
import pytest

from mcpilco.envs.arm_builder import arm_to_xml
from mcpilco.envs.arms import ARMS, random_arm
from mcpilco.envs.robot_logs import HiddenEffect, simulate_log
from mcpilco.models.diagnosis import DiagnosisModel, NominalStart, as_trajectories, at_rest
from mcpilco.models.diagnosis.add import add_effect
from mcpilco.models.diagnosis.analysis import friction_kinks
from mcpilco.models.diagnosis.effects import CoulombFriction
from mcpilco.models.diagnosis.search import floor_check
from mcpilco.models.robot_data import from_frame

FRICTION = 1.0  # N m of MuJoCo frictionloss on joint 3: the joint sticks and slips
PANDA_FRICTION = 2.5  # N m of MuJoCo frictionloss on the Panda's shoulder
ELBOW_FRICTION = 2.14  # N m of MuJoCo frictionloss on the Panda's elbow (joint 4)
SHOULDER_FRICTION = 2.84  # N m of MuJoCo frictionloss on joint 2 beside it
LOG_SEEDS = (2052998038, 1702056618, 1779071844)  # two training logs, one held out


@pytest.fixture(scope="module")
def sticky_log():
    """A 3-joint arm whose joint 3 sticks and slips: the log and its ground truth."""
    arm = random_arm(3, seed=1, joint_types="RRR").rigid()
    sim = simulate_log(arm, [HiddenEffect("frictionloss", 3, FRICTION, 0.0)], duration=4.0, seed=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return as_trajectories([from_frame(sim.table, source="log")]), sim.truth


def _frame(t, q):
    return pd.DataFrame({"t": t, "q1": q[:, 0], "tau1": np.zeros(len(t))})


def test_kinks_are_the_filter_half_window_around_each_stick_phase():
    n = 200
    q = np.zeros((n, 1))
    t = np.arange(n) * 0.004
    q[:, 0] = np.where(t < 0.4, 0.5 * t, 0.2)  # slides at +0.5 rad/s, then stops at row 100
    traj = as_trajectories([from_frame(_frame(t, q), source="stop")])
    m = traj.estimated[0].filter.window // 2
    rest = np.arange(n) >= 100
    kinks = friction_kinks(traj, rest, 1)
    assert np.array_equal(np.flatnonzero(kinks), np.arange(100 - m, 100 + m))
    rest[40] = True  # one row at rest: a velocity crossing zero in the noise, no stick phase
    assert np.array_equal(friction_kinks(traj, rest, 1), kinks)
    given = dataclasses.replace(traj, estimated=[None])  # derivatives from the file: exact
    assert not friction_kinks(given, rest, 1).any()


def test_kinks_cover_the_true_stick_slip_transitions(sticky_log):
    test, truth = sticky_log
    stuck = (np.abs(truth.qd[:, 2]) < 1e-3).astype(np.int8)
    switches = np.flatnonzero(np.diff(stuck)) + 1  # the joint stops or breaks loose
    m = test.estimated[0].filter.window // 2
    switches = switches[(switches >= m) & (switches < len(stuck) - m)]  # not in the edge rows
    assert switches.size >= 4  # the truth: joint 3 sticks and slips several times
    kinks = friction_kinks(test, at_rest(test)[:, 2], 3)
    assert kinks[switches].all()
    assert kinks.mean() < 0.6  # most rows are away from a transition


def test_the_joints_coupled_to_a_sticking_joint_sit_at_the_noise_floor():
    # the Panda table, 2.5 N m of frictionloss on its shoulder (joint 2): the true model
    # leaves the elbow (joint 4, coupled through M_24) at 1.11x the floor when the rows
    # around the shoulder's stick phases are scored, at 0.97x without them
    arm = ARMS["panda"]().without_friction()
    effects = [HiddenEffect("frictionloss", 2, PANDA_FRICTION, 0.0)]
    sims = [simulate_log(arm, effects, duration=5.0, seed=s, counts_per_rev=2**17) for s in (0, 1)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        train, test = (
            as_trajectories([from_frame(s.table, source=f"log{i}")]).interior()
            for i, s in enumerate(sims)
        )
    model = DiagnosisModel(
        NominalStart(arm_to_xml(arm, friction=False)), [CoulombFriction(joint=2, eps=1e-3)]
    ).fit(train)
    (f_c,) = [p["value"] for p in model.parameters() if p["name"] == "F_c"]
    assert abs(f_c - PANDA_FRICTION) < 0.02 * PANDA_FRICTION
    check = floor_check(model, test)
    coupled = np.delete(check.ratio, 1)
    assert coupled.max() <= 1.08, check.ratio
    _, rest = model.set_valued(test, model.predict(test, with_var=False)[0])
    kinks = friction_kinks(test, at_rest(test)[:, 1], 2)
    assert rest[kinks][:, [0, 2, 3, 4, 5, 6]].all()  # coupled joints: set-valued there
    assert not rest[~kinks][:, [0, 2, 3, 4, 5, 6]].any()  # and nowhere else


@pytest.fixture(scope="module")
def sticky_elbow():
    """The Panda table with :data:`ELBOW_FRICTION` of frictionloss on joint 4 and
    :data:`SHOULDER_FRICTION` on joint 2, a 2^19-count encoder and 0.028 N m of torque noise
    (the draw of the Panda case set's dry-friction case at development seed 10): two
    training logs and a held-out log, and the held-out log's truth."""
    arm = ARMS["panda"]().without_friction()
    effects = [
        HiddenEffect("frictionloss", 4, ELBOW_FRICTION, 0.0),
        HiddenEffect("frictionloss", 2, SHOULDER_FRICTION, 0.0),
    ]
    sims = [
        simulate_log(arm, effects, duration=5.0, seed=s, counts_per_rev=2**19, tau_noise=0.028)
        for s in LOG_SEEDS
    ]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        train = as_trajectories(
            [from_frame(s.table, source=f"log{i}") for i, s in enumerate(sims[:2])]
        )
        test = as_trajectories([from_frame(sims[2].table, source="held-out")])
    return arm, train, test, sims[2].truth


def test_the_sticking_joint_itself_sits_at_the_noise_floor(sticky_elbow):
    # the true friction forms, each found by the loop's own refinement (eps scanned and
    # refined): eps at the lower end of its likelihood interval, the elbow's held-out RMSE at
    # the floor (1.16x with the evidence's maximum, eps = 0.0015, whose smoothed sign falls
    # short on the last and first sliding rows of each stick phase) and F_c within 1 %
    arm, train, test, _ = sticky_elbow
    model = DiagnosisModel(NominalStart(arm_to_xml(arm, friction=False))).fit(train.interior())
    for joint in (2, 4):
        model = add_effect(model, CoulombFriction(joint=joint))
    for effect in model.effects:
        (eps,) = [p for p in effect.profile if p.name == "eps"]
        assert effect.eps == pytest.approx(eps.interval[0], rel=1e-3), eps  # the lower end
    levels = {p["effect"].split(" ")[0]: p["value"] for p in model.parameters()}
    assert abs(levels["coulomb:4"] - ELBOW_FRICTION) < 0.01 * ELBOW_FRICTION, levels
    assert abs(levels["coulomb:2"] - SHOULDER_FRICTION) < 0.01 * SHOULDER_FRICTION, levels
    ratio = floor_check(model, test.interior()).ratio
    assert ratio[3] <= 1.05, ratio
    assert ratio.max() <= 1.1, ratio

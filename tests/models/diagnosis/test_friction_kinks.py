"""Dry friction at the noise floor: on the joints coupled to a joint with dry friction, the
rows around its stick phases, where estimated ``qd``/``qdd`` are biased by the friction's
own jump, are held set-valued (:func:`~mcpilco.models.diagnosis.analysis.friction_kinks`);
on the sticking joint itself, the smoothing width ``eps`` is the sharpest the data allow, and
its own rows around its stops are held to the floor as intervals of the filter's smear of the
switch (:func:`~mcpilco.models.diagnosis.analysis.friction_smear`).

Independent truth: MuJoCo's ``frictionloss`` (a dry-friction constraint of known level) in
logs of :func:`mcpilco.envs.robot_logs.simulate_log`, and the simulator's true velocities; a
body stopped by dry friction in closed form; Monte Carlo for the noise an interval absorbs.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pandas as pd
import pytest
from scipy.signal import savgol_coeffs

from mcpilco.envs.arm_builder import arm_to_xml
from mcpilco.envs.arms import ARMS, random_arm
from mcpilco.envs.robot_logs import HiddenEffect, simulate_log
from mcpilco.models.diagnosis import DiagnosisModel, NominalStart, as_trajectories, at_rest
from mcpilco.models.diagnosis.add import add_effect
from mcpilco.models.diagnosis.analysis import (
    acceleration_kernel,
    friction_kinks,
    friction_smear,
    projected_noise_share,
)
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


def _stop_log(mass=0.5, level=2.0, stop_row=150, n=300, dt=0.004):
    """A 1-joint body of inertia ``mass`` sliding against dry friction ``level`` with no drive
    torque: it decelerates at ``level / mass`` and stops midway between rows ``stop_row - 1``
    and ``stop_row`` (held torque 0 from then on, the centre of the set). The log (``q``
    only: ``qd``/``qdd`` estimated) and the exact rest rows."""
    t = np.arange(n) * dt
    t_stop = (stop_row - 0.5) * dt
    a = level / mass
    q = np.where(t < t_stop, a * t_stop * t - 0.5 * a * t**2, 0.5 * a * t_stop**2)[:, None]
    traj = as_trajectories([from_frame(_frame(t, q), source="stop")])
    return traj, t >= t_stop


def test_the_acceleration_kernel_is_how_the_filter_sees_the_acceleration():
    traj, _ = _stop_log()
    est = traj.estimated[0]
    kern = acceleration_kernel(est)
    assert kern.sum() == pytest.approx(1.0, abs=1e-9)  # exact on quadratics
    h = kern.size // 2
    a = np.diff(traj.q[:, 0], 2) / est.filter.sample_time**2  # a[i] at row i + 1
    rows = np.arange(h + 1, traj.n_samples - h - 1)
    seen = np.array([kern @ a[r - 1 - h : r + h] for r in rows])
    assert np.allclose(seen, traj.qdd[rows, 0], atol=1e-6)  # the filter's own qdd
    # where only qdd was estimated (qd given): the first difference of qd, the same way
    only = dataclasses.replace(est, groups=("qdd",))
    kern1 = acceleration_kernel(only)
    qd = np.gradient(traj.q[:, 0], est.filter.sample_time)
    b = np.diff(qd) / est.filter.sample_time  # b[i] between rows i and i + 1
    c = savgol_coeffs(est.filter.window, est.filter.order, deriv=1, delta=est.filter.sample_time)
    m = est.filter.window // 2
    direct = np.array([c[::-1] @ qd[r - m : r + m + 1] for r in rows])
    assert kern1.sum() == pytest.approx(1.0, abs=1e-9)
    assert np.allclose([kern1 @ b[r - 1 - h : r + h] for r in rows], direct, atol=1e-6)


def test_the_smear_is_the_error_the_filter_puts_on_the_sticking_joint():
    # known physics: inertia 0.5, dry friction 2 N m, no drive torque; the exact model
    # M qdd_hat + F s misses the measured torque (0) only where the filter smears the stop
    mass, level = 0.5, 2.0
    traj, rest = _stop_log(mass, level)
    s = np.where(rest, 0.0, 1.0)
    err = 0.0 - (mass * traj.qdd[:, 0] + level * s)
    m = traj.estimated[0].filter.window // 2
    inside = np.arange(m, traj.n_samples - m)  # not the filter's edge rows
    smear = friction_smear(traj, rest, 1)
    assert np.abs(err[inside]).max() > 0.3 * level  # the filter's error next to the stop
    assert np.allclose(np.abs(err[inside]), level * smear[inside], atol=0.02 * level)
    assert not smear[: 150 - m].any() and not smear[150 + m :].any()  # half a window away: 0
    given = dataclasses.replace(traj, estimated=[None])  # derivatives from the file: exact
    assert not friction_smear(given, rest, 1).any()


def test_without_dry_friction_the_intervals_gain_nothing():
    # an effect-free Panda log: a Coulomb block on the shoulder fits a level near 0, so its
    # intervals around the joint's reversals are near 0 wide and its held-out RMSE is that
    # of the nominal model
    arm = ARMS["panda"]().without_friction()
    sims = [simulate_log(arm, [], duration=5.0, seed=s, counts_per_rev=2**17) for s in (0, 1)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        train, test = (
            as_trajectories([from_frame(s.table, source=f"log{i}")]).interior()
            for i, s in enumerate(sims)
        )
    start = NominalStart(arm_to_xml(arm, friction=False))
    nominal = DiagnosisModel(start).fit(train)
    model = DiagnosisModel(start, [CoulombFriction(joint=2, eps=1e-3)]).fit(train)
    raw = model.predict(test, with_var=False)[0]
    width = friction_smear(test, at_rest(test)[:, 1], 2)
    assert width.any()  # the shoulder reverses: rows around its reversals get an interval
    gain = floor_check(nominal, test).rmse[1] / floor_check(model, test).rmse[1]
    assert gain < 1.01, gain
    mean, _ = model.set_valued(test, raw)
    moved = ~at_rest(test)[:, 1]
    assert np.abs(mean - raw)[moved, 1].max() < 0.05 * PANDA_FRICTION


def test_the_sticking_shoulder_is_held_to_the_floor_without_the_filter_smear():
    # the Panda table with 2 N m of frictionloss on its base joint (the largest inertia) and
    # 3 N m on joint 6, the true friction forms and levels: the base joint's own rows around
    # its stops hold it at 1.43x the floor, no model of the estimated states predicting the
    # filter's smear of the switch there; judged with the smear's intervals (and their share
    # of the noise taken off the floor) it is at the floor, and so is every other joint
    arm = ARMS["panda"]().without_friction()
    effects = [HiddenEffect("frictionloss", 1, 2.0, 0.0), HiddenEffect("frictionloss", 6, 3.0, 0.0)]
    sims = [
        simulate_log(arm, effects, duration=5.0, seed=s, counts_per_rev=2**19, tau_noise=0.03)
        for s in (0, 1, 2)
    ]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        train = as_trajectories(
            [from_frame(s.table, source=f"log{i}") for i, s in enumerate(sims[:2])]
        ).interior()
        test = as_trajectories([from_frame(sims[2].table, source="held-out")]).interior()
    model = DiagnosisModel(
        NominalStart(arm_to_xml(arm, friction=False)),
        [CoulombFriction(joint=1, eps=1e-5), CoulombFriction(joint=6, eps=1e-5)],
    ).fit(train)
    levels = [p["value"] for p in model.parameters()]
    assert np.allclose(levels, [2.0, 3.0], rtol=0.01), levels
    check = floor_check(model, test)
    strict = check.rmse / check.floor
    assert strict[0] > 1.3, strict  # the smear alone
    assert check.ratio.max() <= 1.05, check.ratio
    widths = model.smear_widths(test)
    assert widths[:, [1, 2, 3, 4, 6]].max() == 0.0  # only the sticking joints' own rows
    assert 0.0 < widths[:, 0].max() <= 2.0 * 1.01  # at most the level
    assert (widths[:, 0] > 0).mean() < 0.2  # around the stops only


def test_projected_noise_share_is_what_an_interval_leaves_of_the_noise():
    z = np.random.default_rng(0).standard_normal(400_000)
    for a in (0.0, 0.5, 1.0, 2.5):
        left = np.mean(np.maximum(np.abs(z) - a, 0.0) ** 2)
        assert projected_noise_share(a) == pytest.approx(left, rel=0.01, abs=1e-4)

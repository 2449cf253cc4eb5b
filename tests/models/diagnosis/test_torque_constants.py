"""Motor-current logs against a model in torque units: torque constants before effects.

Independent truth: logs of :func:`mcpilco.envs.robot_logs.simulate_log` written as currents
``i = tau / k_t`` plus noise with known ``k_t`` (one constant negative: a motor mounted
reversed), positions and currents only; the hidden effect, if any, is known.
"""

from __future__ import annotations

import dataclasses
import json
import re
import warnings

import numpy as np
import pytest

from mcpilco.envs.arm_builder import arm_to_xml
from mcpilco.envs.arms import random_arm
from mcpilco.envs.robot_logs import HiddenEffect, simulate_log, write_log
from mcpilco.models.diagnosis import (
    DiagnosisModel,
    NominalStart,
    TorqueScale,
    currents_to_torque,
    diagnose,
    estimate_torque_constants,
    floor_check,
    given_torque_constants,
    heldout_floor,
    load_trajectories,
    run_diagnosis,
)
from mcpilco.models.diagnosis.search import FLOOR_FACTOR

DURATION = 4.0
K_T = np.array([0.1, -2.0, 1.5])  # joint-side torque constants of the logs [N m/A]
UNIT_EFFECTS = ("spring", "offset", "cogging")  # what a unit mismatch used to be named


@pytest.fixture(scope="module")
def arm():
    return random_arm(3, seed=1, joint_types="RRR").rigid()


@pytest.fixture(scope="module")
def start(arm):
    return NominalStart(arm_to_xml(arm, friction=False))


def current_logs(arm, folder, effects=()):
    """Training and held-out current logs (seeds 0 and 1) as position-only files."""
    paths = [
        write_log(
            folder / f"log{s}.csv",
            simulate_log(arm, effects, duration=DURATION, seed=s, torque_constants=K_T),
        )
        for s in (0, 1)
    ]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return [load_trajectories([p]) for p in paths]


@pytest.fixture(scope="module")
def no_effect(arm, tmp_path_factory):
    return current_logs(arm, tmp_path_factory.mktemp("no_effect"))


def _unit_effects(d):
    return [c.label for c in d.candidates if c.significant and c.effect.key in UNIT_EFFECTS]


def test_no_effect_constants_recovered_and_nothing_named(arm, start, no_effect):
    """Estimated k_t cover the truth on every joint; in torque units the nominal (true) model
    sits at the floor and no spring/offset/cogging is named. Read in amperes, the same log
    is far from the floor (the mismatch the constants remove)."""
    train, test = no_effect
    assert train.output == "i"
    amps = floor_check(DiagnosisModel(start).fit(train), test)
    assert (amps.ratio > 5).any(), amps.ratio

    train_t, test_t, constants = currents_to_torque(train, test, start)
    assert constants.source == "estimated" and train_t.output == "tau"
    assert (np.abs(constants.value - K_T) <= constants.ci95).all(), constants.text()
    assert (constants.ci95 < 0.25 * np.abs(K_T)).all()
    np.testing.assert_allclose(train_t.y, train.y * constants.value)
    d = diagnose(DiagnosisModel(start, constants.effects()).fit(train_t), test_t)
    assert d.best is None and _unit_effects(d) == [], d.table()
    assert "no significant missing effect" in d.verdict(), d.verdict()
    assert (d.base.ratio <= FLOOR_FACTOR).all(), d.base.ratio


def test_floor_counts_the_constants_uncertainty(start, no_effect):
    """A model that takes ``k_hat`` as exact gets ``sd(k)^2 mean(i^2)`` per joint added to its
    floor; one with a free scale on every joint (the loop's first version) fits it itself."""
    train, test, constants = currents_to_torque(*no_effect, start)
    unknown = dataclasses.replace(test, torque_constants=None)
    fixed = DiagnosisModel(start).fit(train)
    mean, _ = fixed.predict(test, with_var=False)
    with_k = heldout_floor(fixed, test, mean)
    without = heldout_floor(fixed, unknown, mean)
    current = test.y / constants.value
    extra = constants.std**2 * np.mean(current**2, axis=0)
    np.testing.assert_allclose(with_k**2 - without**2, extra, rtol=1e-9)
    assert (extra > 0).all()
    free = DiagnosisModel(start, [TorqueScale(j) for j in (1, 2, 3)]).fit(train)
    mean, _ = free.predict(test, with_var=False)
    np.testing.assert_array_equal(
        heldout_floor(free, test, mean), heldout_floor(free, unknown, mean)
    )


def test_damping_found_in_torque_units(arm, start, tmp_path):
    """A hidden damping 0.5 N m s/rad on joint 2 is named with F_v in torque units."""
    train, test = current_logs(arm, tmp_path, [HiddenEffect("damping", 2, 0.5)])
    train, test, constants = currents_to_torque(train, test, start)
    assert (np.abs(constants.value - K_T) <= constants.ci95).all(), constants.text()
    d = diagnose(DiagnosisModel(start, constants.effects()).fit(train), test, n_confirm=1)
    assert d.best is not None and d.best.label == "viscous:2", d.table()
    (f_v,) = d.best.estimates
    assert f_v.unit == "N·m·s/rad" and abs(f_v.value - 0.5) <= f_v.ci95, f_v.text()
    # the interval carries the relative uncertainty of k_t on joint 2 (F_v scales with it)
    assert f_v.ci95 >= f_v.value * constants.ci95[1] / abs(constants.value[1])
    assert _unit_effects(d) == [], d.table()


def test_given_constants_are_used_as_they_are(start, no_effect):
    train, test = no_effect
    wrong = [0.2, 3.0, -1.0]  # not the truth: used all the same, no estimate
    train_t, test_t, constants = currents_to_torque(train, test, start, wrong)
    assert constants.source == "given"
    np.testing.assert_array_equal(train_t.y, train.y * np.array(wrong))
    np.testing.assert_array_equal(test_t.y, test.y * np.array(wrong))
    np.testing.assert_array_equal(constants.ci95, 0.0)
    np.testing.assert_array_equal(constants.output_variance(test_t.y), 0.0)


@pytest.mark.parametrize(
    "k_t, match",
    [
        ([0.1, 0.0, 1.5], "joint 2 has k_t = 0.0"),
        ([0.1, float("inf"), 1.5], "joint 2 has k_t = inf"),
        ([0.1, None, 1.5], "joint 2 has no value"),
        ([0.1, 2.0], "needs 3 values"),
        ([0.1, 2.0, 1.5, 1.0], "needs 3 values"),
    ],
)
def test_bad_given_constants_are_refused(k_t, match):
    with pytest.raises(ValueError, match=match):
        given_torque_constants(k_t, "RRR")


def test_some_constants_given_the_others_estimated(start, no_effect):
    train, test = no_effect
    train_t, _, constants = currents_to_torque(train, test, start, [None, -2.5, float("nan")])
    np.testing.assert_array_equal(constants.given, [False, True, False])
    assert constants.value[1] == -2.5 and constants.ci95[1] == 0.0
    np.testing.assert_array_equal(train_t.y[:, 1], train.y[:, 1] * -2.5)
    estimated = [0, 2]
    assert (np.abs(constants.value - K_T)[estimated] <= constants.ci95[estimated]).all()
    assert "given, used as it is" in constants.text().splitlines()[2]


def test_constants_for_torque_files_are_refused(start, no_effect):
    train, test = no_effect
    train_t, test_t, _ = currents_to_torque(train, test, start, K_T)
    with pytest.raises(ValueError, match="apply to motor-current logs"):
        currents_to_torque(train_t, test_t, start, K_T)


def test_a_current_without_torque_is_not_identifiable(start, no_effect):
    """Joint 3's current replaced by noise (no torque in it): the estimate does not guess a
    constant; joint 3 stays in A with a free scale and the reason, the others are estimated
    as before. A given constant is used as it is."""
    y = no_effect[0].y.copy()
    y[:, 2] = np.random.default_rng(0).normal(0.0, 0.01, y.shape[0])
    train = dataclasses.replace(no_effect[0], y=y)
    found = estimate_torque_constants(train, start.robot.rnea, "RRR")
    assert found.in_current.tolist() == [False, False, True]
    assert found.value[2] == 1.0 and found.free_scale[2] and "wider than 25%" in found.reasons[2]
    assert (np.abs(found.value[:2] - K_T[:2]) <= found.ci95[:2]).all(), found.text()
    assert "joint 3: k_t not identifiable" in found.text() and "diagnosed in A" in found.text()
    assert found.to_dict()["joints"][2]["identifiable"] is False
    given = estimate_torque_constants(train, start.robot.rnea, "RRR", given=[None, None, 1.5])
    assert given.value[2] == 1.5 and given.source == "given and estimated"
    assert not given.in_current.any()


def test_unidentifiable_constant_keeps_its_sign_from_friction(start, no_effect):
    """Joint 3's current replaced by a dry friction of 0.8 N m through a reversed motor
    (``k_3 = -0.5``: ``i = -1.6 tanh(qd / 0.01)`` A) plus noise, no model torque: the
    magnitude of ``k_3`` is not identifiable, its sign is (friction opposes motion), so the
    joint is diagnosed in A with ``k_t`` taken as -1 and a friction found there keeps its
    physical sign. The same current with a forward motor gives +1."""
    train0 = no_effect[0]
    friction = np.tanh(train0.qd[:, 2] / 0.01) * 0.8
    noise = np.random.default_rng(0).normal(0.0, 0.01, train0.y.shape[0])
    for k_3, sign in ((-0.5, -1.0), (0.5, 1.0)):
        y = train0.y.copy()
        y[:, 2] = friction / k_3 + noise
        found = estimate_torque_constants(dataclasses.replace(train0, y=y), start.robot.rnea, "RRR")
        assert found.in_current.tolist() == [False, False, True], found.text()
        assert found.value[2] == sign and "friction opposes motion" in found.reasons[2]
    assert "sign reversed" not in found.text()


def test_unidentifiable_constant_still_names_the_effect(tmp_path):
    """A cogging torque on the last joint (0.3 N m, 8 periods per rad) that the nominal model
    says carries little torque: its k_t is not identifiable (the run used to stop there).
    Now the run completes, joint 3 is diagnosed in A with the reason in the summary and the
    report, cogging:3 is named with its amplitude in A (truth 0.3 / k_3 = 0.15 A), and the
    joints end at the floor."""
    arm = random_arm(3, seed=1, joint_types="RRR").rigid()
    k_t = np.array([0.5, -1.5, 2.0])
    effects = [HiddenEffect("cogging", 3, 0.3, 8.0)]
    paths = [
        write_log(
            tmp_path / f"log{s}.csv",
            simulate_log(arm, effects, duration=DURATION, seed=s, torque_constants=k_t),
        )
        for s in (0, 1)
    ]
    xml = tmp_path / "robot.xml"
    xml.write_text(arm_to_xml(arm, friction=False))
    lines: list[str] = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        summary = run_diagnosis(
            [paths[0]],
            [paths[1]],
            model=xml,
            auto=3,
            plots=False,
            rerun=False,
            out=tmp_path / "run",
            log=lines.append,
        )
    joints = summary["torque_constants"]["joints"]
    assert [j["identifiable"] for j in joints] == [True, True, False], joints
    assert "wider than 25%" in joints[2]["reason"]
    assert any("joint 3: k_t not identifiable" in t for t in lines)
    last = summary["versions"][-1]
    assert "cogging:3" in last and "scale:3" in last, summary["versions"]
    assert not any(k in last for k in ("spring", "offset", "payload")), last
    assert max(summary["rmse_over_floor"][-1]) <= FLOOR_FACTOR, summary["rmse_over_floor"]
    assert "no significant missing effect" in summary["verdict"]
    assert summary["robot_file"]["skipped"].startswith("joints [3] are diagnosed in A")
    html = (tmp_path / "run" / "report.html").read_text()
    assert "joint 3 in A" in html and "torque constant not identifiable" in html
    (line,) = [t for t in lines if "cogging:3" in t and "(joint 3): A = " in t]
    value, ci95 = map(float, re.search(r"A = (\S+) ± (\S+) A$", line).groups())
    assert abs(abs(value) - 0.3 / k_t[2]) <= ci95, line


def test_diagnose_command_estimates_or_takes_the_constants(arm, no_effect, tmp_path, command):
    """Without ``--torque-constants`` the command estimates them (reported in the summary,
    covering the truth) and ends at the floor; bad given constants exit 2."""
    xml = tmp_path / "robot.xml"
    xml.write_text(arm_to_xml(arm, friction=False))
    files = [name for t in no_effect for name in t.names]
    argv = ["--model", str(xml), "--train", files[0], "--test", files[1]]
    argv += ["--no-plots", "--no-rerun", "--out", str(tmp_path / "run")]
    assert command("mcpilco-diagnose", argv) == 0
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    found = summary["torque_constants"]
    assert found["source"] == "estimated" and found["rows"] > 0
    for joint, k_t in zip(found["joints"], K_T, strict=True):
        assert abs(joint["k_t"] - k_t) <= joint["ci95"] and joint["unit"] == "N·m/A", joint
    assert "no significant missing effect" in summary["verdict"]
    assert command("mcpilco-diagnose", [*argv, "--torque-constants", "0.1", "0", "1.5"]) == 2
    assert command("mcpilco-diagnose", [*argv, "--torque-constants", "0.1", "-2"]) == 2


@pytest.mark.slow  # about 30 s of CPU: two 4 s logs of the 7-joint Panda and the fits
def test_a_payload_does_not_bias_the_constants(tmp_path):
    """A 1.4 kg payload at the Panda's flange that the model lacks loads every joint, the
    wrist most against its own torque: fitted one joint at a time, each constant takes part
    of it (a wrist's by a factor of 2), beyond its interval; fitted jointly with a payload at
    the flange (one weight vector for every joint, :func:`currents_to_torque`) the largest
    error is less than half of the joint-by-joint fit's, and within 3% on every joint (about
    1% against 50% here: the bilinear fit by Gauss-Newton, the current the response). On the
    3-joint arm, whose last body carries most of every joint's torque, the payload would
    trade off with a common scale of the constants: the joint fit is not used there."""
    from mcpilco.envs.arms import panda

    arm = panda().without_friction()
    k_t = np.array([-3.0, -1.9, 1.8, -0.12, -0.68, -0.82, -0.12])
    payload = [HiddenEffect("payload", 7, 1.4, 0.05)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        log = simulate_log(arm, payload, duration=DURATION, seed=0, torque_constants=k_t)
        train = load_trajectories([write_log(tmp_path / "log.csv", log)])
    nominal = NominalStart(arm_to_xml(arm, friction=False))
    alone = estimate_torque_constants(train, nominal.robot.rnea, arm.joint_types)
    assert (np.abs(alone.value - k_t) > alone.ci95).any(), alone.text()
    assert np.max(np.abs(alone.value / k_t - 1.0)) > 0.3, alone.text()
    _, _, joint = currents_to_torque(train, train, nominal)
    worst = np.max(np.abs(joint.value / k_t - 1.0))
    assert worst < 0.5 * np.max(np.abs(alone.value / k_t - 1.0)), joint.text()
    assert worst < 0.03, joint.text()

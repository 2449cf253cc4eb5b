"""The noise floor with input noise, and a verdict that the held-out error supports.

Independent truth: logs of :func:`mcpilco.envs.robot_logs.simulate_log` (positions and
torques only) with their ground truth: the encoder's step and reading noise, the noise-free
applied torque and the hidden effect.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from mcpilco.envs.arm_builder import arm_to_xml
from mcpilco.envs.arms import random_arm
from mcpilco.envs.robot_logs import HiddenEffect, simulate_log, write_log
from mcpilco.models.diagnosis import (
    DiagnosisModel,
    NominalStart,
    ViscousFriction,
    auto_improve,
    diagnose,
    heldout_floor,
    input_noise,
    load_trajectories,
    noise_floor,
    position_noise,
    run_diagnosis,
)
from mcpilco.models.diagnosis.data import DERIVATIVE_WINDOW
from mcpilco.models.diagnosis.search import (
    FLOOR_FACTOR,
    MIN_VERDICT_ROWS,
    Candidate,
    Diagnosis,
    FloorCheck,
)

DURATION = 4.0
COARSE = 2**12  # encoder counts per revolution whose noise reaches the predicted torque
READING_NOISE = 0.3  # simulate_log's default encoder reading noise [counts]


@pytest.fixture(scope="module")
def arm():
    return random_arm(3, seed=1, joint_types="RRR").rigid()


def make_logs(arm, tmp_path, effects=(), **kw):
    """Training and held-out logs (seeds 0 and 1) as position-only files, and their truth;
    ``qd``/``qdd`` estimated with the shortest span, whose noise reaches the torque."""
    logs = [simulate_log(arm, effects, duration=DURATION, seed=s, **kw) for s in (0, 1)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # coarse encoders warn about qdd
        trajs = [
            load_trajectories(
                [write_log(tmp_path / f"log{s}.csv", log)], derivative_window=DERIVATIVE_WINDOW
            )
            for s, log in enumerate(logs)
        ]
    return trajs[0], trajs[1], logs[1].truth


def nominal(arm, train):
    return DiagnosisModel(NominalStart(arm_to_xml(arm, friction=False))).fit(train)


# ------------------------------------------------------------------------- noise floor
def test_input_noise_matches_the_encoder_and_the_true_prediction_error(arm, tmp_path):
    train, test, truth = make_logs(arm, tmp_path, counts_per_rev=COARSE)
    step = 2 * math.pi / COARSE
    (sigma_q,) = position_noise(test)
    np.testing.assert_allclose(sigma_q, step * math.sqrt(READING_NOISE**2 + 1 / 12), rtol=0.1)
    model = nominal(arm, train)
    mean, _ = model.predict(test, with_var=False)
    inputs = input_noise(test, lambda tr: model.predict(tr, with_var=False)[0])
    # the nominal model is the true one: its error against the noise-free torque is the
    # noise that the estimated qd/qdd carry
    true_in = np.sqrt(np.mean((mean - truth.tau) ** 2, axis=0))
    ratio = inputs.std / true_in
    assert ((ratio > 0.85) & (ratio < 1.15)).all(), ratio


def test_perfect_model_sits_at_the_floor(arm, tmp_path):
    """No hidden effect, coarse encoder: the true (nominal) model's held-out RMSE is ~1x the
    floor with input noise; the measurement-only floor puts it well above 1."""
    train, test, _ = make_logs(arm, tmp_path, counts_per_rev=COARSE)
    model = nominal(arm, train)
    mean, _ = model.predict(test, with_var=False)
    rmse = np.sqrt(np.mean((test.y - mean) ** 2, axis=0))
    before = rmse / noise_floor(test, mean)
    after = rmse / heldout_floor(model, test, mean)
    assert before.max() > 1.3, before  # the measurement-only floor misses the input noise
    assert ((after >= 0.8) & (after <= 1.25)).all(), after


def test_given_derivatives_add_no_input_noise(arm, tmp_path):
    train, test, _ = make_logs(arm, tmp_path)
    test.estimated = [None]
    model = nominal(arm, train)
    mean, _ = model.predict(test, with_var=False)
    np.testing.assert_array_equal(heldout_floor(model, test, mean), noise_floor(test, mean))


# ------------------------------------------------------------------------- verdicts
def test_damping_is_found_and_leaves_the_error_at_the_floor(arm, tmp_path):
    train, test, _ = make_logs(arm, tmp_path, [HiddenEffect("damping", 2, 0.5)])
    versions, diags = auto_improve(nominal(arm, train), test, max_steps=2)
    first, last = diags[0], diags[-1]
    assert first.best is not None and first.best.label == "viscous:2", first.table()
    assert "missing effect: viscous friction on joint 2" in first.verdict()
    assert first.base.failing == [2] and first.after.failing == []
    assert [e.label for e in versions[-1].effects] == ["viscous:2"]
    assert (last.base.ratio <= FLOOR_FACTOR).all(), last.base.ratio
    assert "no significant missing effect" in last.verdict(), last.verdict()


def test_position_dependent_friction_is_unexplained(arm, tmp_path):
    """The friction level varies with q2: no candidate has that form. The loop adds the
    nearest friction term, joint 2 stays above the floor and the final verdict says so."""
    train, test, _ = make_logs(arm, tmp_path, [HiddenEffect("position_friction", 2, 0.3, 2.0)])
    xml = tmp_path / "robot.xml"
    xml.write_text(arm_to_xml(arm, friction=False))
    lines: list[str] = []
    summary = run_diagnosis(
        train.names,
        test.names,
        model=xml,
        auto=2,
        out=tmp_path / "run",
        plots=False,
        rerun=False,
        log=lines.append,
    )
    final = summary["verdict"]
    assert "unexplained" in final and "joint 2" in final, final
    assert "no significant missing effect" not in final
    ratio = np.array(summary["rmse_over_floor"])
    assert ratio[-1, 1] > FLOOR_FACTOR and ratio[0, 1] > ratio[-1, 1]
    assert (ratio[-1, [0, 2]] <= FLOOR_FACTOR).all(), ratio
    assert f"verdict: {final}" in [line.strip() for line in lines]


def test_no_effect_is_no_significant_missing_effect_at_the_floor(arm, tmp_path):
    train, test, _ = make_logs(arm, tmp_path)
    d = diagnose(nominal(arm, train), test)
    assert d.best is None and d.after is None, d.table()
    assert "no significant missing effect" in d.verdict()
    assert (d.base.ratio <= FLOOR_FACTOR).all() and (d.base.ratio >= 0.8).all(), d.base.ratio


def _check(ratio, rows=1000):
    floor = np.ones(len(ratio))
    return FloorCheck("v0", np.array(ratio, dtype=float), floor, rows, {2: "white"})


def _viscous(significant=True):
    return Candidate(
        effect=ViscousFriction(joint=2),
        delta=40.0,
        best_delta=40.0,
        n_variants=1,
        estimates=[],
        outputs=[2],
        heldout_delta_pct=-30.0,
        significant=significant,
    )


def test_verdict_follows_the_floor_checks():
    d = Diagnosis("v0", [], 5.0, 1.0, 2.0, base=_check([1.0, 1.1]))
    assert "no significant missing effect" in d.verdict()
    d.base = _check([1.0, 1.6])
    text = d.verdict()
    assert text.startswith("v0: unexplained: joint 2 at 1.60x the noise floor") and "white" in text
    assert "no significant missing effect" not in text
    d = Diagnosis("v0", [_viscous()], 5.0, 1.0, 2.0, base=_check([1.0, 3.0]))
    d.after = _check([1.0, 1.5])
    text = d.verdict()
    assert "missing effect: viscous friction on joint 2" in text
    assert (
        "explains part of the residual" in text and "joint 2 remains unexplained at 1.50x" in text
    )
    assert "already at the noise floor" not in text
    d.after = _check([1.0, 1.05])
    assert "at the noise floor on every joint" in d.verdict()
    d.base = _check([1.0, 1.1])
    assert "the model was already at the noise floor on every joint (at most 1.10x)" in d.verdict()
    d.base = _check([1.0, 3.0], rows=MIN_VERDICT_ROWS - 1)
    text = d.verdict()
    assert "not enough data" in text and "viscous:2" in text and "missing effect" not in text

"""Each MuJoCo-physics effect of the log generator is named, with its parameter inside its
95 % interval and the held-out error at the noise floor.

Independent truth: the value written into the simulated robot (MuJoCo's joint ``armature``
and ``stiffness``/``springref``), forward-simulated under feedback with only t, q and tau in
the files. Sizes are set from an effect-free log of the same arm (the joint's acceleration or
range) so that each effect stands well above the torque noise.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from mcpilco.envs.arm_builder import arm_to_xml
from mcpilco.envs.arms import random_arm
from mcpilco.envs.robot_logs import HiddenEffect, simulate_log, write_log
from mcpilco.models.diagnosis import DiagnosisModel, NominalStart, diagnose, load_trajectories
from mcpilco.models.diagnosis.search import FLOOR_FACTOR

DURATION = 4.0


@pytest.fixture(scope="module")
def arm():
    return random_arm(3, seed=1, joint_types="RRR").rigid()


def _logs(arm, effects, tmp_path):
    logs = [simulate_log(arm, effects, duration=DURATION, seed=s) for s in (0, 1)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        trajs = [
            load_trajectories([write_log(tmp_path / f"log{s}.csv", log)])
            for s, log in enumerate(logs)
        ]
    return trajs[0], trajs[1], logs[0]


SIZE = 20 * 0.05  # effect torque: about 20 stds of simulate_log's torque noise [N m]


def _effect(kind, probe):
    if kind == "armature":
        qdd = probe.truth.qdd[:, 2]
        return HiddenEffect("armature", 3, SIZE / float(np.std(qdd))), "armature:3", "I_a"
    q = probe.truth.q[:, 1]
    ref = float(np.median(q))
    return HiddenEffect("stiffness", 2, SIZE / float(np.std(q)), ref), "spring:2", "k"


@pytest.mark.parametrize("kind", ["armature", "stiffness"])
def test_generator_effect_is_named_with_its_value_in_its_interval(arm, kind, tmp_path):
    probe = simulate_log(arm, [], duration=DURATION, seed=0)
    effect, label, name = _effect(kind, probe)
    train, test, _ = _logs(arm, [effect], tmp_path)
    model = DiagnosisModel(NominalStart(arm_to_xml(arm, friction=False))).fit(train)
    diag = diagnose(model, test)
    lead = diag.lead
    assert lead is not None and lead.label == label, diag.table()
    est = {p.name: p for p in lead.estimates}[name]
    assert abs(est.value - effect.value) <= est.ci95, (est.value, est.ci95, effect.value)
    assert (diag.after.ratio <= FLOOR_FACTOR).all(), diag.after.ratio

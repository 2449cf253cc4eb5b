"""Backward elimination: an earlier effect whose evidence a later one took is removed.

Independent truth: forward-simulated logs (:func:`mcpilco.envs.robot_logs.simulate_log`) of
a 3-joint arm whose hidden effects are known. A link's inertia acts on every joint up to the
link, a rotor inertia (armature) on its own joint only: with armatures on joints 1 and 2 the
model that also holds link 2's inertia is no better on held-out data, and the link inertia
goes; with a really heavier link 2 and an armature on joint 2, both stay.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from mcpilco.envs.arm_builder import arm_to_xml
from mcpilco.envs.arms import random_arm
from mcpilco.envs.robot_logs import HiddenEffect, simulate_log, write_log
from mcpilco.models.diagnosis import (
    Armature,
    DiagnosisModel,
    LinkInertia,
    NominalStart,
    backward_step,
    load_trajectories,
    run_diagnosis,
)
from mcpilco.models.diagnosis.search import FLOOR_FACTOR

DURATION = 4.0
SIZE = 20 * 0.05  # effect torque: about 20 stds of simulate_log's torque noise [N m]


@pytest.fixture(scope="module")
def arm():
    return random_arm(3, seed=1, joint_types="RRR").rigid()


@pytest.fixture(scope="module")
def probe(arm):
    return simulate_log(arm, [], duration=DURATION, seed=0)


def _logs(arm, effects, folder):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return [
            load_trajectories(
                [
                    write_log(
                        folder / f"log{s}.csv",
                        simulate_log(arm, effects, duration=DURATION, seed=s),
                    )
                ]
            )
            for s in (0, 1)
        ]


def _armature(probe, joint):
    """An armature whose torque is about :data:`SIZE` on the probe's motion."""
    return HiddenEffect("armature", joint, SIZE / float(np.std(probe.truth.qdd[:, joint - 1])))


def test_link_inertia_superseded_by_armatures_is_removed(arm, probe, tmp_path):
    """Armatures on joints 1 and 2 (no link changed): the model with link 2's inertia and
    both armatures loses link 2's inertia once armature:2 is in; the version without it is
    the next version and is as good on the held-out log."""
    train, test = _logs(arm, [_armature(probe, 1), _armature(probe, 2)], tmp_path)
    start = NominalStart(arm_to_xml(arm, friction=False))
    model = DiagnosisModel(start, [LinkInertia(2), Armature(1), Armature(2)]).fit(train)
    step = backward_step(model, test, Armature(2))
    assert step is not None
    minus, removal = step
    assert removal.label == "inertia:2" and removal.by == "armature:2", removal
    assert [e.label for e in minus.effects] == ["armature:1", "armature:2"]
    assert minus.version == model.version + 1
    assert removal.heldout_delta_pct >= -1.0 and "removed link 2 inertia" in removal.text()
    assert backward_step(minus, test, Armature(2)) is None  # the armatures both earn their place


def test_a_real_heavier_link_is_kept(arm, probe, tmp_path):
    """Link 2 really heavier (mass x1.6) and an armature on joint 2: the link's inertia still
    earns its place beside armature:2 (it acts on joint 1 too), nothing is removed."""
    effects = [HiddenEffect("mass", 2, 1.6), _armature(probe, 2)]
    train, test = _logs(arm, effects, tmp_path)
    start = NominalStart(arm_to_xml(arm, friction=False))
    model = DiagnosisModel(start, [LinkInertia(2), Armature(2)]).fit(train)
    assert backward_step(model, test, Armature(2)) is None


def _run(arm, effects, tmp_path):
    paths = [
        write_log(tmp_path / f"log{s}.csv", simulate_log(arm, effects, duration=DURATION, seed=s))
        for s in (0, 1)
    ]
    xml = tmp_path / "robot.xml"
    xml.write_text(arm_to_xml(arm, friction=False))
    kw = dict(model=xml, auto=4, plots=False, rerun=False, sysid=False, log=lambda s: None)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return run_diagnosis([paths[0]], [paths[1]], out=tmp_path / "run", **kw)


def test_rotor_inertias_replace_a_link_inertia_that_led(arm, probe, tmp_path):
    """Armatures on joints 1 and 2: link 2's inertia (acting on both joints) leads the first
    ranking and, added alone, leaves joint 1 above the floor. The run adds the armatures of
    its joints on top and removes the link inertia: the versions show the removal, the last
    holds the two armatures only, at the floor."""
    summary = _run(arm, [_armature(probe, 1), _armature(probe, 2)], tmp_path)
    first = summary["diagnoses"]["v0"]["candidates"][0]
    assert first["effect"] == "link 2 inertia", first
    assert summary["versions"][1].endswith("+ link 2 inertia"), summary["versions"]
    assert "removed link 2 inertia" in summary["versions"][-1], summary["versions"]
    assert summary["versions"][-1].split(" + ", 1)[1].startswith("armature:1, armature:2 (")
    assert "inertia:2" in [r["label"] for r in summary["removed"]]
    assert max(summary["rmse_over_floor"][-1]) <= FLOOR_FACTOR, summary["rmse_over_floor"]
    assert "no significant missing effect" in summary["verdict"]


def test_a_heavier_last_link_stays_a_rigid_body_effect(arm, tmp_path):
    """The last link really heavier (mass x1.6), no rotor inertia: the run ends with the last
    body's inertia (payload or link 3 inertia, one family), no armature, nothing removed."""
    summary = _run(arm, [HiddenEffect("mass", 3, 1.6)], tmp_path)
    last = summary["versions"][-1]
    assert "payload" in last or "link 3 inertia" in last, summary["versions"]
    assert "armature" not in last and summary["removed"] == [], summary["versions"]
    assert max(summary["rmse_over_floor"][-1]) <= FLOOR_FACTOR, summary["rmse_over_floor"]

"""The shape check of a named effect: an effect outside the library is not forced into the
nearest library form.

Independent truth: MuJoCo's dry friction (``frictionloss``: a constant level, the Coulomb
form exactly) against friction whose level varies with the joint's position,
``F (1 + 0.5 sin(w q_2)) tanh(qd_2 / v)`` (applied by :func:`~mcpilco.envs.robot_logs.
simulate_log`), both on joint 2 of a rigid 3-joint arm, with the Coulomb candidate fitted.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from mcpilco.envs.arm_builder import arm_to_xml
from mcpilco.envs.arms import random_arm
from mcpilco.envs.robot_logs import HiddenEffect, simulate_log
from mcpilco.models.diagnosis import DiagnosisModel, NominalStart, as_trajectories, floor_check
from mcpilco.models.diagnosis.effects import (
    Armature,
    CoulombFriction,
    LinkInertia,
    PositionLevel,
    StribeckFriction,
)
from mcpilco.models.diagnosis.search import (
    FLOOR_FACTOR,
    Candidate,
    Diagnosis,
    FloorCheck,
    shape_check,
)
from mcpilco.models.robot_data import from_frame


def _coulomb_model(effect: HiddenEffect):
    """The nominal model of the arm with Coulomb friction on joint 2 fitted to logs (seeds 0
    and 1: training, held out) of the arm with ``effect``."""
    arm = random_arm(3, seed=1, joint_types="RRR").rigid()
    logs = [simulate_log(arm, [effect], duration=4.0, seed=s) for s in (0, 1)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        train, test = (
            as_trajectories([from_frame(log.table, source=f"log{k}")]) for k, log in enumerate(logs)
        )
    v0 = DiagnosisModel(NominalStart(arm_to_xml(arm, friction=False))).fit(train)
    return v0.add(CoulombFriction(joint=2)), test


@pytest.mark.slow  # about 20 s of CPU: four 4 s logs of a 3-joint arm and two fits
def test_position_dependent_friction_is_not_taken_for_coulomb_friction():
    """With a constant level (MuJoCo frictionloss, 0.4 N m) the Coulomb form holds and the
    check finds nothing; with a level that varies by +-50% along the joint's travel (0.2 N m,
    w = 3 /rad) the fitted Coulomb term leaves the joint within the floor factor, yet the
    position-dependent level is significant beside it: the effect is not of the library's
    form."""
    coulomb, test = _coulomb_model(HiddenEffect("frictionloss", 2, 0.4))
    assert shape_check(coulomb, test) == []
    varying, test = _coulomb_model(HiddenEffect("position_friction", 2, 0.2, 3.0))
    assert floor_check(varying, test).ratio[1] < FLOOR_FACTOR + 0.1
    (misfit,) = shape_check(varying, test)
    assert misfit.label == "coulomb:2" and misfit.joint == 2
    assert misfit.explained > 0.1 and misfit.heldout_delta_pct < -1.0, misfit


def test_position_level_needs_the_effect_on_its_joint():
    with pytest.raises(ValueError, match="level"):
        PositionLevel(2)
    with pytest.raises(ValueError, match="level"):
        PositionLevel(2, of=CoulombFriction(joint=1))


def _candidate(effect, delta, rmse, n_weights):
    return Candidate(
        effect, delta, delta, 1, [], [j + 1 for j in effect.outputs(3)],
        heldout_rmse=np.array(rmse), heldout_delta_pct=-10.0, significant=True, group=1,
        n_weights=n_weights,
    )  # fmt: skip


def test_the_simpler_of_two_indistinct_candidates_is_kept():
    """Two missing candidates with correlated torques (a link's inertia and an armature),
    evidences 1 nat apart and the same held-out gain: the data cannot tell them apart, so
    the one with fewer parameters is the missing effect and the verdict says so; with a
    held-out gain clearly larger (20 points) the richer one stays. Two forms of one family
    (Stribeck and Coulomb friction) are not judged by this rule."""
    base = FloorCheck("v0", np.array([1.0, 2.0, 1.0]), np.array([1.0, 1.0, 1.0]), 500)
    rich = _candidate(LinkInertia(2), 31.0, [1.0, 1.0, 1.0], 4)
    simple = _candidate(Armature(2), 30.0, [1.0, 1.01, 1.0], 1)
    d = Diagnosis("v0", [rich, simple], 5.0, 1.0, 2.0, base=base, noise_std=np.ones(3))
    assert d.best is simple
    assert "the simpler one, with 1 parameters, is kept" in d.verdict()
    simple.heldout_rmse = np.array([1.0, 1.2, 1.0])
    assert d.best is rich
    same = _candidate(StribeckFriction(2, velocity=0.1, eps=0.01), 30.0, [1.0, 1.0, 1.0], 2)
    coulomb = _candidate(CoulombFriction(2, eps=0.01), 31.0, [1.0, 1.0, 1.0], 1)
    d = Diagnosis("v0", [same, coulomb], 5.0, 1.0, 2.0, base=base, noise_std=np.ones(3))
    assert d.best is same  # two forms of one family: the alternatives' rule, not this one

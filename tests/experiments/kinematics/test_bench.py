"""Settings of the kinematics benchmark (:mod:`mcpilco.experiments.kinematics.bench`)."""

import pytest

from mcpilco.experiments.kinematics.bench import QUICK, KinematicsBenchSettings


def test_settings_refuse_unknown_parts_and_rendered_measurement_outside_a_and_c():
    assert KinematicsBenchSettings(parts="ac", measurement="aruco").measurement == "aruco"
    with pytest.raises(ValueError, match="subset of 'abcd'"):
        KinematicsBenchSettings(parts="ax")
    with pytest.raises(ValueError, match="parts a and c only"):
        KinematicsBenchSettings(parts="cd", measurement="aruco")
    with pytest.raises(ValueError, match="'ideal' or 'aruco'"):
        KinematicsBenchSettings(measurement="camera")


def test_quick_settings_keep_the_other_options():
    quick = KinematicsBenchSettings(parts="b", seed=3).quick()
    assert quick.parts == "b" and quick.seed == 3
    assert {k: getattr(quick, k) for k in QUICK} == QUICK

"""The quasi-static friction experiment
(:mod:`mcpilco.experiments.collision.quasi_static_friction`): its program, a short run and
the files it writes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mcpilco.experiments.collision.quasi_static_friction import (
    MOVE_SECONDS,
    REST_POSES,
    reference,
    run,
    write_outputs,
)
from mcpilco.experiments.results import read_result


def test_reference_rests_at_each_pose_between_the_moves():
    ref, rests = reference(rest_seconds=2.0)
    assert len(rests) == len(REST_POSES)
    assert rests[0] == (0.0, 2.0)
    for (a, b), (c, _), move in zip(rests, rests[1:], MOVE_SECONDS, strict=False):
        assert b - a == pytest.approx(2.0) and c - b == pytest.approx(move)


def test_short_run_rests_still_and_writes_its_outputs(tmp_path):
    res = run(seed=0, rest_seconds=2.0)
    assert [ph["q1_ref"] for ph in res["phases"]] == list(REST_POSES)
    for ph in res["phases"]:
        assert ph["n"] > 0 and np.isfinite(ph["i1_mean"]) and ph["max_abs_qd1"] < 1e-3
    assert res["stiction_band_A"] == pytest.approx(res["static_friction1"] / res["current_gain1"])
    text = write_outputs(res, tmp_path)
    assert text == (tmp_path / "collision_quasi_static.md").read_text()
    assert text.count("\n| ") == 1 + len(REST_POSES)  # header + one row per rest phase
    saved = read_result(tmp_path / "collision_quasi_static.json").payload()
    assert "arrays" not in saved and len(saved["phases"]) == len(REST_POSES)
    assert (tmp_path / "collision_quasi_static.png").stat().st_size > 0
    assert math.isclose(saved["phases"][1]["q1_ref"], math.pi / 2)


def test_rest_shorter_than_the_settling_time_is_refused():
    with pytest.raises(ValueError, match="rest_seconds must be > settle"):
        run(rest_seconds=1.0)

"""The torque-constants benchmark: its summary on hand-made records (counts worked out by
hand), and one short case against the generator's truth."""

import numpy as np
import pytest

from mcpilco.experiments.diagnosis.torque_constants import run_case, summarise


def _case(seed, z, k_hat, ci95, refused=(), truth=(), missing=None, unit=(), ratio=1.0, **kw):
    return {
        "seed": seed,
        "k_true": [1.0, 1.0, 1.0],
        "k_hat": k_hat,
        "ci95": ci95,
        "refused": list(refused),
        "z": z,
        "truth": list(truth),
        "missing": missing,
        "unit_named": list(unit),
        "ratio": [ratio, 1.0, 1.0],
        "ratio_in_amps": [30.0, 1.0, 1.0],
        "seconds": 2.0,
        **kw,
    }


def test_summary_counts():
    recs = [
        _case(1, [0.5, -1.0, 3.0], [1.0, 2.0, 4.0], [0.1, 0.2, 0.4]),
        _case(
            2,
            [0.0, 1.0],
            [1.0, 2.0, 5.0],
            [0.1, 0.1, 0.0],
            refused=[3],
            missing="offset:1",
            unit=["offset:1"],
            ratio=1.3,
        ),
        _case(
            3,
            [2.5, 0.1, 0.2],
            [1.0, 1.0, 1.0],
            [0.3, 0.1, 0.1],
            truth=["viscous:2"],
            found=True,
            f_v_covered=True,
        ),
        _case(
            4, [0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.1, 0.1, 0.1], truth=["viscous:1"], found=False
        ),
    ]
    s = summarise(recs)
    assert s["estimated_joints"] == 11 and s["refused_joints"] == "1/12"
    assert s["ci95_coverage"] == 9 / 11  # 3.0 and 2.5 outside 1.96
    assert s["median_relative_ci95"] == pytest.approx(0.1)
    assert s["controls"] == 2 and s["controls_missing_effect_named"] == 1
    assert s["controls_unit_like_effect_significant"] == 1 and s["controls_at_floor"] == 1
    assert s["cases_off_floor_in_amps"] == 4
    assert (s["damping_cases"], s["damping_named"], s["damping_f_v_covered"]) == (2, 1, 1)


@pytest.mark.slow
def test_a_control_case_recovers_the_generator_constants():
    rec = run_case(seed=100, duration=3.0, control=True)
    k_hat, ci = np.array(rec["k_hat"]), np.array(rec["ci95"])
    assert rec["truth"] == [] and rec["refused"] == []
    assert (np.abs(k_hat - np.array(rec["k_true"])) <= ci).all()
    assert max(rec["ratio_in_amps"]) > max(rec["ratio"])

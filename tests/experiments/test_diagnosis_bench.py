"""The diagnosis benchmark's summary on hand-made records (counts worked out by hand)."""

import json

from mcpilco.experiments.diagnosis_bench import case_effects, run_speed, summarise


def _effect(seed, truth, before, after, top1, verdict_ok):
    return {
        "seed": seed,
        "truth": truth,
        "rmse_over_noise_before": before,
        "rmse_over_noise_after": after,
        "top1": top1,
        "top3": True,
        "verdict_correct": verdict_ok,
        "all_found": True,
        "seconds": 1.0,
    }


def _control(seed, false_alarm, refined):
    return {
        "seed": seed,
        "truth": [],
        "false_alarm": false_alarm,
        "refined": refined,
        "seconds": 3.0,
    }


def test_summary_counts():
    recs = [
        _effect(1, ["viscous:2"], 20.0, 1.1, True, True),
        _effect(2, ["payload"], 1.7, 1.2, False, True),
        _effect(3, ["offset:3"], 1.05, 1.0, False, False),  # absorbed: left out of top-1
        _effect(4, ["coulomb:1", "viscous:3"], 9.0, 1.6, True, True),
        _control(5, False, True),
        _control(6, True, False),
    ]
    s = summarise(recs)
    assert s["n_absorbed_by_start_model"] == 1 and s["absorbed"] == ["offset:3"]
    assert s["n_effect_cases"] == 2 and s["n_multi_effect_cases"] == 1
    assert s["top1"] == 0.5 and s["verdict_correct"] == 1.0
    assert s["within_1p5_noise_after_add"] == 0.75  # 1.1, 1.2, 1.0 <= 1.5; 1.6 not
    assert s["false_alarm_rate"] == 0.5
    assert s["controls_with_in_span_refinement"] == "1/2"
    assert s["seconds_per_case"] == 10.0 / 6


def test_case_effects_mark_controls_and_two_effect_cases():
    assert case_effects(6, 5, 0) == [0, 1, 1, 1, 1, 0]
    assert case_effects(6, 5, 3) == [0, 1, 2, 1, 1, 0]
    assert case_effects(3, 0, 0) == [1, 1, 1]


def test_speed_part_times_the_loop_and_writes_its_report(tmp_path):
    """A small speed case (one 2 s training log, 501 rows) with the nominal start: the
    report holds its times and verdict, and the damping the generator hid is found."""
    out = run_speed(tmp_path / "speed", starts=("nominal",), auto=1, train_files=1, duration=2.0)
    (rec,) = out["records"]
    assert out["case"]["training_rows"] == 501
    assert rec["cpu_s"] > 0 and rec["wall_s"] > 0
    assert "viscous:2" in rec["versions"][-1], rec["versions"]
    data = json.loads((tmp_path / "speed.json").read_text())
    assert data["records"][0]["verdict"] == rec["verdict"]
    assert "| nominal |" in (tmp_path / "speed.md").read_text()

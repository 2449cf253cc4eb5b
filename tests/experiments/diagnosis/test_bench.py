"""The diagnosis benchmark's scoring on hand-made cases (truth and answer written out, the
scores worked out by hand), its case plan, and one tiny simulated case end to end."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from mcpilco.experiments.diagnosis.bench import (
    CASE_SETS,
    LIBRARY_KINDS,
    SPEED_STAGES,
    case_plan,
    draw_effect,
    run_benchmark,
    run_case,
    run_speed,
    score_record,
)
from mcpilco.experiments.diagnosis.scoring import (
    confusion_counts,
    matches,
    score_case,
    summarise,
    verdict_category,
)
from mcpilco.experiments.results import read_result

AT_FLOOR = "v1: no significant missing effect (no candidate ...); the held-out RMSE is at the floor"
UNEXPLAINED = "v1: unexplained: joint 2 at 1.40x the noise floor (held-out RMSE 0.07, floor 0.05)"


def _effect(kind, joint, value, **extra):
    return {"kind": kind, "joint": joint, "value": value, "ref": 0.0, **extra}


def _param(key, joint, name, value, ci95):
    return {"key": key, "joint": joint, "name": name, "value": value, "ci95": ci95}


def test_verdict_categories():
    assert verdict_category(AT_FLOOR) == "at floor"
    assert verdict_category(UNEXPLAINED) == "unexplained"
    assert verdict_category("v0: not enough data: 120 held-out rows, ...") == "not enough data"
    assert verdict_category("v3: missing effect: viscous friction on joint 2 (...)") == (
        "effect named"
    )
    assert verdict_category("v2: coulomb:2 is better described as Stribeck ...") == ("effect named")


def test_which_candidates_name_an_effect():
    fl = _effect("frictionloss", 2, 0.4)
    assert matches(fl, 3, "coulomb", 2) and matches(fl, 3, "stribeck", 2)
    assert not matches(fl, 3, "coulomb", 1) and not matches(fl, 3, "viscous", 2)
    # a heavier link is the payload's inertial parameters only on the last link
    assert matches(_effect("mass", 3, 1.4), 3, "payload", None)
    assert not matches(_effect("mass", 2, 1.4), 3, "payload", None)
    assert matches(_effect("mass", 2, 1.4), 3, "link_inertia", 2)
    assert matches(_effect("payload", 3, 1.0), 3, "payload", None)
    assert not matches(_effect("position_friction", 2, 0.3), 3, "coulomb", 2)
    with pytest.raises(ValueError, match="'backlash'"):
        matches(_effect("backlash", 1, 0.1), 3, "deadzone", 1)


def test_dry_friction_named_stribeck_counts_with_its_level():
    s = score_case(
        [_effect("frictionloss", 2, 0.4)],
        3,
        ranking=[["stribeck", 2], ["coulomb", 2], ["viscous", 2]],
        named=["stribeck", 2],
        added=[["stribeck", 2]],
        verdict=AT_FLOOR,
        parameters=[
            _param("stribeck", 2, "F_c", 0.41, 0.02),
            _param("stribeck", 2, "F_s-F_c", 0.05, 0.01),
        ],
    )
    assert s["ranks"] == [1] and s["top1"] is True and s["top3"] is True
    assert s["named_correct"] is True and s["found"] == [True] and s["spurious"] == []
    (p,) = s["parameters"]
    assert p["parameter"] == "stribeck:2 F_c" and p["true"] == 0.4 and p["estimate"] == 0.41
    assert math.isclose(p["relative_error"], 0.025) and p["within_ci"] is True
    assert s["verdict_correct"] is True and s["missed_at_floor"] is False
    assert s["false_alarm"] is None


def test_heavier_inner_link_named_payload_is_wrong_and_missed_at_the_floor():
    s = score_case(
        [_effect("mass", 2, 1.4, nominal_link_mass=2.0)],
        3,
        ranking=[["payload", None], ["deadzone", 3], ["link_inertia", 2], ["offset", 2]],
        named=["payload", None],
        added=[["payload", None]],
        verdict=AT_FLOOR,
        parameters=[_param("payload", None, "m", 0.7, 0.1)],
    )
    assert s["ranks"] == [3] and s["top1"] is False and s["top3"] is True
    assert s["named_correct"] is False and s["found"] == [False]
    assert s["spurious"] == ["payload"] and s["parameters"] == []
    # the verdict's category is right (an effect of the library), but a true effect is missing
    assert s["verdict_correct"] is True and s["missed_at_floor"] is True


def test_heavier_last_link_is_a_payload_of_the_added_mass():
    """Link 3 of 2 kg, 1.5x heavier: a payload of 1 kg. The payload is estimated on every
    output joint; the best-determined estimate (largest |value| / ci95) is compared."""
    s = score_case(
        [_effect("mass", 3, 1.5, nominal_link_mass=2.0)],
        3,
        ranking=[["payload", None]],
        named=["payload", None],
        added=[["payload", None]],
        verdict=AT_FLOOR,
        parameters=[
            _param("payload", None, "m", 0.0, 0.05),  # a joint the mass does not move
            _param("payload", None, "m", 1.1, 0.2),
            _param("payload", None, "m", 0.6, 0.5),
        ],
    )
    (p,) = s["parameters"]
    assert p["true"] == 1.0 and p["estimate"] == 1.1 and p["within_ci"] is True
    assert math.isclose(p["relative_error"], 0.1)


def test_controls_false_alarm():
    quiet = score_case([], 2, [["viscous", 1]], None, [], AT_FLOOR)
    assert quiet["false_alarm"] is False and quiet["verdict_correct"] is True
    assert quiet["top1"] is None and quiet["named_correct"] is None and quiet["ranks"] == []
    loud = score_case([], 2, [["offset", 1]], ["offset", 1], [["offset", 1]], AT_FLOOR)
    assert loud["false_alarm"] is True and loud["spurious"] == ["offset:1"]


def test_off_library_effect_needs_an_unexplained_verdict():
    truth = [_effect("position_friction", 2, 0.3)]
    args = ([["coulomb", 2]], ["coulomb", 2], [["coulomb", 2]])
    s = score_case(truth, 3, *args, UNEXPLAINED)
    assert s["expected_verdict"] == "unexplained" and s["verdict_correct"] is True
    assert s["top1"] is None and s["ranks"] == [] and s["spurious"] == ["coulomb:2"]
    wrong = score_case(truth, 3, *args, AT_FLOOR)
    assert wrong["verdict_correct"] is False and wrong["missed_at_floor"] is None


def test_two_effects_rank_within_k_plus_one():
    truth = [_effect("damping", 1, 0.5), _effect("cogging", 2, 0.2)]
    ranking = [["viscous", 1], ["offset", 2], ["cogging", 2], ["spring", 2]]
    s = score_case(truth, 2, ranking, ["viscous", 1], [["viscous", 1]], UNEXPLAINED)
    assert s["ranks"] == [1, 3]
    assert s["top1"] is False  # cogging is 3rd, beyond 1 + 1
    assert s["top3"] is True  # within 3 + 1
    assert s["found"] == [True, False] and s["all_found"] is False
    assert s["expected_verdict"] == "at floor" and s["verdict_correct"] is False


def _record(seed, role, effects, named, added, verdict, before, after, ranking=None):
    rec = {
        "seed": seed,
        "role": role,
        "arm": "RR",
        "n_joints": 2,
        "effects": effects,
        "size_over_noise": [5.0, 0.0] if effects else [0.0, 0.0],
        "ranking": ranking if ranking is not None else ([named] if named else []),
        "named": named,
        "added": added,
        "verdict": verdict,
        "parameters": [],
        "ratio_before": before,
        "ratio_after": after,
        "seconds": 10.0,
    }
    rec["score"] = score_record(rec)
    return rec


def test_summary_counts():
    recs = [
        _record(1, "single", [_effect("damping", 1, 0.5)], ["viscous", 1], [["viscous", 1]],
                AT_FLOOR, [9.0, 1.0], [1.0, 1.1]),
        _record(2, "single", [_effect("damping", 2, 0.5)], ["coulomb", 2], [["coulomb", 2]],
                UNEXPLAINED, [4.0, 1.0], [1.0, 1.5], [["coulomb", 2], ["viscous", 2]]),
        _record(3, "control", [], None, [], AT_FLOOR, [1.0, 1.0], [1.0, 1.0]),
        _record(4, "control", [], ["offset", 1], [["offset", 1]], AT_FLOOR, [1.0, 1.1],
                [1.0, 1.0]),
        _record(5, "off_library", [_effect("position_friction", 2, 0.3)], ["coulomb", 2],
                [["coulomb", 2]], UNEXPLAINED, [2.0, 1.0], [1.4, 1.0]),
    ]  # fmt: skip
    s = summarise(recs)
    assert s["cases"] == {"control": 2, "off_library": 1, "single": 2}
    assert s["top1"] == 0.5 and s["top1_counts"] == "1/2" and s["top3_counts"] == "2/2"
    assert s["top1_by_kind"] == {"damping": "1/2"}
    assert s["false_alarm_rate"] == 0.5 and s["false_alarm_counts"] == "1/2"
    assert s["cases_with_spurious_effects"] == "3/5"  # coulomb:2 twice, offset:1
    assert s["ratio_before_median"] == 6.5 and s["ratio_after_max"] == 1.5
    assert s["at_floor_after_counts"] == "1/2"
    assert s["verdict_correct_counts"] == "4/5"  # all but seed 2
    assert s["verdict_correct_by_role"] == {"control": "2/2", "off_library": "1/1", "single": "1/2"}
    assert s["off_library_unexplained_counts"] == "1/1"
    assert s["missed_at_floor_counts"] == "0/2"
    assert s["seconds_per_case"] == 10.0
    rows, cols, counts = confusion_counts(recs)
    assert rows == ["damping", "position_friction", "none"]
    assert cols == ["coulomb", "offset", "viscous", "none"]
    np.testing.assert_array_equal(counts, [[1, 0, 1, 0], [1, 0, 0, 0], [0, 1, 0, 1]])


def test_case_plan_mixes_the_roles():
    plan = case_plan(per_kind=2, controls=3, multi=2, off_library=1)
    assert len(plan) == 2 * len(LIBRARY_KINDS) + 6
    assert plan[:3] == [
        ("control", []),
        ("single", ["damping"]),
        ("multi", ["damping", "stiffness"]),
    ]
    singles = [k[0] for role, k in plan if role == "single"]
    assert sorted(singles) == sorted(2 * list(LIBRARY_KINDS))
    assert [role for role, _ in plan].count("control") == 3
    assert all(len(set(k)) == 2 for role, k in plan if role == "multi")
    with pytest.raises(ValueError, match="per_kind=-1"):
        case_plan(per_kind=-1)


@pytest.mark.slow  # about 15 s of CPU: three MuJoCo logs and two diagnosis rounds
def test_tiny_simulated_case_finds_its_damping():
    """A 2-joint arm, 2 s logs, damping of 3-30 noise stds on one joint: the record holds
    the generator's truth, its realised size on that joint only, and the loop names it with
    its coefficient within 10%."""
    rec = run_case(seed=3, role="single", kinds=["damping"], duration=2.0, train_files=1,
                   max_joints=2)  # fmt: skip
    (effect,) = rec["effects"]
    j = effect["joint"]
    assert effect["kind"] == "damping" and effect["value"] > 0
    size = np.array(rec["size_over_noise"])
    assert 2.0 < size[j - 1] < 40.0 and np.all(np.delete(size, j - 1) < 1e-3), size
    score = score_record(rec)
    assert score["top1"] is True and score["found"] == [True], rec["ranking"]
    (p,) = score["parameters"]
    assert p["parameter"] == f"viscous:{j} F_v" and p["relative_error"] < 0.1, p


def test_a_value_range_replaces_the_snr_draw():
    """A kind given a range gets its value uniformly from it, whatever the noise; without
    one, a scaled kind's value follows the torque noise (``snr`` times it)."""
    from mcpilco.envs.arms import panda
    from mcpilco.envs.robot_logs import simulate_log

    arm = panda().without_friction()
    probe = simulate_log(arm, [], duration=1.0, seed=0)
    rng = np.random.default_rng(0)
    for noise in (1e-4, 10.0):
        e = draw_effect("frictionloss", arm, probe, rng, noise, (2.0, 3.0))
        assert e.kind == "frictionloss" and 2.0 <= e.value <= 3.0 and 1 <= e.joint <= 7
    tiny = draw_effect("frictionloss", arm, probe, rng, 1e-4)
    assert tiny.value < 0.01  # at most 30 noise stds of 1e-4 N m over rms(tanh) >= ~0.3
    payload = draw_effect("payload", arm, probe, rng, 0.05, (1.0, 1.5))
    assert payload.joint == 7 and 1.0 <= payload.value <= 1.5


@pytest.mark.slow  # about 10 s of CPU: three 1 s logs of a 7-joint arm and a diagnosis
def test_panda_case_set_draws_its_effects_on_the_panda():
    """The Panda set's dry-friction case: two frictionloss effects of 2-3 N m on two
    different joints of the 7-joint Panda, whose torque shows on those joints only."""
    role, kinds, logs = CASE_SETS["panda"].cases[3]
    assert logs == "torque"
    assert kinds == ("frictionloss", "frictionloss")
    rec = run_case(seed=3, role=role, kinds=list(kinds), duration=1.0, train_files=1,
                   arm="panda", sizes=CASE_SETS["panda"].sizes, max_steps=1)  # fmt: skip
    assert rec["arm_name"] == "panda" and rec["n_joints"] == 7
    joints = sorted(e["joint"] for e in rec["effects"])
    assert len(set(joints)) == 2
    assert all(2.0 <= e["value"] <= 3.0 for e in rec["effects"])
    size = np.array(rec["size_over_noise"])
    others = np.delete(size, [j - 1 for j in joints])
    assert size[[j - 1 for j in joints]].min() > 5.0 and np.all(others < 1e-3), size
    with pytest.raises(ValueError, match="'kuka'"):
        run_case(seed=0, role="control", kinds=[], arm="kuka")


def test_iiwa_case_set_is_the_panda_cases_on_the_iiwa():
    """The iiwa set runs the Panda set's fourteen cases (seven effects, torque then current
    logs) on the 7-joint KUKA LBR iiwa 14 table."""
    from mcpilco.envs.arms import ARMS

    iiwa, panda = CASE_SETS["iiwa"], CASE_SETS["panda"]
    assert iiwa.cases == panda.cases and len(iiwa.cases) == 14
    arm = ARMS[iiwa.arm]()
    assert arm.name == "iiwa14" and arm.joint_types == "R" * 7


def test_chosen_seeds_run_as_their_case_of_the_repeated_plan(tmp_path):
    """``seeds``: seed ``s`` runs the case it has when the plan repeats from the first seed
    (the Panda set's dry-friction cases: torque log at 3 + 14 k, current log at 10 + 14 k)."""

    class Capture:
        def run(self, jobs, results_dir, desc=""):
            self.jobs, self.dir = jobs, Path(results_dir)
            return SimpleNamespace(summary=lambda: "", results={})

    runner = Capture()
    out = run_benchmark(runner, case_set="panda", first_seed=0, seeds=[17, 24, 17, 59],
                        out=tmp_path / "r", runs_dir=tmp_path / "runs")  # fmt: skip
    assert out is None  # nothing finished
    assert [j.key for j in runner.jobs] == ["seed17", "seed24", "seed59"]
    kinds = [(j.kwargs["seed"], tuple(j.kwargs["kinds"]), j.kwargs["logs"]) for j in runner.jobs]
    friction = ("frictionloss", "frictionloss")
    assert kinds == [(17, friction, "torque"), (24, friction, "current"), (59, friction, "torque")]
    assert runner.dir == tmp_path / "runs" / "panda" / "nominal"  # the full run's records


def test_an_effect_below_the_noise_is_not_scored_as_missed():
    truth = [_effect("mass", 1, 1.4, nominal_link_mass=4.0)]
    s = score_case(truth, 2, [["viscous", 1]], None, [], AT_FLOOR, size_over_noise=[0.02, 0.0])
    assert s["below_noise"] is True and s["ranks"] == [] and s["top1"] is None
    assert s["missed_at_floor"] is None and s["verdict_correct"] is True
    seen = score_case(truth, 2, [["viscous", 1]], None, [], AT_FLOOR, size_over_noise=[3.0, 0.0])
    assert seen["below_noise"] is False and seen["top3"] is False
    assert seen["missed_at_floor"] is True


def test_speed_part_times_the_loop_and_writes_its_report(tmp_path):
    """A small speed case (one 2 s training log, 501 rows) with the nominal start: the
    report holds its times and verdict, and the damping the generator hid is found."""
    out = run_speed(
        tmp_path / "speed",
        starts=("nominal",),
        auto=1,
        train_files=1,
        duration=2.0,
        breakdown=False,
    )
    (rec,) = out["records"]
    assert out["case"]["training_rows"] == 501
    assert rec["cpu_s"] > 0 and rec["wall_s"] > 0
    assert "viscous:2" in rec["versions"][-1], rec["versions"]
    data = read_result(tmp_path / "speed.json").payload()
    assert data["records"][0]["verdict"] == rec["verdict"]
    assert "| nominal |" in (tmp_path / "speed.md").read_text()


@pytest.mark.slow
def test_speed_breakdown_says_where_the_time_goes(tmp_path):
    """The profiled rerun's stages: a nominal start has no model to fit or refit, and
    scoring the candidates takes a real part of the run."""
    out = run_speed(tmp_path / "speed", starts=("nominal",), auto=1, train_files=1, duration=2.0)
    (rec,) = out["records"]
    stages = {b["stage"]: b["seconds"] for b in rec["breakdown"]}
    assert list(stages) == list(SPEED_STAGES)
    assert stages["start-model fit"] == 0.0 and stages["start-model refits (backfitting)"] == 0.0
    assert stages["candidate scoring (joint effects)"] > 0.1 * sum(stages.values())
    assert "| candidate scoring (joint effects) |" in (tmp_path / "speed.md").read_text()

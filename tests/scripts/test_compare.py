"""``mcpilco-compare``: table, plot and headline from fake result files; argument errors.

The expected numbers are computed by hand from the fake curves below, not by the script.
"""

from __future__ import annotations

import json
import os
import shlex

import numpy as np
import pytest

from mcpilco.agents.baselines.common import make_curve, save_curve, task_env_ids
from mcpilco.agents.baselines.compare import aggregate_method
from mcpilco.agents.mc_pilco import load_config
from mcpilco.envs.tasks.spec import TaskSpec
from mcpilco.experiments.kinematics.reaching import RESULT_LAYOUTS as reaching_layouts
from mcpilco.experiments.mcpilco.bench import RESULT_LAYOUTS as bench_layouts
from mcpilco.experiments.results import read_result, write_result

ENV = "mcpilco/CartpoleSwingUp-v0"


def _trial_curve(seed: int, successes: list[bool]) -> dict:
    pts = [
        {
            "steps": 60 * (k + 1),
            "experience_s": 3.0 * (k + 1),
            "success_rate": float(ok),
            "episodes": 1,
        }
        for k, ok in enumerate(successes)
    ]
    return make_curve("mcpilco", ENV, seed, 0.05, pts, complete=True)


def _sb3_curve(seed: int, rates: list[float], every: int = 20_000) -> dict:
    pts = [
        {
            "steps": every * (i + 1),
            "experience_s": every * (i + 1) * 0.05,
            "success_rate": r,
            "episodes": 10,
        }
        for i, r in enumerate(rates)
    ]
    return make_curve(
        "sac", ENV, seed, 0.05, pts, cpu_s=50.0, steps_done=every * len(rates), complete=True
    )


@pytest.fixture()
def fake_files(tmp_path):
    # MC-PILCO, 2 seeds: first success at trial 2 (9 s) and trial 3 (12 s)
    # -> mean success 0, 0, 0.5, 1, 1 at 3, 6, 9, 12, 15 s -> T90 = 12 s.
    mc = [
        _trial_curve(0, [False, False, True, True, True]),
        _trial_curve(1, [False, False, False, True, True]),
    ]
    # SAC, 2 seeds, evaluations every 20k steps = 1000 s:
    # seed 0: 0.2, 0.9, 1.0; seed 1: 0.0, 0.7, 0.9 -> mean 0.1, 0.8, 0.95 -> T90 = 3000 s.
    sac = [_sb3_curve(0, [0.2, 0.9, 1.0]), _sb3_curve(1, [0.0, 0.7, 0.9])]
    a = tmp_path / "mcpilco.json"
    a.write_text(json.dumps(mc))
    b = tmp_path / "sac.json"
    b.write_text(json.dumps({"curves": sac}))
    return a, b


def test_two_fake_files_give_table_plot_and_ratios(fake_files, tmp_path, capsys, command):
    a, b = fake_files
    out = tmp_path / "results"
    argv = [
        "--collect-only",
        "--methods",
        "mcpilco",
        "sac",
        "--inputs",
        str(a),
        str(b),
        "--out",
        str(out),
        "--runs-dir",
        str(tmp_path / "none"),
        "--tag",
        "fake",
        "--note",
        "two fake files",
    ]
    assert command("mcpilco-compare", argv) == 0
    stem = out / "compare_CartpoleSwingUp-v0_fake"
    report = read_result(stem.with_suffix(".json")).payload()
    mc, sac = report["methods"]["mcpilco"], report["methods"]["sac"]
    assert mc["success_mean"] == pytest.approx([0, 0, 0.5, 1, 1])
    assert mc["t90_s"] == pytest.approx(12.0)
    assert sac["success_mean"] == pytest.approx([0.1, 0.8, 0.95])
    assert sac["t90_s"] == pytest.approx(3000.0)
    ratio = report["headline"]["ratios"]["sac"]["value"]
    assert ratio == pytest.approx(3000.0 / 12.0)  # 250x >= 100x: goal met
    assert report["headline"]["goal"]["sb3"]["status"] == "met"
    # per seed: MC-PILCO seeds reach 90% at 9 s and 12 s, SAC seeds at 2000 s and 3000 s
    assert [s["t90_s"] for s in mc["per_seed"]] == [9.0, 12.0]
    # bootstrap over two seeds: medians 9, 10.5, 12 with chances 1/4, 1/2, 1/4
    assert mc["median_seed_t90_s"] == 10.5 and mc["median_seed_t90_ci95"] == [9.0, 12.0]
    # Wilson, 2 of 2: (1 + z^2/4 - z^2/4) / (1 + z^2/2) = 1 / 2.9208
    assert mc["seeds_reaching_90_ci95"] == pytest.approx([1 / 2.9208, 1.0], abs=1e-4)
    assert [s["t90_s"] for s in sac["per_seed"]] == [2000.0, 3000.0]
    # s.e.m. of SAC at 1000 s: values 0.2, 0.0 -> std (ddof 1) 0.1414 / sqrt(2) = 0.1
    assert sac["success_sem"][0] == pytest.approx(0.1)
    assert sac["cpu_s_per_1k_steps"] == pytest.approx(50.0 / 60.0)
    md = stem.with_suffix(".md").read_text()
    assert "| MC-PILCO | 2 |" in md and "| SAC | 2 |" in md
    assert "250.0x" in md and "**met**" in md
    # the report records the command line that made it, and the results index reads it
    assert report["command"] == shlex.join(["mcpilco-compare", *argv[:-2]])
    assert report["note"] == "two fake files"
    saved = read_result(stem.with_suffix(".json"))
    assert saved.command_of() == report["command"] and f"`{report['command']}`" in md
    png = stem.with_suffix(".png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 5_000
    assert "wrote" in capsys.readouterr().out


def test_unreached_target_gives_a_lower_bound(tmp_path, command):
    mc = [_trial_curve(0, [False, True, True])]  # T90 = 6 s
    slow = [_sb3_curve(0, [0.0, 0.5])]  # never 90% within 2000 s
    a = tmp_path / "a.json"
    a.write_text(json.dumps(mc + slow))
    out = tmp_path / "r"
    assert (
        command(
            "mcpilco-compare",
            [
                "--collect-only",
                "--inputs",
                str(a),
                "--out",
                str(out),
                "--runs-dir",
                str(tmp_path / "none"),
            ],
        )
        == 0
    )
    report = read_result(out / "compare_CartpoleSwingUp-v0.json").payload()
    r = report["headline"]["ratios"]["sac"]
    assert r["value"] is None and r["lower_bound"] == pytest.approx(2000.0 / 6.0)
    assert report["headline"]["goal"]["sb3"]["status"] == "met"  # > 333x is >= 100x
    md = (out / "compare_CartpoleSwingUp-v0.md").read_text()
    assert "not reached (> 2,000 s)" in md and "> 333.3x" in md


@pytest.mark.parametrize(
    ("pilco", "ratio", "bound", "status"),
    [
        ([False, False], 1.0, True, "met"),  # not reached within 6 s: T90 > 6 s
        ([False, True], 1.0, False, "not met"),  # as fast as MC-PILCO
        ([False, False, True], 1.5, False, "met"),
    ],
)
def test_pilco_goal(pilco, ratio, bound, status, tmp_path, command):
    mc = _trial_curve(0, [False, True, True])  # T90 = 6 s
    pc = dict(_trial_curve(0, pilco), method="pilco")
    a = tmp_path / "a.json"
    a.write_text(json.dumps([mc, pc]))
    out = tmp_path / "r"
    assert (
        command(
            "mcpilco-compare",
            [
                "--collect-only",
                "--inputs",
                str(a),
                "--out",
                str(out),
                "--runs-dir",
                str(tmp_path / "none"),
            ],
        )
        == 0
    )
    goal = read_result(out / "compare_CartpoleSwingUp-v0.json").payload()["headline"]["goal"]
    assert goal["pilco"]["ratio"] == pytest.approx(ratio)
    assert goal["pilco"]["ratio_is_lower_bound"] is bound and goal["pilco"]["status"] == status


def test_mean_is_held_between_evaluations_and_cut_at_the_shortest_seed():
    c0 = _sb3_curve(0, [0.5, 1.0, 1.0], every=100)  # 5, 10, 15 s
    c1 = _sb3_curve(1, [1.0], every=200)  # 10 s only
    agg = aggregate_method([c0, c1])
    # grid up to 10 s: at 5 s seed 1 has no evaluation yet (0) -> 0.25; at 10 s -> 1.0
    assert agg["experience_s"] == [5.0, 10.0]
    assert agg["success_mean"] == pytest.approx([0.25, 1.0])
    assert agg["t90_s"] == 10.0


@pytest.fixture
def error_of(command, capsys):
    """``error_of(argv)``: the stderr of ``mcpilco-compare argv``, which must exit 2."""

    def error_of(argv) -> str:
        assert command("mcpilco-compare", argv) == 2
        return capsys.readouterr().err

    return error_of


def test_unknown_method_lists_valid_names(tmp_path, error_of):
    err = error_of(["--methods", "sac", "dqn", "--out", str(tmp_path)])
    assert "unknown method(s) 'dqn'" in err
    assert "mcpilco, pilco, sac, td3, ppo" in err


def test_unknown_env_lists_task_envs(tmp_path, error_of):
    err = error_of(["--env", "mcpilco/Nope-v0", "--out", str(tmp_path)])
    assert "mcpilco/Nope-v0" in err
    assert "mcpilco/CartpoleSwingUp-v0" in err and "mcpilco/DMCCartpoleSwingUp-v0" in err


def test_env_without_task_is_refused(tmp_path, error_of):
    err = error_of(["--env", "mcpilco/MarkerCamera-v0", "--out", str(tmp_path)])
    assert "env 'mcpilco/MarkerCamera-v0' has no task specification" in err
    valid = "valid env ids: InvertedDoublePendulum-v5, InvertedPendulum-v5, Pendulum-v1, "
    valid += "dm_control/cartpole-swingup-v0, "
    assert valid + "dm_control/pendulum-swingup-v0, mcpilco/CartpoleSwingUp-v0" in err


@pytest.mark.parametrize(
    ("flag", "value", "message"),
    [
        ("--steps", "dqn=10", "unknown SB3 method 'dqn'"),
        ("--steps", "ten", "not an integer"),
        ("--sb3-hp", "learning_rate=1", "ALGO.KEY=VALUE"),
    ],
)
def test_bad_budget_or_hyperparameter(flag, value, message, tmp_path, error_of):
    err = error_of([flag, value, "--out", str(tmp_path)])
    assert message in err


def test_collect_only_with_nothing_is_an_error(tmp_path, error_of):
    err = error_of(["--collect-only", "--out", str(tmp_path), "--runs-dir", str(tmp_path / "none")])
    assert "no learning curves" in err


def test_bad_input_file_is_an_error(tmp_path, error_of):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"format": "other", "points": []}))
    err = error_of(["--collect-only", "--inputs", str(bad), "--out", str(tmp_path)])
    assert "format is 'other'" in err


def test_runs_dir_curves_are_collected(tmp_path, command):
    runs = tmp_path / "runs"
    c = _trial_curve(4, [False, True])
    save_curve(runs / "CartpoleSwingUp-v0" / "mcpilco" / "seed4" / "curve.json", c)
    out = tmp_path / "r"
    assert (
        command(
            "mcpilco-compare",
            [
                "--collect-only",
                "--methods",
                "mcpilco",
                "--seeds",
                "1",
                "--first-seed",
                "4",
                "--runs-dir",
                str(runs),
                "--out",
                str(out),
            ],
        )
        == 0
    )
    report = read_result(out / "compare_CartpoleSwingUp-v0.json").payload()
    assert report["methods"]["mcpilco"]["seeds"] == [4]
    assert report["methods"]["mcpilco"]["t90_s"] == 6.0


def test_a_seed_given_twice_counts_once(tmp_path, capsys, command):
    # SAC seed 0 in the runs folder (2 evaluations: 0.0, 1.0) and, longer, in --inputs
    # (3 evaluations: 0.0, 1.0, 0.5); seed 1 only in --inputs (0.0, 0.0, 1.0).
    # Kept: the 3-evaluation seed 0 and seed 1 -> 2 seeds, mean 0.0, 0.5, 0.75 at 1000,
    # 2000, 3000 s -> 90 % never reached; final success 0.75.
    runs = tmp_path / "runs"
    save_curve(runs / "CartpoleSwingUp-v0" / "sac" / "seed0" / "curve.json", _sb3_curve(0, [0, 1]))
    extra = tmp_path / "sac.json"
    extra.write_text(json.dumps([_sb3_curve(0, [0.0, 1.0, 0.5]), _sb3_curve(1, [0, 0, 1.0])]))
    out = tmp_path / "r"
    argv = ["--collect-only", "--methods", "sac", "--seeds", "2", "--runs-dir", str(runs)]
    assert command("mcpilco-compare", [*argv, "--inputs", str(extra), "--out", str(out)]) == 0
    report = read_result(out / "compare_CartpoleSwingUp-v0.json").payload()
    sac = report["methods"]["sac"]
    assert sorted(sac["seeds"]) == [0, 1]
    assert sac["success_mean"] == pytest.approx([0.0, 0.5, 0.75])
    assert sac["t90_s"] is None
    assert len(report["duplicates_dropped"]) == 1
    assert "sac seed 0 (2,000 s)" in report["duplicates_dropped"][0]
    assert "counted once" in capsys.readouterr().err


def test_a_failing_run_is_reported_and_sets_the_exit_code(tmp_path, capsys, command):
    # MC-PILCO seed 0 is finished in the runs folder (2 points cover --trials 1): collected,
    # not rerun; PILCO seed 0 fails (too few GP points): reported with its traceback file
    runs = tmp_path / "runs"
    save_curve(runs / "CartpoleSwingUp-v0" / "mcpilco" / "seed0" / "curve.json",
               _trial_curve(0, [False, True]))  # fmt: skip
    argv = ["--methods", "mcpilco", "pilco", "--seeds", "1", "--trials", "1", "--no-progress"]
    argv += ["--pilco-max-points", "3", "--runs-dir", str(runs), "--out", str(tmp_path / "r")]
    assert command("mcpilco-compare", argv) == 1
    err = capsys.readouterr().err
    assert "FAILED pilco/seed0" in err and "max_points must be an integer >= 10" in err
    report = read_result(tmp_path / "r" / "compare_CartpoleSwingUp-v0.json").payload()
    (failed,) = report["failed"]
    assert failed["method"] == "pilco" and failed["seed"] == 0
    assert "max_points must be an integer >= 10" in failed["error"]
    trace = runs / "CartpoleSwingUp-v0" / "pilco" / "seed0.error.txt"
    assert failed["traceback"] == str(trace) and "Traceback" in trace.read_text()
    assert report["methods"]["mcpilco"]["seeds"] == [0]
    assert not (runs / "CartpoleSwingUp-v0" / "mcpilco" / "seed0.json").exists()  # not rerun


@pytest.mark.parametrize("horizon", [60, None])
def test_mcpilco_from_a_labelled_bench_section(horizon, tmp_path, capsys, command):
    """Three seeds of a bench JSON section: successes from trial 3, 2 and 4 (12, 9, 15 s)
    -> mean 0, 0, 1/3, 2/3, 1 at 3..15 s -> T90 = 15 s; the unlabelled section is ignored.
    A config without a horizon (None) ran the task's (60 steps on the cart-pole)."""
    section = {
        "config": {"horizon": horizon},
        "per_trial": [{"experience_s": 3.0 * (k + 1)} for k in range(5)],
        "per_seed": [
            {"seed": 0, "success": [False, False, False, True, True], "seconds": 10.0},
            {"seed": 1, "success": [False, False, True, True, True], "seconds": 10.0},
            {"seed": 2, "success": [False, False, False, False, True], "seconds": 10.0},
        ],
    }
    other = dict(section, per_seed=[{"seed": 0, "success": [True] * 5}])
    bench = tmp_path / "bench.json"
    runs = {"runs": {ENV: other, f"{ENV} (K2)": section}}
    write_result(bench, bench_layouts[0], runs)
    out = tmp_path / "results"
    common = ["--methods", "mcpilco", "--mcpilco-json", str(bench), "--out", str(out)]
    common += ["--runs-dir", str(tmp_path / "none"), "--collect-only"]
    assert command("mcpilco-compare", [*common, "--mcpilco-label", "K2"]) == 0
    report = read_result(out / "compare_CartpoleSwingUp-v0.json").payload()
    mc = report["methods"]["mcpilco"]
    assert mc["success_mean"] == pytest.approx([0, 0, 1 / 3, 2 / 3, 1])
    assert mc["t90_s"] == pytest.approx(15.0)
    assert command("mcpilco-compare", [*common, "--mcpilco-label", "K9"]) == 2
    assert "--label K9" in capsys.readouterr().err


def test_runs_go_through_the_sweep_runner_and_keep_their_result(tmp_path, command):
    # MC-PILCO with no policy trial (exploration only): a real run in a spawned worker
    runs = tmp_path / "runs"
    argv = ["--methods", "mcpilco", "--seeds", "1", "--trials", "0", "--jobs", "2"]
    argv += ["--mcpilco-preset", "small", "--runs-dir", str(runs), "--out", str(tmp_path / "r")]
    argv += ["--no-progress"]
    assert command("mcpilco-compare", argv) == 0
    record = json.loads((runs / "CartpoleSwingUp-v0" / "mcpilco" / "seed0.json").read_text())
    curve = json.loads(
        (runs / "CartpoleSwingUp-v0" / "mcpilco" / "seed0" / "curve.json").read_text()
    )
    assert record["result"] == curve and record["pid"] != os.getpid()
    report = read_result(tmp_path / "r" / "compare_CartpoleSwingUp-v0.json").payload()
    assert report["methods"]["mcpilco"]["seeds"] == [0] and report["failed"] == []


# MC-PILCO config overrides for a run of seconds (--mcpilco-set)
TINY_MCPILCO = [
    "num_particles=8",
    "num_candidates=1",
    "candidate_weight_scales=null",
    "max_points=40",
    "gp_adam_iters=3",
    "gp_lbfgs_iters=2",
    "num_basis=10",
    "opt.max_steps=2",
    "opt.min_steps=1",
    "opt.monitor_patience=1",
    "log_particles=4",
]


DYNAMICS_TASKS = [e for e in task_env_ids() if TaskSpec.for_env(e).model == "dynamics"]
REACH = "mcpilco/MarkerCameraReach-v0"


@pytest.mark.parametrize("env_id", DYNAMICS_TASKS)
def test_every_task_env_runs_through_compare(env_id, tmp_path, command):
    """One exploration and one policy trial of MC-PILCO on every env with a task spec: the
    curve has a point per trial whose experience is every env step taken times the task's
    control period, and the report carries the method's success figures. Trials last at
    most the horizon of the env's config file (4 s on the dm-control cart-pole, whose file
    lengthens the task's 3 s)."""
    runs, out = tmp_path / "runs", tmp_path / "r"
    argv = ["--env", env_id, "--methods", "mcpilco", "--seeds", "1", "--trials", "1"]
    argv += ["--no-progress", "--runs-dir", str(runs), "--out", str(out)]
    assert command("mcpilco-compare", [*argv, "--mcpilco-set", *TINY_MCPILCO]) == 0
    name = env_id.split("/")[-1]
    run = runs / name / "mcpilco" / "seed0"
    records = json.loads((run / "records.json").read_text())["records"]
    curve = json.loads((run / "curve.json").read_text())
    task = load_config(env_id).task_spec()
    steps = np.cumsum([r["steps"] for r in records])
    assert [r["kind"] for r in records] == ["exploration", "policy"]
    assert all(1 <= r["steps"] <= task.horizon for r in records)
    assert [p["steps"] for p in curve["points"]] == steps.tolist()
    assert [p["experience_s"] for p in curve["points"]] == pytest.approx(steps * task.dt)
    assert [p["success_rate"] for p in curve["points"]] == [float(r["success"]) for r in records]
    report = read_result(out / f"compare_{name}.json").payload()
    mc = report["methods"]["mcpilco"]
    assert mc["seeds"] == [0] and report["failed"] == []
    assert mc["final_success"] == float(records[-1]["success"])
    assert (mc["t100_s"] is None) == (not any(r["success"] for r in records))
    assert (out / f"compare_{name}.png").is_file()


def _reaching_study(path):
    """A two-seed reaching study in ``kinematics_reaching.json``'s format: 4 targets, H = 10,
    hold = 2, 100 identification frames; per trial the (position [m], angle [rad]) errors."""
    errors = {
        0: [([0.002, 0.02, 0.005, 0.009], [0.01, 0.01, 0.04, 0.049])] * 2,  # 3 of 4 reached
        1: [([0.002] * 4, [0.01] * 4), ([0.002] * 4, [0.01] * 4)],  # 4 of 4 reached
    }
    rows = [
        {
            "seed": seed,
            "mcpilco": {
                "horizon": 10,
                "hold": 2,
                "targets": [[0.0] * 6] * 4,
                "rounds": [
                    {"position_error_norm_true": p, "orientation_error_true": a} for p, a in e
                ],
            },
        }
        for seed, e in errors.items()
    ]
    study = {"settings": {"samples": 100, "rounds": 1}, "rows": rows}
    write_result(path, reaching_layouts[0], study)
    return path


def test_reaching_task_compares_the_reaching_study_with_sac(tmp_path, command, capsys):
    """The marker-camera task: MC-PILCO's curves come from the reaching study, one point per
    trial at ``(100 + (k + 1) 4 (10 + 2)) 0.1`` s = 14.8 s, 19.6 s with success 3/4, 3/4 (seed
    0) and 1, 1 (seed 1), so the mean 0.875 never reaches 0.9 and T90 is None; SAC's points
    sit at its evaluation steps times the env's 0.1 s. Without the study, the comparison
    refuses to run MC-PILCO's dynamics agent on a kinematics task."""
    study = _reaching_study(tmp_path / "reach.json")
    runs, out = tmp_path / "runs", tmp_path / "r"
    argv = ["--env", REACH, "--seeds", "1", "--no-progress", "--runs-dir", str(runs)]
    argv += ["--out", str(out)]
    assert command("mcpilco-compare", [*argv, "--methods", "mcpilco"]) == 2
    assert "learns the kinematics on this task" in capsys.readouterr().err
    sac = ["--methods", "mcpilco", "sac", "--steps", "sac=60", "--eval-every", "30"]
    sac += ["--eval-episodes", "2", "--sb3-hp", "sac.learning_starts=20", "sac.train_freq=1"]
    sac += ["sac.gradient_steps=1", "sac.batch_size=8", "--mcpilco-json", str(study)]
    assert command("mcpilco-compare", [*argv, *sac]) == 0
    report = read_result(out / "compare_MarkerCameraReach-v0.json").payload()
    mc, sb = report["methods"]["mcpilco"], report["methods"]["sac"]
    assert mc["experience_s"] == pytest.approx([14.8, 19.6])
    assert mc["success_mean"] == pytest.approx([0.875, 0.875])
    assert mc["t90_s"] is None and mc["seeds"] == [0, 1]
    # final errors: per seed the median over its targets (7 mm, 2 mm), then over seeds
    assert mc["final_info_median"]["position_error"] == pytest.approx(0.0045)
    assert {"position_error", "orientation_error"} <= set(sb["final_info_median"])
    assert "| position_error |" in (out / "compare_MarkerCameraReach-v0.md").read_text()
    curve = json.loads((runs / "MarkerCameraReach-v0" / "sac" / "seed0" / "curve.json").read_text())
    assert [p["steps"] for p in curve["points"]] == [30, 60]
    assert [p["experience_s"] for p in curve["points"]] == pytest.approx([3.0, 6.0])
    assert curve["hyperparams"]["gamma"] == 0.98  # the zoo's ReacherBulletEnv-v0 entry
    assert sb["seeds"] == [0]


def test_a_seed_ending_in_a_failure_holds_it_past_its_budget():
    """Episodes that end early give seeds different budgets: seed 0 fails its trials by
    0.5 s, seed 1 balances at 2.2 s. Seed 0's failure holds up to 2.2 s (a success would need
    another trial): mean 0, 0, 0.5 at 0.2, 0.5, 2.2 s; 100 % (all seeds) not reached."""

    def curve(seed, pts):
        p = [{"steps": 0, "experience_s": t, "success_rate": v, "episodes": 1} for t, v in pts]
        return make_curve("mcpilco", ENV, seed, 0.04, p, complete=True)

    agg = aggregate_method([curve(0, [(0.2, 0.0), (0.5, 0.0)]), curve(1, [(0.2, 0.0), (2.2, 1.0)])])
    assert agg["experience_s"] == [0.2, 0.5, 2.2] and agg["budget_s"] == 2.2
    assert agg["success_mean"] == pytest.approx([0.0, 0.0, 0.5])
    assert agg["t100_s"] is None and agg["t90_s"] is None
    both = [curve(0, [(0.2, 0.0), (1.8, 1.0), (2.4, 1.0)]), curve(1, [(0.2, 0.0), (2.2, 1.0)])]
    agg = aggregate_method(both)
    assert agg["experience_s"] == [0.2, 1.8, 2.2] and agg["t100_s"] == 2.2

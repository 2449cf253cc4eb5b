"""Smoke tests of ``mcpilco-bench-kinematics`` at tiny sizes: the parts run and write their
JSON, Markdown and PNG files (the statistical claims live in the benchmark, not here)."""

import json

import numpy as np
import pytest

from mcpilco.experiments.kinematics.bench import RESULT_LAYOUTS
from mcpilco.experiments.results import read_result, write_result

BENCH = "mcpilco-bench-kinematics"


def test_bench_monte_carlo_part_is_exact_on_noiseless_robots(command, tmp_path):
    rc = command(
        BENCH, ["--parts", "a", "--robots", "1", "--out-dir", str(tmp_path), "--no-progress"]
    )
    assert rc == 0
    res = read_result(tmp_path / "kinematics.json").payload()
    mc = res["monte_carlo"]
    assert mc["triplets"] == 75 and mc["misclassified_triplets"] == 0  # noiseless: exact
    assert mc["structures_recovered"] == 1
    assert (tmp_path / "kinematics_confusion.png").stat().st_size > 0
    assert "100.00% of 75 triplets" in (tmp_path / "kinematics.md").read_text()


def test_bench_merge_keeps_the_parts_not_run(command, tmp_path):
    out = ["--out-dir", str(tmp_path), "--no-progress"]
    assert command(BENCH, ["--parts", "a", "--robots", "1", *out]) == 0
    path = tmp_path / "kinematics.json"
    res = read_result(path).payload()
    row = {f"{n}_{c}_{s}": 0.01 for n in ("linear", "angle") for c in ("r1", "r2")
           for s in ("mean", "min", "max")}  # fmt: skip
    row.update(repeat=0, samples=25, triplets=126, misclassified=3)
    res["noise_vs_samples"] = dict(rows=[row], command="an earlier run of part b")
    write_result(path, RESULT_LAYOUTS[0], res)
    assert command(BENCH, ["--parts", "a", "--robots", "1", "--merge", *out]) == 0
    merged = read_result(path).payload()
    assert merged["noise_vs_samples"]["rows"] == [row]
    assert merged["monte_carlo"]["command"].endswith("--merge --out-dir " + str(tmp_path)
                                                     + " --no-progress")  # fmt: skip
    md = (tmp_path / "kinematics.md").read_text()
    assert "Command: `an earlier run of part b`" in md and "| 0 | 25 | 3 / 126 |" in md
    assert command(BENCH, ["--parts", "a", "--robots", "1", *out]) == 0  # without --merge: dropped
    assert "noise_vs_samples" not in read_result(path).payload()


@pytest.mark.slow
def test_bench_kinematics_tiny_run_writes_outputs(command, tmp_path):
    rc = command(
        BENCH,
        [
            "--parts", "abcd", "--robots", "1", "--samples", "72", "--sizes", "36", "72",
            "--repeats", "1", "--fk-train", "20", "--ctrl-train", "25", "--online-rounds", "1",
            "--ctrl-steps", "5", "--ctrl-refine", "previous", "--ctrl-hold", "2",
            "--out-dir", str(tmp_path), "--no-progress",
        ],
    )  # fmt: skip
    assert rc == 0
    res = read_result(tmp_path / "kinematics.json").payload()
    assert res["monte_carlo"]["misclassified_triplets"] == 0
    assert [r["samples"] for r in res["noise_vs_samples"]["rows"]] == [36, 72]
    assert len(res["fk_gp"]["polynomial_rmse_measured"]) == 7  # 6 pose + geodesic
    assert len(res["fk_gp"]["nine_elements_rmse_true"]) == 7
    assert len(res["fk_gp"]["trimmed_rmse_true"]) == 7
    assert len(res["fk_gp"]["noise_free_training_rmse_true"]) == 4
    rounds = res["controller"]["rounds"]
    assert len(rounds) == 2 and rounds[1]["chosen_start"] == [-1] * 5  # refined from round 0
    assert rounds[1]["n_data"] - rounds[0]["n_data"] >= 5 * 2  # + the frames held at rest
    for key in ("noise_vs_samples", "fk_gp", "controller"):  # the default marker protocol
        assert res[key]["marker_protocol"] == {"facing_cone": 40.0, "visibility_cone": 70.0}
    assert res["fk_gp"]["train_selection"] == "design"
    assert res["controller"]["train_selection"] == "random"
    assert "turned more than 70 deg" in (tmp_path / "kinematics.md").read_text()
    for name in ("kinematics_confusion.png", "kinematics_noise_vs_samples.png",
                 "kinematics_controller.png", "kinematics.md"):  # fmt: skip
        assert (tmp_path / name).stat().st_size > 0


def test_bench_kinematics_rendered_measurement_only_for_parts_a_and_c(command, tmp_path, capsys):
    argv = ["--parts", "cd", "--measurement", "aruco", "--out-dir", str(tmp_path)]
    assert command(BENCH, argv) == 2
    assert "parts a and c only" in capsys.readouterr().err


def test_fk_seed_study_writes_its_table_and_counts_the_goal_from_its_rows(
    command, tmp_path, capsys
):
    out = ["--out-dir", str(tmp_path), "--no-progress", "--runs-dir", str(tmp_path / "runs")]
    assert (
        command(BENCH, ["--fk-seeds", "0", "1", "--samples", "72", "--fk-train", "20", *out]) == 0
    )
    study = read_result(tmp_path / "kinematics_c_seeds.json").payload()
    assert [r["seed"] for r in study["rows"]] == [0, 1]
    row1 = json.loads((tmp_path / "runs" / "c_seeds" / "seed1.json").read_text())["result"]
    assert row1 == study["rows"][1]  # one result file per seed
    assert not (tmp_path / "kinematics.json").exists()  # the study writes only its own files
    limits = np.array([0.006] * 3 + [0.04] * 3)
    for key in ("polynomial", "nine_elements", "chain"):
        table = np.array([r[key][:6] for r in study["rows"]])
        assert study["goal"]["met_per_axis"][key] == (table <= limits).sum(0).tolist()
        np.testing.assert_allclose(study["summary"][key]["mean"][:6], table.mean(0))
    assert "| mean |" in (tmp_path / "kinematics_c_seeds.md").read_text()
    assert command(BENCH, ["--fk-seeds", "0", "--merge", *out]) == 2
    assert "--fk-seeds" in capsys.readouterr().err


def test_reaching_seeds_refuse_merge_and_rendered_measurement(command, tmp_path, capsys):
    out = ["--out-dir", str(tmp_path)]
    assert command(BENCH, ["--reaching-seeds", "0", "--merge", *out]) == 2
    assert "--reaching-seeds use the noise model alone" in capsys.readouterr().err
    argv = ["--reaching-seeds", "0", "--parts", "c", "--measurement", "aruco", *out]
    assert command(BENCH, argv) == 2
    assert "noise model alone" in capsys.readouterr().err

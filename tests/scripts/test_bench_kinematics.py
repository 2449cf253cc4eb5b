"""Smoke tests of scripts/bench_kinematics.py at tiny sizes: the parts run and write their
JSON, Markdown and PNG files (the statistical claims live in the benchmark, not here)."""

import json

import numpy as np
import pytest

from mcpilco.scripts.bench_kinematics import _feature_rank, main


def test_feature_rank_of_a_straight_segment_is_that_of_its_trig_polynomials():
    t = np.linspace(-1.0, 1.0, 50)
    # q1 = q2 = t: products of [1, cos t, sin t] span {1, cos t, sin t, cos 2t, sin 2t}
    assert _feature_rank(np.column_stack([t, t])) == 5
    # q2 = 2 t: frequencies 0, 1, 2, 1 +- 2 -> 1 + 2 * 3 = 7 functions
    assert _feature_rank(np.column_stack([t, 2 * t])) == 7
    q = np.random.default_rng(0).uniform(-1, 1, (50, 2))
    assert _feature_rank(q) == 9  # all 3^2 monomials


def test_bench_monte_carlo_part_is_exact_on_noiseless_robots(tmp_path):
    rc = main(["--parts", "a", "--robots", "1", "--out-dir", str(tmp_path), "--no-progress"])
    assert rc == 0
    res = json.loads((tmp_path / "kinematics.json").read_text())
    mc = res["monte_carlo"]
    assert mc["triplets"] == 75 and mc["misclassified_triplets"] == 0  # noiseless: exact
    assert mc["structures_recovered"] == 1
    assert (tmp_path / "kinematics_confusion.png").stat().st_size > 0
    assert "100.00% of 75 triplets" in (tmp_path / "kinematics.md").read_text()


def test_bench_merge_keeps_the_parts_not_run(tmp_path):
    out = ["--out-dir", str(tmp_path), "--no-progress"]
    assert main(["--parts", "a", "--robots", "1", *out]) == 0
    path = tmp_path / "kinematics.json"
    res = json.loads(path.read_text())
    row = {f"{n}_{c}_{s}": 0.01 for n in ("linear", "angle") for c in ("r1", "r2")
           for s in ("mean", "min", "max")}  # fmt: skip
    row.update(repeat=0, samples=25, triplets=126, misclassified=3)
    res["noise_vs_samples"] = dict(rows=[row], command="an earlier run of part b")
    path.write_text(json.dumps(res))
    assert main(["--parts", "a", "--robots", "1", "--merge", *out]) == 0
    merged = json.loads(path.read_text())
    assert merged["noise_vs_samples"]["rows"] == [row]
    assert merged["monte_carlo"]["command"].endswith("--merge --out-dir " + str(tmp_path)
                                                     + " --no-progress")  # fmt: skip
    md = (tmp_path / "kinematics.md").read_text()
    assert "Command: `an earlier run of part b`" in md and "| 0 | 25 | 3 / 126 |" in md
    assert main(["--parts", "a", "--robots", "1", *out]) == 0  # without --merge: dropped
    assert "noise_vs_samples" not in json.loads(path.read_text())


@pytest.mark.slow
def test_bench_kinematics_tiny_run_writes_outputs(tmp_path):
    rc = main(
        [
            "--parts", "abcd", "--robots", "1", "--samples", "72", "--sizes", "36", "72",
            "--repeats", "1", "--fk-train", "20", "--ctrl-train", "25", "--online-rounds", "1",
            "--ctrl-steps", "5", "--ctrl-refine", "previous", "--ctrl-hold", "2",
            "--out-dir", str(tmp_path), "--no-progress",
        ]
    )  # fmt: skip
    assert rc == 0
    res = json.loads((tmp_path / "kinematics.json").read_text())
    assert res["monte_carlo"]["misclassified_triplets"] == 0
    assert [r["samples"] for r in res["noise_vs_samples"]["rows"]] == [36, 72]
    assert len(res["fk_gp"]["polynomial_rmse_measured"]) == 7  # 6 pose + geodesic
    assert len(res["fk_gp"]["nine_elements_rmse_true"]) == 7
    assert len(res["fk_gp"]["trimmed_rmse_true"]) == 7
    assert len(res["fk_gp"]["noise_free_training_rmse_true"]) == 4
    rounds = res["controller"]["rounds"]
    assert len(rounds) == 2 and rounds[1]["chosen_start"] == [-1] * 5  # refined from round 0
    assert rounds[1]["n_data"] - rounds[0]["n_data"] >= 5 * 2  # + the frames held at rest
    for name in ("kinematics_confusion.png", "kinematics_noise_vs_samples.png",
                 "kinematics_controller.png", "kinematics.md"):  # fmt: skip
        assert (tmp_path / name).stat().st_size > 0


def test_bench_kinematics_rendered_measurement_only_for_parts_a_and_c(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["--parts", "cd", "--measurement", "aruco", "--out-dir", str(tmp_path)])
    assert "parts a and c only" in capsys.readouterr().err

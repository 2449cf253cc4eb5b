"""Smoke tests of scripts/bench_kinematics.py at tiny sizes: the parts run and write their
JSON, Markdown and PNG files (the statistical claims live in the benchmark, not here)."""

import json

import pytest

from mcpilco.scripts.bench_kinematics import main


def test_bench_monte_carlo_part_is_exact_on_noiseless_robots(tmp_path):
    rc = main(["--parts", "a", "--robots", "1", "--out-dir", str(tmp_path), "--no-progress"])
    assert rc == 0
    res = json.loads((tmp_path / "kinematics.json").read_text())
    mc = res["monte_carlo"]
    assert mc["triplets"] == 75 and mc["misclassified_triplets"] == 0  # noiseless: exact
    assert mc["structures_recovered"] == 1
    assert (tmp_path / "kinematics_confusion.png").stat().st_size > 0
    assert "100.00% of 75 triplets" in (tmp_path / "kinematics.md").read_text()


@pytest.mark.slow
def test_bench_kinematics_tiny_run_writes_outputs(tmp_path):
    rc = main(
        [
            "--parts", "abcd", "--robots", "1", "--samples", "72", "--sizes", "36", "72",
            "--repeats", "1", "--fk-train", "20", "--ctrl-train", "25", "--online-rounds", "0",
            "--ctrl-steps", "5", "--out-dir", str(tmp_path), "--no-progress",
        ]
    )  # fmt: skip
    assert rc == 0
    res = json.loads((tmp_path / "kinematics.json").read_text())
    assert res["monte_carlo"]["misclassified_triplets"] == 0
    assert [r["samples"] for r in res["noise_vs_samples"]["rows"]] == [36, 72]
    assert len(res["fk_gp"]["polynomial_rmse_measured"]) == 7  # 6 pose + geodesic
    assert len(res["controller"]["rounds"]) == 1
    for name in ("kinematics_confusion.png", "kinematics_noise_vs_samples.png",
                 "kinematics_controller.png", "kinematics.md"):  # fmt: skip
        assert (tmp_path / name).stat().st_size > 0

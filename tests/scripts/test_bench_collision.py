"""A tiny run of the collision benchmark: its jobs are kept and a rerun reuses them."""

from __future__ import annotations

import pytest

from mcpilco.experiments.results import read_result

TINY = [
    "--train-waypoints", "4", "--gp-points", "150", "--hyper-points", "60",
    "--adam-iters", "3", "--lbfgs-iters", "0", "--test-waypoints", "2", "--final-rest", "1",
    "--push-free-minutes", "0.3", "--push-waypoints", "3", "--cv-points", "80",
    "--cv-validation", "200", "--cv-hyper-points", "40", "--sigma-v-candidates", "0.01,0.03",
    "--alphas", "0,1e-3", "--no-progress",
]  # fmt: skip


@pytest.mark.slow  # about 3 min on 2 busy cores, most of it the simulation
def test_tiny_run_keeps_its_jobs_and_a_rerun_reuses_them(tmp_path, capsys, command):
    argv = [*TINY, "--out-dir", str(tmp_path / "out"), "--runs-dir", str(tmp_path / "runs")]
    assert command("mcpilco-bench-collision", [*argv, "--jobs", "2"]) == 0
    first = read_result(tmp_path / "out" / "collision.json").payload()
    names = {p.stem for p in (tmp_path / "runs").glob("*.json")}
    assert names == {"sigma_v_cv", "PP", "SP", "FC", "PP-sign"}
    assert (tmp_path / "runs" / "data.pt").is_file()
    capsys.readouterr()
    assert (
        command("mcpilco-bench-collision", argv) == 0
    )  # in this process: every job is read back, nothing recomputed
    assert "0 ran, 4 reused" in capsys.readouterr().out
    again = read_result(tmp_path / "out" / "collision.json").payload()
    assert again["estimators"] == first["estimators"] and again["goals"] == first["goals"]

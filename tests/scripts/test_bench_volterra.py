"""mcpilco-bench-volterra in a tiny configuration: outputs, per-run files, reuse."""

from __future__ import annotations

import numpy as np
import pytest

from mcpilco.experiments.identification import volterra as bench
from mcpilco.experiments.results import read_result

pytestmark = pytest.mark.usefixtures("one_torch_thread")  # tiny GP fits


def test_tiny_benchmark_writes_json_pngs_and_table(tmp_path, command):
    out = tmp_path / "res"
    rc = command(
        "mcpilco-bench-volterra",
        [
            "--runs", "1",
            "--orders", "2",
            "--snrs", "20",
            "--n-train", "40",
            "--n-test", "30",
            "--adam-iters", "2",
            "--lbfgs-iters", "0",
            "--out-dir", str(out),
            "--no-progress",
        ]
    )  # fmt: skip
    assert rc == 0
    for name in ("volterra.json", "volterra.md", "volterra_exp1.png", "volterra_exp2.png"):
        assert (out / name).stat().st_size > 0, name
    data = read_result(out / "volterra.json").payload()
    assert data["meta"]["runs_exp1"] == 1 and data["meta"]["runs_exp2"] == 1
    fits1 = data["fits"]["exp1"]
    assert set(fits1) == {"setup1", "setup2"}
    assert set(fits1["setup1"]) == {*bench.EXP1["kinds"], bench.ORACLE}
    fits2 = data["fits"]["exp2"]
    assert set(fits2) == {"r2_snr20"}
    assert set(fits2["r2_snr20"]) == set(bench.EXP2["kinds"])
    for run in data["runs"]:
        assert run["error"] == {}, run["error"]
        assert all(np.isfinite(v) for v in run["fit"].values())
    table = (out / "volterra.md").read_text()
    assert "| setup2 | MPK | 1 |" in table
    assert "| 2 | 20 | MPK | 1 |" in table
    assert "| setup2 | LS_ORACLE | 1 |" in table and "14 monomials" in table

    # one result file per run; a second call reuses them (nothing recomputed: same Fits)
    files = sorted((out / "volterra_runs").rglob("*.json"))
    assert [f.relative_to(out / "volterra_runs").as_posix() for f in files] == [
        "exp1/setup1/seed0.json", "exp1/setup2/seed0.json", "exp2/r2_snr20/seed0.json"
    ]  # fmt: skip
    stamps = [f.stat().st_mtime_ns for f in files]
    again = bench.run_benchmark(
        runs=1,
        out_dir=out,
        progress=False,
        exp1_overrides={"n_train": 40, "n_test": 30, "adam_iters": 2, "lbfgs_iters": 0},
        exp2_overrides={"n_train": 40, "n_test": 30, "adam_iters": 2, "lbfgs_iters": 0,
                        "orders": [2], "snrs_db": [20.0]},
    )  # fmt: skip
    assert again["summary"] == data["summary"] and again["failed"] == []
    assert [f.stat().st_mtime_ns for f in files] == stamps
    assert read_result(out / "volterra.json").payload()["meta"]["runs_reused"] == 3

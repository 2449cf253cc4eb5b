"""Smoke test of scripts/bench_gp_predictor.py at a tiny size (no timing claims)."""

from __future__ import annotations

import json

from mcpilco.scripts.bench_gp_predictor import main


def test_bench_script_writes_json(tmp_path, capsys) -> None:
    out = tmp_path / "bench.json"
    rc = main(
        ["--n-train", "30", "--n-test", "8", "--dim", "2", "--repeats", "1", "--out", str(out)]
    )
    assert rc == 0
    result = json.loads(out.read_text())
    assert result["config"]["n_train"] == 30
    assert set(result["speedup_vs_gpytorch"]) >= {"cached64", "cached32", "fused64", "fused32"}
    assert result["max_abs_diff_cached64_vs_gpytorch"] < 1e-8
    assert result["max_abs_diff_fused64_vs_gpytorch"] < 1e-8
    assert "faster per call" in capsys.readouterr().out

"""Smoke test of ``mcpilco-bench-gp`` at a tiny size (no timing claims)."""

from __future__ import annotations

from mcpilco.experiments.results import read_result


def test_bench_script_writes_json(command, tmp_path, capsys) -> None:
    out = tmp_path / "bench.json"
    rc = command(
        "mcpilco-bench-gp",
        ["--n-train", "30", "--n-test", "8", "--dim", "2", "--repeats", "1", "--out", str(out)],
    )
    assert rc == 0
    result = read_result(out).payload()
    assert result["config"]["n_train"] == 30
    assert set(result["speedup_vs_gpytorch"]) >= {"cached64", "cached32", "fused64", "fused32"}
    assert result["max_abs_diff_cached64_vs_gpytorch"] < 1e-8
    assert result["max_abs_diff_fused64_vs_gpytorch"] < 1e-8
    printed = capsys.readouterr().out
    assert "faster per call" in printed and "ceiling" in printed
    # the ceiling's flop count covers the lower triangle of L^{-1} (N(N+1)/2 entries) times
    # n test points, m outputs and 2 flops per multiply-add, and less than the full square
    vt, (n, n_test, m) = result["variance_term64"], (30, 8, result["config"]["m"])
    assert 2 * m * n_test * n * (n + 1) / 2 <= vt["flops"] <= 2 * m * n_test * n * n
    assert vt["ceiling_speedup_vs_gpytorch"] > 0 and vt["gemm64_reference_gflops_per_s"] > 0

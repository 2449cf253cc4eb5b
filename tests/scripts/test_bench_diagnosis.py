"""mcpilco-bench-diagnosis: a case is a sweep job, reused by the next call; the report files."""

from mcpilco.experiments.results import read_result


def test_a_case_is_a_sweep_job_reused_by_the_next_call(tmp_path, capsys, command):
    argv = ["--cases", "1", "--duration", "2", "--max-joints", "2", "--out", str(tmp_path / "diag")]
    argv += ["--runs-dir", str(tmp_path / "runs")]
    assert command("mcpilco-bench-diagnosis", argv) == 0
    record = tmp_path / "runs" / "random" / "nominal" / "seed1000.json"
    stamp = record.stat().st_mtime_ns
    first = read_result(tmp_path / "diag.json").payload()
    assert first["summary"]["cases"] == {"control": 1}  # case 0 of the plan is a control case
    assert first["seeds"] == [1000] and first["command"].startswith("mcpilco-bench-diagnosis ")
    (case,) = first["cases"]
    assert case["effects"] == [] and case["score"]["expected_verdict"] == "at floor"
    assert (tmp_path / "diag.md").read_text().startswith("# Diagnosis on simulated robot logs")
    assert (tmp_path / "diag_confusion.png").stat().st_size > 0
    assert command("mcpilco-bench-diagnosis", argv) == 0  # the case is read back, not recomputed
    assert "0 ran, 1 reused, 0 failed" in capsys.readouterr().out
    assert record.stat().st_mtime_ns == stamp
    assert read_result(tmp_path / "diag.json").payload()["cases"] == first["cases"]

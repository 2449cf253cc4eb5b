"""``mcpilco-bench-sweep``: a tiny sweep writes its figures; bad sizes are refused."""

from __future__ import annotations

from mcpilco.experiments.results import read_result


def test_tiny_sweep_writes_json_and_table(tmp_path, command):
    argv = ["--backends", "local", "--kinds", "sleep", "--n", "2", "--seconds", "0.05"]
    argv += ["--cpus", "1", "--repeats", "1", "--out", str(tmp_path)]
    assert command("mcpilco-bench-sweep", argv) == 0
    result = read_result(tmp_path / "sweep_overhead.json").payload()
    assert result["command"].startswith("mcpilco-bench-sweep --backends local")
    assert [(r["kind"], r["backend"]) for r in result["summary"]] == [("sleep", "local")]
    assert "| sleep | local |" in (tmp_path / "sweep_overhead.md").read_text()


def test_zero_jobs_is_an_error(tmp_path, capsys, command):
    assert command("mcpilco-bench-sweep", ["--n", "0", "--out", str(tmp_path)]) == 2
    assert "--n, --cpus and --repeats must be >= 1" in capsys.readouterr().err

"""mcpilco-bench-budget: a tiny measurement on one task spec writes the rows, the fitted
constants (positive, reproducing the rows they were fitted to) and the shipped task files'
budgets."""

from __future__ import annotations

import pytest

from mcpilco.experiments.results import read_result


def test_bench_budget_writes_the_measured_model(tmp_path, command, one_torch_thread):
    argv = ["--envs", "Pendulum-v1", "--particles", "10", "40", "--points", "20", "60"]
    assert command("mcpilco-bench-budget", [*argv, "--repeats", "1", "--out", str(tmp_path)]) == 0
    res = read_result(tmp_path / "mcpilco_budget.json")
    assert res.kind == "budget" and res.command.startswith("mcpilco-bench-budget --envs")
    res = {**res.config, **res.summary, **res.cases}
    assert len(res["rows"]) == 4
    fit = res["fitted"]
    assert min(fit.values()) >= 0 and max(fit.values()) > 0
    for r in res["rows"]:
        assert r["seconds"] > 0 and (r["horizon"], r["outputs"]) == (80, 1)
        per_particle = fit["c0_s"] + fit["c1_s"] * r["points"] * r["inputs"]
        expected = r["horizon"] * (fit["ch_s"] + r["outputs"] * r["particles"] * per_particle)
        assert r["fitted_s"] == pytest.approx(expected)
    assert {s["env_id"] for s in res["shipped"]} >= {"mcpilco/CartpoleSwingUp-v0"}
    md = (tmp_path / "mcpilco_budget.md").read_text()
    assert "| Pendulum-v1 | 40 | 80 | 1 |" in md and "Shipped task files" in md


def test_bench_budget_refits_an_earlier_measurement(tmp_path, command, one_torch_thread):
    """--refit reads the rows and provenance back and fits them again to the same constants."""
    argv = ["--envs", "Pendulum-v1", "--particles", "10", "40", "--points", "20", "60"]
    first, second = tmp_path / "a", tmp_path / "b"
    assert command("mcpilco-bench-budget", [*argv, "--repeats", "1", "--out", str(first)]) == 0
    path = first / "mcpilco_budget.json"
    assert command("mcpilco-bench-budget", ["--refit", str(path), "--out", str(second)]) == 0
    a, b = read_result(path), read_result(second / "mcpilco_budget.json")
    assert b.command == a.command and b.summary["fitted"] == pytest.approx(a.summary["fitted"])
    assert b.summary["load_average"] == a.summary["load_average"]

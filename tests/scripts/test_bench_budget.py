"""mcpilco-bench-budget: a tiny measurement on one task spec writes the rows, the fitted
constants (positive, reproducing the rows they were fitted to) and the shipped task files'
budgets."""

from __future__ import annotations

import json

import pytest


def test_bench_budget_writes_the_measured_model(tmp_path, command, one_torch_thread):
    argv = ["--envs", "Pendulum-v1", "--particles", "10", "40", "--points", "20", "60"]
    assert command("mcpilco-bench-budget", [*argv, "--repeats", "1", "--out", str(tmp_path)]) == 0
    res = json.loads((tmp_path / "mcpilco_budget.json").read_text())
    assert len(res["rows"]) == 4 and res["command"].startswith("mcpilco-bench-budget --envs")
    assert res["fitted"]["c0_s"] > 0 or res["fitted"]["c1_s"] > 0
    for r in res["rows"]:
        assert r["seconds"] > 0 and (r["horizon"], r["outputs"]) == (80, 1)
        base = r["particles"] * r["horizon"] * r["outputs"]
        fit = res["fitted"]
        assert r["fitted_s"] == pytest.approx(
            base * (fit["c0_s"] + fit["c1_s"] * r["points"] * r["inputs"])
        )
    assert {s["env_id"] for s in res["shipped"]} >= {"mcpilco/CartpoleSwingUp-v0"}
    md = (tmp_path / "mcpilco_budget.md").read_text()
    assert "| Pendulum-v1 | 40 | 80 | 1 |" in md and "Shipped task files" in md

"""The evaluation benchmark's summary: a seed is solved when all its evaluation episodes
succeed; rates with their Wilson intervals; the headline is the last trial within the
experience budget; the files follow the result schema and say which seeds were dev."""

from __future__ import annotations

import json

import pytest

from mcpilco.experiments.mcpilco.evaluation import at_budget, make_payload, write_report
from mcpilco.models.stats import wilson_interval


def _run(seed: int, evals: list[tuple[int, int]]) -> dict:
    records = [{"index": 0, "kind": "exploration", "experience_s": 4.0, "success": False}]
    for k, (ok, n) in enumerate(evals, start=1):
        records.append(
            {
                "index": k, "kind": "policy", "experience_s": 4.0 * (k + 1), "success": ok > 0,
                "eval_successes": ok, "eval_counted": n, "rollout_dtype": "float64",
            }
        )  # fmt: skip
    return {"seed": seed, "records": records, "seconds": 10.0}


def test_seeds_solved_and_headline(tmp_path):
    runs = [_run(0, [(0, 5), (5, 5), (5, 5)]), _run(1, [(2, 5), (4, 5), (5, 5)])]
    payload = make_payload("Pendulum-v1", runs, 3, 5, 12.0, command="test")
    rows = payload["per_trial"]
    assert [r["seeds_solved"]["k"] for r in rows] == [0, 1, 2]  # 4 of 5 is not solved
    assert [r["episodes"]["k"] for r in rows] == [2, 9, 10]
    assert rows[1]["episodes"]["ci95"] == pytest.approx(list(wilson_interval(9, 10)))
    assert payload["headline"]["experience_s"] == 12.0  # trials at 8, 12, 16 s: 12 is the last
    assert at_budget(rows, 7.0) is None
    path = write_report(payload, tmp_path, "dev")
    data = json.loads(path.read_text())
    assert data["kind"] == "mcpilco_eval" and data["seeds"]["development"] == [0, 1]
    assert (tmp_path / "mcpilco_eval_Pendulum_v1_dev.png").is_file()
    md = (tmp_path / "mcpilco_eval_Pendulum_v1_dev.md").read_text()
    assert "development seed(s)" in md and "1 of 2 seeds solved" in md


def test_seeds_with_grown_horizons_count_at_their_most_experience(tmp_path):
    # seed 1's horizon grew: its second policy trial ends at 14 s instead of 12 s
    grown = _run(1, [(0, 5), (5, 5)])
    grown["records"][2].update(experience_s=14.0, horizon=120)
    payload = make_payload("Pendulum-v1", [_run(0, [(0, 5), (5, 5)]), grown], 2, 5, 12.0)
    rows = payload["per_trial"]
    assert [(r["experience_min_s"], r["experience_s"]) for r in rows] == [(8, 8), (12, 14)]
    assert payload["headline"]["experience_s"] == 8.0  # trial 2 is not by 12 s for seed 1
    md = write_report(payload, tmp_path).with_suffix(".md").read_text()
    assert "| 12-14 s | 2/2" in md and "14 s: 5/5 (H = 120)" in md


def test_a_further_trial_past_the_budget_is_said_so(tmp_path):
    # trials end at 8, 12, 16 s (4 s each): with a 18 s budget the next would end at 20 s
    runs = [_run(0, [(0, 5), (0, 5), (0, 5)]), _run(1, [(0, 5), (5, 5), (5, 5)])]
    md = write_report(make_payload("Pendulum-v1", runs, 3, 5, 18.0), tmp_path)
    text = md.with_suffix(".md").read_text()
    assert "would end at 20.0 s or later on every seed" in text and "nothing is known" not in text
    # with a 25 s budget a further trial (ending at 20 s) would have fitted
    md = write_report(make_payload("Pendulum-v1", runs, 3, 5, 25.0), tmp_path, "b")
    assert "nothing is known of the trials up to 25 s" in md.with_suffix(".md").read_text()

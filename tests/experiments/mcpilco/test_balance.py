"""The balance benchmark's summary, page and figure from a payload written by hand."""

from __future__ import annotations

from mcpilco.experiments.mcpilco.balance import RESULT_LAYOUTS, markdown, replot, summarise
from mcpilco.experiments.results import read_result, write_result


def _runs():
    def trial(k, steps):
        return {"trial": k, "experience_s": 5.0 * (k + 1), "episode_steps": steps,
                "balanced": all(s == 1000 for s in steps)}  # fmt: skip

    return [
        {"seed": 3, "trials": [trial(1, [1000, 1000]), trial(2, [1000, 1000])], "seconds": 60.0},
        {"seed": 4, "trials": [trial(1, [1000, 20]), trial(2, [1000, 1000])], "seconds": 90.0},
    ]


def test_a_seed_balances_after_a_trial_when_every_episode_lasts_the_episode():
    rows = summarise(_runs(), 2)
    assert [r["balanced_seeds"] for r in rows] == [[3], [3, 4]]
    assert [(r["balanced"]["k"], r["balanced"]["n"]) for r in rows] == [(1, 2), (2, 2)]
    assert rows[1]["experience_s"] == 15.0


def test_page_names_development_seeds_and_the_figure_is_redrawn(tmp_path):
    runs = _runs()
    payload = {"env_id": "InvertedDoublePendulum-v5", "trials": 2, "episodes": 2,
               "episode_steps": 1000, "config": {}, "per_trial": summarise(runs, 2),
               "runs": runs}  # fmt: skip
    path = write_result(tmp_path / "b.json", RESULT_LAYOUTS[0], payload, seeds=[3, 4], command="x")
    res = read_result(path)
    page = markdown(res)
    assert "development seeds 3-4" in page
    assert "| 1 | 10 s | 1 of 2 | 50 %" in page
    png, md = replot(res, path)
    assert png.stat().st_size > 0 and md.read_text() == page

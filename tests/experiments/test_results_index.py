"""The results index: rows read from a synthetic results folder, and the committed
``results/README.md`` equal to what the registered benches generate from the committed files."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from mcpilco.experiments.benches import headlines, layouts
from mcpilco.experiments.results import (
    NOT_RECORDED,
    Headline,
    ResultLayout,
    seed_ranges,
    write_result,
)
from mcpilco.experiments.results_index import index_rows, render_index, write_index

REPO = Path(__file__).resolve().parents[2]
SPEED = ResultLayout("speed")  # a synthetic bench's layout
RUNS = ResultLayout("runs", cases=("sections",))  # a synthetic bench measured in parts


def _write(folder: Path, name: str, layout: ResultLayout, data: dict, **kw) -> None:
    path = folder / name
    path.parent.mkdir(parents=True, exist_ok=True)
    write_result(path, layout, data, **kw)
    path.with_suffix(".md").write_text("# table\n")


SYNTHETIC = (
    Headline("Speed", "speed.json", lambda r: f"{r['ratio']:.1f}x faster", "speed.md"),
    Headline(
        "Success",
        "runs/success.json",
        lambda r: f"{100 * r['rate']:.0f} % success",
        "runs/success.md",
        part="hold",
        seeds=lambda r: seed_ranges(r["sections"]["hold"]),
    ),
)


def _synthetic_folder(root: Path) -> Path:
    results = root / "results"
    _write(
        results, "speed.json", SPEED, {"ratio": 6.46, "seeds": [0, 1, 2, 4]}, command="bench --fast"
    )
    _write(
        results,
        "runs/success.json",
        RUNS,
        {
            "rate": 0.95,
            "sections": {"hold": [3, 4, 5, 6]},
            "commands": {"hold": "train --hold 2", "iid": "train --hold 1"},
            "measured": {"hold": "2026-01-01", "iid": "2026-01-02"},
        },
    )
    return results


def test_seed_ranges():
    assert seed_ranges([0, 1, 2, 5, 7, 8, 8]) == "0-2, 5, 7-8"
    assert seed_ranges([3]) == "3"
    assert seed_ranges([]) == NOT_RECORDED


def test_rows_of_a_synthetic_folder(tmp_path):
    results = _synthetic_folder(tmp_path)
    rows = index_rows(results, SYNTHETIC)
    assert [r.capability for r in rows] == ["Speed", "Success"]
    speed, success = rows
    today = json.loads((results / "speed.json").read_text())["date"][:10]
    assert speed.figure == "6.5x faster"
    assert speed.command == "bench --fast"
    assert speed.seeds == "0-2, 4"
    assert speed.date == today
    assert speed.page == "speed.md"
    assert success.figure == "95 % success"
    assert success.command == "train --hold 2"  # the row's part picks its command
    assert success.seeds == "3-6"
    assert success.date == "2026-01-01"  # and its date

    text = render_index(results, SYNTHETIC)
    table = [line for line in text.splitlines() if line.startswith("| ")]
    assert table[0].startswith("| capability | headline figure | command | seeds | measured")
    assert table[1] == (
        f"| Speed | 6.5x faster | `bench --fast` | 0-2, 4 | {today} | [speed.md](speed.md) |"
    )
    assert table[2] == (
        "| Success | 95 % success | `train --hold 2` | 3-6 | 2026-01-01 "
        "| [runs/success.md](runs/success.md) |"
    )
    out = write_index(results, registry=SYNTHETIC)
    assert out == results / "README.md" and out.read_text() == text


def test_missing_or_changed_files_are_named(tmp_path):
    results = _synthetic_folder(tmp_path)
    (results / "speed.md").unlink()
    with pytest.raises(FileNotFoundError, match="speed.md"):
        index_rows(results, SYNTHETIC)
    results = _synthetic_folder(tmp_path / "b")
    write_result(results / "speed.json", SPEED, {"rate": 1.0})
    with pytest.raises(ValueError, match=r"speed\.json.*'Speed'"):
        index_rows(results, SYNTHETIC)
    (results / "speed.json").write_text(json.dumps({"ratio": 1.0}))  # not the result schema
    with pytest.raises(ValueError, match=r"speed\.json.*schema"):
        index_rows(results, SYNTHETIC)


def test_committed_index_is_up_to_date():
    """results/README.md equals what ``mcpilco-results-index`` writes from the committed files."""
    committed = (REPO / "results" / "README.md").read_text()
    assert committed == render_index(REPO / "results"), (
        "results/README.md is out of date: run mcpilco-results-index"
    )


def test_every_headline_file_exists_and_has_its_benchs_kind():
    kinds = layouts()
    for h in headlines():
        assert (REPO / "results" / h.path).is_file(), h.path
        assert (REPO / "results" / h.page).is_file(), h.page
        assert json.loads((REPO / "results" / h.path).read_text())["kind"] in kinds


def test_console_script(command, tmp_path):
    assert command("mcpilco-results-index", ["--help"]) == 0
    missing = tmp_path / "none"
    assert command("mcpilco-results-index", ["--results", str(missing)]) == 2

"""The results index: rows read from a synthetic results folder, and the committed
``results/README.md`` equal to what the registry generates from the committed JSON."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

from mcpilco.experiments.results_index import (
    NOT_RECORDED,
    REGISTRY,
    Headline,
    index_rows,
    render_index,
    seed_ranges,
    write_index,
)

REPO = Path(__file__).resolve().parents[2]


def _write(folder: Path, name: str, data: dict) -> None:
    path = folder / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data))
    path.with_suffix(".md").write_text("# table\n")


SYNTHETIC = (
    Headline(
        "Speed",
        "speed.json",
        lambda d: f"{d['ratio']:.1f}x faster",
        "speed.md",
    ),
    Headline(
        "Success",
        "runs/success.json",
        lambda d: f"{100 * d['rate']:.0f} % success",
        "runs/success.md",
        key="hold",
        seeds=lambda d: seed_ranges(d["sections"]["hold"]),
    ),
)


def _synthetic_folder(root: Path) -> Path:
    results = root / "results"
    _write(
        results,
        "speed.json",
        {"ratio": 6.46, "command": "bench --fast", "seeds": [0, 1, 2, 4], "measured": "2026-01-02"},
    )
    _write(
        results,
        "runs/success.json",
        {
            "rate": 0.95,
            "sections": {"hold": [3, 4, 5, 6]},
            "commands": {"hold": "train --hold 2", "iid": "train --hold 1"},
            "measured": {"iid": "2026-01-01"},
        },
    )
    return results


def test_seed_ranges():
    assert seed_ranges([0, 1, 2, 5, 7, 8, 8]) == "0-2, 5, 7-8"
    assert seed_ranges([3]) == "3"
    assert seed_ranges([]) == NOT_RECORDED


def test_rows_of_a_synthetic_folder(tmp_path):
    results = _synthetic_folder(tmp_path)
    rows = index_rows(results, SYNTHETIC, use_git=False)
    assert [r.capability for r in rows] == ["Speed", "Success"]
    speed, success = rows
    assert speed.figure == "6.5x faster"
    assert speed.command == "bench --fast"
    assert speed.seeds == "0-2, 4"
    assert speed.date == "2026-01-02"
    assert speed.page == "speed.md"
    assert success.figure == "95 % success"
    assert success.command == "train --hold 2"  # the row's key picks its command
    assert success.seeds == "3-6"
    assert success.date == NOT_RECORDED  # "measured" has no entry for this key, git is off

    text = render_index(results, SYNTHETIC, use_git=False)
    table = [line for line in text.splitlines() if line.startswith("| ")]
    assert table[0].startswith("| capability | headline figure | command | seeds | measured")
    assert table[1] == (
        "| Speed | 6.5x faster | `bench --fast` | 0-2, 4 | 2026-01-02 | [speed.md](speed.md) |"
    )
    assert table[2] == (
        "| Success | 95 % success | `train --hold 2` | 3-6 | not recorded "
        "| [runs/success.md](runs/success.md) |"
    )
    out = write_index(results, registry=SYNTHETIC, use_git=False)
    assert out == results / "README.md" and out.read_text() == text


def test_date_falls_back_to_the_last_commit(tmp_path):
    if shutil.which("git") is None:
        pytest.skip("git is not installed")
    results = _synthetic_folder(tmp_path)
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-c", "commit.gpgsign=false"]
    subprocess.run(["git", "init", "-q"], cwd=tmp_path, check=True)
    subprocess.run([*git, "add", "."], cwd=tmp_path, check=True)
    env = {"GIT_AUTHOR_DATE": "2025-03-04T12:00:00+00:00", "PATH": "/usr/bin:/bin"}
    subprocess.run([*git, "commit", "-q", "-m", "r"], cwd=tmp_path, check=True, env=env)
    rows = index_rows(results, SYNTHETIC, use_git=True)
    assert rows[0].date == "2026-01-02"  # recorded in the JSON: kept
    assert rows[1].date == "2025-03-04 (last commit)"


def test_missing_or_changed_files_are_named(tmp_path):
    results = _synthetic_folder(tmp_path)
    (results / "speed.md").unlink()
    with pytest.raises(FileNotFoundError, match="speed.md"):
        index_rows(results, SYNTHETIC, use_git=False)
    results = _synthetic_folder(tmp_path / "b")
    (results / "speed.json").write_text(json.dumps({"rate": 1.0}))
    with pytest.raises(ValueError, match=r"speed\.json.*'Speed'"):
        index_rows(results, SYNTHETIC, use_git=False)


def test_committed_index_is_up_to_date():
    """results/README.md equals what ``mcpilco-results-index`` writes from the committed JSON."""
    if shutil.which("git") is None or not (REPO / ".git").exists():
        pytest.skip("the dates fall back to the git history, which this copy lacks")
    committed = (REPO / "results" / "README.md").read_text()
    assert committed == render_index(REPO / "results"), (
        "results/README.md is out of date: run mcpilco-results-index"
    )


def test_every_registered_file_exists():
    for h in REGISTRY:
        assert (REPO / "results" / h.path).is_file(), h.path
        assert (REPO / "results" / h.page).is_file(), h.page


def test_console_script(command, tmp_path):
    assert command("mcpilco-results-index", ["--help"]) == 0
    missing = tmp_path / "none"
    assert command("mcpilco-results-index", ["--results", str(missing)]) == 2

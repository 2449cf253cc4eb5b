"""The one result schema (:mod:`mcpilco.experiments.results`) and the conversion of the files
written before it (:mod:`mcpilco.experiments.infra.convert_results`)."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest
from scipy import stats as sps

from mcpilco.experiments.infra.convert_results import (
    check_converted,
    convert,
    legacy_kind,
    to_legacy,
)
from mcpilco.experiments.results import (
    SCHEMA,
    ResultLayout,
    build_result,
    over_seeds,
    rate,
    read_result,
    result_from_dict,
    write_result,
)

REPO = Path(__file__).resolve().parents[2]
LAYOUT = ResultLayout("toy", config=("settings",), cases=("runs",), failures=("failed",))


def test_write_and_read_lay_the_payload_out_by_sections(tmp_path):
    payload = {
        "settings": {"n": 3},
        "seeds": [0, 1, 1000],
        "runs": [{"seed": 0, "x": 1.5}],
        "failed": ["seed7"],
        "mean_x": 1.5,
        "machine": "test box",
    }
    path = write_result(tmp_path / "toy.json", LAYOUT, payload, command="toy --n 3")
    raw = json.loads(path.read_text())
    assert raw["schema"] == SCHEMA and raw["kind"] == "toy" and raw["command"] == "toy --n 3"
    assert raw["date"].endswith("Z") and raw["machine"] == "test box"
    assert raw["config"] == {"settings": {"n": 3}, "seeds": [0, 1, 1000]}
    assert raw["cases"] == {"runs": [{"seed": 0, "x": 1.5}]}
    assert raw["failures"] == {"failed": ["seed7"]} and raw["summary"] == {"mean_x": 1.5}
    assert raw["seeds"] == {"all": [0, 1, 1000], "development": [0, 1]}
    res = read_result(path)
    assert res["mean_x"] == 1.5 and res.get("nothing") is None and "runs" in res
    back = res.payload()
    assert {k: back[k] for k in payload if k != "machine"} == {
        k: v for k, v in payload.items() if k != "machine"
    }
    assert back["command"] == "toy --n 3" and back["measured"] == raw["date"]


def test_parts_keep_their_own_command_and_date():
    payload = {
        "runs": {"a": 1},
        "commands": {"a": "bench --label a"},
        "measured": {"a": "2026-01-02", "b": "2026-01-05"},
    }
    res = build_result(LAYOUT, payload)
    assert res.command_of("a") == "bench --label a" and res.date_of("b") == "2026-01-05"
    assert res.date == "2026-01-05"  # the latest part
    assert res.payload()["commands"] == payload["commands"]
    assert res.payload()["measured"] == payload["measured"]


def test_reader_refuses_other_files(tmp_path):
    bad = tmp_path / "old.json"
    bad.write_text(json.dumps({"timing": []}))
    with pytest.raises(ValueError, match=r"old\.json.*schema"):
        read_result(bad)
    bad.write_text("{")
    with pytest.raises(ValueError, match="not valid JSON"):
        read_result(bad)
    with pytest.raises(ValueError, match="section 'cases'"):
        result_from_dict({"schema": SCHEMA, "kind": "k", "date": "d", "cases": []})


def test_rate_and_over_seeds_intervals():
    r = rate(3, 10)
    ref = sps.binomtest(3, 10).proportion_ci(method="wilson")
    assert r["rate"] == 0.3 and r["n"] == 10
    assert r["ci95"] == pytest.approx([ref.low, ref.high], abs=1e-4)
    m = over_seeds([1.0, 2.0, 3.0, 4.0, float("nan")])
    assert m["median"] == 2.5 and m["n"] == 4 and m["ci95"][0] <= 2.5 <= m["ci95"][1]


def test_conversion_rebuilds_the_old_object_and_detects_a_changed_number():
    old = {
        "measured": "2026-01-02",
        "command": "toy --old",
        "settings": {"n": 3},
        "runs": [1.0, 2.0],
        "mean": 1.5,
    }
    res = convert(old, "quasi_static_friction")
    assert res.date == "2026-01-02" and res.command == "toy --old"
    assert to_legacy(res) == old
    check_converted(res)
    changed = copy.deepcopy(res)
    changed.summary["mean"] = 1.6
    with pytest.raises(ValueError, match="does not rebuild"):
        check_converted(changed)


def _result_files() -> list[Path]:
    return sorted((REPO / "results").rglob("*.json"))


def test_every_committed_bench_result_is_in_the_schema():
    """Every bench's file under results/ is in the schema (the trial records of a training run
    are not a bench's result)."""
    for path in _result_files():
        if legacy_kind(path) is not None:
            assert json.loads(path.read_text()).get("schema") == SCHEMA, path


def _converted_files() -> list[Path]:
    return [p for p in _result_files() if "legacy" in json.loads(p.read_text())]


@pytest.mark.parametrize("path", _converted_files(), ids=lambda p: str(p.relative_to(REPO)))
def test_converted_files_hold_the_old_numbers_unchanged(path):
    """A converted file rebuilds the old file exactly (the SHA-256 of the old object, taken
    before conversion, matches the object rebuilt from the new sections)."""
    check_converted(result_from_dict(json.loads(path.read_text()), str(path)), str(path))

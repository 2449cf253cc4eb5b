"""Trial records: one typed record written and read in one place; files of every version
(older fields, unknown keys) load and write back unchanged."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from mcpilco.agents.common.records import (
    RECORDS_NAME,
    TrialRecord,
    read_records,
    record_line,
    write_records,
)
from mcpilco.agents.mc_pilco import MCPilcoConfig

REPO = Path(__file__).resolve().parents[3]
# records.json of a demo run written by an early version (keys since dropped: time_upright,
# mean_abs_x; fields since added: steps, time_in_goal, snapshot_*)
OLD_RECORDS = REPO / "results" / "h100" / "demo_seed1_records.json"


def test_an_old_records_file_loads_and_writes_back_unchanged(tmp_path):
    data = json.loads(OLD_RECORDS.read_text())
    config, records = read_records(OLD_RECORDS)
    assert config == data["config"]
    assert [r.index for r in records] == list(range(len(data["records"])))
    assert records[1].kind == "policy" and records[1].steps is None  # not written then
    assert records[1].extra["time_upright"] == data["records"][1]["time_upright"]
    assert records[1].cost == data["records"][1]["cost"]
    # its config reads as today's config (legacy cost names, fields added since)
    cfg = MCPilcoConfig.from_dict(config)
    assert cfg.cost_length_scales == {"x": 1.0, "theta": 3.0} and cfg.cost_angle_mode == "abs"
    assert cfg.policy_init == "box"  # a field added since: its value of that time
    write_records(tmp_path, cfg, records)
    again = json.loads((tmp_path / RECORDS_NAME).read_text())
    assert again["records"] == data["records"]
    assert not list(tmp_path.glob("*.tmp"))


def test_a_record_round_trips_and_leaves_out_what_does_not_apply():
    rec = TrialRecord(index=0, kind="exploration")
    rec.update(cost=59.5, success=False, time_in_goal=0.0, steps=60, wall_s=0.2)
    rec.experience_s = 3.0
    d = rec.to_dict()
    assert d == {
        "index": 0, "kind": "exploration", "cost": 59.5, "success": False,
        "time_in_goal": 0.0, "steps": 60, "wall_s": 0.2, "experience_s": 3.0,
    }  # fmt: skip
    assert TrialRecord.from_dict(d) == rec
    odd = {**d, "future_field": [1, 2]}
    assert TrialRecord.from_dict(odd).to_dict() == odd


def test_bad_records_are_named():
    with pytest.raises(TypeError, match="no field 'colour'"):
        TrialRecord(index=0, kind="policy").update(colour="red")
    with pytest.raises(ValueError, match="kind must be one of"):
        TrialRecord(index=0, kind="random")
    with pytest.raises(ValueError, match="needs 'index' and 'kind'"):
        TrialRecord.from_dict({"cost": 1.0})


def test_read_records_names_a_file_that_is_not_one(tmp_path):
    (tmp_path / RECORDS_NAME).write_text("{")
    with pytest.raises(ValueError, match="not a records file"):
        read_records(tmp_path)
    (tmp_path / RECORDS_NAME).write_text('{"rows": []}')
    with pytest.raises(ValueError, match="no 'records' list"):
        read_records(tmp_path / RECORDS_NAME)
    with pytest.raises(FileNotFoundError):
        read_records(tmp_path / "missing.json")


def test_record_line_of_a_policy_trial():
    rec = TrialRecord.from_dict(
        {
            "index": 2, "kind": "policy", "experience_s": 9.0, "cost": 12.5, "success": True,
            "time_in_goal": 1.25, "steps": 60, "wall_s": 3.0, "gp_fit_s": 1.0,
            "gp_points": 120, "opt_steps": 50, "s_per_opt_step": 0.02,
            "cpu_s_per_opt_step": 0.03, "opt_final_cost": 10.0, "n_at_limits": 3,
        }
    )  # fmt: skip
    line = record_line(rec)
    assert line.startswith("trial 2 (policy, 9 s of experience): cost 12.50, success True")
    assert "GP fit 1.0 s on N=120, 50 opt steps" in line
    assert "3 transitions at the task's limits" in line

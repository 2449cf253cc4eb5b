"""Command-line checks of ``mcpilco-train``: clear errors for bad arguments, a tiny run."""

from __future__ import annotations

import json

import pytest

from mcpilco.scripts.train_mcpilco import build_parser, config_from_args, main


def _error_of(argv, capsys) -> str:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2  # argparse usage error
    return capsys.readouterr().err


def test_unknown_env_lists_registered_ids(capsys, tmp_path):
    err = _error_of(["--env", "mcpilco/Nope-v0", "--out", str(tmp_path)], capsys)
    assert "unknown env id 'mcpilco/Nope-v0'" in err
    assert "mcpilco/CartpoleSwingUp-v0" in err and "mcpilco/DMCCartpoleSwingUp-v0" in err


@pytest.mark.parametrize("value", ["0", "-3", "ten"])
def test_non_positive_particles_is_an_error(value, capsys, tmp_path):
    err = _error_of(["--particles", value, "--out", str(tmp_path)], capsys)
    assert "--particles" in err


def test_horizon_mismatch_is_an_error(capsys, tmp_path):
    err = _error_of(["--horizon", "40", "--out", str(tmp_path)], capsys)
    assert "horizon mismatch" in err and "60" in err


def test_unknown_kernel_is_an_error(capsys, tmp_path):
    err = _error_of(["--kernel", "linear", "--out", str(tmp_path)], capsys)
    assert "--kernel" in err


def test_overrides_reach_the_config():
    args = build_parser().parse_args(
        ["--preset", "demo", "--trials", "2", "--particles", "7", "--opt-steps", "9"]
        + ["--candidates", "3", "--explore-hold", "1"]
    )
    cfg = config_from_args(args)
    assert (cfg.num_trials, cfg.num_particles, cfg.opt.max_steps) == (2, 7, 9)
    assert cfg.explore_hold == 1
    assert cfg.opt_steps_first <= 9 and cfg.num_candidates == 3


def test_dm_control_env_gets_iid_exploration_unless_told():
    dmc = ["--env", "mcpilco/DMCCartpoleSwingUp-v0"]
    assert config_from_args(build_parser().parse_args(dmc)).explore_hold == 1
    told = build_parser().parse_args(dmc + ["--explore-hold", "2"])
    assert config_from_args(told).explore_hold == 2
    assert config_from_args(build_parser().parse_args([])).explore_hold == 2


def test_zero_candidates_is_an_error(capsys, tmp_path):
    err = _error_of(["--candidates", "0", "--out", str(tmp_path)], capsys)
    assert "--candidates" in err


def test_tiny_training_run(tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["--preset", "demo", "--trials", "1", "--particles", "8", "--opt-steps", "3"]
    argv += ["--threads", "1", "--no-progress", "--no-rrd", "--out", str(out), "--seed", "1"]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "trial 1 (policy" in text and "success" in text and "done in" in text
    records = json.loads((out / "records.json").read_text())["records"]
    assert [r["opt_steps"] for r in records if r["kind"] == "policy"] == [3]
    assert (out / "checkpoint.pt").is_file()

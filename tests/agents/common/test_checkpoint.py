"""Checkpoints and GP files: tensors and plain data only, damaged files named with a remedy,
a run stopped before its first checkpoint reported clearly by --resume."""

from __future__ import annotations

import pickle
import random

import numpy as np
import pytest
import torch

from mcpilco.agents.common.checkpoint import (
    CHECKPOINT_VERSION,
    atomic_torch_save,
    load_checkpoint,
    rng_state,
)
from mcpilco.models.torch_files import load_torch_file


class _Evil:
    """Unpickling this would run code; a safe load must refuse the file."""

    def __reduce__(self):
        return (print, ("code ran",))


def test_numpy_and_rng_state_round_trip_exactly(tmp_path):
    rng = np.random.default_rng(3)
    obj = {
        "version": CHECKPOINT_VERSION,
        "config": {"seed": 3, "num_trials": 2},
        "next_trial": 1,
        "records": [{"index": 0}],
        "episodes": [{"obs": rng.normal(size=(5, 4)), "actions": np.ones((4, 1), np.float32)}],
        "flags": (np.bool_(True), np.float64(2.5), np.int64(7)),
        "rng": rng_state(rng),
    }
    path = tmp_path / "checkpoint.pt"
    atomic_torch_save(obj, path)
    back = load_checkpoint(path)
    np.testing.assert_array_equal(back["episodes"][0]["obs"], obj["episodes"][0]["obs"])
    assert back["episodes"][0]["actions"].dtype == np.float32
    assert back["flags"] == (True, 2.5, 7)
    fresh = np.random.default_rng(0)
    fresh.bit_generator.state = back["rng"]["numpy"]
    assert fresh.normal() == rng.normal()
    random.setstate(back["rng"]["python"])


@pytest.mark.parametrize(
    "content, message",
    [
        (b"", "is empty"),
        (b"garbage \x00\x01 not a zip", "damaged or truncated"),
        ("truncated", "damaged or truncated"),
        ("evil", "objects other than tensors"),
    ],
)
def test_bad_checkpoints_are_named_with_a_remedy(tmp_path, content, message):
    path = tmp_path / "checkpoint.pt"
    if content == "truncated":
        atomic_torch_save({"version": CHECKPOINT_VERSION, "x": torch.zeros(1000)}, path)
        path.write_bytes(path.read_bytes()[:500])
    elif content == "evil":
        torch.save({"version": CHECKPOINT_VERSION, "x": _Evil()}, path, pickle_protocol=2)
    else:
        path.write_bytes(content)
    with pytest.raises(ValueError, match=message) as err:
        load_checkpoint(path)
    assert str(path) in str(err.value) and "--overwrite" in str(err.value)


def test_unsafe_objects_are_not_saved(tmp_path):
    with pytest.raises(TypeError, match="cannot store a _Evil"):
        atomic_torch_save({"x": _Evil()}, tmp_path / "f.pt")
    assert not (tmp_path / "f.pt").exists()


def test_missing_and_folder_paths(tmp_path):
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "checkpoint.pt.tmp").write_bytes(b"partial")
    with pytest.raises(FileNotFoundError, match="stopped while writing its first checkpoint"):
        load_checkpoint(tmp_path / "run" / "checkpoint.pt")
    with pytest.raises(ValueError, match="is not a file"):
        load_torch_file(tmp_path / "run", "GP file", "fit again")


def test_missing_gp_file_is_named(tmp_path):
    from mcpilco.models.gp import GPRegressor

    with pytest.raises(FileNotFoundError, match="GP file .*gp_trial03.pt does not exist"):
        GPRegressor.load(tmp_path / "gp_trial03.pt", lambda batch: None)


def test_resume_of_a_damaged_checkpoint_is_one_line_exit_2(tmp_path, capsys, command):
    (tmp_path / "checkpoint.pt").write_bytes(pickle.dumps({"version": 3}))
    code = command("mcpilco-train", ["--out", str(tmp_path), "--resume", "--no-progress"])
    err = capsys.readouterr().err.splitlines()
    assert code == 2 and len(err) == 1
    assert "checkpoint.pt" in err[0] and "--overwrite" in err[0]


@pytest.mark.slow
def test_sigkill_after_a_trial_loses_no_finished_trial(tmp_path):
    """A real kill: SIGKILL once the exploration trial is reported, then --resume."""
    import os
    import signal
    import subprocess
    import sys

    cmd = [sys.executable, "-m", "mcpilco.scripts.train_mcpilco", "--out", str(tmp_path)]
    cmd += ["--trials", "1", "--particles", "10", "--opt-steps", "3", "--max-points", "30"]
    cmd += ["--threads", "1", "--no-progress", "--no-rrd"]
    env = {**os.environ, "MUJOCO_GL": "egl"}
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, env=env)
    line = proc.stdout.readline()
    while line and not line.startswith("trial 0 "):
        line = proc.stdout.readline()
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert line.startswith("trial 0 ")
    done = subprocess.run([*cmd, "--resume"], capture_output=True, text=True, env=env)
    assert done.returncode == 0, done.stderr
    assert "trials 0..0 done" in done.stdout or "trials 0..1 done" in done.stdout


def test_save_checkpoint_writes_what_load_checkpoint_checks(tmp_path):
    from mcpilco.agents.common.checkpoint import rng_state, save_checkpoint
    from mcpilco.agents.mc_pilco import MCPilcoConfig

    cfg = MCPilcoConfig(seed=4)
    records = [{"index": k, "kind": "policy" if k else "exploration"} for k in range(3)]
    state = {"episodes": [{"obs": np.ones((2, 4))}], "records": records}
    save_checkpoint(tmp_path / "c.pt", cfg, 3, rng=rng_state(np.random.default_rng(0)), **state)
    ckpt = load_checkpoint(tmp_path / "c.pt")
    assert ckpt["version"] == CHECKPOINT_VERSION and ckpt["next_trial"] == 3
    assert MCPilcoConfig.from_dict(ckpt["config"]) == cfg
    np.testing.assert_array_equal(ckpt["episodes"][0]["obs"], np.ones((2, 4)))


def test_check_resume_compares_the_saved_config_as_a_config_of_its_type():
    """Each agent's config: a fixed field that changed is named; a field the saved config
    lacks (added later) takes its value of that time; a saved config of another agent is
    refused."""
    from mcpilco.agents.baselines.pilco import PilcoConfig
    from mcpilco.agents.baselines.sb3 import SB3Config
    from mcpilco.agents.common.checkpoint import check_resume
    from mcpilco.agents.mc_pilco import MCPilcoConfig

    for cfg, other in (
        (MCPilcoConfig(seed=1), MCPilcoConfig(seed=2)),
        (PilcoConfig(seed=1), PilcoConfig(seed=2)),
        (SB3Config("sac", seed=1), SB3Config("sac", seed=2)),
    ):
        check_resume(cfg.to_dict(), cfg, ("env_id", "seed"))
        with pytest.raises(ValueError, match="cannot resume: seed=2 differs from the .* 1"):
            check_resume(cfg.to_dict(), other, ("env_id", "seed"))
    old = MCPilcoConfig().to_dict()
    del old["explore_hold"]  # saved before the field existed: i.i.d. exploration
    check_resume(old, MCPilcoConfig(explore_hold=1), ("explore_hold",))
    with pytest.raises(ValueError, match="explore_hold=2 differs from the checkpoint's 1"):
        check_resume(old, MCPilcoConfig(explore_hold=2), ("explore_hold",))
    with pytest.raises(ValueError, match="does not read as a MCPilcoConfig"):
        check_resume(PilcoConfig().to_dict(), MCPilcoConfig(), ("seed",))

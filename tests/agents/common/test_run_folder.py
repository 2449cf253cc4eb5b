"""Run folders: refusal of another run, --overwrite, the flock lock across processes, the
manifest of a real (exploration-only) MC-PILCO run."""

from __future__ import annotations

import dataclasses
import json
import signal
import subprocess
import sys
import time

import pytest

from mcpilco.agents.common.run_folder import (
    LOCK_NAME,
    MANIFEST_NAME,
    RunFolderBusyError,
    open_run_folder,
)

# a child process that holds the folder's lock until killed
_HOLDER = (
    "import sys, time\n"
    "from mcpilco.agents.common.run_folder import open_run_folder\n"
    "run = open_run_folder(sys.argv[1])\n"
    "print('locked', flush=True)\n"
    "time.sleep(60)\n"
)


def _finished_run(path):
    """A folder as an earlier run left it: checkpoint, PNG, records, manifest."""
    with open_run_folder(path) as run:
        for name in ("checkpoint.pt", "trial_01_particles.png", "records.json"):
            (path / name).write_bytes(b"x")
        run.record("checkpoint.pt", "trial_*_particles.png", "records.json")


def test_new_run_refuses_a_folder_with_another_run(tmp_path):
    _finished_run(tmp_path)
    with pytest.raises(ValueError, match="holds another run .*--resume.*--overwrite"):
        open_run_folder(tmp_path)
    assert (tmp_path / "checkpoint.pt").read_bytes() == b"x"  # nothing was touched


def test_legacy_run_without_manifest_is_recognised(tmp_path):
    (tmp_path / "checkpoint.pt").write_bytes(b"x")
    with pytest.raises(ValueError, match="holds another run"):
        open_run_folder(tmp_path)


def test_overwrite_deletes_the_old_runs_files_only(tmp_path):
    _finished_run(tmp_path)
    (tmp_path / "notes.txt").write_text("mine")
    with open_run_folder(tmp_path, overwrite=True) as run:
        assert run.files == [MANIFEST_NAME, LOCK_NAME]
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == [MANIFEST_NAME, "notes.txt", LOCK_NAME]


def test_resume_keeps_and_extends_the_manifest(tmp_path):
    _finished_run(tmp_path)
    with open_run_folder(tmp_path, resume=True) as run:
        (tmp_path / "run.rrd").write_bytes(b"y")
        run.record("run.rrd")
    files = json.loads((tmp_path / MANIFEST_NAME).read_text())["files"]
    assert files == sorted(
        [
            "checkpoint.pt",
            LOCK_NAME,
            MANIFEST_NAME,
            "records.json",
            "run.rrd",
            "trial_01_particles.png",
        ]
    )


def test_bad_folders_and_flags_are_clear_errors(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match="is a file"):
        open_run_folder(tmp_path / "file")
    with pytest.raises(ValueError, match="exclude each other"):
        open_run_folder(tmp_path / "a", resume=True, overwrite=True)


def test_second_process_fails_at_once_and_a_kill_releases_the_lock(tmp_path):
    holder = subprocess.Popen(
        [sys.executable, "-c", _HOLDER, str(tmp_path)], stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout.readline().strip() == "locked"
        t0 = time.perf_counter()
        with pytest.raises(RunFolderBusyError, match=f"in use by process {holder.pid}"):
            open_run_folder(tmp_path, resume=True)
        assert time.perf_counter() - t0 < 1.0  # fails at once, does not wait
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    with open_run_folder(tmp_path, resume=True):  # the kernel released the killed lock
        pass


def test_manifest_lists_every_file_an_mcpilco_run_writes(tmp_path):
    from mcpilco.agents.mc_pilco import run_mcpilco
    from tests.agents.mc_pilco.test_trainer import SMOKE

    cfg = dataclasses.replace(SMOKE, num_trials=0)
    run_mcpilco(cfg, tmp_path, progress=False, log=None)
    listed = json.loads((tmp_path / MANIFEST_NAME).read_text())["files"]
    on_disk = sorted(p.name for p in tmp_path.iterdir())
    assert listed == on_disk
    assert {"checkpoint.pt", "records.json", "run.rrd"} <= set(listed)
    with pytest.raises(ValueError, match="holds another run"):
        run_mcpilco(cfg, tmp_path, progress=False, log=None)
    again = run_mcpilco(cfg, tmp_path, progress=False, log=None, overwrite=True)
    assert len(again.records) == 1

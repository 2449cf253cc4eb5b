"""The sweep runner: result files, resume, failures, the argparse helper, kill and resume on
the local backend and on a local Ray instance."""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mcpilco.experiments.infra.probe import probe_jobs, sleep_job
from mcpilco.experiments.infra.sweep import (
    InProcessBackend,
    Job,
    LocalBackend,
    SweepError,
    SweepRunner,
    add_sweep_arguments,
    backend_from_args,
    error_path,
    result_path,
)


def _expected(n: int) -> dict[str, dict]:
    return {f"probe{i}": {"index": i, "square": i * i} for i in range(n)}


def _results(folder: Path) -> dict[str, dict]:
    return {p.stem: json.loads(p.read_text())["result"] for p in sorted(folder.glob("*.json"))}


def test_one_file_per_job_and_a_second_run_reuses_them(tmp_path):
    runner = SweepRunner(InProcessBackend(), progress=False, log=None)
    jobs = probe_jobs(4, 0.0)
    first = runner.run(jobs, tmp_path)
    assert first.ran == [f"probe{i}" for i in range(4)] and not first.skipped
    assert first.results == _expected(4) == _results(tmp_path)
    record = json.loads(result_path(tmp_path, "probe2").read_text())
    assert record["function"] == "mcpilco.experiments.infra.probe:sleep_job"
    assert record["kwargs"] == {"index": 2, "seconds": 0.0, "fail": False}
    assert record["threads"] == record["cpus"] == 1
    assert not list(tmp_path.glob(".*.tmp"))  # no temporary file left behind
    stamps = {p.name: p.stat().st_mtime_ns for p in tmp_path.glob("*.json")}

    again = runner.run(jobs, tmp_path)
    assert again.ran == [] and again.skipped == [j.key for j in jobs]
    assert again.results == first.results
    assert {p.name: p.stat().st_mtime_ns for p in tmp_path.glob("*.json")} == stamps

    # a job whose arguments changed is rerun; the others are reused
    changed = [*jobs[:3], Job("probe3", sleep_job, {"index": 30, "seconds": 0.0})]
    third = runner.run(changed, tmp_path)
    assert third.ran == ["probe3"] and third.results["probe3"] == {"index": 30, "square": 900}
    assert runner.run(jobs, tmp_path, rerun=True).ran == [j.key for j in jobs]


def test_a_failing_job_is_recorded_and_the_sweep_goes_on(tmp_path):
    messages: list[str] = []
    runner = SweepRunner(InProcessBackend(), progress=False, log=messages.append)
    report = runner.run(probe_jobs(4, 0.0, fail=(1,)), tmp_path)
    assert report.ran == ["probe0", "probe2", "probe3"] and report.exit_code == 1
    (failure,) = report.failed
    assert failure.key == "probe1" and failure.kwargs["fail"] is True
    assert "ValueError: probe job 1 fails on purpose" in failure.error
    text = error_path(tmp_path, "probe1").read_text()
    assert '"fail": true' in text and "Traceback" in text and "sleep_job" in text
    assert not result_path(tmp_path, "probe1").exists()
    assert any("FAILED probe1" in m for m in messages)
    assert "FAILED probe1" in report.summary() and "probe1.error.txt" in report.summary()

    fixed = runner.run(probe_jobs(4, 0.0), tmp_path)  # the failed job alone reruns
    assert fixed.ran == ["probe1"] and fixed.exit_code == 0
    assert not error_path(tmp_path, "probe1").exists()
    assert fixed.results == _expected(4)


def test_local_processes_set_the_threads_keep_the_cpus_and_report_failures(tmp_path):
    jobs = [
        Job("t/one", sleep_job, {"index": 1, "seconds": 0.3}, cpus=1),
        Job("t/two", sleep_job, {"index": 2, "seconds": 0.3}, cpus=2, threads=3),
        Job("t/three", sleep_job, {"index": 3, "seconds": 0.3}, cpus=1),
        Job("t/bad", sleep_job, {"index": 4, "seconds": 0.0, "fail": True}),
    ]
    report = SweepRunner(LocalBackend(2), progress=False, log=None).run(jobs, tmp_path)
    assert sorted(report.ran) == ["t/one", "t/three", "t/two"]
    assert [f.key for f in report.failed] == ["t/bad"]
    assert (tmp_path / "t" / "bad.error.txt").is_file()
    rec = {k: json.loads((tmp_path / f"{k}.json").read_text()) for k in report.ran}
    assert rec["t/two"]["threads"] == 3 and rec["t/two"]["pid"] != os.getpid()
    # the 2-CPU job ran alone: no other job's time overlaps it on the 2 CPUs
    two = rec["t/two"]
    for key in ("t/one", "t/three"):
        assert rec[key]["end"] <= two["start"] or rec[key]["start"] >= two["end"], key


def test_jobs_are_checked():
    with pytest.raises(SweepError, match="job key"):
        Job("../up", sleep_job)
    with pytest.raises(SweepError, match="module-level"):
        Job("x", lambda: 1)
    with pytest.raises(SweepError, match="duplicate"):
        SweepRunner(progress=False).run([Job("a", sleep_job), Job("a", sleep_job)], "unused")


def test_the_argparse_helper_picks_the_backend():
    p = argparse.ArgumentParser()
    add_sweep_arguments(p)
    assert isinstance(backend_from_args(p.parse_args([])), InProcessBackend)
    local = backend_from_args(p.parse_args(["--jobs", "3"]))
    assert isinstance(local, LocalBackend) and local.workers == 3
    with pytest.raises(SweepError, match="--jobs"):
        backend_from_args(p.parse_args(["--jobs", "0"]))
    args = p.parse_args(["--ray", "--jobs", "2"])
    assert args.ray == "local" and args.jobs == 2
    assert p.parse_args(["--ray", "10.1.2.3:6379"]).ray == "10.1.2.3:6379"


def _kill_and_resume(tmp_path: Path, backend: list[str], n: int = 8, seconds: float = 1.0):
    """Start a probe sweep in a subprocess, SIGKILL its process group once 3 results are
    written, resume it; returns (files at the kill, their mtimes, the resumed run's stdout)."""
    out = tmp_path / "sweep"
    cmd = [
        sys.executable,
        "-m",
        "mcpilco.experiments.infra.probe",
        "--out",
        str(out),
        "--n",
        str(n),
    ]
    cmd += ["--seconds", str(seconds), "--no-progress", *backend]
    proc = subprocess.Popen(
        cmd, start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    deadline = time.monotonic() + 180
    try:
        while len(list(out.glob("*.json"))) < 3 and time.monotonic() < deadline:
            assert proc.poll() is None, proc.stdout.read()
            time.sleep(0.02)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    done = {p.name: p.stat().st_mtime_ns for p in out.glob("*.json")}
    assert 3 <= len(done) < n, "the sweep should be killed halfway"
    for p in out.glob("*.json"):  # every file present is whole (written atomically)
        json.loads(p.read_text())
    resumed = subprocess.run(cmd, capture_output=True, text=True, timeout=240)
    assert resumed.returncode == 0, resumed.stdout + resumed.stderr
    return out, done, resumed.stdout


def test_local_sweep_killed_halfway_resumes_the_rest(tmp_path):
    out, done, stdout = _kill_and_resume(tmp_path, ["--jobs", "2"])
    # only the jobs without a result reran; the finished ones were left untouched
    assert f"{8 - len(done)} ran, {len(done)} reused, 0 failed" in stdout
    assert {p: (out / p).stat().st_mtime_ns for p in done} == done
    assert _results(out) == _expected(8)


def test_local_workers_exit_when_the_sweep_process_is_killed(tmp_path):
    """SIGKILL of the sweep process alone (not its group): its workers, each in a 60 s job,
    are gone within seconds instead of running their jobs to the end unseen."""
    out = tmp_path / "sweep"
    cmd = [sys.executable, "-m", "mcpilco.experiments.infra.probe", "--out", str(out), "--n", "2"]
    cmd += ["--seconds", "60", "--no-progress", "--jobs", "2"]
    proc = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        workers: list[int] = []
        while len(workers) < 2 and time.monotonic() < deadline:
            ps = subprocess.run(
                ["ps", "-o", "pid=", "--ppid", str(proc.pid)], capture_output=True, text=True
            )
            workers = [int(p) for p in ps.stdout.split()]
            time.sleep(0.2)
        assert len(workers) >= 2, "the sweep should have started its workers"
        time.sleep(3)  # the workers have imported the job and sleep in it
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        deadline = time.monotonic() + 15
        alive = workers
        while alive and time.monotonic() < deadline:
            alive = [p for p in alive if _running(p)]
            time.sleep(0.2)
        assert not alive, f"workers {alive} outlived the sweep process"
        assert not list(out.glob("*.json"))
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


def _running(pid: int) -> bool:
    """Whether ``pid`` is a live process (not a zombie awaiting its reaper)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.slow  # 50-65 s on 2 busy cores: two local Ray starts (6-9 s each), the sweeps
def test_ray_sweep_killed_halfway_resumes_to_the_local_results(tmp_path):
    """A local Ray instance of 2 CPUs on 127.0.0.1, started by the sweep subprocess."""
    pytest.importorskip("ray")
    out, done, stdout = _kill_and_resume(tmp_path, ["--ray", "--jobs", "2"])
    assert "ray, local, 2 CPUs" in stdout
    assert f"{8 - len(done)} ran, {len(done)} reused, 0 failed" in stdout
    assert {p: (out / p).stat().st_mtime_ns for p in done} == done
    local = SweepRunner(LocalBackend(2), progress=False, log=None).run(
        probe_jobs(8, 0.0), tmp_path / "local"
    )
    ray_records = {p.name: json.loads(p.read_text()) for p in out.glob("*.json")}
    assert sorted(ray_records) == sorted(p.name for p in (tmp_path / "local").glob("*.json"))
    assert _results(out) == local.results == _expected(8)
    assert {r["pid"] for r in ray_records.values()} != {os.getpid()}


def test_a_local_ray_instance_is_refused_where_it_would_not_be_loopback_only():
    """Ray imported before the runner set its environment would listen on every interface:
    the backend refuses to start it (and starts nothing)."""
    pytest.importorskip("ray")
    code = (
        "import ray\n"
        "from mcpilco.experiments.infra.sweep import RayBackend, SweepError\n"
        "try:\n"
        "    RayBackend(None, num_cpus=1).__enter__()\n"
        "except SweepError as err:\n"
        "    print('refused:', err, ray.is_initialized())\n"
    )
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAY_")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert "refused: a local Ray instance would take the routable address" in out.stdout, out
    assert out.stdout.strip().endswith("False")

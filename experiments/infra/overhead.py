"""Overhead per job of the sweep runner's backends, measured with probe jobs of known cost.

The same sweep (``n`` probe jobs of ``seconds`` each, one CPU each) runs on each backend with
the same CPUs; the ideal wall time is ``ceil(n / cpus) * seconds``. Reported per backend and
job kind (:data:`~mcpilco.experiments.infra.probe.KINDS`):

``wall_s``
    the whole :meth:`~mcpilco.experiments.infra.sweep.SweepRunner.run` call: backend start (worker
    processes or the Ray instance), the jobs, result files, shutdown.
``startup_s``
    from the call to the start of the first job (worker start, imports, Ray start).
``overhead_per_job_s``
    ``(wall_s - ideal_s) * cpus / n``: what each job adds to the wall time of a CPU slot,
    startup included.
``workers_up_s``
    from the call to the first job of the last worker to start (every CPU busy from then).
``shutdown_s``
    from the end of the last job to the end of the call (last result file, shutdown).
``dispatch_gap_s``
    mean time between the end of a job and the start of the next one in the same worker
    process: the steady-state cost per job (result transfer, result file, next submission).
``job_wall_s``
    mean wall time of a job as the worker measured it (``spin``: its CPU work, which slows
    down when other processes share the cores).
``load_1min``
    the machine's 1-minute load average around the sweep, to read the figures against.
"""

from __future__ import annotations

import json
import math
import os
import platform
import statistics
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from mcpilco.experiments.infra.probe import probe_jobs, spin_rounds
from mcpilco.experiments.infra.sweep import (
    InProcessBackend,
    LocalBackend,
    RayBackend,
    SweepRunner,
    result_path,
)
from mcpilco.experiments.results import Headline, Result, ResultLayout, write_result

BACKENDS = ("local", "ray")
"""Backends the overhead benchmark can compare."""


def make_backend(name: str, cpus: int) -> Any:
    """``local``: ``cpus`` spawned processes (in-process for 1); ``ray``: a local Ray
    instance with ``cpus`` CPUs."""
    if name == "local":
        return LocalBackend(cpus) if cpus > 1 else InProcessBackend()
    if name == "ray":
        return RayBackend(None, num_cpus=cpus)
    raise ValueError(f"backend must be one of {BACKENDS}, got {name!r}")


def measure_sweep(
    backend: str, kind: str, n: int, seconds: float, cpus: int, rounds: int = 0
) -> dict[str, Any]:
    """Run one probe sweep in a fresh temporary folder and time it (see the module doc)."""
    jobs = probe_jobs(n, seconds, kind, rounds=rounds)
    runner = SweepRunner(make_backend(backend, cpus), progress=False, log=None)
    with tempfile.TemporaryDirectory(prefix="sweep-overhead-") as tmp:
        load_before = os.getloadavg()[0]
        t_start = time.time()
        report = runner.run(jobs, tmp)
        t_end = time.time()
        load_after = os.getloadavg()[0]
        records = [_read(result_path(Path(tmp), j.key)) for j in jobs]
    if report.failed:
        raise RuntimeError(report.summary())
    ideal = math.ceil(n / cpus) * seconds
    by_pid: dict[int, list[dict[str, Any]]] = {}
    for rec in records:
        by_pid.setdefault(rec["pid"], []).append(rec)
    gaps = [
        b["start"] - a["end"]
        for recs in by_pid.values()
        for a, b in zip(
            sorted(recs, key=lambda r: r["start"]),
            sorted(recs, key=lambda r: r["start"])[1:],
            strict=False,
        )
    ]
    return {
        "backend": backend,
        "backend_name": report.backend,
        "kind": kind,
        "jobs": n,
        "cpus": cpus,
        "seconds_per_job": seconds,
        "ideal_s": ideal,
        "wall_s": report.wall_s,
        "startup_s": min(r["start"] for r in records) - t_start,
        "workers_up_s": max(min(r["start"] for r in recs) for recs in by_pid.values()) - t_start,
        "shutdown_s": t_end - max(r["end"] for r in records),
        "overhead_per_job_s": (report.wall_s - ideal) * cpus / n,
        "dispatch_gap_s": statistics.mean(gaps) if gaps else None,
        "job_wall_s": statistics.mean(r["wall_s"] for r in records),
        "worker_processes": len(by_pid),
        "load_1min": (load_before + load_after) / 2,
    }


def _read(path: Path) -> dict[str, Any]:

    return json.loads(path.read_text())


def measure(
    backends: Sequence[str] = BACKENDS,
    kinds: Sequence[str] = ("sleep", "spin"),
    n: int = 8,
    seconds: float = 1.0,
    cpus: int = 2,
    repeats: int = 2,
) -> dict[str, Any]:
    """:func:`measure_sweep` for every backend and kind, ``repeats`` times each (backends
    alternate within a repeat, so that a busy machine affects them alike)."""
    rounds = spin_rounds(seconds)
    rows = []
    for rep in range(repeats):
        for kind in kinds:
            for backend in backends:
                row = measure_sweep(backend, kind, n, seconds, cpus, rounds=rounds)
                row["repeat"] = rep
                rows.append(row)
    return {
        "machine": f"{platform.machine()}, {platform.python_version()}",
        "jobs": n,
        "cpus": cpus,
        "seconds_per_job": seconds,
        "spin_rounds": rounds,
        "runs": rows,
        "summary": summarise(rows),
    }


def summarise(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Median over repeats per (backend, kind)."""
    out = []
    keys = sorted({(r["backend"], r["kind"]) for r in rows}, key=lambda k: (k[1], k[0]))
    for backend, kind in keys:
        sel = [r for r in rows if r["backend"] == backend and r["kind"] == kind]
        row = {"backend": backend, "kind": kind, "repeats": len(sel)}
        fields = (
            "wall_s",
            "startup_s",
            "workers_up_s",
            "shutdown_s",
            "overhead_per_job_s",
            "dispatch_gap_s",
            "job_wall_s",
        )
        for field in (*fields, "load_1min"):
            vals = [r[field] for r in sel if r[field] is not None]
            row[field] = statistics.median(vals) if vals else None
        row["ideal_s"] = sel[0]["ideal_s"]
        out.append(row)
    return out


def markdown(result: dict[str, Any], command: str) -> str:
    """The summary table of :func:`measure` with its protocol."""

    def f(v: float | None, digits: int = 2) -> str:
        return "-" if v is None else f"{v:.{digits}f}"

    lines = [
        "# Sweep runner overhead",
        "",
        f"`{command}`: {result['jobs']} jobs of {result['seconds_per_job']:g} s on "
        f"{result['cpus']} CPUs (ideal wall time {result['summary'][0]['ideal_s']:g} s), "
        f"median of {result['summary'][0]['repeats']} sweeps per row; machine "
        f"{result['machine']}. `sleep` jobs wait, `spin` jobs do a fixed amount of CPU work "
        f"({result['spin_rounds']} SHA-256 rounds, calibrated to the job time on one idle core). "
        "Each sweep starts its backend (spawned processes, or a local Ray instance on "
        "127.0.0.1) and shuts it down, as a benchmark script does.",
        "",
        "| jobs | backend | wall s | first job starts s | all workers up s | shutdown s "
        "| overhead per job s | dispatch gap s | job wall s | load |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in result["summary"]:
        lines.append(
            f"| {r['kind']} | {r['backend']} | {f(r['wall_s'])} | {f(r['startup_s'])} | "
            f"{f(r['workers_up_s'])} | {f(r['shutdown_s'])} | {f(r['overhead_per_job_s'])} | "
            f"{f(r['dispatch_gap_s'], 3)} | {f(r['job_wall_s'])} | "
            f"{f(r['load_1min'], 1)} |"
        )
    lines += [
        "",
        "overhead per job = (wall - ideal) x CPUs / jobs, startup included (the backend's "
        "start and each worker's first import of torch); dispatch gap = "
        "mean time between the end of a job and the start of the next one in the same "
        "worker (steady state); load = the machine's 1-minute load average during the sweeps "
        f"(other processes included; {result['cpus']} = the backend's CPUs busy). Where it "
        "exceeds the CPUs, the jobs share the cores with other work and the figures grow.",
    ]
    return "\n".join(lines) + "\n"


def write_report(result: dict[str, Any], out_dir: Path) -> str:
    """``sweep_overhead.json`` (``result``) and ``sweep_overhead.md`` (:func:`markdown` of
    ``result["command"]``) in ``out_dir``; returns the Markdown."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    write_result(out_dir / "sweep_overhead.json", RESULT_LAYOUTS[0], result)
    text = markdown(result, result["command"])
    (out_dir / "sweep_overhead.md").write_text(text)
    return text


# -- result file and headline rows of the results index -----------------------------------

RESULT_LAYOUTS = (
    ResultLayout(
        "sweep_overhead", config=("jobs", "cpus", "seconds_per_job", "spin_rounds"), cases=("runs",)
    ),
)
"""The layout of ``sweep_overhead.json`` (:mod:`mcpilco.experiments.results`)."""


def _sweep_row(r: Result) -> str:
    by: dict[str, list[dict[str, Any]]] = {}
    for s in r["summary"]:
        by.setdefault(s["backend"], []).append(s)
    parts = []
    for backend, rows in by.items():
        start = [x["startup_s"] for x in rows]
        gap = [x["dispatch_gap_s"] for x in rows]
        parts.append(
            f"{backend}: start {min(start):.0f}-{max(start):.0f} s, "
            f"{1e3 * min(gap):.0f}-{1e3 * max(gap):.0f} ms between jobs"
        )
    return "sweep runner overhead, " + "; ".join(parts)


HEADLINES = (
    Headline("Sweeps", "sweep_overhead.json", _sweep_row, "sweep_overhead.md", seeds=lambda r: "-"),
)
"""The sweep runner's row of the results index."""

"""Probe jobs of known cost, to check a sweep backend and measure its overhead.

:func:`sleep_job` waits a fixed time (no CPU), :func:`spin_job` does a fixed amount of CPU
work; both return a value that depends on their arguments only, so that two sweeps of the
same jobs on any backends write the same results. :func:`probe_jobs` builds a sweep of them.

Command line (a smoke test of a backend, e.g. a Ray cluster)::

    python -m mcpilco.experiments.infra.probe --out runs/probe --n 8 --seconds 1 --jobs 2
    python -m mcpilco.experiments.infra.probe --out runs/probe --n 8 --seconds 1 --ray auto
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import time
from typing import Any

from mcpilco.experiments.infra.sweep import Job, SweepError, add_sweep_arguments, runner_from_args

KINDS = ("sleep", "spin")
"""Probe job kinds: waiting (no CPU) and CPU work."""

SPIN_BLOCK = 4096
"""Hash rounds between two clock reads of the calibration of :func:`spin_rounds`."""


def _checksum(index: int, rounds: int) -> str:
    """SHA-256 chain of ``rounds`` rounds from ``index``: the fixed CPU work of a spin job."""
    digest = index.to_bytes(8, "little")
    for _ in range(rounds):
        digest = hashlib.sha256(digest).digest()
    return digest.hex()[:16]


def spin_rounds(seconds: float) -> int:
    """Hash rounds of :func:`_checksum` that take about ``seconds`` of CPU on this machine."""
    n, t0 = 0, time.process_time()
    while time.process_time() - t0 < 0.2:
        _checksum(0, SPIN_BLOCK)
        n += SPIN_BLOCK
    return max(1, int(n * seconds / (time.process_time() - t0)))


def sleep_job(index: int, seconds: float, fail: bool = False) -> dict[str, Any]:
    """Wait ``seconds``; raise :class:`ValueError` when ``fail``."""
    time.sleep(seconds)
    if fail:
        raise ValueError(f"probe job {index} fails on purpose")
    return {"index": index, "square": index * index}


def spin_job(index: int, rounds: int, fail: bool = False) -> dict[str, Any]:
    """``rounds`` SHA-256 rounds (one core); raise :class:`ValueError` when ``fail``."""
    checksum = _checksum(index, rounds)
    if fail:
        raise ValueError(f"probe job {index} fails on purpose")
    return {"index": index, "checksum": checksum}


def probe_jobs(
    n: int, seconds: float, kind: str = "sleep", fail: tuple[int, ...] = (), rounds: int = 0
) -> list[Job]:
    """``n`` probe jobs ``probe<i>`` of ``seconds`` each (``spin``: ``rounds`` hash rounds,
    :func:`spin_rounds` of ``seconds`` when 0); the indices in ``fail`` raise."""
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    if kind == "sleep":
        return [
            Job(f"probe{i}", sleep_job, {"index": i, "seconds": seconds, "fail": i in fail})
            for i in range(n)
        ]
    rounds = rounds or spin_rounds(seconds)
    return [
        Job(f"probe{i}", spin_job, {"index": i, "rounds": rounds, "fail": i in fail})
        for i in range(n)
    ]


def main(argv: list[str] | None = None) -> int:
    """Run a probe sweep into ``--out``; exit code 1 when a job failed."""
    p = argparse.ArgumentParser(
        prog="python -m mcpilco.experiments.infra.probe", description=__doc__
    )
    p.add_argument("--out", required=True, help="results folder of the sweep")
    p.add_argument("--n", type=int, default=8, help="number of jobs")
    p.add_argument("--seconds", type=float, default=1.0, help="seconds per job")
    p.add_argument("--kind", choices=KINDS, default="sleep")
    p.add_argument("--rounds", type=int, default=0, help="spin: hash rounds (0: calibrate)")
    p.add_argument("--fail", type=int, nargs="*", default=[], help="indices of jobs that raise")
    p.add_argument("--no-progress", action="store_true")
    add_sweep_arguments(p)
    args = p.parse_args(argv)
    try:
        runner = runner_from_args(args, progress=not args.no_progress)
        jobs = probe_jobs(args.n, args.seconds, args.kind, tuple(args.fail), args.rounds)
    except (SweepError, ValueError) as err:
        p.error(str(err))
    report = runner.run(jobs, args.out, desc="probe")
    print(report.summary())
    return report.exit_code


if __name__ == "__main__":
    sys.exit(main())

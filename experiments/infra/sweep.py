"""Resumable sweep runner: independent jobs in local processes or on Ray, one file per job.

A *job* (:class:`Job`) is a module-level function, its keyword arguments and a unique
``key``; it returns a JSON-serialisable value. :meth:`SweepRunner.run` runs a list of jobs and
writes each finished job's value to ``<results_dir>/<key>.json`` (atomically: a temporary
file in the same folder, then a rename), so that a sweep killed at any point loses at most
the jobs in flight. Running the same sweep again skips every job whose result file exists
and was written for the same function and arguments (a file written for other arguments is
rerun and replaced). A job that raises is recorded in ``<key>.error.txt`` (its arguments and
traceback); the sweep goes on, and :class:`SweepReport` lists the failed jobs.

Backends:

* in-process (``--jobs 1``, the default): the jobs run one after the other in the calling
  process;
* local processes (``--jobs N``): a :class:`~concurrent.futures.ProcessPoolExecutor` with
  ``N`` spawned workers, at most ``N`` jobs in flight;
* Ray (``--ray``: a local Ray instance bound to 127.0.0.1 with ``--jobs`` CPUs, all CPUs when
  ``--jobs`` is not given; ``--ray ADDRESS``: an existing cluster, e.g. ``auto`` or
  ``10.0.0.5:6379``). Ray is the optional extra ``mcpilco[cluster]``; each job is a Ray task
  reserving ``Job.cpus`` CPUs. The result files are written by the driver, so the cluster's
  nodes need no shared file system for them.

In every backend, each job runs with its thread count set explicitly (``Job.threads``,
default ``Job.cpus``): :func:`torch.set_num_threads` and a :mod:`threadpoolctl` limit of the
BLAS / OpenMP pools, both restored afterwards.

Scripts get the options from one helper::

    parser = argparse.ArgumentParser()
    add_sweep_arguments(parser)               # --jobs N, --ray [ADDRESS]
    args = parser.parse_args()
    runner = runner_from_args(args)
    report = runner.run(jobs, results_dir)
    print(report.summary())
    return report.exit_code
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import json
import os
import re
import socket
import sys
import time
import traceback
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any, Protocol

from mcpilco.models.files import write_atomic

LOCAL_RAY = "local"
"""Value of ``--ray`` without an address: start a local Ray instance (loopback only)."""

LOOPBACK = "127.0.0.1"
"""Address a local Ray instance binds to."""

RESULT_SUFFIX = ".json"
"""Suffix of a job's result file, ``<key>.json``."""

ERROR_SUFFIX = ".error.txt"
"""Suffix of a failed job's report (arguments and traceback), ``<key>.error.txt``."""

_KEY_PATTERN = re.compile(r"[A-Za-z0-9_.=+,-]+(/[A-Za-z0-9_.=+,-]+)*")
"""Allowed job keys: path components of letters, digits and ``_.=+,-`` (no ``..``)."""


class SweepError(RuntimeError):
    """A sweep cannot start (bad jobs, a backend that is not available)."""


# ------------------------------------------------------------------------------ jobs
@dataclasses.dataclass(frozen=True)
class Job:
    """One independent unit of work of a sweep.

    Attributes:
        key: unique name of the job in its sweep, also the result file's name
            (``<results_dir>/<key>.json``); letters, digits, ``_.=+,-`` and ``/`` between
            components (sub-folders).
        fn: a module-level function (picklable by reference) returning a JSON-serialisable
            value (dicts, lists, numbers, strings; numpy scalars and arrays are converted).
        kwargs: its keyword arguments; picklable, and with a JSON form (recorded in the
            result file and compared when the sweep resumes).
        cpus: CPUs the job uses (a Ray task reserves them).
        threads: torch / BLAS threads set in the worker before the job runs (default
            ``cpus``).
    """

    key: str
    fn: Callable[..., Any]
    kwargs: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    cpus: int = 1
    threads: int | None = None

    def __post_init__(self) -> None:
        if not _KEY_PATTERN.fullmatch(self.key) or ".." in self.key.split("/"):
            raise SweepError(
                f"job key {self.key!r}: use letters, digits, '_.=+,-' and '/' between parts"
            )
        if self.cpus < 1 or (self.threads is not None and self.threads < 1):
            raise SweepError(f"job {self.key}: cpus and threads must be >= 1")
        if "<locals>" in getattr(self.fn, "__qualname__", "<locals>"):
            raise SweepError(f"job {self.key}: fn must be a module-level function")

    @property
    def function(self) -> str:
        """``module:qualname`` of :attr:`fn` (the module's import name also when it runs as
        ``__main__`` under ``python -m``)."""
        module = self.fn.__module__
        if module == "__main__":
            spec = getattr(sys.modules["__main__"], "__spec__", None)
            module = spec.name if spec is not None else module
        return f"{module}:{self.fn.__qualname__}"

    @property
    def thread_count(self) -> int:
        """Threads the job runs with."""
        return self.threads or self.cpus

    def describe(self) -> str:
        """One line: key, function and arguments."""
        args = ", ".join(f"{k}={v!r}" for k, v in self.kwargs.items())
        if len(args) > 300:
            args = args[:297] + "..."
        return f"{self.key}: {self.function}({args})"


@dataclasses.dataclass(frozen=True)
class JobFailure:
    """A job that raised (or whose worker died); ``error_path`` holds its traceback."""

    key: str
    function: str
    kwargs: dict[str, Any]
    error: str
    error_path: Path


@dataclasses.dataclass
class SweepReport:
    """Outcome of :meth:`SweepRunner.run`.

    Attributes:
        results: job key -> value, for every job that has a result (run now or found on
            disk), in the order of the job list; values are as read back from the JSON file.
        ran: keys of the jobs run by this call that succeeded.
        skipped: keys of the jobs whose result file was reused.
        failed: the jobs that failed in this call.
        wall_s: wall-clock seconds of the call.
        backend: description of the backend.
    """

    results: dict[str, Any]
    ran: list[str]
    skipped: list[str]
    failed: list[JobFailure]
    wall_s: float
    backend: str

    @property
    def exit_code(self) -> int:
        """Process exit code of a script whose sweep this was: 1 when a job failed, else 0."""
        return 1 if self.failed else 0

    def summary(self) -> str:
        """Counts, then one line per failed job with its arguments and traceback file."""
        lines = [
            f"sweep ({self.backend}): {len(self.ran)} ran, {len(self.skipped)} reused, "
            f"{len(self.failed)} failed in {self.wall_s:.1f} s"
        ]
        for f in self.failed:
            args = json.dumps(f.kwargs, default=str)
            if len(args) > 300:
                args = args[:297] + "..."
            lines.append(f"  FAILED {f.key}: {f.error}")
            lines.append(f"    {f.function} {args}\n    traceback: {f.error_path}")
        return "\n".join(lines)


# ------------------------------------------------------------------------- result files
def to_json_value(obj: Any) -> Any:
    """``json.dumps`` fallback: numpy scalars and arrays, paths; else :class:`TypeError`."""
    if hasattr(obj, "tolist") and type(obj).__module__ == "numpy":
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, set | frozenset):
        return sorted(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def _json_form(obj: Any) -> Any:
    """``obj`` as it reads back from JSON (anything without a JSON form as its ``str``)."""

    def fallback(o: Any) -> Any:
        try:
            return to_json_value(o)
        except TypeError:
            return str(o)

    return json.loads(json.dumps(obj, default=fallback))


def result_path(results_dir: Path, key: str) -> Path:
    """Where the result of job ``key`` is written."""
    return Path(results_dir) / f"{key}{RESULT_SUFFIX}"


def error_path(results_dir: Path, key: str) -> Path:
    """Where the traceback of a failed job ``key`` is written."""
    return Path(results_dir) / f"{key}{ERROR_SUFFIX}"


def load_result(results_dir: Path, job: Job) -> dict[str, Any] | None:
    """The result record of ``job`` if its file exists, reads and was written for the same
    function and arguments; else None."""
    path = result_path(results_dir, job.key)
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    same = record.get("function") == job.function and record.get("kwargs") == _json_form(
        dict(job.kwargs)
    )
    return record if same else None


# ------------------------------------------------------------------------------ workers
def _set_torch_threads(threads: int) -> int | None:
    """Set torch's intra-op threads; returns the previous count (None without torch)."""
    try:
        import torch
    except ImportError:  # pragma: no cover - torch is a dependency
        return None
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    return before


def execute(fn: Callable[..., Any], kwargs: Mapping[str, Any], threads: int) -> dict[str, Any]:
    """Run one job in the current process with ``threads`` torch / BLAS threads.

    Never raises for the job's own errors: returns ``{"ok": True, "value", ...}`` or
    ``{"ok": False, "error", "traceback", ...}``, with the host, process id, start and end
    times (``time.time``), wall and CPU seconds.
    """
    from threadpoolctl import threadpool_limits

    before = _set_torch_threads(threads)  # imports torch: a new worker's first job waits here
    start, t0, c0 = time.time(), time.perf_counter(), time.process_time()
    out: dict[str, Any] = {"host": socket.gethostname(), "pid": os.getpid(), "start": start}
    try:
        with threadpool_limits(limits=threads):
            value = fn(**kwargs)
        out.update(ok=True, value=json.loads(json.dumps(value, default=to_json_value)))
    except Exception as err:  # noqa: BLE001  (reported per job; the sweep goes on)
        out.update(ok=False, error=f"{type(err).__name__}: {err}", traceback=traceback.format_exc())
    finally:
        if before is not None:
            _set_torch_threads(before)
    out.update(end=time.time(), wall_s=time.perf_counter() - t0, cpu_s=time.process_time() - c0)
    return out


# ----------------------------------------------------------------------------- backends
class Backend(Protocol):
    """Runs jobs and yields ``(index, payload of execute)`` as they finish."""

    name: str

    def slots(self) -> int:
        """Jobs that can run at once (CPUs of a Ray cluster)."""
        ...

    def __enter__(self) -> Backend: ...

    def __exit__(self, *exc: object) -> None: ...

    def map_unordered(self, jobs: Sequence[Job]) -> Iterator[tuple[int, dict[str, Any]]]: ...


def _died(err: BaseException) -> dict[str, Any]:
    """Payload of a job whose worker process died."""
    return {
        "ok": False,
        "error": f"{type(err).__name__}: the worker process died while the job ran "
        "(killed, out of memory or crashed); this may be the job or another one in flight",
        "traceback": "".join(traceback.format_exception(err)),
    }


class InProcessBackend:
    """The jobs one after the other in the calling process."""

    name = "in-process"

    def slots(self) -> int:
        return 1

    def __enter__(self) -> InProcessBackend:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def map_unordered(self, jobs: Sequence[Job]) -> Iterator[tuple[int, dict[str, Any]]]:
        for i, job in enumerate(jobs):
            yield i, execute(job.fn, job.kwargs, job.thread_count)


PARENT_POLL_S = 1.0  # seconds between a local worker's checks that the sweep still runs


def _watch_parent(parent: int) -> None:
    while os.getppid() == parent:
        time.sleep(PARENT_POLL_S)
    os._exit(1)  # the sweep's process is gone: the job in flight has no one to report to


def exit_with_parent(parent: int) -> None:
    """Initializer of a local worker: a daemon thread ends the worker within
    :data:`PARENT_POLL_S` once the sweep process ``parent`` is gone (killed with SIGTERM or
    SIGKILL, which runs no cleanup), instead of leaving it to finish its job unseen. The
    job's own checkpoints are what a rerun resumes from."""
    import threading

    threading.Thread(target=_watch_parent, args=(parent,), daemon=True).start()


class LocalBackend:
    """``workers`` spawned processes (CPUs); jobs in flight use at most ``workers`` CPUs
    together (``Job.cpus``; a job wider than that runs alone), so that a kill loses at most
    those. A worker that dies fails the jobs in flight and the pool is restarted; a worker
    whose sweep process is killed exits (:func:`exit_with_parent`)."""

    def __init__(self, workers: int) -> None:
        if workers < 1:
            raise SweepError(f"workers must be >= 1, got {workers}")
        self.workers = workers
        self.name = f"local, {workers} processes"

    def slots(self) -> int:
        return self.workers

    def __enter__(self) -> LocalBackend:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def _pool(self) -> ProcessPoolExecutor:
        import multiprocessing

        # spawned, not forked: a fork copies the parent's torch thread pools and CUDA state
        return ProcessPoolExecutor(
            self.workers,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=exit_with_parent,
            initargs=(os.getpid(),),
        )

    def _fits(self, job: Job, inflight: Mapping[Future, int], jobs: Sequence[Job]) -> bool:
        """Whether ``job`` can start next to the jobs in flight."""
        busy = sum(jobs[i].cpus for i in inflight.values())
        return not inflight or busy + job.cpus <= self.workers

    def map_unordered(self, jobs: Sequence[Job]) -> Iterator[tuple[int, dict[str, Any]]]:
        pending = collections.deque(range(len(jobs)))
        while pending:
            pool = self._pool()
            inflight: dict[Future, int] = {}
            broken = False
            try:
                while (pending and not broken) or inflight:
                    while pending and not broken and self._fits(jobs[pending[0]], inflight, jobs):
                        i = pending.popleft()
                        job = jobs[i]
                        fut = pool.submit(execute, job.fn, dict(job.kwargs), job.thread_count)
                        inflight[fut] = i
                    done, _ = wait(inflight, return_when=FIRST_COMPLETED)
                    for fut in done:
                        i = inflight.pop(fut)
                        try:
                            yield i, fut.result()
                        except BrokenProcessPool as err:
                            broken = True
                            yield i, _died(err)
            finally:
                # no wait for the idle workers' exit (seconds with torch loaded): the
                # interpreter joins them at its end
                pool.shutdown(wait=False, cancel_futures=True)


LOCAL_RAY_ENV = {"RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0", "RAY_USAGE_STATS_ENABLED": "0"}
"""Environment of a local Ray instance (set before ``ray`` is imported): a loopback node address
(the variable applies on Linux too) and no usage report."""


def import_ray(local: bool = False) -> Any:
    """The ``ray`` module, or a :class:`SweepError` saying how to install it. ``local``: set
    :data:`LOCAL_RAY_ENV` first (where the process has not imported Ray yet)."""
    if local and "ray" not in sys.modules:
        for name, value in LOCAL_RAY_ENV.items():
            os.environ.setdefault(name, value)
    try:
        import ray
    except ImportError as err:
        raise SweepError(
            "--ray needs Ray, an optional dependency: pip install 'mcpilco[cluster]' "
            "(or pip install 'ray>=2.9')"
        ) from err
    return ray


class RayBackend:
    """Ray tasks, each reserving ``Job.cpus`` CPUs.

    ``address`` None: a local Ray instance with ``num_cpus`` CPUs (all when None), bound to
    127.0.0.1, without dashboard and usage reporting, shut down at the end. Otherwise
    :func:`ray.init` connects to the cluster at ``address`` (``auto``, ``HOST:PORT`` or
    ``ray://HOST:PORT``). An already initialised Ray (e.g. by a test) is used as it is.
    """

    def __init__(self, address: str | None = None, num_cpus: int | None = None) -> None:
        self.address = address
        self.num_cpus = num_cpus
        where = f"cluster {address}" if address else f"local, {num_cpus or 'all'} CPUs"
        self.name = f"ray, {where}"
        self._owns = False

    def __enter__(self) -> RayBackend:
        ray = import_ray(local=self.address is None)
        if ray.is_initialized():
            return self
        if self.address is None:
            constants = getattr(getattr(ray, "_private", None), "ray_constants", None)
            if getattr(constants, "ENABLE_RAY_CLUSTER", False):  # imported without LOCAL_RAY_ENV
                raise SweepError(self._not_loopback("the routable address"))
            ctx = ray.init(
                num_cpus=self.num_cpus,
                include_dashboard=False,
                _node_ip_address=LOOPBACK,
                configure_logging=False,
                log_to_driver=True,
            )
            self._owns = True
            node_ip = ctx.address_info.get("node_ip_address")
            if node_ip != LOOPBACK:
                self.__exit__()
                raise SweepError(self._not_loopback(node_ip))
        else:
            ray.init(address=self.address, configure_logging=False, log_to_driver=True)
        self._owns = True
        return self

    @staticmethod
    def _not_loopback(address: str) -> str:
        return (
            f"a local Ray instance would take {address}, not {LOOPBACK}: ray was imported "
            "before the sweep runner set "
            f"{', '.join(f'{k}={v}' for k, v in LOCAL_RAY_ENV.items())}; set them in the "
            "environment, or let import_ray(local=True) import it"
        )

    def __exit__(self, *exc: object) -> None:
        if self._owns:
            import_ray().shutdown()
            self._owns = False

    def slots(self) -> int:
        ray = import_ray()
        if ray.is_initialized():
            return int(ray.cluster_resources().get("CPU", 0))
        return self.num_cpus or os.cpu_count() or 1

    def map_unordered(self, jobs: Sequence[Job]) -> Iterator[tuple[int, dict[str, Any]]]:
        ray = import_ray()
        remote = ray.remote(execute)
        refs = {
            remote.options(num_cpus=job.cpus, max_retries=0).remote(
                job.fn, dict(job.kwargs), job.thread_count
            ): i
            for i, job in enumerate(jobs)
        }
        try:
            while refs:
                done, _ = ray.wait(list(refs), num_returns=1)
                i = refs.pop(done[0])
                try:
                    payload = ray.get(done[0])
                except Exception as err:  # noqa: BLE001  (a worker that died, a lost node)
                    payload = _died(err)
                yield i, payload
        finally:
            for ref in refs:
                ray.cancel(ref, force=True)


# ------------------------------------------------------------------------------ runner
class SweepRunner:
    """Runs lists of :class:`Job` on a backend with resume, a progress bar and failure files.

    Args:
        backend: :class:`InProcessBackend`, :class:`LocalBackend` or :class:`RayBackend`.
        progress: a tqdm bar over the jobs (on stderr) with the estimated remaining time.
        log: where one-line messages go (failures, stale result files); None: silent.
    """

    def __init__(
        self,
        backend: Backend | None = None,
        progress: bool = True,
        log: Callable[[str], None] | None = None,
    ) -> None:
        self.backend = backend if backend is not None else InProcessBackend()
        self.progress = progress
        self.log = log

    @property
    def in_process(self) -> bool:
        """Whether the jobs run in the calling process (their own output is then visible)."""
        return isinstance(self.backend, InProcessBackend)

    def slots(self) -> int:
        """Jobs that run at once."""
        return self.backend.slots()

    def run(
        self,
        jobs: Sequence[Job],
        results_dir: str | Path,
        *,
        rerun: bool = False,
        desc: str = "jobs",
    ) -> SweepReport:
        """Run the jobs that have no result yet (all with ``rerun``); write one result file
        per finished job as it finishes and one ``.error.txt`` per failed job.

        Raises:
            SweepError: duplicate keys, or a backend that cannot start.
        """
        from tqdm.auto import tqdm

        t0 = time.perf_counter()
        results_dir = Path(results_dir)
        keys = [j.key for j in jobs]
        dupes = sorted({k for k in keys if keys.count(k) > 1})
        if dupes:
            raise SweepError(f"duplicate job keys: {dupes}")
        found: dict[str, Any] = {}
        todo: list[Job] = []
        for job in jobs:
            record = None if rerun else load_result(results_dir, job)
            if record is not None:
                found[job.key] = record["result"]
                continue
            if not rerun and result_path(results_dir, job.key).is_file():
                self._say(f"{job.key}: result file written for other arguments, rerunning")
            todo.append(job)
        ran: list[str] = []
        failed: list[JobFailure] = []
        name = self.backend.name
        if todo:
            bar = tqdm(
                total=len(jobs),
                initial=len(found),
                desc=desc,
                unit="job",
                disable=not self.progress,
                file=sys.stderr,
                dynamic_ncols=True,
            )
            try:
                with self.backend as backend:
                    name = backend.name
                    for i, payload in backend.map_unordered(todo):
                        job = todo[i]
                        if payload.get("ok"):
                            found[job.key] = self._write_result(results_dir, job, payload)
                            ran.append(job.key)
                        else:
                            failed.append(self._write_failure(results_dir, job, payload))
                            msg = f"FAILED {job.describe()}: {payload['error']}"
                            if self.progress:
                                bar.write(msg, file=sys.stderr)
                            else:
                                self._say(msg)
                            bar.set_postfix_str(f"{len(failed)} failed")
                        bar.update(1)
            finally:
                bar.close()
        results = {k: found[k] for k in keys if k in found}
        return SweepReport(
            results=results,
            ran=ran,
            skipped=[k for k in keys if k in found and k not in ran],
            failed=failed,
            wall_s=time.perf_counter() - t0,
            backend=name,
        )

    def _say(self, message: str) -> None:
        if self.log is not None:
            self.log(message)

    @staticmethod
    def _write_result(results_dir: Path, job: Job, payload: dict[str, Any]) -> Any:
        record = {
            "key": job.key,
            "function": job.function,
            "kwargs": _json_form(dict(job.kwargs)),
            "cpus": job.cpus,
            "threads": job.thread_count,
            "host": payload.get("host"),
            "pid": payload.get("pid"),
            "wall_s": payload.get("wall_s"),
            "cpu_s": payload.get("cpu_s"),
            "start": payload.get("start"),
            "end": payload.get("end"),
            "result": payload["value"],
        }
        write_atomic(result_path(results_dir, job.key), json.dumps(record, indent=1) + "\n")
        error_path(results_dir, job.key).unlink(missing_ok=True)
        return payload["value"]

    @staticmethod
    def _write_failure(results_dir: Path, job: Job, payload: dict[str, Any]) -> JobFailure:
        path = error_path(results_dir, job.key)
        kwargs = _json_form(dict(job.kwargs))
        text = (
            f"job: {job.key}\nfunction: {job.function}\n"
            f"kwargs: {json.dumps(kwargs, indent=1)}\n"
            f"cpus: {job.cpus}, threads: {job.thread_count}\n"
            f"host: {payload.get('host')}, pid: {payload.get('pid')}\n"
            f"error: {payload['error']}\n\n{payload.get('traceback', '')}"
        )
        write_atomic(path, text)
        return JobFailure(job.key, job.function, kwargs, payload["error"], path)


# -------------------------------------------------------------------------------- CLI
def add_sweep_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--jobs N`` and ``--ray [ADDRESS]`` (one argument group) to ``parser``."""
    group = parser.add_argument_group(
        "sweep", "where the independent jobs run; finished jobs are kept and skipped on rerun"
    )
    group.add_argument(
        "--jobs",
        type=int,
        default=None,
        metavar="N",
        help="local worker processes, one job each (default 1: in this process); with --ray "
        "and no ADDRESS: the CPUs of the local Ray instance (default: all)",
    )
    group.add_argument(
        "--ray",
        nargs="?",
        const=LOCAL_RAY,
        default=None,
        metavar="ADDRESS",
        help="run the jobs on Ray (pip install 'mcpilco[cluster]'): without ADDRESS a local "
        "instance on 127.0.0.1, else the cluster at ADDRESS (auto, HOST:PORT, ray://HOST:PORT)",
    )


def backend_from_args(args: argparse.Namespace) -> Backend:
    """The backend ``--jobs`` / ``--ray`` ask for.

    Raises:
        SweepError: ``--jobs`` below 1, or ``--ray`` without Ray installed.
    """
    jobs = getattr(args, "jobs", None)
    if jobs is not None and jobs < 1:
        raise SweepError(f"--jobs must be >= 1, got {jobs}")
    ray_address = getattr(args, "ray", None)
    if ray_address is not None:
        import_ray(local=ray_address == LOCAL_RAY)
        if ray_address == LOCAL_RAY:
            return RayBackend(None, num_cpus=jobs)
        return RayBackend(ray_address)
    if jobs is None or jobs == 1:
        return InProcessBackend()
    return LocalBackend(jobs)


def runner_from_args(
    args: argparse.Namespace, *, progress: bool = True, log: Callable[[str], None] | None = print
) -> SweepRunner:
    """A :class:`SweepRunner` on the backend of ``--jobs`` / ``--ray`` (see
    :func:`add_sweep_arguments`); ``progress`` and ``log`` as in :class:`SweepRunner`.

    Raises:
        SweepError: as :func:`backend_from_args`.
    """
    return SweepRunner(backend_from_args(args), progress=progress, log=log)

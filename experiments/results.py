"""One result file format for every benchmark: :func:`write_result` writes it,
:func:`read_result` is its one reader.

A result file is one JSON object::

    {
      "schema": "mcpilco-result/1",
      "kind": "mcpilco",                   # which bench wrote it (experiments.benches)
      "date": "2026-12-07T10:40:00Z",      # UTC; a date alone for files measured before
      "command": "mcpilco-bench-mcpilco --parts runs ...",   # the exact command line
      "version": "0.2.0", "commit": "0dc048b...",            # null where not recorded
      "machine": "x86_64 2 CPUs, ...",     # or null
      "parts": {"runs (hold2)": {"date": ..., "command": ...}, ...},  # files measured in parts
      "seeds": {"all": [...], "development": [...]},
      "config": {...}, "summary": {...}, "cases": {...}, "failures": {...}
    }

The four sections are mappings of named entries. Which entry of a bench's payload goes to
which section is the bench's :class:`ResultLayout` (``config``: the settings; ``cases``: the
per-seed / per-case records; ``failures``: what failed; everything else: ``summary``, the
aggregates). A seed is a *development seed* when defaults were chosen on it
(:data:`DEVELOPMENT_SEEDS`: 0-99, the house rule); reports on other seeds are the numbers a
user may quote.

Intervals: every rate is reported with its 95 % Wilson interval (:func:`rate`), every median
or interquartile mean over seeds with a percentile-bootstrap interval over the seeds
(:func:`over_seeds`; the seeds are the unit, rliable's convention). Both come from
:mod:`mcpilco.models.stats`.

A :class:`Result` reads like the payload the bench wrote: ``result["timing"]`` finds the entry
in whichever section holds it, and :meth:`Result.payload` gives the whole payload back (with
``command`` / ``measured`` or, for files measured in parts, ``commands`` / ``measured``
mappings), so a bench that extends its own file (``--append``) reads it through this module.
"""

from __future__ import annotations

import datetime
import importlib.metadata
import json
import shlex
import subprocess
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.models.files import write_atomic
from mcpilco.models.stats import STATISTICS, bootstrap_interval, wilson_interval

SCHEMA = "mcpilco-result/1"  # the format tag every result file starts with
SECTIONS = ("config", "summary", "cases", "failures")  # the payload's sections, in file order
ENVELOPE_KEYS = ("command", "commands", "measured", "machine")  # payload keys lifted out
DEVELOPMENT_SEEDS = range(0, 100)  # seeds defaults may be chosen on (house rule)
NOT_RECORDED = "not recorded"  # what a report says where a file does not record a field


@dataclass(frozen=True)
class ResultLayout:
    """Which payload entries of a bench go to which section (the rest go to ``summary``), and
    where the seeds are when they are not the payload's ``seeds`` list (``seeds``: a function
    of the payload)."""

    kind: str
    config: tuple[str, ...] = ()
    cases: tuple[str, ...] = ()
    failures: tuple[str, ...] = ()
    seeds: Callable[[Mapping[str, Any]], Iterable[int]] | None = None  # the payload's seeds

    def section_of(self, key: str) -> str:
        """The section of payload entry ``key`` (``seed`` / ``seeds``: ``config``)."""
        for name in ("config", "cases", "failures"):
            if key in getattr(self, name):
                return name
        return "config" if key in ("seed", "seeds") else "summary"


@dataclass
class Result:
    """A result file in memory; see the module docstring for the fields."""

    kind: str
    date: str
    command: str | None = None
    version: str | None = None
    commit: str | None = None
    machine: str | None = None
    parts: dict[str, dict[str, str]] = field(default_factory=dict)
    seeds: dict[str, list[int]] = field(default_factory=lambda: {"all": [], "development": []})
    config: dict[str, Any] = field(default_factory=dict)
    summary: dict[str, Any] = field(default_factory=dict)
    cases: dict[str, Any] = field(default_factory=dict)
    failures: dict[str, Any] = field(default_factory=dict)
    legacy: dict[str, Any] | None = None

    def __getitem__(self, key: str) -> Any:
        for name in SECTIONS:
            section = getattr(self, name)
            if key in section:
                return section[key]
        raise KeyError(key)

    def __contains__(self, key: str) -> bool:
        return any(key in getattr(self, name) for name in SECTIONS)

    def get(self, key: str, default: Any = None) -> Any:
        """``self[key]``, or ``default`` when no section holds ``key``."""
        return self[key] if key in self else default

    def payload(self) -> dict[str, Any]:
        """The bench's payload: the sections merged, with the provenance as the bench keeps it
        (``command`` and ``measured``, or ``commands`` / ``measured`` mappings by part)."""
        out: dict[str, Any] = {}
        for name in SECTIONS:
            out.update(getattr(self, name))
        if self.parts:
            cmds = {k: p["command"] for k, p in self.parts.items() if p.get("command")}
            if cmds:
                out["commands"] = cmds
            days = {k: p["date"] for k, p in self.parts.items() if p.get("date")}
            out["measured"] = days or self.date
        else:
            if self.command is not None:
                out["command"] = self.command
            out["measured"] = self.date
        if self.machine is not None:
            out["machine"] = self.machine
        return out

    def command_of(self, part: str | None = None) -> str:
        """The command that measured ``part`` (or the file), else :data:`NOT_RECORDED`."""
        if part is not None and part in self.parts and self.parts[part].get("command"):
            return self.parts[part]["command"]
        return self.command or NOT_RECORDED

    def date_of(self, part: str | None = None) -> str:
        """The UTC date (YYYY-MM-DD) ``part`` (or the file) was measured."""
        if part is not None and part in self.parts and self.parts[part].get("date"):
            return self.parts[part]["date"][:10]
        return self.date[:10] if self.date else NOT_RECORDED

    def to_dict(self) -> dict[str, Any]:
        """The JSON object of the file."""
        out: dict[str, Any] = {
            "schema": SCHEMA,
            "kind": self.kind,
            "date": self.date,
            "command": self.command,
            "version": self.version,
            "commit": self.commit,
            "machine": self.machine,
        }
        if self.parts:
            out["parts"] = self.parts
        out["seeds"] = self.seeds
        for name in SECTIONS:
            out[name] = getattr(self, name)
        if self.legacy is not None:
            out["legacy"] = self.legacy
        return out


def utc_now() -> str:
    """The current UTC time, ISO 8601 to the second with a ``Z``."""
    now = datetime.datetime.now(datetime.UTC).replace(microsecond=0)
    return now.isoformat().replace("+00:00", "Z")


def package_version() -> str | None:
    """The installed version of ``mcpilco``, None when it is not installed."""
    try:
        return importlib.metadata.version("mcpilco")
    except importlib.metadata.PackageNotFoundError:
        return None


def git_commit() -> str | None:
    """The commit of the source tree the package runs from (``git rev-parse HEAD`` in its
    folder, ``+dirty`` when it has uncommitted changes); None outside a git checkout."""
    here = Path(__file__).resolve().parent
    try:
        head = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=10
        )
        if head.returncode != 0:
            return None
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=here,
            capture_output=True,
            text=True,
            timeout=30,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return head.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")


def command_line(argv: Sequence[str] | None = None, prog: str | None = None) -> str:
    """The exact command line: ``prog`` (default the program's name) and ``argv`` (default
    ``sys.argv[1:]``), shell-quoted."""
    prog = prog or Path(sys.argv[0]).name or "python"
    args = list(sys.argv[1:] if argv is None else argv)
    return shlex.join([prog, *args])


def development_seeds(seeds: Iterable[int]) -> list[int]:
    """The seeds among ``seeds`` that are development seeds (:data:`DEVELOPMENT_SEEDS`)."""
    return sorted({int(s) for s in seeds if int(s) in DEVELOPMENT_SEEDS})


def seeds_entry(seeds: Iterable[int]) -> dict[str, list[int]]:
    """The ``seeds`` field: all seeds and the development seeds among them."""
    every = sorted({int(s) for s in seeds})
    return {"all": every, "development": development_seeds(every)}


def rate(successes: int, trials: int) -> dict[str, Any]:
    """A rate with its 95 % Wilson interval: ``{"k", "n", "rate", "ci95"}``."""
    lo, hi = wilson_interval(int(successes), int(trials))
    return {"k": int(successes), "n": int(trials), "rate": successes / trials, "ci95": [lo, hi]}


def over_seeds(values: Sequence[float], statistic: str = "median") -> dict[str, Any]:
    """A median / IQM / mean over seeds (one value per seed) with its 95 % percentile-bootstrap
    interval over the seeds: ``{statistic, "ci95", "n"}``."""
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    lo, hi = bootstrap_interval(x, statistic)
    return {statistic: STATISTICS[statistic](x), "ci95": [lo, hi], "n": int(x.size)}


def _jsonable(obj: Any) -> Any:
    """``json.dumps`` fallback: numpy scalars and arrays, paths."""
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"a result holds a {type(obj).__name__}, which JSON cannot store")


def _seed_list(payload: Mapping[str, Any]) -> list[int]:
    seeds = payload.get("seeds")
    if isinstance(seeds, list) and all(isinstance(s, int) for s in seeds):
        return seeds
    for owner in (payload, payload.get("config") or {}):
        if isinstance(owner, Mapping) and isinstance(owner.get("seed"), int):
            return [owner["seed"]]
    return []


def build_result(
    layout: ResultLayout,
    payload: Mapping[str, Any],
    *,
    seeds: Iterable[int] | None = None,
    command: str | None = None,
    date: str | None = None,
    version: str | None = None,
    commit: str | None = None,
) -> Result:
    """A :class:`Result` of ``payload`` (the bench's entries by name) laid out by ``layout``.

    ``command`` / ``commands``, ``measured`` and ``machine`` entries of the payload become the
    provenance (``commands`` / ``measured`` mappings: the file's ``parts``); ``seeds``
    defaults to the payload's ``seeds`` list (or its ``seed``).
    """
    body = {k: v for k, v in payload.items() if k not in ENVELOPE_KEYS}
    res = Result(kind=layout.kind, date=date or utc_now(), version=version, commit=commit)
    for key, value in body.items():
        getattr(res, layout.section_of(key))[key] = value
    measured, commands = payload.get("measured"), payload.get("commands")
    if isinstance(measured, Mapping):
        for part, day in measured.items():
            res.parts.setdefault(part, {})["date"] = day
        if date is None and measured:
            res.date = max(measured.values())
    elif isinstance(measured, str) and date is None:
        res.date = measured
    if isinstance(commands, Mapping):
        for part, cmd in commands.items():
            res.parts.setdefault(part, {})["command"] = cmd
    res.command = command or (payload.get("command") if "command" in payload else None)
    res.machine = payload.get("machine")
    if seeds is None:
        seeds = layout.seeds(payload) if layout.seeds is not None else _seed_list(payload)
    res.seeds = seeds_entry(seeds)
    return res


def write_result(
    path: str | Path,
    layout: ResultLayout,
    payload: Mapping[str, Any],
    *,
    seeds: Iterable[int] | None = None,
    command: str | None = None,
) -> Path:
    """Write ``payload`` as a result file of ``layout.kind`` to ``path`` (atomically), with
    the UTC time, the command line (``command``, else the payload's, else ``sys.argv``), the
    package version and the git commit. Returns the path."""
    cmd = command or payload.get("command")
    res = build_result(
        layout,
        payload,
        seeds=seeds,
        command=cmd if isinstance(cmd, str) else command_line(),
        date=utc_now(),
        version=package_version(),
        commit=git_commit(),
    )
    path = Path(path)
    write_atomic(path, json.dumps(res.to_dict(), indent=1, default=_jsonable) + "\n")
    return path


def result_from_dict(data: Mapping[str, Any], source: str = "result") -> Result:
    """A :class:`Result` from a file's JSON object; ValueError naming ``source`` when it is
    not one."""
    if not isinstance(data, Mapping) or data.get("schema") != SCHEMA:
        raise ValueError(
            f"{source}: not a result file of schema {SCHEMA} (a file written before it can be "
            "converted with mcpilco-results-index --convert)"
        )
    for name in ("kind", "date"):
        if not isinstance(data.get(name), str):
            raise ValueError(f"{source}: field '{name}' must be a string")
    for name in SECTIONS:
        if not isinstance(data.get(name, {}), Mapping):
            raise ValueError(f"{source}: section '{name}' must be a mapping")
    return Result(
        kind=data["kind"],
        date=data["date"],
        command=data.get("command"),
        version=data.get("version"),
        commit=data.get("commit"),
        machine=data.get("machine"),
        parts=dict(data.get("parts") or {}),
        seeds=dict(data.get("seeds") or {"all": [], "development": []}),
        config=dict(data.get("config") or {}),
        summary=dict(data.get("summary") or {}),
        cases=dict(data.get("cases") or {}),
        failures=dict(data.get("failures") or {}),
        legacy=data.get("legacy"),
    )


def read_result(path: str | Path) -> Result:
    """Read a result file. Raises FileNotFoundError, or ValueError naming the file when it is
    not valid JSON or not of :data:`SCHEMA`."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise ValueError(f"{path}: not valid JSON ({err})") from err
    return result_from_dict(data, str(path))


def percent(x: float) -> str:
    """``0.875`` -> ``"88 %"``."""
    return f"{100 * x:.0f} %"


def seed_ranges(seeds: Iterable[int]) -> str:
    """``[0, 1, 2, 5, 7, 8]`` -> ``"0-2, 5, 7-8"`` (sorted, repeats dropped)."""
    vals = sorted({int(s) for s in seeds})
    if not vals:
        return NOT_RECORDED
    parts, start, prev = [], vals[0], vals[0]
    for s in [*vals[1:], None]:
        if s is not None and s == prev + 1:
            prev = s
            continue
        parts.append(f"{start}" if start == prev else f"{start}-{prev}")
        if s is not None:
            start = prev = s
    return ", ".join(parts)


@dataclass(frozen=True)
class Headline:
    """One headline figure a bench exports to the results index.

    Args:
        capability: what the figure measures, as the README names the capability.
        path: the result file that backs it, relative to the results folder.
        figure: reads the figure (one short sentence) from the :class:`Result`.
        page: the file a reader opens for the details (``.md`` or ``.png``).
        part: which part of a file measured in parts (its ``parts`` key) the row belongs to.
        seeds: reads the seeds (a short text); by default the file's ``seeds``.
    """

    capability: str
    path: str
    figure: Callable[[Result], str]
    page: str
    part: str | None = None
    seeds: Callable[[Result], str] | None = None

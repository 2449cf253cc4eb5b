"""Conversion of result files written before :mod:`mcpilco.experiments.results` existed.

Each bench used to write its own JSON object, with the date, the command and the machine
under names of its own (``measured``, ``command``, ``commands``, ``meta``). :func:`convert`
lays such an object out by its bench's :class:`~mcpilco.experiments.results.ResultLayout`,
lifts the provenance into the envelope and keeps, under ``legacy``, the SHA-256 of the old
object (canonical JSON, sorted keys) and its provenance entries verbatim, so that
:func:`to_legacy` rebuilds the old object exactly: a converted file holds every number of the
old one, unchanged, which :func:`check_converted` verifies. This module is the only reader of
the old layouts.
"""

from __future__ import annotations

import hashlib
import json
import subprocess
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from mcpilco.experiments.benches import layout
from mcpilco.experiments.results import (
    ENVELOPE_KEYS,
    SCHEMA,
    SECTIONS,
    Result,
    build_result,
    result_from_dict,
)
from mcpilco.models.files import write_atomic

# File name -> result kind of the files written before the schema (the first match wins).
LEGACY_KINDS: tuple[tuple[str, str], ...] = (
    ("bench_gp_predictor*.json", "gp_predictor"),
    ("collision_quasi_static.json", "quasi_static_friction"),
    ("collision.json", "collision"),
    ("compare_*.json", "compare"),
    ("diagnosis_learned_start.json", "diagnosis_learned_start"),
    ("diagnosis_robot_logs.json", "diagnosis"),
    ("diagnosis_speed.json", "diagnosis_speed"),
    ("mcpilco_cartpole.json", "mcpilco"),
    ("mcpilco_tracking.json", "mcpilco_tracking"),
    ("inverse_dynamics.json", "inverse_dynamics"),
    ("kinematics_c_seeds.json", "kinematics_seeds"),
    ("kinematics_reaching.json", "kinematics_reaching"),
    ("kinematics*.json", "kinematics"),
    ("marker_detection.json", "marker_detection"),
    ("robustness.json", "robustness"),
    ("sweep_overhead.json", "sweep_overhead"),
    ("torque_constants.json", "torque_constants"),
    ("volterra.json", "volterra"),
)


def digest(obj: Any) -> str:
    """SHA-256 of ``obj`` as canonical JSON (sorted keys, no spaces)."""
    text = json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()


def legacy_kind(path: Path) -> str | None:
    """The result kind of an old file by its name, None for a file that is not a bench's
    result (e.g. the trial records of a training run)."""
    for pattern, kind in LEGACY_KINDS:
        if path.match(pattern):
            return kind
    return None


def last_commit_date(path: Path) -> str | None:
    """Author date (YYYY-MM-DD) of the last commit that changed ``path``; None outside git."""
    try:
        out = subprocess.run(
            ["git", "log", "-1", "--format=%as", "--", path.name],
            cwd=path.parent,
            capture_output=True,
            text=True,
            timeout=30,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    date = out.stdout.strip()
    return date if out.returncode == 0 and date else None


def convert(data: Mapping[str, Any], kind: str, fallback_date: str | None = None) -> Result:
    """The :class:`Result` of an old bench object ``data`` of kind ``kind``; ``fallback_date``
    (the file's last commit) dates a file that recorded no date, marked in ``legacy``."""
    meta = data.get("meta")
    command = data.get("command")
    if command is None and isinstance(meta, Mapping):
        command = meta.get("command")
    res = build_result(layout(kind), data, command=command if isinstance(command, str) else None)
    res.legacy = {
        "sha256": digest(dict(data)),
        "envelope": {k: data[k] for k in ENVELOPE_KEYS if k in data},
    }
    if not isinstance(data.get("measured"), (str, Mapping)):
        res.date = fallback_date or ""  # the old file recorded no date
        res.legacy["date"] = "last commit of the file" if fallback_date else "not recorded"
    return res


def to_legacy(result: Result) -> dict[str, Any]:
    """The old object a converted result was made from (ValueError when it was not
    converted)."""
    if result.legacy is None:
        raise ValueError(f"a {result.kind} result written in the schema has no old object")
    out: dict[str, Any] = {}
    for name in SECTIONS:
        out.update(getattr(result, name))
    out.update(result.legacy["envelope"])
    return out


def check_converted(result: Result, source: str = "result") -> None:
    """Raise ValueError naming ``source`` unless ``result`` rebuilds its old object exactly."""
    if digest(to_legacy(result)) != result.legacy["sha256"]:
        raise ValueError(f"{source}: the converted file does not rebuild the old one")


def convert_file(path: Path) -> bool:
    """Convert ``path`` in place when it is an old bench result, or lay a converted file out
    again by its bench's current layout; True when the file changed.

    Files written in the schema by a bench and files that are not a bench's result are left
    alone.
    """
    data = json.loads(path.read_text())
    kind = legacy_kind(path)
    if not isinstance(data, dict) or kind is None:
        return False
    if data.get("schema") == SCHEMA:
        if "legacy" not in data:
            return False
        converted = result_from_dict(data, str(path))
        dated = converted.legacy.get("date") == "last commit of the file"
        res = convert(to_legacy(converted), converted.kind, converted.date if dated else None)
    else:
        res = convert(data, kind, last_commit_date(path))
    check_converted(result_from_dict(json.loads(json.dumps(res.to_dict()))), str(path))
    if res.to_dict() == data:
        return False
    write_atomic(path, json.dumps(res.to_dict(), indent=1) + "\n")
    return True


def convert_tree(results_dir: str | Path) -> list[Path]:
    """Convert every old bench result under ``results_dir``; the converted paths."""
    return [p for p in sorted(Path(results_dir).rglob("*.json")) if convert_file(p)]

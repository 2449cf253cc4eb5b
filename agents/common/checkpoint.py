"""Atomic, safe checkpoints of a run (MC-PILCO, the PILCO baseline; one file per run,
replaced after every trial), and the check that a resumed run is the run that was started.

A checkpoint is written to ``<path>.tmp`` and moved over ``<path>`` with ``os.replace``,
which is atomic on POSIX: a run killed while writing leaves the previous checkpoint intact,
so ``--resume`` never loses a finished trial; a run killed while writing its first one
leaves no checkpoint, and ``--resume`` says that no trial finished.

Checkpoints hold only tensors and plain data (numpy arrays as tagged tensors, the numpy
generator's state as integers) and are read with ``torch.load(weights_only=True)``
(:mod:`mcpilco.models.torch_files`): loading a checkpoint from someone else cannot run code.
A missing, empty, truncated or damaged file is reported naming the file and what to do.
"""

from __future__ import annotations

import os
import random
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mcpilco.envs.numbers import shown
from mcpilco.models.torch_files import atomic_torch_save, load_torch_file

__all__ = [
    "CHECKPOINT_NAME",
    "CHECKPOINT_VERSION",
    "atomic_torch_save",
    "check_resume",
    "checkpoint_problem",
    "load_checkpoint",
    "restore_state",
    "rng_state",
    "save_checkpoint",
    "set_rng_state",
]

CHECKPOINT_NAME = "checkpoint.pt"
"""The checkpoint file in a run's output folder."""

CHECKPOINT_VERSION = 3
"""Format of the checkpoint dict (3: tensors and plain data only, numpy arrays tagged)."""
_REQUIRED_KEYS = ("version", "config", "next_trial")  # keys every checkpoint holds


def rng_state(np_rng: np.random.Generator) -> dict[str, Any]:
    """States of the torch (CPU, and CUDA once used), numpy (run generator) and Python
    generators."""
    state = {
        "torch": torch.get_rng_state(),
        "numpy": np_rng.bit_generator.state,
        "python": random.getstate(),
    }
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(state: dict[str, Any], np_rng: np.random.Generator) -> None:
    """Restore what :func:`rng_state` saved (the CUDA generators where this machine has the
    same number of GPUs; else they keep their seeding).

    Raises:
        ValueError: ``state`` is not such a state (a damaged or crafted checkpoint).
    """
    try:
        _set_rng_state(state, np_rng)
    except (RuntimeError, KeyError, TypeError, ValueError, IndexError) as err:
        raise ValueError(
            f"the checkpoint's generator states cannot be restored ({type(err).__name__}); "
            "start the run again with --overwrite"
        ) from None


def _set_rng_state(state: dict[str, Any], np_rng: np.random.Generator) -> None:
    torch.set_rng_state(state["torch"])
    cuda = state.get("cuda")
    if cuda is not None and torch.cuda.is_available() and len(cuda) == torch.cuda.device_count():
        torch.cuda.set_rng_state_all(cuda)
    np_rng.bit_generator.state = state["numpy"]
    random.setstate(state["python"])


def load_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """Load a checkpoint written by :func:`save_checkpoint` (``weights_only=True``);
    checks the format version.

    Raises:
        FileNotFoundError: no checkpoint at ``path`` (no trial of the run finished).
        ValueError: the file is empty, truncated, damaged, unsafe or of another version
            (the message names the file and what to do).
    """
    path = Path(path)
    remedy = (
        "start the run again with --overwrite (or restore the file from a backup); "
        "its finished trials cannot be resumed from this file"
    )
    if not path.exists():
        partial = path.with_name(path.name + ".tmp").exists()
        raise FileNotFoundError(
            f"no checkpoint at {path}: no trial of a run in {path.parent} finished"
            + (" (the run was stopped while writing its first checkpoint)" if partial else "")
            + "; start the run without --resume (with --overwrite if the folder holds files "
            "of the stopped run), or pass the --out of the run to resume"
        )
    ckpt = load_torch_file(path, "checkpoint", remedy, follow_links=False)
    if not isinstance(ckpt, dict) or any(k not in ckpt for k in _REQUIRED_KEYS):
        raise ValueError(
            f"checkpoint {path} is not a run checkpoint (no {_REQUIRED_KEYS}); {remedy}"
        )
    if ckpt.get("version") != CHECKPOINT_VERSION:
        raise ValueError(
            f"checkpoint {path} has format version {shown(ckpt.get('version'))}, this version "
            f"reads {CHECKPOINT_VERSION}; {remedy}"
        )
    problem = checkpoint_problem(ckpt)
    if problem is not None:
        raise ValueError(f"checkpoint {path} does not match its format: {problem}; {remedy}")
    return ckpt


def save_checkpoint(path: str | os.PathLike, config: Any, next_trial: int, **state: Any) -> None:
    """Write the checkpoint of a run whose trials ``0 .. next_trial - 1`` are done: the format
    version, ``config.to_dict()``, ``next_trial`` and ``state`` (tensors and plain data),
    atomically (the commit point of a trial)."""
    atomic_torch_save(
        {
            "version": CHECKPOINT_VERSION,
            "config": config.to_dict(),
            "next_trial": int(next_trial),
            **state,
        },
        path,
    )


def check_resume(saved: Mapping[str, Any], config: Any, keys: tuple[str, ...]) -> None:
    """Raise ``ValueError`` naming the first of ``keys`` whose value in ``config`` differs
    from the checkpoint's ``saved`` config (a run resumes only what it started).

    ``saved`` is read as a config of ``config``'s type (``type(config).from_dict``), so that
    a field added after the checkpoint was written takes the value the run had then.
    """
    try:
        was_config = type(config).from_dict(dict(saved))
    except (TypeError, ValueError) as err:
        raise ValueError(
            f"cannot resume: the checkpoint's config does not read as a "
            f"{type(config).__name__} ({err}); use a new output folder"
        ) from None
    for key in keys:
        was, now = getattr(was_config, key), getattr(config, key)
        if was != now:
            raise ValueError(
                f"cannot resume: {key}={now!r} differs from the checkpoint's {was!r}; use the "
                "same value or a new output folder"
            )


_KEY_TYPES: dict[str, type | tuple[type, ...]] = {
    "version": int,
    "config": dict,
    "next_trial": int,
    "episodes": list,
    "records": list,
    "arrays": list,
    "opt_curves": list,
    "policy": dict,
    "policy_settings": dict,
    "population": dict,
    "optimizer": (dict, type(None)),
    "gp_file": (str, type(None)),
    "rng": dict,
}  # type of each key a checkpoint may hold (MC-PILCO's and PILCO's)
_GP_FILE = re.compile(r"^gp_trial\d{2,}\.pt$")  # name of a run's GP file (in its folder)


def checkpoint_problem(ckpt: dict[str, Any]) -> str | None:
    """What in the checkpoint dict ``ckpt`` does not match the format (None: nothing).

    Checked: the type of every key of :data:`_KEY_TYPES` it holds and that ``rng`` is
    there; ``next_trial`` within ``1 .. config.num_trials + 1`` (the trials of the run that
    wrote it) and equal to the number of records, each record a mapping with its index;
    episodes mappings of finite numpy arrays; the GP file a plain ``gp_trialXX.pt`` name
    (read from the run folder, never elsewhere); ``rng`` with the torch, numpy and Python
    generator states; the policy's and population's states mappings of tensors.
    """
    for key, kind in _KEY_TYPES.items():
        if key in ckpt and (not isinstance(ckpt[key], kind) or isinstance(ckpt[key], bool)):
            names = (
                kind.__name__ if isinstance(kind, type) else " or ".join(k.__name__ for k in kind)
            )
            return f"{key} is of type {type(ckpt[key]).__name__}, not {names}"
    if "rng" not in ckpt:
        return "no rng (generator states)"
    trials = ckpt["config"].get("num_trials")
    if isinstance(trials, bool) or not isinstance(trials, int) or trials < 0:
        return f"config.num_trials is {shown(trials)}, not an integer >= 0"
    nxt = ckpt["next_trial"]
    if not 1 <= nxt <= trials + 1:
        return f"next_trial {nxt} is outside 1..{trials + 1} (the run's trials)"
    records = ckpt["records"]
    if len(records) != nxt:
        return f"{len(records)} trial records for next_trial {nxt}"
    for i, rec in enumerate(records):
        if not isinstance(rec, dict) or rec.get("index") != i:
            return f"records[{i}] is not the record of trial {i}"
    for i, ep in enumerate(ckpt["episodes"]):
        if not isinstance(ep, dict):
            return f"episodes[{i}] is not a mapping"
        for key, value in ep.items():
            if isinstance(value, np.ndarray) and value.dtype.kind == "f":
                if not np.all(np.isfinite(value)):
                    return f"episodes[{i}].{key} holds NaN or inf"
    gp_file = ckpt.get("gp_file")
    if gp_file is not None and not _GP_FILE.match(gp_file):
        return f"gp_file {shown(gp_file)} is not a GP file name of the run folder"
    rng = ckpt["rng"]
    if not isinstance(rng.get("torch"), torch.Tensor) or rng["torch"].dtype != torch.uint8:
        return "rng.torch is not a generator state"
    if not isinstance(rng.get("numpy"), dict) or not isinstance(rng.get("python"), tuple | list):
        return "rng.numpy or rng.python is not a generator state"
    for key in ("policy", "population"):
        state = ckpt.get(key)
        if state is not None and not all(isinstance(v, torch.Tensor) for v in state.values()):
            return f"{key} is not a mapping of tensors"
    return None


def restore_state(module: torch.nn.Module, state: Any, what: str, path: Path) -> None:
    """``module.load_state_dict(state)``; a state of other keys or shapes (a checkpoint of
    another setting or a crafted one) becomes one ValueError naming ``what`` and ``path``."""
    try:
        module.load_state_dict(state)
    except (RuntimeError, KeyError, TypeError, ValueError, AttributeError) as err:
        first = " ".join(str(err).split())[:160]
        raise ValueError(
            f"checkpoint {path}: the saved {what} does not fit this run's {what} ({first}); "
            "resume with the settings the run was started with, or start it again with "
            "--overwrite"
        ) from None

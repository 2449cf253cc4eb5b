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
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mcpilco.models.torch_files import atomic_torch_save, load_torch_file

__all__ = [
    "CHECKPOINT_NAME",
    "CHECKPOINT_VERSION",
    "atomic_torch_save",
    "check_resume",
    "load_checkpoint",
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
    same number of GPUs; else they keep their seeding)."""
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
    ckpt = load_torch_file(path, "checkpoint", remedy)
    if not isinstance(ckpt, dict) or any(k not in ckpt for k in _REQUIRED_KEYS):
        raise ValueError(
            f"checkpoint {path} is not a run checkpoint (no {_REQUIRED_KEYS}); {remedy}"
        )
    if ckpt.get("version") != CHECKPOINT_VERSION:
        raise ValueError(
            f"checkpoint {path} has format version {ckpt.get('version')}, this version reads "
            f"{CHECKPOINT_VERSION}; {remedy}"
        )
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

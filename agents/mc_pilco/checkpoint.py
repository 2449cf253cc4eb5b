"""Atomic checkpoints of an MC-PILCO run (one file per run, replaced after every trial).

A checkpoint is written to ``<path>.tmp`` and moved over ``<path>`` with ``os.replace``,
which is atomic on POSIX: a run killed while writing leaves the previous checkpoint intact,
so ``--resume`` never loses a finished trial.
"""

from __future__ import annotations

import os
import random
from pathlib import Path
from typing import Any

import numpy as np
import torch

CHECKPOINT_VERSION = 2


def atomic_torch_save(obj: Any, path: str | os.PathLike) -> None:
    """``torch.save(obj, path)`` through a temporary file and ``os.replace``."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as fh:
        torch.save(obj, fh)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


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
    """Load a checkpoint written by the MC-PILCO loop; checks the format version."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(
            f"no checkpoint at {path}; run without --resume first (or pass the run's --out)"
        )
    ckpt = torch.load(path, map_location="cpu", weights_only=False)
    if ckpt.get("version") != CHECKPOINT_VERSION:
        raise ValueError(
            f"checkpoint {path} has version {ckpt.get('version')}, expected {CHECKPOINT_VERSION}"
        )
    return ckpt

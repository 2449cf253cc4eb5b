"""Where tensors live: parse a user's ``device`` option and check that it can be used.

Everything in mcpilco runs on the CPU; a CUDA device is optional (the MC-PILCO particle
rollout and the cached GP predictor can use one). Nothing requires it.
"""

from __future__ import annotations

import torch

__all__ = ["DEVICE_TYPES", "check_device_name", "resolve_device"]

DEVICE_TYPES = ("cpu", "cuda")
"""Device types the ``device`` options accept (``"cuda:1"`` names a GPU by index)."""


def check_device_name(name: str | torch.device) -> torch.device:
    """``torch.device(name)`` if it names a CPU or CUDA device, else ``ValueError``.

    Only the syntax is checked (a config written on a GPU machine still loads on a CPU one);
    :func:`resolve_device` also checks that the device exists here.
    """
    try:
        dev = torch.device(name)
    except (RuntimeError, TypeError) as err:
        raise ValueError(f"device must be 'cpu', 'cuda' or 'cuda:<index>', got {name!r}") from err
    if dev.type not in DEVICE_TYPES:
        raise ValueError(f"device must be 'cpu', 'cuda' or 'cuda:<index>', got {name!r}")
    return dev


def resolve_device(name: str | torch.device) -> torch.device:
    """The :class:`torch.device` named by ``name``, checked to be usable on this machine.

    Raises ``ValueError`` naming the fix when a CUDA device is asked for and this torch build
    or machine has none (or not that index).
    """
    dev = check_device_name(name)
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise ValueError(
                f"device {name!r} asked for, but torch {torch.__version__} sees no CUDA device "
                "(a CPU-only build or no GPU); use device 'cpu'"
            )
        count = torch.cuda.device_count()
        if dev.index is not None and dev.index >= count:
            raise ValueError(f"device {name!r} asked for, but only {count} CUDA device(s) exist")
    return dev

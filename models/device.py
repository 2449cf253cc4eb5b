"""Where tensors live: parse a user's ``device`` option and check that it can be used, and
keep the CPU's freed tensor memory in the process (:func:`retain_host_memory`).

Everything in mcpilco runs on the CPU; a CUDA device is optional (the MC-PILCO particle
rollout and the cached GP predictor can use one). Nothing requires it.
"""

from __future__ import annotations

import ctypes
import sys

import torch

__all__ = [
    "DEVICE_TYPES",
    "GLIBC_INITIAL_THRESHOLD",
    "MMAP_THRESHOLD_MAX",
    "check_device_name",
    "resolve_device",
    "retain_host_memory",
]

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


MMAP_THRESHOLD_MAX = 32 * 2**20
"""glibc's largest ``M_MMAP_THRESHOLD`` on 64-bit Linux (bytes); :func:`retain_host_memory`'s
default."""

GLIBC_INITIAL_THRESHOLD = 128 * 1024
"""glibc's initial ``M_MMAP_THRESHOLD`` and ``M_TRIM_THRESHOLD`` (bytes); passed to
:func:`retain_host_memory` it pins glibc's default behaviour (a contrast for benchmarks)."""

_M_TRIM_THRESHOLD = -1  # glibc <malloc.h> parameter numbers
_M_MMAP_THRESHOLD = -3


def retain_host_memory(
    mmap_threshold: int = MMAP_THRESHOLD_MAX, trim_threshold: int = 2**30
) -> bool:
    """Keep freed CPU memory in this process's heap instead of handing it back to the OS.

    PyTorch's CPU tensors come from ``malloc``. glibc serves a block of at least
    ``M_MMAP_THRESHOLD`` bytes (128 KiB at start, raised adaptively) by a fresh ``mmap``
    and unmaps it on ``free``, and trims the heap's free top above ``M_TRIM_THRESHOLD``. A
    particle rollout allocates and frees hundreds of such blocks per optimisation step
    (``(m, N, M)`` kernel panels, ``4 m N M`` bytes in float32), so each one is zero-filled
    again page by page, one minor page fault per 4 KiB page, unless the adaptive threshold
    happens to have risen above the block size (it depends on the allocation history).
    Fixing both thresholds high (``mallopt``) reuses the freed blocks instead (figures in
    ``docs/performance.md``, "Memory"). The price: the process keeps its peak heap (blocks above
    ``mmap_threshold`` are still unmapped on free).

    Process-wide; call it once, from the program that owns the process (the scripts do).

    Args:
        mmap_threshold: bytes, ``1 <= mmap_threshold <= MMAP_THRESHOLD_MAX``.
        trim_threshold: bytes, ``1 <= trim_threshold < 2**31``.

    Returns:
        True when glibc took both settings; False where there is no glibc ``mallopt``
        (macOS, Windows, musl), which leaves the allocator as it was.
    """
    for name, value, top in (
        ("mmap_threshold", mmap_threshold, MMAP_THRESHOLD_MAX),
        ("trim_threshold", trim_threshold, 2**31 - 1),
    ):
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= top:
            raise ValueError(f"{name} must be an int in [1, {top}] (bytes), got {value!r}")
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt  # the C library this process runs on
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    # musl's mallopt is a stub that returns 0; glibc returns 1 on success
    return mallopt(_M_MMAP_THRESHOLD, mmap_threshold) == 1 and (
        mallopt(_M_TRIM_THRESHOLD, trim_threshold) == 1
    )

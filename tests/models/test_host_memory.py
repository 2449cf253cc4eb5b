"""``retain_host_memory``: freed tensor memory is reused instead of being faulted in again.

Independent truth: the kernel's count of minor page faults of a process (``getrusage``). A
fresh ``mmap`` of ``B`` bytes costs about ``B / 4096`` faults when it is first written; a
block reused from the heap costs none. Each case runs in a fresh interpreter, whose small
heap holds no free block that could serve the request by chance.
"""

from __future__ import annotations

import subprocess
import sys

import pytest

from mcpilco.models.device import GLIBC_INITIAL_THRESHOLD, MMAP_THRESHOLD_MAX, retain_host_memory

linux_glibc = pytest.mark.skipif(
    not sys.platform.startswith("linux") or not retain_host_memory(),
    reason="needs Linux with glibc's mallopt",
)

BLOCK = 2 * 2**20  # bytes: above glibc's initial 128 KiB mmap threshold, below 32 MiB
PAGES = BLOCK // 4096

_PROBE = """
import resource, sys
import torch
from mcpilco.models.device import retain_host_memory

args = [int(a) for a in sys.argv[1:]]
assert retain_host_memory(*args)
def cycles(repeats):
    for _ in range(repeats):
        t = torch.empty({block} // 4, dtype=torch.float32)
        t.fill_(1.0)
        del t
cycles(20)  # the heap settles to the settings first
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
cycles(20)
print((resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / 20)
"""


def _faults_per_block(*thresholds: int) -> float:
    """Minor page faults per allocate-fill-free cycle of a ``BLOCK``-byte tensor in a fresh
    interpreter after ``retain_host_memory(*thresholds)``."""
    out = subprocess.run(
        [sys.executable, "-c", _PROBE.format(block=BLOCK), *map(str, thresholds)],
        capture_output=True,
        text=True,
        check=True,
        timeout=120,
    )
    return float(out.stdout.strip().splitlines()[-1])


@linux_glibc
def test_low_thresholds_fault_every_block_in_again() -> None:
    """The contrast that makes the next test meaningful: with glibc's initial thresholds
    fixed (128 KiB), each cycle maps a fresh block and faults in (nearly) all its pages."""
    assert _faults_per_block(GLIBC_INITIAL_THRESHOLD, GLIBC_INITIAL_THRESHOLD) > 0.5 * PAGES


@linux_glibc
def test_retained_memory_is_reused_without_faults() -> None:
    assert _faults_per_block() < 0.02 * PAGES


@pytest.mark.parametrize(
    "kwargs",
    [
        {"mmap_threshold": 0},
        {"mmap_threshold": MMAP_THRESHOLD_MAX + 1},
        {"trim_threshold": 2**31},
        {"trim_threshold": 1.5},
        {"mmap_threshold": True},
    ],
)
def test_bad_thresholds_raise(kwargs: dict) -> None:
    with pytest.raises(ValueError, match="threshold must be an int"):
        retain_host_memory(**kwargs)

"""Keep freed memory in the process instead of handing it back to the kernel (glibc only).

Why: a training step allocates and frees dozens of tensors of 1-10 MB. glibc serves blocks that
large with fresh ``mmap`` pages and returns them on ``free``, so every step page-faults on every
temporary: about 900 faults a step in the learner, which on a virtual machine cost as much as the
arithmetic. Raising the mmap and trim thresholds makes freed blocks reusable by the next step.
Measured in ``benchmarks/learner_speed.py``.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
#: glibc's ceiling for M_MMAP_THRESHOLD on 64-bit systems; blocks above it are still mmapped.
MMAP_THRESHOLD_BYTES = 32 * 1024 * 1024
TRIM_THRESHOLD_BYTES = 1024 * 1024 * 1024

_done = False


def keep_freed_memory() -> bool:
    """Set glibc's thresholds once per process; returns whether they are in effect."""
    global _done
    if _done:
        return True
    if not sys.platform.startswith("linux"):
        return False
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # musl and other libcs without mallopt
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    _done = bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(
        mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))
    return _done

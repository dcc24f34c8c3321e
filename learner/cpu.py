"""What this CPU can do for the learner: native bf16 arithmetic, and its measured matmul peak.

PyTorch's guidance for bf16 autocast on a CPU is to use it where the CPU computes bf16 natively
(AVX-512 BF16 or AMX): elsewhere bf16 is emulated in fp32 and only adds conversions.
``native_bf16`` reads that from the CPU's flags (Linux's ``/proc/cpuinfo``), and from oneDNN's
own check where there are no such flags to read.
"""

from __future__ import annotations

import time
from functools import lru_cache
from pathlib import Path

import torch

#: CPU flags (``/proc/cpuinfo``) that mean native bf16 dot products.
BF16_FLAGS = ("avx512_bf16", "amx_bf16")


@lru_cache(maxsize=None)
def cpu_flags() -> frozenset[str]:
    """The first processor's flags in ``/proc/cpuinfo`` (empty where there is none)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("flags"):
                return frozenset(line.split(":", 1)[1].split())
    except OSError:
        pass
    return frozenset()


def native_bf16() -> bool:
    """Whether this CPU computes bf16 natively (see the module doc)."""
    flags = cpu_flags()
    if flags:
        return any(f in flags for f in BF16_FLAGS)
    return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())


def matmul_gflops(threads: int, dtype: torch.dtype = torch.float32, n: int = 1024, seconds: float = 1.0) -> float:
    """Measured GFLOP/s of an ``n x n`` matmul in ``dtype`` on ``threads`` torch threads (the
    process's thread count is restored after)."""
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        a = torch.randn(n, n, generator=torch.Generator().manual_seed(0)).to(dtype)
        b = torch.randn(n, n, generator=torch.Generator().manual_seed(1)).to(dtype)
        out = torch.empty(n, n, dtype=dtype)
        for _ in range(3):
            torch.mm(a, b, out=out)
        reps, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            torch.mm(a, b, out=out)
            reps += 1
        return 2.0 * n ** 3 * reps / (time.perf_counter() - t0) / 1e9
    finally:
        torch.set_num_threads(before)

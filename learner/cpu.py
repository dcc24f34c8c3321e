"""What this CPU can do for the learner: native bf16 arithmetic, its measured matmul peak, and the
fingerprint of its float arithmetic.

PyTorch's guidance for bf16 autocast on a CPU is to use it where the CPU computes bf16 natively
(AVX-512 BF16 or AMX): elsewhere bf16 is emulated in fp32 and only adds conversions.
``native_bf16`` reads that from the CPU's flags (Linux's ``/proc/cpuinfo``), and from oneDNN's
own check where there are no such flags to read.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import time
from functools import lru_cache
from pathlib import Path

import torch

#: CPU flags (``/proc/cpuinfo``) that mean native bf16 dot products.
BF16_FLAGS = ("avx512_bf16", "amx_bf16")


@lru_cache(maxsize=None)
def _cpuinfo(field: str) -> str | None:
    """The first processor's ``field`` in ``/proc/cpuinfo`` (None where there is none)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.split(":", 1)[0].strip() == field:
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return None


def cpu_flags() -> frozenset[str]:
    """The first processor's flags in ``/proc/cpuinfo`` (empty where there is none)."""
    return frozenset((_cpuinfo("flags") or "").split())


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


#: Packages whose version enters the numerics fingerprint: the learner's arithmetic, the envs'.
NUMERICS_PACKAGES = ("torch", "numpy", "mujoco")


@lru_cache(maxsize=None)
def numerics_fingerprint(threads: int = 1) -> str:
    """12 hex digits that tell two machines' float arithmetic apart (evidence, not a proof).

    A run is bitwise reproducible from its seed only where its float arithmetic is the same. That
    holds on one machine, but not across CPUs: MKL and oneDNN pick their code path (and so their
    order of summation) by CPU, and torch's own kernels by its vector width; a different order
    changes the last bit of a sum, and a training amplifies it into another set of weights. So
    this hashes the result of three fused-Adam steps (the learner's optimiser) of a small conv +
    batch norm + MLP network on seeded data, computed on ``threads`` intra-op threads (the
    learner's), with the versions of ``NUMERICS_PACKAGES`` (numpy's BLAS and MuJoCo's arithmetic
    enter by version only). Under one fingerprint a run trains to the same files, as two trainings
    on one machine do; under another it lands at another point of its entry's seed spread. It
    speaks for the CPU only: a learner on a GPU is not bitwise reproducible at all
    (``docs/cluster.md``). Cached per thread count: computed once per process.
    """
    versions = [f"{name}=={version}" for name, version in _versions().items()]
    before = torch.get_num_threads()
    torch.set_num_threads(max(1, threads))
    try:
        with torch.random.fork_rng(devices=[]):  # the caller's global generator is left as it was
            torch.manual_seed(0)
            net = torch.nn.Sequential(torch.nn.Conv2d(3, 32, 3), torch.nn.BatchNorm2d(32), torch.nn.LeakyReLU(),
                                      torch.nn.Flatten(), torch.nn.Linear(32 * 5 * 5, 128), torch.nn.ReLU(),
                                      torch.nn.Linear(128, 7))
            gen = torch.Generator().manual_seed(0)
            x = torch.randn(512, 3, 7, 7, generator=gen)
            y = torch.randint(0, 7, (512,), generator=gen)
            opt = torch.optim.Adam(net.parameters(), lr=1e-3, fused=True)
            for _ in range(3):
                opt.zero_grad()
                torch.nn.functional.cross_entropy(net(x), y).backward()
                opt.step()
        digest = hashlib.sha256(" ".join(versions).encode())
        for p in net.parameters():
            digest.update(p.detach().contiguous().numpy().tobytes())
        return digest.hexdigest()[:12]
    finally:
        torch.set_num_threads(before)


def _versions() -> dict[str, str]:
    """The installed version of each of ``NUMERICS_PACKAGES`` ("absent" where it is not installed)."""
    out = {}
    for name in NUMERICS_PACKAGES:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = "absent"
    return out


def machine_summary() -> str:
    """The CPU's model name and the versions that the numerics fingerprint reads, in one line."""
    name = _cpuinfo("model name") or "unknown CPU"
    return ", ".join([name, *(f"{pkg} {version}" for pkg, version in _versions().items())])

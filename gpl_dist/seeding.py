"""Seeds derived from integers, so every rollout and correction is reproducible from the run seed.

A seed is a pure function of its parts (run seed, round, task id, attempt index, ...), never of
which worker ran the unit or in which order units finished.
"""

from __future__ import annotations

import numpy as np


def derive_seed(*parts: int) -> int:
    """A 63-bit seed that depends on every part (order matters)."""
    hi, lo = np.random.SeedSequence([int(p) & 0xFFFFFFFF for p in parts]).generate_state(2, dtype=np.uint32)
    return ((int(hi) << 32) | int(lo)) & ((1 << 63) - 1)


def derive_rng(*parts: int) -> np.random.Generator:
    """A numpy Generator seeded by ``parts``."""
    return np.random.default_rng([int(p) & 0xFFFFFFFF for p in parts])

"""Seeds derived from integers, so every rollout and correction is reproducible from the run seed.

A seed is a pure function of its parts (run seed, round, task id, attempt index, ...), never of
which worker ran the unit or in which order units finished.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np


def derive_seed(*parts: int) -> int:
    """A 63-bit seed that depends on every part (order matters)."""
    hi, lo = np.random.SeedSequence([int(p) & 0xFFFFFFFF for p in parts]).generate_state(2, dtype=np.uint32)
    return ((int(hi) << 32) | int(lo)) & ((1 << 63) - 1)


def derive_rng(*parts: int) -> np.random.Generator:
    """A numpy Generator seeded by ``parts``."""
    return np.random.default_rng([int(p) & 0xFFFFFFFF for p in parts])


# The named streams: one per purpose, each used only through its function below, so two modules
# that must draw the same numbers (the rollout loop's oracle and the teaching page's hints) cannot
# disagree. The tags are part of every archived run's numbers: never change one.
_CORRECTION, _ACTIONS, _INSTRUCTION_PHRASING, _CORRECTION_PHRASING = 0xC0, 0xAC7, 0xFA, 0xFB
_EVALUATION, _RL = 0xE7A1, 0x5B3


def correction_rng(seed: int, task_id: int, attempt_index: int) -> np.random.Generator:
    """The oracle's choices for the correction after attempt ``attempt_index`` of ``task_id``."""
    return derive_rng(seed, task_id, attempt_index, _CORRECTION)


def actions_rng(seed: int, round_index: int, task_ids: Sequence[int]) -> np.random.Generator:
    """Sampled actions of one batch of tasks (a work unit) in round ``round_index``."""
    return derive_rng(seed, round_index, *task_ids[:1], len(task_ids), _ACTIONS)


def reset_seed(seed: int, task_id: int, attempt_index: int) -> int:
    """The env's reset seed for attempt ``attempt_index`` of ``task_id``."""
    return derive_seed(seed, task_id, attempt_index)


def instruction_phrasing_rng(seed: int, task_id: int) -> np.random.Generator:
    """The paraphrase drawn for ``task_id``'s instruction."""
    return derive_rng(seed, task_id, _INSTRUCTION_PHRASING)


def correction_phrasing_rng(seed: int, task_id: int, attempt_index: int) -> np.random.Generator:
    """The paraphrase drawn for the correction after attempt ``attempt_index``."""
    return derive_rng(seed, task_id, attempt_index, _CORRECTION_PHRASING)


def evaluation_seed(seed: int) -> int:
    """The rollout seed of a meta-test with evaluation seed ``seed``."""
    return derive_seed(seed, _EVALUATION)


def rl_seed(seed: int, task_id: int) -> int:
    """The seed of an RL job on ``task_id`` (32 bits: SB3 seeds numpy's legacy generator too)."""
    return derive_seed(seed, task_id, _RL) % 2**32

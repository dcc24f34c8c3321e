"""Synthetic attempts for tests and benchmarks (no env, no expert): realistic-looking shapes only.

``grid``: ``(7, 7, 6)`` uint8 egocentric windows cut from a random 25x25 multi-room-like map (walls,
doors, a few coloured objects; channels: object type, colour, state, three sparse flag planes) along
a random walk, so consecutive observations overlap like real ones. ``vector``: ``(28,)`` float32
smooth random walks (relocation-like).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from gpl_dist.records import Attempt, WorkUnit

GRID = "grid"
VECTOR = "vector"
TOKENS = 12
_WORDS = "go to the red green blue door room key ball box enter left right pick up move square triangle".split()


def _sentence(rng: np.random.Generator, n: int) -> tuple[str, np.ndarray]:
    words = [str(w) for w in rng.choice(_WORDS, size=n)]
    ids = np.zeros(TOKENS, np.int64)
    ids[: min(n, TOKENS)] = rng.integers(2, 40, size=min(n, TOKENS))
    return " ".join(words), ids


def _grid_observations(rng: np.random.Generator, steps: int) -> np.ndarray:
    size, pad = 25, 3
    world = np.zeros((size + 2 * pad, size + 2 * pad, 6), np.uint8)
    world[:, :, 0] = 2  # outside the map reads as wall
    inner = world[pad : pad + size, pad : pad + size]
    inner[:, :, 0] = 1  # empty floor
    for x in (0, 8, 16, 24):  # room walls with a door each
        inner[:, x, 0] = 2
        inner[x, :, 0] = 2
    for x in (4, 12, 20):
        for w in (8, 16):
            inner[x, w, 0], inner[x, w, 1], inner[x, w, 2] = 4, rng.integers(0, 6), rng.integers(0, 3)
            inner[w, x, 0], inner[w, x, 1] = 4, rng.integers(0, 6)
    objs = rng.integers(1, size - 1, size=(6, 2))
    inner[objs[:, 0], objs[:, 1], 0] = rng.integers(5, 9, size=6)
    inner[objs[:, 0], objs[:, 1], 1] = rng.integers(0, 6, size=6)
    inner[objs[0, 0], objs[0, 1], 3] = 1  # goal flag
    moves = np.array([[0, 1], [1, 0], [0, -1], [-1, 0]])
    walk = np.cumsum(moves[rng.integers(0, 4, size=steps)] * (rng.random((steps, 1)) < 0.6), axis=0)
    pos = np.clip(walk + rng.integers(1, size - 1, size=2), 0, size - 1) + pad
    d = np.arange(-3, 4)
    obs = world[pos[:, 0, None, None] + d[None, :, None], pos[:, 1, None, None] + d[None, None, :]]
    obs[:, 3, 3, 4] = rng.integers(0, 4, size=steps)  # agent direction
    obs[:, :, :, 5] = 0
    return obs


def make_attempt(
    rng: np.random.Generator, kind: str, task_id: int, k: int, steps: int, split: str = "train", policy_version: int = 0
) -> Attempt:
    """A synthetic attempt with random observations (tests and benchmarks)."""
    if kind == GRID:
        obs = _grid_observations(rng, steps)
    elif kind == VECTOR:
        obs = np.cumsum(rng.normal(0, 0.05, size=(steps, 28)), axis=0).astype(np.float32)
    else:
        raise ValueError(kind)
    instr, instr_ids = _sentence(np.random.default_rng(task_id), 6)
    corrected = bool(rng.random() < 0.8)
    corr, corr_ids = _sentence(rng, 4) if corrected else ("", np.zeros(TOKENS, np.int64))
    completion = float(min(1.0, rng.random() * 0.5 + 0.15 * k))
    return Attempt(
        task_id=task_id, split=split, attempt_index=k, instruction=instr, instruction_ids=instr_ids,
        observations=obs, actions=rng.integers(0, 7, steps).astype(np.int64),
        expert_actions=rng.integers(0, 7, steps).astype(np.int64), completion=completion,
        success=completion >= 0.95, correction=corr, correction_kind="subgoal" if corrected else "",
        correction_ids=corr_ids, seed=int(rng.integers(0, 2**31)), policy_version=policy_version,
    )


def synthetic_unit(
    round_index: int,
    unit_index: int,
    task_ids: Sequence[int],
    kind: str = GRID,
    attempts_per_task: int = 3,
    steps: int | tuple[int, int] = 100,
    seed: int = 0,
    interleave: bool = True,
) -> tuple[WorkUnit, list[Attempt]]:
    """A work unit and its attempts: ``attempts_per_task`` (k = 0, 1, ...) per task.

    ``steps`` is a fixed length or an inclusive ``(low, high)`` range; ``interleave`` orders the
    attempts k-major (all tasks' attempt 0, then attempt 1, ...), as a batched worker would.
    """
    rng = np.random.default_rng([seed, round_index, unit_index])
    unit = WorkUnit(round_index, unit_index, tuple(task_ids), "train", seed, round_index)
    order = [(t, k) for k in range(attempts_per_task) for t in task_ids] if interleave else [
        (t, k) for t in task_ids for k in range(attempts_per_task)
    ]
    out = []
    for t, k in order:
        n = steps if isinstance(steps, int) else int(rng.integers(steps[0], steps[1] + 1))
        out.append(make_attempt(rng, kind, t, k, n, policy_version=round_index))
    return unit, out

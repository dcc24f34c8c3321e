"""The task set: (level, seed) pairs, read from the versioned file ``gpl_babyai/splits/babyai.json``.

Task ``t`` is row ``t`` of the file's ``tasks``: ``[level index, seed, mission, bot steps]`` (the
level's name is ``levels[level index]``; ``bot steps`` is how many steps the BabyAI bot, as
minigrid ships it, took to solve it from its start). ``gpl_babyai.generate`` writes the file.
"""

from __future__ import annotations

import functools
import json
from pathlib import Path
from typing import NamedTuple

SPLIT_FILE = Path(__file__).with_name("splits") / "babyai.json"


class Task(NamedTuple):
    """One row of the task table: a BabyAI level, its seed, its mission, the bot's steps from its start."""

    level: str
    seed: int
    mission: str
    bot_steps: int


@functools.cache
def table() -> dict:
    """The split file's contents."""
    return json.loads(SPLIT_FILE.read_text())


@functools.cache
def tasks() -> tuple[Task, ...]:
    """Every task, by task id."""
    raw = table()
    levels = raw["levels"]
    return tuple(Task(levels[i], int(seed), mission, int(steps)) for i, seed, mission, steps in raw["tasks"])


def num_tasks() -> int:
    """The number of tasks (ids ``0..num_tasks-1``)."""
    return len(tasks())


def splits() -> dict[str, tuple[int, ...]]:
    """Every split: name -> task ids, in the file's order."""
    return {name: tuple(int(t) for t in ids) for name, ids in table()["splits"].items()}


def check_task_id(task_id) -> int:
    """``task_id`` as an int; ``ValueError`` naming it unless an int in ``0..num_tasks-1``."""
    n = num_tasks()
    if isinstance(task_id, bool) or not hasattr(task_id, "__index__") or not 0 <= int(task_id) < n:
        raise ValueError(f"task_id must be an int in 0..{n - 1}, got {task_id!r}")
    return int(task_id)


def task(task_id: int) -> Task:
    """The row of ``task_id``."""
    return tasks()[check_task_id(task_id)]


def tasks_of_level(level: str) -> tuple[int, ...]:
    """The task ids of ``level``, ascending."""
    return tuple(i for i, t in enumerate(tasks()) if t.level == level)

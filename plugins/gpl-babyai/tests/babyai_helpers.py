"""Shared helpers of the plug-in's tests: reference minigrid envs and sample tasks."""

from __future__ import annotations

import contextlib
import io

import gymnasium as gym
import minigrid  # noqa: F401
import numpy as np

from gpl_babyai import tasks as task_table


def reference_level(level: str, seed: int):
    """minigrid's own env of ``level`` generated with ``seed`` (unwrapped), and its first observation image."""
    env = gym.make(f"BabyAI-{level}-v0").unwrapped
    with contextlib.redirect_stdout(io.StringIO()):
        obs, _ = env.reset(seed=seed)
    return env, obs["image"]


def sample_tasks(per_level: int, split: str | None = None) -> list[int]:
    """``per_level`` tasks of every level (of ``split`` when given), spread over its seeds."""
    chosen = set(task_table.splits()[split]) if split else None
    out = []
    for level in task_table.table()["levels"]:
        ids = [t for t in task_table.tasks_of_level(level) if chosen is None or t in chosen]
        if ids:
            out += [ids[int(i)] for i in np.linspace(0, len(ids) - 1, num=min(per_level, len(ids))).round()]
    return out

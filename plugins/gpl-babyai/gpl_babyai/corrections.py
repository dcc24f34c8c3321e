"""Correction oracles of the BabyAI domain, in BabyAI's own words.

All corrections are computed after an attempt from the env's final state and its progress through
the task's plan (``gpl_babyai.plan``: the subgoals the bot achieves from the start knowing the
whole map; ``env.subgoals_done`` = ``k``, how many the attempt achieved in order). Subgoal ``k``
is the first one the attempt did not achieve.

Kinds (``make_corrector(kind)``):

- ``default`` / ``subgoal`` (the paper's oracle): the text of subgoal ``k``: "open the red door",
  "pick up the blue key", "go to the green ball", "put the yellow box next to the grey key";
  the last subgoal when ``k`` reached it without BabyAI's verifier agreeing.
- ``directional``: where the object of subgoal ``k`` lies from the agent's final pose,
  "the <colour> <type> is <where>" with ``where`` one of "in front of you", "behind you",
  "on your left", "on your right": with ``v`` the vector from the agent to the object,
  ``f`` its component along the agent's heading and ``r`` to its right, "in front of you" if
  ``|f| >= |r|`` and ``f >= 0``, "behind you" if ``|f| >= |r|`` and ``f < 0``, else "on your
  right" (``r > 0``) or "on your left". The object: the door of an ``open`` subgoal; for
  ``pickup`` and ``goto``, the nearest object of the subgoal's type and colour on the grid
  (Manhattan distance; ties drawn with ``rng``); for ``putnext``, the object to move, or the
  object to put it next to while the agent carries the former. When that object is in the
  agent's hands (nothing of it on the grid), the subgoal's text instead.
- ``all``: ``subgoal`` or ``directional``, drawn with ``rng``.
- ``retry`` (the retry control): ``RETRY_TEXT``, the same sentence after every attempt.

A solved attempt gets ``DONE_TEXT`` (the rollout never asks: it stops a solved task).
``full_information(env)``: the plan's subgoals joined by "then", e.g. "pick up the yellow key then
open the yellow door".
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
from minigrid.core.constants import COLOR_NAMES

from gpl_dist.records import Correction

DONE_TEXT = "you are done"
RETRY_TEXT = "you are not done"
KINDS = ("default", "subgoal", "directional", "all", "retry")
WHERE = ("in front of you", "behind you", "on your left", "on your right")
OBJECT_TYPES = ("key", "ball", "box")
DOOR = "door"


def _unwrapped(env: Any):
    return getattr(env, "unwrapped", env)


def subgoal_correction(env: Any) -> Correction:
    """The first subgoal of the plan the attempt did not achieve."""
    u = _unwrapped(env)
    if u.success:
        return Correction(DONE_TEXT, "subgoal")
    plan = u.plan
    return Correction(plan[min(u.subgoals_done, len(plan) - 1)].text, "subgoal")


def _where(level, target) -> str:
    ax, ay = (int(v) for v in level.agent_pos)
    vx, vy = int(target[0]) - ax, int(target[1]) - ay
    dx, dy = (int(v) for v in level.dir_vec)
    rx, ry = (int(v) for v in level.right_vec)
    f, r = vx * dx + vy * dy, vx * rx + vy * ry
    if abs(f) >= abs(r):
        return WHERE[0] if f >= 0 else WHERE[1]
    return WHERE[3] if r > 0 else WHERE[2]


def _nearest(level, kind: str, colour: str, rng: np.random.Generator):
    """The position of the nearest grid object of ``kind`` and ``colour`` (ties drawn with
    ``rng``), or None when there is none on the grid."""
    ax, ay = (int(v) for v in level.agent_pos)
    best, spots = None, []
    grid = level.grid
    for y in range(grid.height):
        for x in range(grid.width):
            cell = grid.get(x, y)
            if cell is not None and cell.type == kind and cell.color == colour:
                d = abs(x - ax) + abs(y - ay)
                if best is None or d < best:
                    best, spots = d, [(x, y)]
                elif d == best:
                    spots.append((x, y))
    if not spots:
        return None
    return spots[int(rng.integers(len(spots)))] if len(spots) > 1 else spots[0]


def directional_correction(env: Any, rng: np.random.Generator) -> Correction:
    """Where the object of the first subgoal not achieved lies, from the agent's final pose."""
    u = _unwrapped(env)
    if u.success:
        return Correction(DONE_TEXT, "directional")
    level = u.level
    plan = u.plan
    goal = plan[min(u.subgoals_done, len(plan) - 1)]
    a = goal.args
    if goal.kind == "open":
        thing, spot = (DOOR, a[2]), (a[0], a[1])
    elif goal.kind in ("pickup", "goto"):
        thing = (a[0], a[1])
        spot = _nearest(level, a[0], a[1], rng)
    else:
        c = level.carrying
        thing = (a[2], a[3]) if c is not None and c.type == a[0] and c.color == a[1] else (a[0], a[1])
        spot = _nearest(level, thing[0], thing[1], rng)
    if spot is None:
        return Correction(goal.text, "directional")
    return Correction(f"the {thing[1]} {thing[0]} is {_where(level, spot)}", "directional")


def retry_correction(env: Any) -> Correction:
    """The same sentence after every attempt: it says nothing of the attempt."""
    return Correction(RETRY_TEXT, "retry")


def full_information(env: Any) -> str:
    """The plan's subgoals, joined by "then"."""
    return " then ".join(_unwrapped(env).subgoal_texts)


class BabyAICorrector:
    """``correct(env, rng) -> Correction`` and ``full_information(env) -> str`` for one kind."""

    def __init__(self, kind: str = "default"):
        if kind not in KINDS:
            raise ValueError(f"unknown babyai correction kind '{kind}' (known: {', '.join(KINDS)})")
        self.kind = "subgoal" if kind == "default" else kind

    def correct(self, env: Any, rng: np.random.Generator) -> Correction:
        kind = self.kind
        if kind == "all":
            kind = ("subgoal", "directional")[int(rng.integers(2))]
        if kind == "subgoal":
            return subgoal_correction(env)
        if kind == "directional":
            return directional_correction(env, rng)
        return retry_correction(env)

    def full_information(self, env: Any) -> str:
        return full_information(env)


def make_corrector(kind: str = "default") -> BabyAICorrector:
    """The oracle of ``kind`` (``KINDS``)."""
    return BabyAICorrector(kind)


@functools.cache
def phrasings() -> tuple[str, ...]:
    """Every sentence an oracle of a text kind can say (what a person's correction is compared with)."""
    objects = [(t, c) for t in OBJECT_TYPES for c in COLOR_NAMES]
    things = objects + [(DOOR, c) for c in COLOR_NAMES]
    subgoal = ([f"open the {c} door" for c in COLOR_NAMES] + [f"pick up the {c} {t}" for t, c in objects]
               + [f"go to the {c} {t}" for t, c in things]
               + [f"put the {c1} {t1} next to the {c2} {t2}" for t1, c1 in objects for t2, c2 in things])
    directional = [f"the {c} {t} is {w}" for t, c in things for w in WHERE]
    return (*subgoal, *directional, DONE_TEXT, RETRY_TEXT)

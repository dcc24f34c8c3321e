"""Correction oracles of the multi-room domain (paper §6.1.1 and Table 4).

All corrections are computed after an attempt from the env's final state and its per-episode
tracking (``env.unwrapped.min_subgoals_left``: the fewest subgoals left at any step). Let
``k = 5 - min_subgoals_left`` be the index of the first subgoal of the task's list (see
``MultiRoomEnv``) that the attempt never completed.

Kinds (``make_multiroom_corrector(kind)``):

- ``"default"`` / ``"subgoal"`` (the paper's): the text of subgoal ``k``, e.g.
  "enter the blue room", "pick up the green triangle" (the authors' ``all_subgoals[5 - left]``).
- ``"subgoal_goal_room_apart"``: ``subgoal``, but the fourth subgoal (``k = 3``) is said
  "go to the <goal room> room", so it is worded unlike the first ("enter the <object room>
  room"), as the authors' code does (``carry <goalroom> door``; the paper's text says "enter").
  With "enter" for both, a model that sees corrections as an order-free set and no trajectory
  cannot tell "enter the object's room" from "enter the goal's room" (``research/correction_pairs.py``).
  The kind recorded is ``subgoal``.
- ``"directional"``: the compass direction of subgoal ``k``'s target from the agent's final cell,
  ``"<thing> is <dir>"`` with ``dir`` in north, northeast, east, southeast, south, southwest,
  west, northwest (45-degree sectors centred on each; north = -y) or ``here`` (same cell):

  ====  ============================  ===================================
  k     thing                         target cell
  ====  ============================  ===================================
  0     "the object room"             the object room's door
  1     "the object"                  the true object (the agent if held)
  2     "the exit"                    the object room's door
  3     "the goal room"               the goal room's door
  4     "the goal"                    the true goal
  ====  ============================  ===================================

- ``"binary"``: one yes/no fact about the final state relevant to subgoal ``k``:

  - k = 0: "you are in the right room" if inside the object room, else "you are in the wrong
    room" (the hallway counts as a wrong room);
  - k = 1: "you have the wrong object" if holding a decoy; else right/wrong room with respect to
    the region (room or hallway) where the true object lies;
  - k = 2: "you have the right object" if holding it, "you have the wrong object" if holding a
    decoy, else "you do not have the object";
  - k = 3, 4: holding the true object -> right/wrong room w.r.t. the goal room; holding a decoy
    -> "you have the wrong object"; empty hands -> "you do not have the object".
- ``"all"``: one of subgoal / directional / binary, uniformly with ``rng``.
- ``"retry"`` (the retry control): ``RETRY_TEXT``, the same sentence after every attempt, whatever
  it did. A policy trained with it still sees its earlier trajectories, so its gain over attempts
  is what retrying alone buys; set against GPL's, it separates retrying from what the correction says.
- ``"reward"`` (the GPR variant): the attempt's outcome in words, ``"reward <n> of five"`` with
  ``n`` in zero..five the number of subgoals completed (= 5 x completion).

A solved attempt gets ``"you are done"`` (kind ``subgoal``, or the oracle's own kind for
``directional`` / ``binary``; ``reward`` says "reward five of five"). The rollout worker stops
rolling a solved task out, so this is rarely asked for.

``full_information(env)``: the 5 subgoals in one sentence joined by "then" (26 words).
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from gpl_dist.envs.multiroom import CORRECTION_KINDS
from gpl_dist.envs.multiroom_core import COLOURS, DOOR_CELL, REGION_FLAT, SHAPES, XY, compass
from gpl_dist.records import Correction

KINDS = CORRECTION_KINDS  # declared with the domain
_NUMBERS = ("zero", "one", "two", "three", "four", "five")
DONE_TEXT = "you are done"


def _state(env: Any):
    u = getattr(env, "unwrapped", env)
    k = 5 - u.min_subgoals_left
    return u, k


def subgoal_correction(env: Any) -> Correction:
    """The first subgoal of the original plan that the attempt never achieved (the paper's oracle)."""
    u, k = _state(env)
    if u.success or k >= 5:
        return Correction(DONE_TEXT, "subgoal")
    return Correction(u.subgoal_texts[k], "subgoal")


def subgoal_goal_room_apart_correction(env: Any) -> Correction:
    """``subgoal_correction``, with the goal room's subgoal said "go to the <goal room> room"."""
    u, k = _state(env)
    if k == 3:  # success leaves no subgoal (k = 5)
        return Correction(f"go to the {COLOURS[u.task.goal_room]} room", "subgoal")
    return subgoal_correction(env)


def directional_correction(env: Any) -> Correction:
    """The compass direction of the next subgoal's target from the agent's final cell (``directional``)."""
    u, k = _state(env)
    if u.success or k >= 5:
        return Correction(DONE_TEXT, "directional")
    task = u.task
    if k == 0:
        thing, cell = "the object room", DOOR_CELL[task.obj_room]
    elif k == 1:
        thing, cell = "the object", u._obj_cell[0]  # never held yet (else k >= 2): on the grid
    elif k == 2:
        thing, cell = "the exit", DOOR_CELL[task.obj_room]
    elif k == 3:
        thing, cell = "the goal room", DOOR_CELL[task.goal_room]
    else:
        thing, cell = "the goal", task.goals[0].cell
    (tx, ty), (ax, ay) = XY[cell], XY[u._pos]
    return Correction(f"{thing} is {compass(tx - ax, ty - ay)}", "directional")


def binary_correction(env: Any) -> Correction:
    """One yes/no fact about the final state relevant to the next subgoal (module docstring: ``binary``)."""
    u, k = _state(env)
    if u.success or k >= 5:
        return Correction(DONE_TEXT, "binary")
    task = u.task
    region = REGION_FLAT[u._pos]

    def room_fact(ok: bool) -> Correction:
        return Correction("you are in the right room" if ok else "you are in the wrong room", "binary")

    carrying = u._carrying
    if k == 0:
        return room_fact(region == 1 + task.obj_room)
    if k == 1:
        if carrying > 0:
            return Correction("you have the wrong object", "binary")
        return room_fact(region == REGION_FLAT[u._obj_cell[0]])
    if carrying > 0:
        return Correction("you have the wrong object", "binary")
    if carrying < 0:
        return Correction("you do not have the object", "binary")
    if k == 2:
        return Correction("you have the right object", "binary")
    return room_fact(region == 1 + task.goal_room)


def reward_correction(env: Any) -> Correction:
    """``reward <n> of five``: the subgoals completed, in words (the reward variant)."""
    u, k = _state(env)
    return Correction(f"reward {_NUMBERS[min(k, 5)]} of five", "reward")


#: The retry control's one sentence (words of the domain's vocabulary, so no model's shapes change).
RETRY_TEXT = "you are not done"


def retry_correction(env: Any) -> Correction:
    """The same sentence after every attempt (module docstring: ``retry``): it says nothing of the attempt."""
    return Correction(RETRY_TEXT, "retry")


def full_information(env: Any) -> str:
    """Every subgoal of the task's plan, joined by ``then``."""
    u = getattr(env, "unwrapped", env)
    return " then ".join(u.subgoal_texts)


class MultiRoomCorrector:
    """``correct(env, rng) -> Correction`` and ``full_information(env) -> str`` for one kind."""

    _RULES = {
        "subgoal": subgoal_correction,
        "directional": directional_correction,
        "binary": binary_correction,
        "reward": reward_correction,
        "subgoal_goal_room_apart": subgoal_goal_room_apart_correction,
        "retry": retry_correction,
    }

    def __init__(self, kind: str = "default"):
        if kind not in KINDS:
            raise ValueError(f"unknown multiroom correction kind '{kind}' (known: {', '.join(KINDS)})")
        self.kind = "subgoal" if kind == "default" else kind

    def correct(self, env: Any, rng: np.random.Generator) -> Correction:
        kind = self.kind
        if kind == "all":
            kind = ("subgoal", "directional", "binary")[int(rng.integers(3))]
        return self._RULES[kind](env)

    def full_information(self, env: Any) -> str:
        return full_information(env)


_COMPASS = ("north", "northeast", "east", "southeast", "south", "southwest", "west", "northwest", "here")
_THINGS = ("the object room", "the object", "the exit", "the goal room", "the goal")


@functools.cache
def phrasings(kind: str | None = None) -> tuple[str, ...]:
    """Every correction a multi-room oracle of a text kind (subgoal, directional, binary, retry) can
    say, or those of ``kind`` alone (none for ``reward``, whose sentence is a count): the phrasings
    a person's correction is compared with (``gpl_dist.app.teaching``)."""
    rooms = [f"enter the {c} room" for c in COLOURS] + [f"exit the {c} room" for c in COLOURS]
    things = [f"pick up the {c} {s}" for c in COLOURS for s in SHAPES] + [f"go to the {c} goal" for c in COLOURS]
    goal_room = [f"go to the {c} room" for c in COLOURS]
    directional = [f"{thing} is {d}" for thing in _THINGS for d in _COMPASS]
    binary = ["you are in the right room", "you are in the wrong room", "you have the wrong object",
              "you have the right object", "you do not have the object"]
    by_kind = {"subgoal": (*rooms, *things, DONE_TEXT), "subgoal_goal_room_apart": (*rooms, *goal_room, *things, DONE_TEXT),
               "directional": (*directional, DONE_TEXT), "binary": (*binary, DONE_TEXT), "retry": (RETRY_TEXT,),
               "reward": ()}
    by_kind["default"] = by_kind["subgoal"]
    by_kind["all"] = (*rooms, *things, *directional, *binary, DONE_TEXT)
    if kind is not None:
        return by_kind[kind]
    return (*rooms, *goal_room, *things, *directional, *binary, DONE_TEXT, RETRY_TEXT)


def make_multiroom_corrector(kind: str = "default") -> MultiRoomCorrector:
    """The oracle of ``kind`` in default/subgoal, directional, binary, all, reward."""
    return MultiRoomCorrector(kind)

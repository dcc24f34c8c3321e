"""Correction oracle of robotic object relocation (the paper's computational proxy for a human).

Called once an attempt has ended, on the env in its final state. Rules (paper section 6.1.2, with
the probabilities of the authors' code):

1. **touch** (deterministic): the goal block moved less than 0.03 from its position at reset, or
   another movable block moved more than it -> ``"Touch the <goal colour> block"``.
2. otherwise one of, drawn with ``rng``:

   - p=0.5 **directional**: ``"Move a little <dir>"`` / ``"Move a lot <dir>"``; ``<dir>`` is the
     one of 8 directions (``up``, ``up right``, ``right``, ...) closest in angle to block->target;
     "a little" when the block is less than 0.3 from the target;
   - p=0.2 **relational**: ``"Move <dir> of the <colour> block"``, the target's direction from the
     fixed block nearest the target;
   - p=0.2 the same for the second-nearest fixed block;
   - p=0.1 **relational**: ``"Move closer to the <colour> block"``, the fixed block minimising
     dist(block, target) + dist(block, goal block).

``kind``: ``default`` / ``mixed`` (the rules above), or a single type for tests and ablations:
``directional``, ``relational`` (the three relational forms in proportion 2:2:1), ``touch``.
``reward`` is the GPR variant (see ``reward_text``). ``retry`` is the retry control: ``RETRY_TEXT``,
the same sentence after every attempt whatever it did, so a policy trained with it gains over
attempts from retrying alone (set against GPL's gain, it separates retrying from what is said).

``full_information(env)``: which block and the exact target, digits spelled out so the shared
tokenizer reads them: ``"move red to x zero point nine three y minus zero point four one"``
(two decimals; ``minus`` for negative values).
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np

from gpl_dist.envs.relocation_core import (
    CORRECTION_KINDS,
    DIGIT_WORDS,
    DIRECTION_PHRASES,
    FIXED_COLORS,
    FIXED_XY,
    MOVABLE_COLORS,
    direction_phrase,
    spell_number,
)
from gpl_dist.records import Correction

TOUCH_MIN_MOVE = 0.03
A_LITTLE = 0.3
KINDS = CORRECTION_KINDS  # declared with the domain
#: The retry control's one sentence (words of the domain's vocabulary, so no model's shapes change).
RETRY_TEXT = "move the block"


def _state(env: Any):
    e = getattr(env, "unwrapped", env)
    task = e.task
    blocks = np.array([e.block_xy(i) for i in range(3)])
    return e, task, blocks, np.array(task.target)


def touch_needed(env: Any) -> bool:
    """Rule 1: the goal block barely moved, or another movable block moved more than it."""
    e, task, blocks, _ = _state(env)
    moved = np.hypot(*(blocks - e.initial_blocks).T)
    goal = moved[task.block]
    return bool(goal < TOUCH_MIN_MOVE or np.any(np.delete(moved, task.block) > goal))


def touch_text(env: Any) -> str:
    """``Touch the <colour> block``: the block the attempt should have moved."""
    _, task, _, _ = _state(env)
    return f"Touch the {task.block_color} block"


def directional_text(env: Any) -> str:
    """``Move a little/a lot <dir>``: the way from where the goal block ended to the target."""
    _, task, blocks, target = _state(env)
    d = target - blocks[task.block]
    amount = "a little" if math.hypot(*d) < A_LITTLE else "a lot"
    return f"Move {amount} {direction_phrase(d[0], d[1])}"


def relational_text(env: Any, rank: int) -> str:
    """``"Move <dir> of the <colour> block"`` for the ``rank``-th (0 or 1) nearest fixed block to the target."""
    _, _, _, target = _state(env)
    order = np.argsort(np.hypot(*(FIXED_XY - target).T), kind="stable")
    f = int(order[rank])
    d = target - FIXED_XY[f]
    return f"Move {direction_phrase(d[0], d[1])} of the {FIXED_COLORS[f]} block"


def closer_text(env: Any) -> str:
    """``Move closer to the <colour> block``: the fixed block minimising its distance to the target plus to the goal block."""
    _, task, blocks, target = _state(env)
    cost = np.hypot(*(FIXED_XY - target).T) + np.hypot(*(FIXED_XY - blocks[task.block]).T)
    return f"Move closer to the {FIXED_COLORS[int(np.argmin(cost))]} block"


def reward_text(env: Any) -> str:
    """GPR's scalar feedback: the attempt's completion in tenths, as a word (``"reward seven"``)."""
    e = getattr(env, "unwrapped", env)
    return f"reward {DIGIT_WORDS[int(round(10.0 * e.completion()))]}"


def full_information_text(env: Any) -> str:
    """Which block to move and the exact target, digits spelt out (module docstring)."""
    _, task, _, target = _state(env)
    return f"move {MOVABLE_COLORS[task.block]} to x {spell_number(target[0])} y {spell_number(target[1])}"


def _relational(env: Any, u: float) -> Correction:
    """Relational correction for ``u`` uniform in [0, 0.5): nearest (0.2), second (0.2), closer (0.1)."""
    if u < 0.2:
        return Correction(relational_text(env, 0), "relational")
    if u < 0.4:
        return Correction(relational_text(env, 1), "relational")
    return Correction(closer_text(env), "relational")


class RelocationCorrector:
    """``correct(env, rng) -> Correction`` and ``full_information(env) -> str`` (see module docstring)."""

    def __init__(self, kind: str = "default"):
        if kind not in KINDS:
            raise ValueError(f"unknown relocation correction kind '{kind}' (known: {', '.join(KINDS)})")
        self.kind = kind

    def correct(self, env: Any, rng: np.random.Generator) -> Correction:
        kind = self.kind
        if kind == "touch":
            return Correction(touch_text(env), "touch")
        if kind == "directional":
            return Correction(directional_text(env), "directional")
        if kind == "relational":
            return _relational(env, 0.5 * rng.random())
        if kind == "reward":
            return Correction(reward_text(env), "reward")
        if kind == "retry":
            return Correction(RETRY_TEXT, "retry")
        # default / mixed
        if touch_needed(env):
            return Correction(touch_text(env), "touch")
        u = rng.random()
        if u < 0.5:
            return Correction(directional_text(env), "directional")
        return _relational(env, u - 0.5)

    def full_information(self, env: Any) -> str:
        return full_information_text(env)


@functools.cache
def phrasings(kind: str | None = None) -> tuple[str, ...]:
    """Every correction the relocation oracle of a text kind can say (touch, directional,
    relational, retry), or those of ``kind`` alone (none for ``reward``): the phrasings a person's
    correction is compared with (``gpl_dist.app.teaching``)."""
    touch = tuple(f"Touch the {c} block" for c in MOVABLE_COLORS)
    directional = tuple(f"Move {amount} {d}" for amount in ("a little", "a lot") for d in DIRECTION_PHRASES)
    relational = (*(f"Move {d} of the {c} block" for c in FIXED_COLORS for d in DIRECTION_PHRASES),
                  *(f"Move closer to the {c} block" for c in FIXED_COLORS))
    by_kind = {"touch": touch, "directional": directional, "relational": relational, "retry": (RETRY_TEXT,),
               "reward": (), "default": (*touch, *directional, *relational)}
    by_kind["mixed"] = by_kind["default"]
    if kind is not None:
        return by_kind[kind]
    return (*touch, *directional, *relational, RETRY_TEXT)


def make_relocation_corrector(kind: str = "default") -> RelocationCorrector:
    """The relocation oracle of ``kind`` (``default`` and ``mixed`` are the paper's)."""
    return RelocationCorrector(kind)

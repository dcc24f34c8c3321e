"""Multi-room object manipulation (paper §6.1.1): a fast standalone numpy grid world.

See :class:`MultiRoomEnv` for the full specification. Static data (layout, tasks, encodings) lives
in :mod:`gpl_dist.envs.multiroom_core`; rendering in :mod:`gpl_dist.envs.multiroom_render`.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from gpl_dist.envs.modes import check_modes
from gpl_dist.envs.multiroom_core import (
    ACTION_DROP,
    ACTION_PICKUP,
    COLOURS,
    D_OPEN,
    DOOR_CELL,
    DOOR_INDEX_FLAT,
    K_FLOOR,
    KIND_FLAT,
    NUM_TASKS,
    PAD,
    REGION_FLAT,
    SHAPES,
    START_CELL,
    STEP,
    VIEW,
    VIS_LUT,
    VIS_REGION,
    XY,
    MultiRoomTask,
    check_task_id,
    get_task,
    task_static,
)
from gpl_dist.language import ParaphraseRule, Paraphrases, Vocabulary
from gpl_dist.models.sizes import Sizes
from gpl_dist.roles import DomainSpec, lazy

__all__ = ["MultiRoomEnv", "MultiRoomTask", "VOCABULARY", "DOMAIN", "make_env", "make_splits",
           "HELDOUT_OBJECTS", "MAX_STEPS"]

MAX_STEPS = 100
NUM_SUBGOALS = 5

#: Every word of instructions, corrections (all kinds) and the full-information text. The order
#: is fixed: token ids are ``2 + index`` and must never change (append new words at the end).
WORDS = (
    "move", "to", "square", "ball", "triangle",
    "blue", "green", "grey", "purple", "red", "yellow",
    "enter", "the", "room", "pick", "up", "exit", "go", "goal", "then",
    "you", "are", "done", "in", "wrong", "right", "have", "do", "not", "object", "is", "here",
    "north", "south", "east", "west", "northeast", "northwest", "southeast", "southwest",
    "reward", "of", "zero", "one", "two", "three", "four", "five",
)
VOCABULARY = Vocabulary(words=WORDS, max_tokens=32)

_THING = "(?P<thing>the object room|the object|the exit|the goal room|the goal)"
#: Five phrasings of the instruction and of every correction form (``Paraphrases``): the
#: canonical one, two said in training (``model.paraphrases``), two held out for
#: ``eval.phrasings: heldout``. Held-out phrasings are new sentences of words that training
#: phrasings use (``tests/test_env_contract.py`` checks), so they test the text encoders'
#: generalisation, not unseen words.
PARAPHRASES = Paraphrases((
    ParaphraseRule(r"move (?P<oc>\w+) (?P<os>\w+) to (?P<gc>\w+) square", (
        "Move {oc} {os} to {gc} square", "bring the {oc} {os} to the {gc} square",
        "carry the {oc} {os} over to the {gc} goal", "bring the {oc} {os} over to the {gc} goal",
        "carry the {oc} {os} to the {gc} square")),
    ParaphraseRule(r"enter the (?P<c>\w+) room", (
        "enter the {c} room", "go into the {c} room", "walk inside the {c} room", "go inside the {c} room",
        "walk into the {c} room")),
    ParaphraseRule(r"pick up the (?P<c>\w+) (?P<s>\w+)", (
        "pick up the {c} {s}", "grab the {c} {s}", "take the {c} {s} with you", "take the {c} {s}",
        "grab the {c} {s} with you")),
    ParaphraseRule(r"exit the (?P<c>\w+) room", (
        "exit the {c} room", "leave the {c} room", "get out of the {c} room", "go out of the {c} room",
        "walk out of the {c} room")),
    ParaphraseRule(r"go to the (?P<c>\w+) room", (  # correction kind subgoal_goal_room_apart; no new words
        "go to the {c} room", "walk to the {c} room", "head for the {c} room", "walk over to the {c} room",
        "head over to the {c} room")),
    ParaphraseRule(r"go to the (?P<c>\w+) goal", (
        "go to the {c} goal", "walk to the {c} square", "stand on the {c} goal", "go to the {c} square",
        "stand on the {c} square")),
    ParaphraseRule(_THING + r" is (?P<d>\w+)", (
        "{thing} is {d}", "{thing} lies {d}", "head {d} for {thing}", "go {d} for {thing}", "{thing} lies {d} of you")),
    ParaphraseRule(r"you are in the (?P<rw>right|wrong) room", (
        "you are in the {rw} room", "this is the {rw} room", "you stand in the {rw} room",
        "you are inside the {rw} room", "you stand inside the {rw} room")),
    ParaphraseRule(r"you have the (?P<rw>right|wrong) object", (
        "you have the {rw} object", "you carry the {rw} object", "you are holding the {rw} object",
        "the {rw} object is with you", "you carry the {rw} object with you")),
    ParaphraseRule(r"you do not have the object", (
        "you do not have the object", "you are not holding the object", "you carry no object",
        "you do not carry the object", "you are holding no object")),
    ParaphraseRule(r"you are done", (
        "you are done", "well done", "the task is done", "the task is well done", "done well")),
    ParaphraseRule(r"you are not done", (  # the retry control's one sentence; no new words
        "you are not done", "the task is not done", "not done", "you are not done with the task",
        "the task is not well done")),
))

#: Correction oracle kinds (``gpl_dist.corrections.multiroom``): ``default`` is the paper's subgoal oracle.
CORRECTION_KINDS = ("default", "subgoal", "directional", "binary", "all", "reward", "subgoal_goal_room_apart", "retry")

#: (colour, shape) combinations held out by the ``heldout_*`` splits (paper Table 5).
HELDOUT_OBJECTS = (("green", "triangle"), ("red", "ball"))
#: The harder Table 5 (split file version 2): 4 of the 18 (colour, shape) combinations held out by
#: the ``heldout4_*`` splits, chosen once: the two above and two more of other colours, so every
#: shape and four colours are held out.
HELDOUT4_OBJECTS = (("green", "triangle"), ("red", "ball"), ("purple", "square"), ("yellow", "triangle"))
#: In-distribution test tasks of the ``heldout4`` splits (``heldout4_indist_test``).
HELDOUT4_INDIST_TASKS = 250


class MultiRoomEnv(gym.Env):
    """Multi-room object manipulation: carry one object to one goal square in another room.

    ## Description
    A 19x19 grid: six 6x5 rooms (interiors) to the west and east of a central north-south
    hallway (x = 8..10). Each room has one door in the hallway wall, with a fixed colour that
    names the room: blue (7, 3) north-west, green (11, 3) north-east, grey (7, 9) west,
    purple (11, 9) east, red (7, 15) south-west, yellow (11, 15) south-east. Doors start closed;
    moving into a closed door opens it and the agent does not move on that step; doors never close.
    The agent starts at (8, 12) in the hallway and has no heading. A task places the true object
    (colour x shape, shape in ball / triangle / square) in the object room, the true goal square
    in the goal room (another room), and 3 decoy objects (other colour-shape combinations,
    distinct) and 3 decoy goals (other colours, distinct) in random rooms; the 8 items sit at
    distinct cells. Objects and goals can be walked over. ``pickup`` takes the object under the
    agent if its hands are empty; ``drop`` puts the carried object down only on a floor cell
    (room or hallway, not a door) that holds neither an object nor a goal (so a cell never holds
    two items and an object never hides a goal); otherwise both are no-ops. A carried object
    moves with the agent and is not on the grid. The task is solved when the agent stands on the
    true goal while carrying the true object.

    ## Instruction grammar
    ``"Move <object colour> <object shape> to <goal colour> square"`` (paper §6.1.1), e.g.
    "Move green triangle to green square". It names no room: 108 instructions cover 3240 tasks.

    ## Corrections
    (see :mod:`gpl_dist.corrections.multiroom`) The task's 5 subgoals, from the start state:
    "enter the <object room> room", "pick up the <colour> <shape>", "exit the <object room>
    room", "enter the <goal room> room", "go to the <goal colour> goal". Kinds: ``subgoal``
    (paper default: the first subgoal the attempt never completed), ``directional`` (compass
    direction of that subgoal's target, e.g. "the goal room is southwest"), ``binary`` (yes/no
    facts, e.g. "you are in the wrong room", "you have the wrong object"), ``reward`` (GPR:
    "reward three of five"), ``subgoal_goal_room_apart`` (``subgoal`` with the fourth subgoal said
    "go to the <goal room> room", worded unlike the first as in the authors' code) and the
    full-information text (all 5 subgoals joined by "then").

    ## Observation
    ``Box(0, 255, (7, 7, 6), uint8)``, ``obs[row, col, ch]``; the agent is at ``[3, 3]``,
    ``row = 3 + dy``, ``col = 3 + dx`` (north up, east right). Per cell:

    - ch 0 type: 0 unseen, 1 empty floor, 2 wall, 3 door, 4 ball, 5 triangle, 6 square, 7 goal;
    - ch 1 colour: 0 none, 1 blue, 2 green, 3 grey, 4 purple, 5 red, 6 yellow;
    - ch 2 door state: 0 no door, 1 closed, 2 open;
    - ch 3, 4, 5: carried object's type (0 none, 4..6) and colour (0..6), and the carrying flag
      (0/1) -- the same value in every cell of the window.

    The agent's own cell shows what it stands on (floor, object, goal or door). Cells outside the
    grid read as wall. Visibility is per region (walls and closed doors hide what lies behind
    them): walls, doors and out-of-grid cells are always visible (the layout is the same in every
    task); the hallway is always visible; the floor of a room (and its items) is visible only
    when the agent is inside that room, or in the hallway / on a door cell while that room's door
    is open. Hidden cells read 0 in channels 0-2. (Room-to-room sight lines never fit in the 7x7
    window, so "through an open door" is exactly "from the hallway".)

    ## Action space
    ``Discrete(6)``, the paper's order:

    | 0 | up (north, -y)   |
    | 1 | left (west, -x)  |
    | 2 | right (east, +x) |
    | 3 | down (south, +y) |
    | 4 | pickup           |
    | 5 | drop             |

    ## Completion metric
    ``L(state)``, the number of the 5 subgoals still to do, seen from the current state
    (regions: a room is its interior; door cells belong to the hallway):

    - carrying the true object: 0 on the true goal; 1 inside the goal room; 2 in the hallway;
      3 inside any other room (the object room or a wrong room: that room must be exited);
    - otherwise: 4 if the agent is in the region (room or hallway) where the true object lies,
      else 5. (A held decoy does not count; it shows in the corrections instead.)

    ``min_subgoals_left`` is the minimum of ``L`` over the episode (reset included) and
    subgoal ``k`` (0-based) is done iff ``k < 5 - min_subgoals_left``; hence "enter" is done once
    the agent stood in the object room while the object was there, "pick up" once it held the
    object, "exit" once it was in the hallway holding it, "enter <goal room>" once it was in the
    goal room holding it, "go to" on success. ``info["completion"] = (5 - min_subgoals_left) / 5``
    (best so far, as the authors' code). ``info["subgoals"]`` = list of (text, done) for the 5
    subgoals, ``info["success"]`` = sticky success flag. ``info["instruction"]`` is the task's
    instruction (as minigrid's ``mission``) and ``info["instruction_ids"]`` its token ids
    (``VOCABULARY.encode``, 32 ints, as a tuple), in every info; the observation
    stays the array above, which is what the policy reads.

    ## Reward
    ``reward_mode="dense"`` (paper appendix, the PPO experts' reward), after the step:
    ``100 * (previous min_subgoals_left - new min_subgoals_left)`` (i.e. +100 once per newly
    completed subgoal) ``- 0.01 * |agent - w|_2`` where ``w`` is the cell of the next waypoint
    from the current state: carrying the true object -> the true goal if inside the goal room,
    else the door of the room the agent is in (to exit it), else (hallway) the goal room's door;
    not carrying it -> the object if the agent is in the object's region, else the door of the
    room the agent is in, else (hallway) the door of the room holding the object. After success
    the reward is just the distance term (0 while the agent stays on the goal). Losing progress
    (``L`` rising) is not penalised (the authors' code subtracted 100 and used the squared
    distance; the paper's text, followed here, does neither).
    ``reward_mode="sparse"``: 1.0 on the step the task is first solved, else 0.0.

    ## Termination
    By default never terminates (``terminated`` is always False; success is sticky in ``info``):
    the paper's protocol runs every attempt its full 100 steps and reads the best completion, and
    collection, evaluation and teaching use this default. ``terminate_on_success=True`` ends the
    episode (``terminated=True``) on the step the task is first solved, as most gymnasium users
    expect. The env itself truncates at 100 steps (``truncated=True`` from the 100th step on), as does the
    TimeLimit wrapper of ``gymnasium.make("gpl/MultiRoom-v0", task_id=...)``.

    ## Tasks and splits
    ``task_id`` in 0..3239 enumerates (object colour, shape, object room, goal colour, goal room
    != object room): ``task_id = (((oc*3 + shape)*6 + obj_room)*6 + goal_colour)*5 + k`` with
    colours (blue, green, grey, purple, red, yellow), shapes (ball, triangle, square), rooms in
    door-colour order, and the goal room the k-th of the five other rooms. Decoys and all item
    cells are drawn from ``np.random.default_rng([12345, task_id])``; the env is deterministic
    given the task (``reset(seed=...)`` only seeds ``self.np_random``). Splits are in
    ``gpl_dist/splits/multiroom.json`` (see :func:`make_splits`).

    ## Rendering
    ``render_mode="rgb_array"``: the full grid, 32 px tiles (608x608x3 uint8).
    ``render_mode="ansi"``: the grid as text, two characters a cell, with the cells visited since
    reset and a legend (``multiroom_render.render_text``). ``picture_points()``: the agent's pixel in
    the RGB picture (what a drawn path follows).
    """

    metadata = {"render_modes": ["rgb_array", "ansi"], "render_fps": 10}
    domain_name = "multiroom"
    #: what each point of ``picture_points()`` follows (the teaching page's legend)
    picture_point_names = ("the agent",)

    def __init__(self, task_id: int, render_mode: str | None = None, reward_mode: str = "dense",
                 terminate_on_success: bool = False):
        self.task_id = check_task_id(task_id)
        self.terminate_on_success = bool(terminate_on_success)
        self.render_mode, self.reward_mode = check_modes(render_mode, reward_mode)
        self.observation_space = spaces.Box(0, 255, (VIEW, VIEW, 6), np.uint8)
        self.action_space = spaces.Discrete(6)
        task, enc, goal_cells, obj_codes, texts = task_static(self.task_id)
        self.task: MultiRoomTask = task
        self.instruction: str = task.instruction
        self.instruction_ids: tuple[int, ...] = tuple(int(i) for i in VOCABULARY.encode(task.instruction))
        self.subgoal_texts: tuple[str, ...] = texts
        self._enc0 = enc
        self._goal_cells = goal_cells
        self._obj_codes = obj_codes
        self._goal_cell = task.goals[0].cell
        self._goal_region = 1 + task.goal_room
        self._goal_door = DOOR_CELL[task.goal_room]
        self._dense = reward_mode == "dense"
        self._reset_state()

    # ------------------------------------------------------------------ state
    def _reset_state(self) -> None:
        self._enc = self._enc0.copy()
        self._pos = START_CELL
        # the cells visited since reset, kept only for the text picture (render_mode "ansi")
        self._trail: list[int] | None = [START_CELL] if self.render_mode == "ansi" else None
        self._door_mask = 0
        self._obj_cell = [o.cell for o in self.task.objects]  # -1 while carried
        self._obj_at = {c: i for i, c in enumerate(self._obj_cell)}
        self._carrying = -1  # -1 none, 0 true object, 1..3 decoys
        self._carry_vec = np.zeros(3, dtype=np.uint8)
        self._steps = 0
        self._success = False
        self._left = self._subgoals_left_now()
        self._min_left = self._left

    def _subgoals_left_now(self) -> int:
        region = REGION_FLAT[self._pos]
        if self._carrying == 0:
            if region == self._goal_region:
                return 0 if self._pos == self._goal_cell else 1
            return 2 if region == 0 else 3
        return 4 if region == REGION_FLAT[self._obj_cell[0]] else 5

    def _waypoint(self) -> int:
        """Cell of the next waypoint (see the Reward section)."""
        pos = self._pos
        region = REGION_FLAT[pos]
        if self._carrying == 0:
            if region == self._goal_region:
                return self._goal_cell
            return self._goal_door if region == 0 else DOOR_CELL[region - 1]
        target = self._obj_cell[0]
        target_region = REGION_FLAT[target]
        if region == target_region:
            return target
        return DOOR_CELL[region - 1] if region != 0 else DOOR_CELL[target_region - 1]

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        self._reset_state()
        return self._obs(), self._info()

    def step(self, action):
        a = int(action)
        pos = self._pos
        if a < 4:
            if a < 0:
                raise ValueError(f"invalid action {action!r} (expected 0..5)")
            nxt = STEP[a][pos]
            if nxt >= 0:
                k = KIND_FLAT[nxt]
                if k == K_FLOOR:
                    self._pos = nxt
                else:  # a door
                    bit = 1 << DOOR_INDEX_FLAT[nxt]
                    if self._door_mask & bit:
                        self._pos = nxt
                    else:
                        self._door_mask |= bit
                        x, y = XY[nxt]
                        self._enc[y + PAD, x + PAD, 2] = D_OPEN
        elif a == ACTION_PICKUP:
            if self._carrying < 0:
                i = self._obj_at.pop(pos, -1)
                if i >= 0:
                    self._carrying = i
                    self._obj_cell[i] = -1
                    t, c = self._obj_codes[i]
                    self._carry_vec = np.array((t, c, 1), dtype=np.uint8)
                    x, y = XY[pos]
                    self._enc[y + PAD, x + PAD] = (1, 0, 0)
        elif a == ACTION_DROP:
            i = self._carrying
            if i >= 0 and self.can_drop_at(pos):
                self._carrying = -1
                self._obj_cell[i] = pos
                self._obj_at[pos] = i
                self._carry_vec = np.zeros(3, dtype=np.uint8)
                x, y = XY[pos]
                t, c = self._obj_codes[i]
                self._enc[y + PAD, x + PAD] = (t, c, 0)
        else:
            raise ValueError(f"invalid action {action!r} (expected 0..5)")
        self._steps += 1
        if self._trail is not None:
            self._trail.append(self._pos)

        left = self._subgoals_left_now()
        self._left = left
        gained = self._min_left - left
        newly_solved = False
        if gained > 0:
            self._min_left = left
            if left == 0 and not self._success:
                self._success = newly_solved = True
        if self._dense:
            wx, wy = XY[self._waypoint()]
            x, y = XY[self._pos]
            reward = (100.0 * gained if gained > 0 else 0.0) - 0.01 * ((wx - x) ** 2 + (wy - y) ** 2) ** 0.5
        else:
            reward = 1.0 if newly_solved else 0.0
        terminated = self._success and self.terminate_on_success
        return self._obs(), reward, terminated, self._steps >= MAX_STEPS, self._info()

    def _obs(self) -> np.ndarray:
        x, y = XY[self._pos]
        region = REGION_FLAT[self._pos]
        key = 63 + region if region > 0 else self._door_mask
        vis = VIS_LUT[key][VIS_REGION[y:y + VIEW, x:x + VIEW]]
        obs = np.empty((VIEW, VIEW, 6), dtype=np.uint8)
        np.multiply(self._enc[y:y + VIEW, x:x + VIEW], vis[:, :, None], out=obs[:, :, :3])
        obs[:, :, 3:] = self._carry_vec
        return obs

    def _info(self) -> dict[str, Any]:
        n_done = NUM_SUBGOALS - self._min_left
        t = self.subgoal_texts
        return {
            "completion": n_done / NUM_SUBGOALS,
            "subgoals": [(t[0], n_done > 0), (t[1], n_done > 1), (t[2], n_done > 2), (t[3], n_done > 3), (t[4], n_done > 4)],
            "success": self._success,
            "instruction": self.instruction,
            "instruction_ids": self.instruction_ids,
        }

    def render(self):
        if self.render_mode == "ansi":
            from gpl_dist.envs.multiroom_render import render_text

            return render_text(self, self._trail or [self._pos])
        if self.render_mode != "rgb_array":
            return None
        from gpl_dist.envs.multiroom_render import render_grid

        cells: dict[tuple[int, int], tuple] = {}
        for i, c in enumerate(DOOR_CELL):
            cells[XY[c]] = ("door", i + 1, 0, bool(self._door_mask >> i & 1))
        for g in self.task.goals:
            cells[g.xy] = ("goal", COLOURS.index(g.colour) + 1, 0, False)
        for i, c in enumerate(self._obj_cell):
            if c >= 0:
                t, col = self._obj_codes[i]
                cells[XY[c]] = ("floor", col, t, False)
        carried = self._obj_codes[self._carrying] if self._carrying >= 0 else (0, 0)
        return render_grid(cells, XY[self._pos], carried)

    def picture_points(self) -> tuple[tuple[float, float], ...]:
        """Where the agent is in the ``rgb_array`` picture, in pixels (x, y): what a drawn path follows."""
        from gpl_dist.envs.multiroom_render import TILE

        x, y = XY[self._pos]
        return ((x * TILE + TILE / 2, y * TILE + TILE / 2),)

    # ------------------------------------------------------------------ privileged read-only state
    def can_drop_at(self, cell: int) -> bool:
        """Whether ``drop`` would succeed at flat cell ``cell`` (given a carried object)."""
        return KIND_FLAT[cell] == K_FLOOR and cell not in self._obj_at and cell not in self._goal_cells

    @property
    def agent_pos(self) -> tuple[int, int]:
        """Agent's (x, y)."""
        return XY[self._pos]

    @property
    def agent_region(self) -> int:
        """0 hallway (door cells included), 1 + i inside room i."""
        return REGION_FLAT[self._pos]

    @property
    def door_open(self) -> tuple[bool, ...]:
        """Open flags of the 6 doors, in colour order (blue, green, grey, purple, red, yellow)."""
        return tuple(bool(self._door_mask >> i & 1) for i in range(6))

    @property
    def carrying(self) -> int:
        """-1 empty hands, 0 the true object, 1..3 a decoy (index into ``task.objects``)."""
        return self._carrying

    @property
    def object_positions(self) -> tuple[tuple[int, int] | None, ...]:
        """(x, y) of each of ``task.objects`` on the grid, None while carried."""
        return tuple(XY[c] if c >= 0 else None for c in self._obj_cell)

    @property
    def steps(self) -> int:
        return self._steps

    @property
    def success(self) -> bool:
        return self._success

    @property
    def subgoals_left(self) -> int:
        """``L`` of the current state (see Completion metric)."""
        return self._left

    @property
    def min_subgoals_left(self) -> int:
        """Minimum of ``L`` over the episode so far; the first undone subgoal is ``5 - this``."""
        return self._min_left

    @property
    def completion(self) -> float:
        return (NUM_SUBGOALS - self._min_left) / NUM_SUBGOALS


def make_env(task_id: int, **kwargs: Any) -> MultiRoomEnv:
    """The unwrapped env of ``task_id`` (``kwargs``: ``render_mode``, ``reward_mode``,
    ``terminate_on_success``)."""
    return MultiRoomEnv(task_id, **kwargs)


def make_splits(seed: int = 0) -> dict[str, list[int]]:
    """The versioned splits (written to ``gpl_dist/splits/multiroom.json`` by ``__main__``).

    - ``train`` (1700), ``test`` (250) and ``valid`` (the other 1290): a seeded permutation of all
      3240 tasks. Every task has its own 5-subgoal list, so no test task's list is in train
      (the paper's condition).
    - ``heldout_train`` (1700): tasks none of whose 4 objects (true or decoy) is one of
      ``HELDOUT_OBJECTS``, so those colour-shape combinations are never seen in training;
      ``heldout_test``: every task whose true object is a held-out combination (paper Table 5).
    - ``heldout4_*`` (version 2), with the 4 combinations of ``HELDOUT4_OBJECTS``: of the tasks none of
      whose objects is held out (1029), ``heldout4_indist_test`` (250, drawn with its own stream, so
      the splits above are unchanged) tests the same model in distribution and ``heldout4_train``
      is the rest (779: fewer than 1700, as a task has 4 objects); ``heldout4_test``: every task
      whose true object is held out (720).
    - ``heldout4_valid`` (version 3): the tasks of none of the ``heldout4_*`` splits above, that is
      every task whose true object is seen in training and some decoy is held out (1491). The
      ``heldout4`` runs are chosen on it (learning curve, instruction-swap control): it holds no
      task they train on and no test task. No valid task can have a held-out true object, as every
      such task is in ``heldout4_test``.
    """
    rng = np.random.default_rng(seed)
    perm = rng.permutation(NUM_TASKS)
    clean, heldout_test = _held_out(HELDOUT_OBJECTS)
    heldout_train = np.asarray(clean)[rng.permutation(len(clean))[:1700]]
    clean4, heldout4_test = _held_out(HELDOUT4_OBJECTS)
    order4 = np.asarray(clean4)[np.random.default_rng([seed, 4]).permutation(len(clean4))]
    return {
        "train": sorted(int(t) for t in perm[:1700]),
        "test": sorted(int(t) for t in perm[1700:1950]),
        "valid": sorted(int(t) for t in perm[1950:]),
        "heldout_train": sorted(int(t) for t in heldout_train),
        "heldout_test": sorted(heldout_test),
        "heldout4_train": sorted(int(t) for t in order4[HELDOUT4_INDIST_TASKS:]),
        "heldout4_indist_test": sorted(int(t) for t in order4[:HELDOUT4_INDIST_TASKS]),
        "heldout4_test": sorted(heldout4_test),
        "heldout4_valid": sorted(set(range(NUM_TASKS)) - set(clean4) - set(heldout4_test)),
    }


def _held_out(objects: tuple[tuple[str, str], ...]) -> tuple[list[int], list[int]]:
    """``(tasks with none of objects, tasks whose true object is one of them)``."""
    held = set(objects)
    clean, test = [], []
    for t in range(NUM_TASKS):
        objs = get_task(t).objects
        if (objs[0].colour, objs[0].shape) in held:
            test.append(t)
        elif not any((o.colour, o.shape) in held for o in objs):
            clean.append(t)
    return clean, test


def decoy_overlap(task_ids) -> tuple[float, float]:
    """Fractions of ``task_ids`` with a decoy of the true object's colour, and of its shape: how
    far a held-out combination's words were seen on other objects of the same task."""
    tasks = [get_task(int(t)).objects for t in task_ids]
    colour = sum(any(o.colour == objs[0].colour for o in objs[1:]) for objs in tasks)
    shape = sum(any(o.shape == objs[0].shape for o in objs[1:]) for objs in tasks)
    return colour / max(len(tasks), 1), shape / max(len(tasks), 1)


SPLIT_NOTE = (
    "make_splits(0) in gpl_dist/envs/multiroom.py: train/test/valid = 1700/250/1290 of a seeded "
    "permutation; heldout_train = 1700 tasks without any object in HELDOUT_OBJECTS "
    f"({', '.join(' '.join(c) for c in HELDOUT_OBJECTS)}); heldout_test = all tasks whose true object is held out; "
    f"version 2 adds heldout4_* with HELDOUT4_OBJECTS ({', '.join(' '.join(c) for c in HELDOUT4_OBJECTS)}): "
    f"heldout4_indist_test = {HELDOUT4_INDIST_TASKS} tasks without a held-out object (own stream), heldout4_train = "
    "the other such tasks, heldout4_test = all tasks whose true object is held out; version 3 adds heldout4_valid "
    "= every task in none of the heldout4 splits (true object seen, a decoy held out)"
)

DOMAIN = DomainSpec(
    name="multiroom",
    env_id="gpl/MultiRoom-v0",
    num_tasks=NUM_TASKS,
    obs_shape=(VIEW, VIEW, 6),
    obs_dtype="uint8",
    num_actions=6,
    steps_per_attempt=MAX_STEPS,
    trajectory_stride=25,
    vocabulary=VOCABULARY,
    make_env=make_env,
    split_names=("train", "valid", "test", "heldout_train", "heldout_test", "heldout4_train", "heldout4_indist_test",
                 "heldout4_test", "heldout4_valid"),
    valid_splits={"train": "valid", "heldout4_train": "heldout4_valid"},
    experts={"scripted": lazy("gpl_dist.experts.multiroom:MultiRoomExpert")},
    correction_kinds=CORRECTION_KINDS,
    make_corrector=lazy("gpl_dist.corrections.multiroom:make_multiroom_corrector"),
    correction_phrasings=lazy("gpl_dist.corrections.multiroom:phrasings"),
    paraphrases=PARAPHRASES,
    model_sizes=Sizes(
        state_channels=(8, 8), state_mlp=(32, 32),
        traj_state_channels=(4, 4), traj_state_mlp=(32, 32), traj_conv=4, traj_mlp=(16, 4),
        text_conv=4, correction_mlp=(16, 4), instruction_mlp=(16, 32),
        pair_mlp=(32, 32), pair_final_relu=True, policy_mlp=(64, 64),
    ),
    # Table 1 (GPL, c0..c5) and Table 3 (c7, c10)
    paper_completion={0: 0.066, 1: 0.46, 2: 0.65, 3: 0.73, 4: 0.77, 5: 0.82, 7: 0.83, 10: 0.86},
    # codes per channel: type 0..7, colour 0..6, door 0..2, carried type 0..6, carried colour 0..6, flag 0..1
    obs_categories=(8, 7, 3, 7, 7, 2),
)

# Shapes and colour names, re-exported for other modules.
OBJECT_SHAPES = SHAPES
OBJECT_COLOURS = COLOURS


if __name__ == "__main__":  # regenerate the split file: python -m gpl_dist.envs.multiroom
    from gpl_dist.splits import write_splits

    print(write_splits("multiroom", make_splits(0), seed=0, note=SPLIT_NOTE, version=3))

"""Static data of the multi-room domain: the fixed 19x19 layout, the 3240 tasks, the encodings.

Everything here is a pure function of the task id (or of nothing) and is computed once per
process (``functools.lru_cache``), so building an env costs a dictionary look-up and a copy.

Cells are addressed by ``(x, y)`` with x growing east and y growing south (north up), or by the
flat index ``c = y * 19 + x``.

Layout (the authors' v5 layout, see the env docstring for the picture)::

    walls      border x=0, x=18, y=0, y=18; full-height x=7 and x=11;
               room dividers y=6 and y=12 for x<=7 and x>=11
    hallway    x=8..10, y=1..17 (the agent starts at (8, 12))
    rooms      0 blue   x=1..6,   y=1..5    door (7, 3)
               1 green  x=12..17, y=1..5    door (11, 3)
               2 grey   x=1..6,   y=7..11   door (7, 9)
               3 purple x=12..17, y=7..11   door (11, 9)
               4 red    x=1..6,   y=13..17  door (7, 15)
               5 yellow x=12..17, y=13..17  door (11, 15)

A room is named after the colour of its door ("the blue room").
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from gpl_dist.errors import UsageError

SIZE = 19
PAD = 3  # half the 7x7 view; the padded grids are (SIZE + 2*PAD)^2
VIEW = 7
NUM_CELLS = SIZE * SIZE

COLOURS = ("blue", "green", "grey", "purple", "red", "yellow")  # colour code = index + 1
SHAPES = ("ball", "triangle", "square")
NUM_ROOMS = 6
NUM_TASKS = 6 * 3 * 6 * 6 * 5  # 3240

# Observation channel-0 codes.
T_UNSEEN, T_EMPTY, T_WALL, T_DOOR, T_BALL, T_TRIANGLE, T_SQUARE, T_GOAL = range(8)
SHAPE_TYPE = {"ball": T_BALL, "triangle": T_TRIANGLE, "square": T_SQUARE}
# Channel-2 door codes.
D_NONE, D_CLOSED, D_OPEN = 0, 1, 2

# Static cell kinds.
K_FLOOR, K_WALL, K_DOOR = 0, 1, 2

DOOR_XY = ((7, 3), (11, 3), (7, 9), (11, 9), (7, 15), (11, 15))
DOOR_CELL = tuple(y * SIZE + x for x, y in DOOR_XY)
ROOM_BOUNDS = (  # (x0, x1, y0, y1) inclusive interiors
    (1, 6, 1, 5), (12, 17, 1, 5),
    (1, 6, 7, 11), (12, 17, 7, 11),
    (1, 6, 13, 17), (12, 17, 13, 17),
)
START_XY = (8, 12)
START_CELL = START_XY[1] * SIZE + START_XY[0]

# Moves in action order 0 north (-y), 1 west (-x), 2 east (+x), 3 south (+y).
MOVES = ((0, -1), (-1, 0), (1, 0), (0, 1))
ACTION_PICKUP, ACTION_DROP = 4, 5


def _build_layout():
    kind = np.full((SIZE, SIZE), K_FLOOR, dtype=np.int8)
    kind[0, :] = kind[-1, :] = kind[:, 0] = kind[:, -1] = K_WALL
    kind[:, 7] = kind[:, 11] = K_WALL
    for y in (6, 12):
        kind[y, :8] = K_WALL
        kind[y, 11:] = K_WALL
    door_index = np.full((SIZE, SIZE), -1, dtype=np.int8)
    for i, (x, y) in enumerate(DOOR_XY):
        kind[y, x] = K_DOOR
        door_index[y, x] = i
    # region: -1 wall, 0 hallway (door cells included), 1 + i room i's interior
    region = np.full((SIZE, SIZE), -1, dtype=np.int8)
    region[1:18, 8:11] = 0
    for i, (x0, x1, y0, y1) in enumerate(ROOM_BOUNDS):
        region[y0:y1 + 1, x0:x1 + 1] = 1 + i
    for x, y in DOOR_XY:
        region[y, x] = 0
    assert ((region >= 0) == (kind != K_WALL)).all()
    return kind, door_index, region


KIND, DOOR_INDEX, REGION = _build_layout()
KIND_FLAT = tuple(int(v) for v in KIND.ravel())
DOOR_INDEX_FLAT = tuple(int(v) for v in DOOR_INDEX.ravel())
REGION_FLAT = tuple(int(v) for v in REGION.ravel())
XY = tuple((c % SIZE, c // SIZE) for c in range(NUM_CELLS))
# NEIGHBOURS[c] = ((action, neighbour cell), ...) for the non-wall neighbours of a non-wall cell.
NEIGHBOURS = tuple(
    tuple((a, (XY[c][1] + dy) * SIZE + XY[c][0] + dx) for a, (dx, dy) in enumerate(MOVES)
          if 0 <= XY[c][0] + dx < SIZE and 0 <= XY[c][1] + dy < SIZE
          and KIND_FLAT[(XY[c][1] + dy) * SIZE + XY[c][0] + dx] != K_WALL)
    if KIND_FLAT[c] != K_WALL else ()
    for c in range(NUM_CELLS)
)
def _build_step():
    """STEP[a][c]: cell reached by move ``a`` from ``c`` ignoring doors; -1 into a wall."""
    table = []
    for dx, dy in MOVES:
        row = []
        for c in range(NUM_CELLS):
            x, y = XY[c]
            nx, ny = x + dx, y + dy
            if KIND_FLAT[c] == K_WALL or not (0 <= nx < SIZE and 0 <= ny < SIZE) or KIND[ny, nx] == K_WALL:
                row.append(-1)
            else:
                row.append(ny * SIZE + nx)
        table.append(tuple(row))
    return tuple(table)


STEP = _build_step()

ITEM_CELLS = tuple(  # the 12 cells of each room where items are placed at generation
    tuple(y * SIZE + x for y in range(y0 + 1, y1) for x in range(x0 + 1, x1))
    for x0, x1, y0, y1 in ROOM_BOUNDS
)


def _padded_static():
    """Padded (25, 25) arrays: encoded static grid (3 channels) and visibility region codes."""
    n = SIZE + 2 * PAD
    enc = np.zeros((n, n, 3), dtype=np.uint8)
    enc[..., 0] = T_WALL  # out-of-grid reads as wall
    vis_region = np.zeros((n, n), dtype=np.intp)  # 0: always visible (walls, doors, outside)
    for y in range(SIZE):
        for x in range(SIZE):
            k = KIND[y, x]
            py, px = y + PAD, x + PAD
            if k == K_WALL:
                enc[py, px, 0] = T_WALL
            elif k == K_DOOR:
                i = DOOR_INDEX[y, x]
                enc[py, px] = (T_DOOR, i + 1, D_CLOSED)
            else:
                enc[py, px, 0] = T_EMPTY
                vis_region[py, px] = 1 + REGION[y, x]  # 1 hallway, 2 + i room i
    return enc, vis_region


STATIC_ENC, VIS_REGION = _padded_static()
VIS_REGION.setflags(write=False)


def _build_vis_lut():
    """LUT[key, vis_region] -> 1 visible / 0 hidden.

    key 0..63: the agent is in the hallway or on a door cell and the door bit mask is ``key``;
    every room whose door is open is visible. key 64 + i: the agent is inside room i; only room i
    (and the hallway, seen through the open door) is visible.
    """
    lut = np.zeros((64 + NUM_ROOMS, 2 + NUM_ROOMS), dtype=np.uint8)
    lut[:, 0] = lut[:, 1] = 1
    for mask in range(64):
        for i in range(NUM_ROOMS):
            lut[mask, 2 + i] = (mask >> i) & 1
    for i in range(NUM_ROOMS):
        lut[64 + i, 2 + i] = 1
    return lut


VIS_LUT = _build_vis_lut()


@dataclass(frozen=True)
class ObjectSpec:
    """One object of a task: its colour, shape, room and cell."""

    colour: str
    shape: str
    room: int
    cell: int

    @property
    def xy(self) -> tuple[int, int]:
        return XY[self.cell]


@dataclass(frozen=True)
class GoalSpec:
    """One goal square of a task: its colour, room and cell."""

    colour: str
    room: int
    cell: int

    @property
    def xy(self) -> tuple[int, int]:
        return XY[self.cell]


@dataclass(frozen=True)
class MultiRoomTask:
    """One of the 3240 tasks (a pure function of ``task_id``).

    Rooms are indices 0..5 named by ``COLOURS[room]`` (the door's colour).
    ``objects[0]`` / ``goals[0]`` are the true object / goal; the rest are decoys.
    """

    task_id: int
    obj_colour: str
    obj_shape: str
    obj_room: int
    goal_colour: str
    goal_room: int
    objects: tuple[ObjectSpec, ...]
    goals: tuple[GoalSpec, ...]

    @property
    def obj_room_name(self) -> str:
        return COLOURS[self.obj_room]

    @property
    def goal_room_name(self) -> str:
        return COLOURS[self.goal_room]

    @property
    def decoy_objects(self) -> tuple[ObjectSpec, ...]:
        return self.objects[1:]

    @property
    def decoy_goals(self) -> tuple[GoalSpec, ...]:
        return self.goals[1:]

    @property
    def instruction(self) -> str:
        return f"Move {self.obj_colour} {self.obj_shape} to {self.goal_colour} square"

    @property
    def subgoal_texts(self) -> tuple[str, ...]:
        return subgoal_texts(self)


def check_task_id(task_id) -> int:
    """``task_id`` as an int; ``ValueError`` unless it is one of the domain's tasks."""
    if isinstance(task_id, (bool, np.bool_)) or not isinstance(task_id, (int, np.integer)):
        raise UsageError(f"multiroom task_id must be an int in 0..{NUM_TASKS - 1}, got {task_id!r}")
    if not 0 <= int(task_id) < NUM_TASKS:
        raise UsageError(f"multiroom task_id must be in 0..{NUM_TASKS - 1}, got {task_id}")
    return int(task_id)


def decode_task_id(task_id: int) -> tuple[int, int, int, int, int]:
    """``task_id`` -> (object colour, shape, object room, goal colour, goal room) indices.

    task_id = (((oc * 3 + shape) * 6 + obj_room) * 6 + goal_colour) * 5 + k, where the goal room
    is the k-th (0-based, increasing) of the five rooms other than the object room.
    """
    task_id = check_task_id(task_id)
    rest, k = divmod(task_id, 5)
    rest, gc = divmod(rest, 6)
    rest, oroom = divmod(rest, 6)
    oc, shape = divmod(rest, 3)
    groom = [r for r in range(NUM_ROOMS) if r != oroom][k]
    return oc, shape, oroom, gc, groom


@lru_cache(maxsize=None)
def get_task(task_id: int) -> MultiRoomTask:
    """The task of ``task_id``; decoys and positions come from ``default_rng([12345, task_id])``."""
    oc, shape, oroom, gc, groom = decode_task_id(task_id)
    rng = np.random.default_rng([12345, int(task_id)])
    used: set[int] = set()

    def place(room: int) -> int:
        free = [c for c in ITEM_CELLS[room] if c not in used]
        cell = free[int(rng.integers(len(free)))]
        used.add(cell)
        return cell

    objects = [ObjectSpec(COLOURS[oc], SHAPES[shape], oroom, place(oroom))]
    goals = [GoalSpec(COLOURS[gc], groom, place(groom))]
    combos = [(c, s) for c in range(6) for s in range(3) if (c, s) != (oc, shape)]
    for j in rng.choice(len(combos), size=3, replace=False):
        c, s = combos[int(j)]
        room = int(rng.integers(NUM_ROOMS))
        objects.append(ObjectSpec(COLOURS[c], SHAPES[s], room, place(room)))
    other = [c for c in range(6) if c != gc]
    for j in rng.choice(len(other), size=3, replace=False):
        room = int(rng.integers(NUM_ROOMS))
        goals.append(GoalSpec(COLOURS[other[int(j)]], room, place(room)))
    return MultiRoomTask(int(task_id), COLOURS[oc], SHAPES[shape], oroom, COLOURS[gc], groom,
                         tuple(objects), tuple(goals))


def subgoal_texts(task: MultiRoomTask) -> tuple[str, ...]:
    """The five subgoals of the task's plan from the start state, as text."""
    return (
        f"enter the {COLOURS[task.obj_room]} room",
        f"pick up the {task.obj_colour} {task.obj_shape}",
        f"exit the {COLOURS[task.obj_room]} room",
        f"enter the {COLOURS[task.goal_room]} room",
        f"go to the {task.goal_colour} goal",
    )


@lru_cache(maxsize=None)
def task_static(task_id: int):
    """Per-task arrays the env copies on reset: padded encoded grid with items, goal cells."""
    task = get_task(task_id)
    enc = STATIC_ENC.copy()
    for g in task.goals:
        x, y = g.xy
        enc[y + PAD, x + PAD] = (T_GOAL, COLOURS.index(g.colour) + 1, 0)
    for o in task.objects:
        x, y = o.xy
        enc[y + PAD, x + PAD] = (SHAPE_TYPE[o.shape], COLOURS.index(o.colour) + 1, 0)
    enc.setflags(write=False)
    goal_cells = frozenset(g.cell for g in task.goals)
    obj_codes = tuple((SHAPE_TYPE[o.shape], COLOURS.index(o.colour) + 1) for o in task.objects)
    return task, enc, goal_cells, obj_codes, subgoal_texts(task)


def compass(dx: float, dy: float) -> str:
    """One of 8 compass words for the offset (dx east, dy south), or ``here`` for (0, 0)."""
    if dx == 0 and dy == 0:
        return "here"
    angle = np.degrees(np.arctan2(-dy, dx)) % 360.0  # 0 = east, 90 = north
    names = ("east", "northeast", "north", "northwest", "west", "southwest", "south", "southeast")
    return names[int(((angle + 22.5) % 360.0) // 45.0)]

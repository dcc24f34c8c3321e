"""RGB rendering of the multi-room grid with minigrid's drawing primitives.

Each cell is drawn as one tile (``TILE`` px, 3x supersampled then downsampled as minigrid does);
tiles are cached by content, and the static background (walls, floor) is drawn once per process.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from minigrid.core.constants import COLORS as MG_COLORS
from minigrid.utils.rendering import (
    downsample,
    fill_coords,
    point_in_circle,
    point_in_rect,
    point_in_triangle,
)

from gpl_dist.envs.multiroom_core import (
    COLOURS,
    K_WALL,
    KIND,
    SIZE,
    T_BALL,
    T_SQUARE,
    T_TRIANGLE,
)

TILE = 32
_SUB = 3
_RGB = {name: np.asarray(MG_COLORS[name], dtype=np.uint8) for name in COLOURS}
_WALL = np.array([170, 170, 170], dtype=np.uint8)  # lighter than the grey (100) items
_FLOOR_LINE = np.array([60, 60, 60], dtype=np.uint8)
_AGENT = np.array([255, 255, 255], dtype=np.uint8)


def _draw_shape(img: np.ndarray, shape: int, rgb: np.ndarray, scale: float = 1.0, cx: float = 0.5, cy: float = 0.5) -> None:
    r = 0.31 * scale
    if shape == T_BALL:
        fill_coords(img, point_in_circle(cx, cy, r), rgb)
    elif shape == T_TRIANGLE:
        fill_coords(img, point_in_triangle((cx, cy - r), (cx - r, cy + r), (cx + r, cy + r)), rgb)
    elif shape == T_SQUARE:
        fill_coords(img, point_in_rect(cx - r * 0.85, cx + r * 0.85, cy - r * 0.85, cy + r * 0.85), rgb)


@lru_cache(maxsize=4096)
def tile(kind: str, colour: int, shape: int, door_open: bool, agent: bool, carried_shape: int, carried_colour: int) -> np.ndarray:
    """One cell's RGB tile. ``kind`` in {floor, wall, door, goal}; colours are 1..6 codes, 0 none."""
    n = TILE * _SUB
    img = np.zeros((n, n, 3), dtype=np.uint8)
    if kind == "wall":
        fill_coords(img, point_in_rect(0, 1, 0, 1), _WALL)
    elif kind == "door":
        rgb = _RGB[COLOURS[colour - 1]]
        if door_open:  # an open door: coloured outline only, the floor shows through
            fill_coords(img, point_in_rect(0.88, 1.0, 0, 1), rgb)
            fill_coords(img, point_in_rect(0, 0.12, 0, 1), rgb)
        else:  # a closed door: solid colour with a dark panel and a handle
            fill_coords(img, point_in_rect(0, 1, 0, 1), rgb)
            fill_coords(img, point_in_rect(0.06, 0.94, 0.06, 0.94), (rgb * 0.45).astype(np.uint8))
            fill_coords(img, point_in_circle(0.75, 0.5, 0.08), rgb)
    elif kind == "goal":
        fill_coords(img, point_in_rect(0, 1, 0, 1), _RGB[COLOURS[colour - 1]])
    if kind != "wall":  # grid lines
        fill_coords(img, point_in_rect(0, 0.031, 0, 1), _FLOOR_LINE)
        fill_coords(img, point_in_rect(0, 1, 0, 0.031), _FLOOR_LINE)
    if shape:
        _draw_shape(img, shape, _RGB[COLOURS[colour - 1]])
    if agent:
        # The agent: a white ring (it has no heading), so what it stands on stays visible; the
        # object it carries is drawn small on a white badge in the tile's top-right corner.
        outer, inner = point_in_circle(0.5, 0.5, 0.47), point_in_circle(0.5, 0.5, 0.37)
        fill_coords(img, lambda x, y: outer(x, y) and not inner(x, y), _AGENT)
        if carried_shape:
            fill_coords(img, point_in_rect(0.62, 1.0, 0.0, 0.38), _AGENT)
            _draw_shape(img, carried_shape, _RGB[COLOURS[carried_colour - 1]], scale=0.5, cx=0.81, cy=0.19)
    out = downsample(img, _SUB)
    out.setflags(write=False)
    return out


@lru_cache(maxsize=1)
def background() -> np.ndarray:
    """The RGB picture of the walls and doors, shared by every task."""
    img = np.zeros((SIZE * TILE, SIZE * TILE, 3), dtype=np.uint8)
    for y in range(SIZE):
        for x in range(SIZE):
            kind = "wall" if KIND[y, x] == K_WALL else "floor"
            img[y * TILE:(y + 1) * TILE, x * TILE:(x + 1) * TILE] = tile(kind, 0, 0, False, False, 0, 0)
    img.setflags(write=False)
    return img


def render_grid(cells: dict[tuple[int, int], tuple], agent_xy: tuple[int, int], carried: tuple[int, int]) -> np.ndarray:
    """Full-grid RGB image.

    ``cells`` maps (x, y) -> (kind, colour, shape, door_open) for every non-floor, non-wall cell
    (doors, goals, objects); ``carried`` is the carried object's (shape type, colour) or (0, 0).
    """
    img = background().copy()
    todo = dict(cells)
    todo.setdefault(agent_xy, ("floor", 0, 0, False))
    for (x, y), (kind, colour, shape, door_open) in todo.items():
        is_agent = (x, y) == agent_xy
        t = tile(kind, colour, shape, door_open, is_agent, carried[0] if is_agent else 0, carried[1] if is_agent else 0)
        img[y * TILE:(y + 1) * TILE, x * TILE:(x + 1) * TILE] = t
    return img


#: One letter per colour code 1..6 in the text picture (grey is "e": "g" is green).
COLOUR_LETTERS = "bgepry"
#: One letter per object type code (4 ball, 5 triangle, 6 square).
SHAPE_LETTERS = {T_BALL: "o", T_TRIANGLE: "t", T_SQUARE: "s"}
TEXT_LEGEND = ("colours: b blue, g green, e grey, p purple, r red, y yellow | ot s: ball, triangle, square "
               "object | G goal | D closed door, d open | @ agent | . path").replace("ot s", "o t s")


def render_text(env, trail: list[int]) -> str:
    """The grid as text, two characters a cell (a kind letter and a colour letter, ``TEXT_LEGEND``):
    walls ``##``, doors ``Db`` (closed) / ``db`` (open), objects ``tg`` (a green triangle), goals
    ``Gr``, the agent ``@`` followed by its carried object's colour letter or a space, the cells of
    ``trail`` (flat indices) that hold nothing else ``. ``; then the legend and what is carried."""
    from gpl_dist.envs.multiroom_core import COLOURS as NAMES
    from gpl_dist.envs.multiroom_core import DOOR_CELL, XY

    rows = [["##" if KIND[y, x] == K_WALL else "  " for x in range(SIZE)] for y in range(SIZE)]
    for c in trail:
        x, y = XY[c]
        rows[y][x] = ". "
    for i, c in enumerate(DOOR_CELL):
        x, y = XY[c]
        rows[y][x] = ("d" if env.door_open[i] else "D") + COLOUR_LETTERS[i]
    for g in env.task.goals:
        rows[g.xy[1]][g.xy[0]] = "G" + COLOUR_LETTERS[NAMES.index(g.colour)]
    for i, xy in enumerate(env.object_positions):
        if xy is not None:
            shape, colour = env._obj_codes[i]
            rows[xy[1]][xy[0]] = SHAPE_LETTERS[shape] + COLOUR_LETTERS[colour - 1]
    ax, ay = env.agent_pos
    under = [f"the {g.colour} goal" for g in env.task.goals if tuple(g.xy) == (ax, ay)]
    under += [f"the {o.colour} {o.shape}" for o, xy in zip(env.task.objects, env.object_positions) if xy == (ax, ay)]
    carried = env._obj_codes[env.carrying] if env.carrying >= 0 else None
    rows[ay][ax] = "@" + (COLOUR_LETTERS[carried[1] - 1] if carried else " ")
    held = "nothing"
    if carried:
        obj = env.task.objects[env.carrying]
        held = f"the {obj.colour} {obj.shape}"
    standing = f"; standing on {' and '.join(under)}" if under else ""
    return "\n".join("".join(r) for r in rows) + f"\n{TEXT_LEGEND}\ncarrying {held}{standing}; {len(trail) - 1} steps"

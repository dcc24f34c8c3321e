"""Top-down RGB picture of the relocation arena, drawn with PIL (no OpenGL needed, works headless)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from PIL import Image, ImageDraw

from gpl_dist.envs.relocation_core import BLOCK_HALF, BLOCK_QPOS, FIXED_XY

SIZE = 400
#: World window: centre and half-width (a square, x right, y up).
CENTER = (0.7, 0.0)
HALF = 1.2
TABLE = (222, 214, 196)
MOVABLE_RGB = ((255, 0, 77), (0, 255, 179), (255, 255, 0))
FIXED_RGB = ((255, 0, 255), (128, 128, 128), (255, 255, 255), (0, 0, 255), (0, 255, 0))
TARGET_RGB = (220, 0, 0)
GRIPPER_RGB = (40, 40, 40)
_SCALE = SIZE / (2 * HALF)


def _px(x: float, y: float) -> tuple[float, float]:
    return ((x - CENTER[0] + HALF) * _SCALE, (CENTER[1] + HALF - y) * _SCALE)


def picture_xy(x: float, y: float) -> tuple[float, float]:
    """The pixel (x, y) of table point ``(x, y)`` in ``render_topdown``'s picture."""
    return _px(x, y)


def _square(draw: ImageDraw.ImageDraw, x: float, y: float, rgb, outline=(0, 0, 0), width: int = 1) -> None:
    x0, y0 = _px(x - BLOCK_HALF, y + BLOCK_HALF)
    x1, y1 = _px(x + BLOCK_HALF, y - BLOCK_HALF)
    draw.rectangle([x0, y0, x1, y1], fill=rgb, outline=outline, width=width)


def render_topdown(env: Any) -> np.ndarray:
    """``(400, 400, 3)`` uint8: table, fixed and movable blocks in their colours (the goal block
    outlined in red), the U gripper as thick dark lines, the target as a red ring (radius = the
    0.03 success radius) with a cross."""
    img = Image.new("RGB", (SIZE, SIZE), TABLE)
    draw = ImageDraw.Draw(img)
    q = env.data.qpos
    # target
    tx, ty = env.task.target
    cx, cy = _px(tx, ty)
    r = 0.03 * _SCALE
    draw.ellipse([cx - r, cy - r, cx + r, cy + r], outline=TARGET_RGB, width=2)
    draw.line([cx - 1.6 * r, cy, cx + 1.6 * r, cy], fill=TARGET_RGB, width=1)
    draw.line([cx, cy - 1.6 * r, cx, cy + 1.6 * r], fill=TARGET_RGB, width=1)
    for (fx, fy), rgb in zip(FIXED_XY, FIXED_RGB):
        _square(draw, fx, fy, rgb)
    for i, rgb in enumerate(MOVABLE_RGB):
        goal = i == env.task.block
        _square(draw, q[BLOCK_QPOS[i]], q[BLOCK_QPOS[i] + 1], rgb,
                outline=TARGET_RGB if goal else (0, 0, 0), width=2 if goal else 1)
    # gripper: bar (0, -0.1)-(0, 0.1), prongs to x = 0.1, in the gripper frame
    gx, gy, th = float(q[0]), float(q[1]), float(q[2])
    c, s = math.cos(th), math.sin(th)

    def world(px: float, py: float) -> tuple[float, float]:
        return _px(gx + c * px - s * py, gy + s * px + c * py)

    w = max(2, int(round(0.04 * _SCALE)))
    draw.line([world(0.1, -0.1), world(0.0, -0.1), world(0.0, 0.1), world(0.1, 0.1)], fill=GRIPPER_RGB,
              width=w, joint="curve")
    return np.asarray(img, dtype=np.uint8)


#: Characters of the text picture: columns and rows over the same window as the RGB picture
#: (a terminal cell is about twice as tall as wide, so a column covers half a row's height).
TEXT_COLS, TEXT_ROWS = 48, 24
TEXT_LEGEND = ("fixed blocks P purple, E grey, W white, B blue, G green | movable r red, c cyan, y yellow "
               "(the goal block upper-case) | X target | @ gripper, : its path | * the goal block's path")


def render_text(env: Any, trail: list[tuple[float, float, float, float]]) -> str:
    """The arena seen from above as text (``TEXT_LEGEND``), with the paths of ``trail``
    (gripper x, y, goal block x, y after each step), then the goal block's start, end and target."""
    grid = [[" "] * TEXT_COLS for _ in range(TEXT_ROWS)]

    def put(x: float, y: float, ch: str) -> None:
        col = int((x - CENTER[0] + HALF) / (2 * HALF) * TEXT_COLS)
        row = int((CENTER[1] + HALF - y) / (2 * HALF) * TEXT_ROWS)
        if 0 <= col < TEXT_COLS and 0 <= row < TEXT_ROWS:
            grid[row][col] = ch

    for gx, gy, _, _ in trail:
        put(gx, gy, ":")
    for _, _, bx, by in trail:
        put(bx, by, "*")
    q = env.data.qpos
    put(float(q[0]), float(q[1]), "@")  # under the blocks and the target: they matter more
    for (fx, fy), ch in zip(FIXED_XY, "PEWBG"):
        put(fx, fy, ch)
    tx, ty = env.task.target
    put(tx, ty, "X")
    for i, ch in enumerate("rcy"):
        bx, by = env.block_xy(i)
        put(bx, by, ch.upper() if i == env.task.block else ch)
    border = "+" + "-" * TEXT_COLS + "+"
    (sx, sy), (ex, ey) = trail[0][2:], trail[-1][2:]
    where = (f"goal block ({env.task.block_color}) from ({sx:.2f}, {sy:.2f}) to ({ex:.2f}, {ey:.2f}); "
             f"target ({tx:.2f}, {ty:.2f}), {env.distance():.2f} away; {len(trail) - 1} steps")
    return "\n".join([border, *("|" + "".join(r) + "|" for r in grid), border, TEXT_LEGEND, where])

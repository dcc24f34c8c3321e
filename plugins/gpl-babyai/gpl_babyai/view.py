"""BabyAI's 7x7x3 egocentric view, computed from a cached encoding of the grid.

minigrid's ``gen_obs`` slices the grid into a new ``Grid`` of objects, rotates it, propagates
visibility cell by cell and encodes it: about 97 % of a step. ``GridCache`` keeps the whole grid
encoded once (padded with walls, as minigrid reads cells outside the grid) plus a transparency
map, updates the one cell an action can change, and cuts the view out with precomputed index
arrays. Visibility is minigrid's ``Grid.process_vis`` rule (light spreads along each row, away
from the agent, and one row further away from the agent past every transparent cell), computed
row by row with a lookup table over the 7-bit rows. ``tests/test_env.py`` checks the result
against minigrid's own ``gen_obs`` on random states of every level, bit for bit.

Layout, as minigrid's ``obs["image"]``: ``view[i, j]`` with ``i`` across (left to right as the
agent faces) and ``j`` along the view (``j = 6`` is the agent's row, ``j = 0`` the farthest);
the agent is at ``(3, 6)`` and that cell shows what it carries (``empty`` when nothing).
"""

from __future__ import annotations

import numpy as np
from minigrid.core.constants import COLOR_TO_IDX, OBJECT_TO_IDX

VIEW = 7
PAD = VIEW - 1
AGENT_I, AGENT_J = VIEW // 2, VIEW - 1
WALL_CODE = (OBJECT_TO_IDX["wall"], COLOR_TO_IDX["grey"], 0)
EMPTY_CODE = (OBJECT_TO_IDX["empty"], 0, 0)


def _view_offsets() -> tuple[np.ndarray, np.ndarray]:
    """``(DX, DY)``: int ``(4, 7, 7)`` offsets from the agent of view cell ``[i, j]``, per direction.

    Built by applying minigrid's own steps (``get_view_exts``, then ``rotate_left`` ``dir + 1``
    times, where ``rotate_left`` moves cell ``(i, j)`` to ``(j, size - 1 - i)``) to coordinates.
    """
    tops = {0: (0, -(VIEW // 2)), 1: (-(VIEW // 2), 0), 2: (-VIEW + 1, -(VIEW // 2)), 3: (-(VIEW // 2), -VIEW + 1)}
    dx = np.zeros((4, VIEW, VIEW), np.int64)
    dy = np.zeros((4, VIEW, VIEW), np.int64)
    for d in range(4):
        tx, ty = tops[d]
        cells = {(i, j): (tx + i, ty + j) for i in range(VIEW) for j in range(VIEW)}
        for _ in range(d + 1):
            cells = {(j, VIEW - 1 - i): xy for (i, j), xy in cells.items()}
        for (i, j), (x, y) in cells.items():
            dx[d, i, j], dy[d, i, j] = x, y
    return dx, dy


DX, DY = _view_offsets()


def _row_table() -> tuple[np.ndarray, np.ndarray]:
    """``(LIT, NEXT)``: int ``(128, 128)`` indexed ``[lit bits, transparent bits]`` of one view row.

    ``LIT``: the row's visible cells once light has spread along it (left to right past every
    transparent lit cell, then right to left); ``NEXT``: the cells of the next row (one further
    from the agent) that this row lights: both neighbours of a transparent lit cell's spread and
    the cell itself. Bit ``i`` is view column ``i``.
    """
    lit_out = np.zeros((128, 128), np.int64)
    next_out = np.zeros((128, 128), np.int64)
    for lit in range(128):
        for clear in range(128):
            on = [(lit >> i) & 1 for i in range(VIEW)]
            see = [(clear >> i) & 1 for i in range(VIEW)]
            nxt = [0] * VIEW
            for i in range(VIEW - 1):
                if on[i] and see[i]:
                    on[i + 1] = nxt[i + 1] = nxt[i] = 1
            for i in range(VIEW - 1, 0, -1):
                if on[i] and see[i]:
                    on[i - 1] = nxt[i - 1] = nxt[i] = 1
            lit_out[lit, clear] = sum(b << i for i, b in enumerate(on))
            next_out[lit, clear] = sum(b << i for i, b in enumerate(nxt))
    return lit_out, next_out


LIT, NEXT = (t.tolist() for t in _row_table())
#: bit pattern -> bool (7,) row
ROW_BITS = np.array([[(b >> i) & 1 for i in range(VIEW)] for b in range(128)], dtype=bool)
_WEIGHTS = 1 << np.arange(VIEW)


def encode_cell(obj) -> tuple[int, int, int]:
    """minigrid's code of one cell's content (``empty`` for None)."""
    return EMPTY_CODE if obj is None else obj.encode()


def transparent(obj) -> bool:
    """Whether light passes the cell (minigrid: empty, or an object that ``see_behind``)."""
    return obj is None or obj.see_behind()


class GridCache:
    """The grid of a minigrid env encoded once: ``enc`` uint8 ``(W + 12, H + 12, 3)`` and
    ``clear`` bool ``(W + 12, H + 12)``, padded by 6 cells of wall; ``seen`` bool, same shape:
    every cell visible in some view since ``rebuild`` (what the BabyAI bot calls its
    ``vis_mask``; ``seen_grid()`` is the unpadded view of it)."""

    def __init__(self, level) -> None:
        self.level = level
        self.rebuild()

    def rebuild(self) -> None:
        grid = self.level.grid
        w, h = grid.width, grid.height
        self.enc = np.empty((w + 2 * PAD, h + 2 * PAD, 3), np.uint8)
        self.enc[:] = WALL_CODE
        self.clear = np.zeros((w + 2 * PAD, h + 2 * PAD), bool)
        for j in range(h):
            for i in range(w):
                self.refresh(i, j)
        self.seen = np.zeros((w + 2 * PAD, h + 2 * PAD), bool)
        self._w, self._h = w, h

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """Copies of ``enc`` and ``clear`` (to ``restore`` the grid as it is now)."""
        return self.enc.copy(), self.clear.copy()

    def restore(self, arrays: tuple[np.ndarray, np.ndarray]) -> None:
        """``enc`` and ``clear`` as ``arrays`` recorded them; nothing seen."""
        enc, clear = arrays
        self.enc = enc.copy()
        self.clear = clear.copy()
        self.seen = np.zeros_like(clear)
        self._w, self._h = self.level.grid.width, self.level.grid.height

    def refresh(self, x: int, y: int) -> None:
        """Re-encode grid cell ``(x, y)`` (after an action changed it)."""
        obj = self.level.grid.get(x, y)
        self.enc[x + PAD, y + PAD] = encode_cell(obj)
        self.clear[x + PAD, y + PAD] = transparent(obj)

    def seen_grid(self) -> np.ndarray:
        """bool ``(W, H)`` view of ``seen`` (not a copy)."""
        return self.seen[PAD:PAD + self._w, PAD:PAD + self._h]

    def observe(self) -> np.ndarray:
        """The agent's view, uint8 ``(7, 7, 3)`` (minigrid's ``obs["image"]``); marks its visible
        cells in ``seen``."""
        level = self.level
        ax, ay = level.agent_pos
        d = level.agent_dir
        xs = DX[d] + (ax + PAD)
        ys = DY[d] + (ay + PAD)
        clear_bits = (self.clear[xs, ys] * _WEIGHTS[:, None]).sum(axis=0).tolist()  # per row j
        rows = [0] * VIEW
        lit = 1 << AGENT_I
        for j in range(VIEW - 1, -1, -1):
            c = clear_bits[j]
            rows[j] = LIT[lit][c]
            lit = NEXT[lit][c]
        vis = ROW_BITS[rows].T  # (i, j)
        obs = self.enc[xs, ys]
        obs[~vis] = 0
        carrying = level.carrying
        obs[AGENT_I, AGENT_J] = EMPTY_CODE if carrying is None else carrying.encode()
        self.seen[xs[vis], ys[vis]] = True
        return obs

"""Lazy bit-parallel BFS for the relocation expert's gripper approach (see ``relocation.py``).

The gripper grid (131 x 161 cells) is one Python integer, cell (i, j) at bit ``i * W + j`` with
``W = ny + 1`` (a zero guard column stops row wrap-around), so one BFS ring is a handful of
big-integer shifts / ors / ands (~1 us each) instead of ~10 numpy passes over the grid. The BFS
is *resumable*: it grows only as far as a query needs (the gripper's cell, its 7 x 7
neighbourhood when the cell is blocked) and continues when a later query, on the same cached
field, lies further out. Distances are exactly those of the dense BFS (``gripper_cost_to_go``)
wherever that one is finite, so the controller's decisions do not change; what changes is that a
cached field never has to be recomputed because the gripper left the explored radius, and that a
field whose start is blocked (the gripper touching a block: common on a learner's states) is
not recomputed every step.
"""

from __future__ import annotations

_CHECK = 8  # cumulative "seen" snapshot every _CHECK rings (binary search for a cell's ring)


class LazyField:
    """BFS rings from one goal cell over a free-cell bitset; ``dist(i, j)`` grows it on demand."""

    __slots__ = ("nx", "ny", "w", "free", "unseen", "fronts", "seen", "done")

    def __init__(self, free: int, goal: tuple[int, int], nx: int, ny: int):
        self.nx, self.ny, self.w = nx, ny, ny + 1
        g = 1 << (goal[0] * self.w + goal[1])
        self.free = free | g
        self.unseen = self.free & ~g
        self.fronts = [g]
        self.seen = [g]  # seen[m]: cells within ring m * _CHECK
        self.done = False

    def _grow(self, n: int) -> None:
        """Add up to n rings (stops when the wavefront dies)."""
        w, unseen, fronts = self.w, self.unseen, self.fronts
        f = fronts[-1]
        for _ in range(n):
            g = ((f << 1) | (f >> 1) | (f << w) | (f >> w)) & unseen
            if not g:
                self.done = True
                break
            unseen ^= g
            fronts.append(g)
            f = g
            if (len(fronts) - 1) % _CHECK == 0:
                self.seen.append(self.free & ~unseen)
        self.unseen = unseen

    def reach(self, pos: int) -> bool:
        """Grow until bit ``pos`` is reached; False when it never is (blocked or cut off)."""
        if not (self.free >> pos) & 1:
            return False
        while (self.unseen >> pos) & 1:
            if self.done:
                return False
            self._grow(4)
        return True

    def ring(self, pos: int) -> int:
        """Ring (BFS distance) of a reached bit."""
        seen = self.seen
        lo, hi = 0, len(seen)  # first snapshot containing pos is in [lo, hi); hi = none does
        while lo < hi:
            mid = (lo + hi) // 2
            if (seen[mid] >> pos) & 1:
                hi = mid
            else:
                lo = mid + 1
        k = max(0, (lo - 1) * _CHECK + 1) if lo > 0 else 0
        fronts = self.fronts
        while not (fronts[k] >> pos) & 1:
            k += 1
        return k

    def dist(self, i: int, j: int) -> float:
        if not (0 <= i < self.nx and 0 <= j < self.ny):
            return float("inf")
        pos = i * self.w + j
        return float(self.ring(pos)) if self.reach(pos) else float("inf")

    def step_down(self, i: int, j: int, d0: int, moves) -> tuple[int, int] | None:
        """First neighbour (in ``moves`` order) one ring closer to the goal, or None."""
        if d0 <= 0:
            return None
        f = self.fronts[d0 - 1]
        for di, dj in moves:
            ii, jj = i + di, j + dj
            if 0 <= ii < self.nx and 0 <= jj < self.ny and (f >> (ii * self.w + jj)) & 1:
                return ii, jj
        return None

"""Scripted expert for robotic object relocation: carry the block in the U, plan on grids.

Why scripted: the paper trained one PPO policy per task (1000 of them); a feedback controller that
reads the simulator's state is near-optimal from *any* state (DAgger labels the policy's own,
off-course states), costs tens of microseconds a label and needs no training. Labels are a
single action (``act(env) -> int``), a deterministic function of the simulator state plus a
small per-env memory (the last block move, for tie-breaking; reset-safe).

Method (facts the design rests on: blocks only translate, never rotate; one action is a force
on one axis, so any axis-monotone "staircase" path costs the same time, L1 length / 0.65 units/s
while pushing; the block stops within ~0.02 once the gripper stops pushing):

1. **Cradle pushing.** The block sits inside the U (against the bar, between the prongs). From
   there +x pushes use the bar and +-y pushes the inner face of a prong, so the block can be
   carried along any +x/+-y staircase with no re-posing, and the prongs stop it sliding away.
   Only -x moves need another pose (the back of the bar, gripper on the block's right); they
   are rare (every target lies right of the start blocks) and cost 3x in the planner.
2. **Block cost-to-go grid** (0.02 cells, per task and coarse positions of the other two movable
   blocks, cached): Bellman-Ford on numpy arrays; a move is allowed when the swept footprint
   (block plus U in that move's pushing pose) clears the fixed and the other movable blocks.
   The move at the block's cell is the neighbour of least cost (ties: keep the last move, which
   gives commitment without flipping routes). Within 0.04 of the target a fine controller acts
   on the block's predicted rest point and retracts when it is within 0.008.
3. **Approach** (block not in the pose the move needs): a BFS cost-to-go grid for the gripper's
   origin to a standoff 0.145 behind the pose, with all eight blocks dilated by the U's shape
   (cached per task, movable-block cells at 0.03 and goal cell at 0.04); the gripper follows it
   with a rest-point controller (``p + v * 0.09 s``) to a look-ahead cell, then slides into the
   pose along the U's axis. The BFS is a bitset wavefront grown lazily (``relocation_grid``):
   only as far as the gripper's cell, resumed when it wanders further, so a cached field is never
   recomputed for a new gripper position, only when a block or the goal changes cell (on a
   learner's states, where the gripper bumps blocks, the dense BFS was rerun nearly every step).

``research/relocation_expert.py`` measures its completion over all 1000 tasks, from the start
and from perturbed states, and its labels per second. Residual losses: tight passes next to fixed
blocks (the U snags), long tasks that run out of time (pushing is 0.65 units/s), and a few
approach dead-locks when the standoff lies on the edge of the dilated obstacles.

Labels: ``act(env)`` is the controller's action; ``label(env)`` adds the distribution the learner
is trained toward (KL, as the authors trained toward their PPO experts' action distributions). The
controller's choices are bang-bang and its ties are broken by memory, which the policy cannot
see: toward a waypoint the soft label weights the x and y action by ``|error|^2`` (its mean force
points along the error instead of switching axis at 45 degrees), and in the cradle it is uniform
over the pushes of equal planned cost. Other branches (fine control, -x from the back pose) are
one-hot. Measured on the states of a trained policy, a privileged MLP (exact target given)
matched the hard labels on about 80 % of states; half of its mistakes were on the approach to a
waypoint, and a fifth of the hard labels depended on the memory.

The hinge angle is small in practice (the U's contacts lock it), the pose uses it exactly; the
planners assume it is zero.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from gpl_dist.envs.relocation_core import BLOCK_HALF, BLOCK_QPOS, FIXED_XY
from gpl_dist.experts.relocation_grid import LazyField

_RES = 0.02
# block grid
_BX0, _BY0, _BNX, _BNY = -0.3, -1.5, 101, 151
# gripper grid
_GX0, _GY0, _GNX, _GNY = -0.8, -1.6, 131, 161
#: The U as boxes (bar, lower prong, upper prong) relative to the gripper origin (theta = 0).
_U_BOXES = np.array([[-0.02, 0.02, -0.12, 0.12], [-0.02, 0.12, -0.12, -0.08], [-0.02, 0.12, 0.08, 0.12]])
# moves: +x, -x, +y, -y
_MOVES = ((1, 0), (-1, 0), (0, 1), (0, -1))
_MOVE_ACTION = (2, 3, 0, 1)
_MOVE_COST = (1.0, 3.0, 1.0, 1.0)
#: block centre in the gripper frame while pushing with each move
_CONTACT = ((0.054, 0.0), (-0.054, 0.0), (0.057, -0.047), (0.057, 0.047))
#: +x footprints with the block on the lower / upper prong (mode 0 / 1)
_XMODE_CONTACT = ((0.054, -0.047), (0.054, 0.047))
_CRADLE_X = 0.054
_STANDOFF = 0.145
_TAU_FREE = 0.09
_TAU_BLOCK = 0.03
_FINE = 0.04
_HOLD = 0.008
#: sharpness of the soft label toward a waypoint (see ``RelocationExpert._goto``)
_SOFT_POWER = 2.0

#: ``(action, probs)``: the expert's action and its float32 ``(4,)`` action distribution
Label = tuple[int, np.ndarray]


def _one_hot(action: int) -> np.ndarray:
    probs = np.zeros(4, dtype=np.float32)
    probs[action] = 1.0
    return probs


def _boxes(xy: np.ndarray, half: float = BLOCK_HALF) -> np.ndarray:
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    return np.stack([xy[:, 0] - half, xy[:, 0] + half, xy[:, 1] - half, xy[:, 1] + half], axis=1)


def _mark(mask: np.ndarray, x0: float, y0: float, fp: np.ndarray, obstacles: np.ndarray, margin: float) -> None:
    """Mark the grid centres c where any box of ``fp`` (relative to c) overlaps an obstacle box."""
    nx, ny = mask.shape
    for f in fp:
        for o in obstacles:
            lo_x = o[0] - f[1] - margin
            hi_x = o[1] - f[0] + margin
            lo_y = o[2] - f[3] - margin
            hi_y = o[3] - f[2] + margin
            i0 = max(int(math.ceil((lo_x - x0) / _RES)), 0)
            i1 = min(int(math.floor((hi_x - x0) / _RES)) + 1, nx)
            j0 = max(int(math.ceil((lo_y - y0) / _RES)), 0)
            j1 = min(int(math.floor((hi_y - y0) / _RES)) + 1, ny)
            if i0 < i1 and j0 < j1:
                mask[i0:i1, j0:j1] = True


def _footprint(move: int) -> np.ndarray:
    cx, cy = _CONTACT[move]
    u = _U_BOXES + np.array([-cx, -cx, -cy, -cy])
    return np.concatenate([[[-BLOCK_HALF, BLOCK_HALF, -BLOCK_HALF, BLOCK_HALF]], u])


_FOOTPRINTS = [_footprint(k) for k in range(4)]


def _shift(a: np.ndarray, di: int, dj: int, fill: float | np.floating) -> np.ndarray:
    """out[i, j] = a[i + di, j + dj] (fill outside)."""
    out = np.full_like(a, fill)
    nx, ny = a.shape
    out[max(-di, 0):nx - max(di, 0), max(-dj, 0):ny - max(dj, 0)] = a[max(di, 0):nx - max(-di, 0) or None,
                                                                      max(dj, 0):ny - max(-dj, 0) or None]
    return out


def _fp(cx: float, cy: float) -> np.ndarray:
    u = _U_BOXES + np.array([-cx, -cx, -cy, -cy])
    return np.concatenate([[[-BLOCK_HALF, BLOCK_HALF, -BLOCK_HALF, BLOCK_HALF]], u])


def block_cost_to_go(target: np.ndarray, x0: float, y0: float, nx: int, ny: int) -> tuple:
    """Cost-to-go (cells) of the goal block on a local grid, per lateral mode (0: block on the
    lower prong, after +y pushes; 1: on the upper prong, after -y pushes), around the fixed blocks."""
    obstacles = _boxes(FIXED_XY)

    def free(fp):
        m = np.zeros((nx, ny), dtype=bool)
        _mark(m, x0, y0, fp, obstacles, 0.012)
        return ~m

    fx = [free(_fp(*_XMODE_CONTACT[m])) for m in (0, 1)]
    fmx = free(_fp(*_CONTACT[1]))
    fpy = free(_fp(*_CONTACT[2]))  # mode 0
    fmy = free(_fp(*_CONTACT[3]))  # mode 1
    allow = {
        (0, 0): fx[0] & _shift(fx[0], 1, 0, False), (0, 1): fx[1] & _shift(fx[1], 1, 0, False),
        (1, 0): fmx & _shift(fmx, -1, 0, False), (1, 1): fmx & _shift(fmx, -1, 0, False),
        (2, 0): fpy & _shift(fpy, 0, 1, False), (3, 1): fmy & _shift(fmy, 0, -1, False),
    }
    inf = np.float32(np.inf)
    cost = [np.full((nx, ny), inf, dtype=np.float32), np.full((nx, ny), inf, dtype=np.float32)]
    ti = min(max(int(round((target[0] - x0) / _RES)), 0), nx - 1)
    tj = min(max(int(round((target[1] - y0) / _RES)), 0), ny - 1)
    cost[0][ti, tj] = cost[1][ti, tj] = 0.0
    for _ in range(3000):
        py = _shift(cost[0], 0, 1, inf) + 1.0
        my = _shift(cost[1], 0, -1, inf) + 1.0
        py = np.where(allow[(2, 0)], py, inf)
        my = np.where(allow[(3, 1)], my, inf)
        new = []
        for m in (0, 1):
            px = np.where(allow[(0, m)], _shift(cost[m], 1, 0, inf) + 1.0, inf)
            mx = np.where(allow[(1, m)], _shift(cost[m], -1, 0, inf) + 3.0, inf)
            ys = np.minimum(py + (1.0 if m == 1 else 0.0), my + (1.0 if m == 0 else 0.0))
            new.append(np.minimum(np.minimum(cost[m], px), np.minimum(mx, ys)))
        if np.array_equal(new[0], cost[0]) and np.array_equal(new[1], cost[1]):
            break
        cost = new
    return cost, allow


def gripper_cost_to_go(goal: tuple[float, float], blocks: np.ndarray, start: tuple[int, int]) -> np.ndarray:
    """BFS distance (cells) of the gripper origin to ``goal`` around every block (U at theta 0).

    Dense reference implementation (stops 15 rings past ``start``); the expert uses the lazy,
    equivalent ``gripper_field``."""
    obstacles = np.concatenate([_boxes(FIXED_XY), _boxes(blocks)])
    blocked = np.zeros((_GNX, _GNY), dtype=bool)
    _mark(blocked, _GX0, _GY0, _U_BOXES, obstacles, 0.01)
    free = ~blocked
    gi = min(max(int(round((goal[0] - _GX0) / _RES)), 0), _GNX - 1)
    gj = min(max(int(round((goal[1] - _GY0) / _RES)), 0), _GNY - 1)
    free[gi, gj] = True
    dist = np.full((_GNX, _GNY), np.inf)
    dist[gi, gj] = 0.0
    unseen = free.copy()
    unseen[gi, gj] = False
    front = np.zeros_like(free)
    front[gi, gj] = True
    reached_at = None
    si, sj = start
    for it in range(1, 1000):
        grow = np.zeros_like(front)
        grow[1:] |= front[:-1]
        grow[:-1] |= front[1:]
        grow[:, 1:] |= front[:, :-1]
        grow[:, :-1] |= front[:, 1:]
        grow &= unseen
        unseen &= ~grow
        if not grow.any():
            break
        dist[grow] = it
        front = grow
        if reached_at is None and 0 <= si < _GNX and 0 <= sj < _GNY and dist[si, sj] < np.inf:
            reached_at = it
        if reached_at is not None and it > reached_at + 15:
            break
    return dist


_FIXED_BLOCKED = np.zeros((_GNX, _GNY), dtype=bool)
_mark(_FIXED_BLOCKED, _GX0, _GY0, _U_BOXES, _boxes(FIXED_XY), 0.01)


def gripper_field(goal: tuple[float, float], blocks: np.ndarray) -> LazyField:
    """``gripper_cost_to_go`` as a lazily grown bitset BFS (same distances where that is finite)."""
    blocked = np.zeros((_GNX, _GNY + 1), dtype=bool)
    blocked[:, _GNY] = True
    blocked[:, :_GNY] = _FIXED_BLOCKED
    _mark(blocked[:, :_GNY], _GX0, _GY0, _U_BOXES, _boxes(blocks), 0.01)
    free = int.from_bytes(np.packbits(~blocked, axis=None, bitorder="little").tobytes(), "little")
    gi = min(max(int(round((goal[0] - _GX0) / _RES)), 0), _GNX - 1)
    gj = min(max(int(round((goal[1] - _GY0) / _RES)), 0), _GNY - 1)
    return LazyField(free, (gi, gj), _GNX, _GNY)


class _Snapshot(NamedTuple):
    """What the expert reads of the state: gripper pose ``(gx, gy, th)`` with ``c, s = cos, sin(th)``
    and velocity ``(vx, vy)``; the goal block's position and velocity; the target; the block in the
    gripper's frame ``(rx, ry)``, and whether it sits in the U (``in_cradle``) or behind its bar
    (``in_back``)."""

    gx: float
    gy: float
    c: float
    s: float
    vx: float
    vy: float
    bx: float
    by: float
    bvx: float
    bvy: float
    tx: float
    ty: float
    rx: float
    ry: float
    in_cradle: bool
    in_back: bool

    @classmethod
    def of(cls, e: Any) -> "_Snapshot":
        q, v = e.data.qpos, e.data.qvel
        bq = BLOCK_QPOS[e.task.block]
        gx, gy, th = float(q[0]), float(q[1]), float(q[2])
        bx, by = float(q[bq]), float(q[bq + 1])
        c, s = math.cos(th), math.sin(th)
        # block in the gripper frame
        rx = c * (bx - gx) + s * (by - gy)
        ry = -s * (bx - gx) + c * (by - gy)
        tx, ty = e.task.target
        return cls(gx=gx, gy=gy, c=c, s=s, vx=float(v[0]), vy=float(v[1]), bx=bx, by=by, bvx=float(v[bq]),
                   bvy=float(v[bq + 1]), tx=tx, ty=ty, rx=rx, ry=ry,
                   in_cradle=0.03 < rx < 0.095 and abs(ry) < 0.065, in_back=-0.085 < rx < -0.03 and abs(ry) < 0.05)


class RelocationExpert:
    """Cradle-pushing expert (see the module docstring); ``act(env)`` for wrapped or bare envs."""

    soft_labels = True

    def __init__(self, cache_size: int = 4096):
        self._block_plans: dict[tuple, tuple] = {}
        self._grip_plans: dict[tuple, LazyField] = {}
        self._memory: dict[int, list] = {}
        self._cache_size = cache_size
        self._grip_cache_size = min(cache_size, 1024)  # a grown field holds ~0.1-1 MB of rings

    # -- planning ----------------------------------------------------------------------------

    def _block_plan(self, e: Any) -> tuple:
        """(cost per mode, allowed moves, grid origin x, y, shape) of the task, cached per task."""
        plan = self._block_plans.get(e.task_id)
        if plan is None:
            if len(self._block_plans) >= self._cache_size:
                self._block_plans.clear()
            tx, ty = e.task.target
            x0 = -0.1
            y0 = min(-0.25, ty) - 0.4
            nx = int(round((tx + 0.35 - x0) / _RES)) + 1
            ny = int(round((max(0.25, ty) + 0.4 - y0) / _RES)) + 1
            cost, allow = block_cost_to_go(np.array([tx, ty]), x0, y0, nx, ny)
            plan = (cost, allow, x0, y0, nx, ny)
            self._block_plans[e.task_id] = plan
        return plan

    def _grip_plan(self, e: Any, q: np.ndarray, goal: tuple[float, float]) -> LazyField:
        """The gripper's BFS field to ``goal`` (cached per task, movable-block cells, goal cell)."""
        cells = tuple(int(round(float(x) / 0.03)) for x in q[3:9])
        gk = (int(round(goal[0] / 0.04)), int(round(goal[1] / 0.04)))
        key = (e.task_id,) + cells + gk
        plan = self._grip_plans.get(key)
        if plan is None:
            if len(self._grip_plans) >= self._grip_cache_size:
                self._grip_plans.clear()
            plan = gripper_field((gk[0] * 0.04, gk[1] * 0.04), np.array(cells, dtype=float).reshape(3, 2) * 0.03)
            self._grip_plans[key] = plan
        return plan

    # -- control -----------------------------------------------------------------------------

    @staticmethod
    def _goto(gx: float, gy: float, vx: float, vy: float, wx: float, wy: float, tau: float = _TAU_FREE) -> Label:
        """Bang-bang step toward the rest point's error: the hard action is the dominant axis; the
        soft label puts ``|e_axis|^p`` on each axis's action, so its mean force points along the error."""
        ex = wx - (gx + vx * tau)
        ey = wy - (gy + vy * tau)
        ax = 2 if ex > 0 else 3
        ay = 0 if ey > 0 else 1
        hard = ax if abs(ex) >= abs(ey) else ay
        wx_, wy_ = abs(ex) ** _SOFT_POWER, abs(ey) ** _SOFT_POWER
        if wx_ + wy_ <= 0.0:
            return hard, _one_hot(hard)
        probs = np.zeros(4, dtype=np.float32)
        probs[ax] = wx_ / (wx_ + wy_)
        probs[ay] = wy_ / (wx_ + wy_)
        return hard, probs

    def act(self, env: Any) -> int:
        return self.label(env)[0]

    def label(self, env: Any) -> Label:
        """``(action, probs)``: the controller's action and the distribution over the actions it
        holds equally good (the learner's target; see the module docstring, "Labels").

        Three steps: read the state (``_Snapshot``), choose the block's next move (``_choose_move``),
        then push it or approach the pose that can (``_act``).
        """
        e = getattr(env, "unwrapped", env)
        q = e.data.qpos
        st = _Snapshot.of(e)
        mem = self._memory.get(id(e))
        if mem is None or mem[1] > e.steps:
            mem = [0, e.steps]
            if len(self._memory) > 10_000:
                self._memory.clear()
            self._memory[id(e)] = mem
        mem[1] = e.steps
        move, tied = self._choose_move(e, q, st, mem[0])
        if move is not None:
            mem[0] = move
        return self._act(e, q, st, move, tied)

    def _choose_move(self, e: Any, q: np.ndarray, st: "_Snapshot", last: int) -> tuple[int | None, tuple[int, ...]]:
        """``(move, tied)``: which way the block should go next (None: it is where it should be)."""
        tx, ty, bx, by = st.tx, st.ty, st.bx, st.by
        ex, ey = tx - (bx + st.bvx * _TAU_BLOCK), ty - (by + st.bvy * _TAU_BLOCK)
        if abs(tx - bx) < _FINE and abs(ty - by) < _FINE:
            if abs(ex) < _HOLD and abs(ey) < _HOLD:
                return None, ()
            if abs(ex) >= abs(ey) and not (ex < 0 and ex > -0.02 and abs(ey) >= _HOLD):
                return (0 if ex > 0 else 1), ()
            if abs(ey) >= _HOLD:
                return (2 if ey > 0 else 3), ()
            return None, ()
        # plan from where the block will coast to (the gripper carries it ~0.03 further)
        move, tied = self._plan_move(e, q, bx + st.bvx * 0.045, by + st.bvy * 0.045, st.ry, last)
        if move is None:  # off the plan: straight at the target
            dx, dy = tx - bx, ty - by
            move = (0 if dx > 0 else 1) if abs(dx) >= abs(dy) else (2 if dy > 0 else 3)
        return move, tied

    def _act(self, e: Any, q: np.ndarray, st: "_Snapshot", move: int | None, tied: tuple[int, ...]) -> Label:
        """Push the block ``move``-wards when the gripper is in the pose for it, else approach the pose."""
        gx, gy, vx, vy, bx, by, c, s = st.gx, st.gy, st.vx, st.vy, st.bx, st.by, st.c, st.s
        # -- in the pose: push
        if move is None:
            if st.in_cradle:
                return self._goto(gx, gy, vx, vy, bx - c * (_CRADLE_X + 0.03), by - s * (_CRADLE_X + 0.03))
            if st.in_back:
                return self._goto(gx, gy, vx, vy, bx + c * (_CRADLE_X + 0.03), by + s * (_CRADLE_X + 0.03))
            move = 0 if st.tx > bx else 1  # settle in a pose near the block
        if move != 1 and st.in_cradle:
            # equal-cost moves the cradle can make are equally good; -x needs the other pose
            pushes = [_MOVE_ACTION[k] for k in tied if k != 1] or [_MOVE_ACTION[move]]
            probs = np.zeros(4, dtype=np.float32)
            probs[pushes] = 1.0 / len(pushes)
            return _MOVE_ACTION[move], probs
        if move == 1 and st.in_back:
            return 3, _one_hot(3)
        # -- approach the pose
        sign = 1.0 if move != 1 else -1.0
        # slide in along the U's axis when on the lane behind the pose
        lane_x = sign * st.rx
        if 0.085 <= lane_x < 0.32 and abs(st.ry) < 0.04:
            vlat = -s * vx + c * vy
            elat = st.ry - vlat * _TAU_FREE
            if abs(elat) > 0.02:
                nx_, ny_ = (-s, c) if elat > 0 else (s, -c)
                return self._goto(gx, gy, 0.0, 0.0, gx + nx_, gy + ny_, 0.0)
            return self._goto(gx, gy, 0.0, 0.0, gx + sign * c, gy + sign * s, 0.0)
        d = sign * (_CRADLE_X + _STANDOFF)
        sx, sy = bx - c * d, by - s * d
        gi = int(round((gx - _GX0) / _RES))
        gj = int(round((gy - _GY0) / _RES))
        if abs(gx - sx) + abs(gy - sy) < 0.05:
            return self._goto(gx, gy, vx, vy, sx, sy)
        if not (0 <= gi < _GNX and 0 <= gj < _GNY):
            return self._goto(gx, gy, vx, vy, sx, sy)
        wi, wj = self._lookahead(self._grip_plan(e, q, (sx, sy)), gi, gj)
        if wi is None:
            return self._goto(gx, gy, vx, vy, sx, sy)
        return self._goto(gx, gy, vx, vy, _GX0 + wi * _RES, _GY0 + wj * _RES)

    def _plan_move(self, e: Any, q: np.ndarray, bx: float, by: float, ry: float, last: int):
        """``(move, tied)``: the block's next move from the cost-to-go grid (None when off the
        grid) and every move of the same least cost (empty when the move is not the grid's)."""
        # leave the start row first: lateral moves next to another movable block would snag the U
        for k in range(3):
            if k != e.task.block:
                ox, oy = float(q[BLOCK_QPOS[k]]), float(q[BLOCK_QPOS[k] + 1])
                if abs(ox - bx) < 0.17 and abs(oy - by) < 0.36 and e.task.target[0] > bx + 0.05:
                    return 0, ()
        cost, allow, x0, y0, nx, ny = self._block_plan(e)
        i = int(round((bx - x0) / _RES))
        j = int(round((by - y0) / _RES))
        if not (0 <= i < nx and 0 <= j < ny):
            return None, ()
        mode = 0 if ry < 0 else 1
        best, opts = math.inf, []
        for k, (di, dj) in enumerate(_MOVES):
            am = allow.get((k, mode)) if k < 2 else allow.get((k, 0 if k == 2 else 1))
            ii, jj = i + di, j + dj
            if am is None or not (0 <= ii < nx and 0 <= jj < ny) or not am[i, j]:
                continue
            if k < 2:
                cc = float(cost[mode][ii, jj]) + _MOVE_COST[k]
            else:
                nm = 0 if k == 2 else 1
                cc = float(cost[nm][ii, jj]) + 1.0 + (1.0 if nm != mode else 0.0)
            if cc < best - 1e-6:
                best, opts = cc, [k]
            elif cc < best + 1e-6:
                opts.append(k)
        if not opts or not math.isfinite(best):
            # off the plan (e.g. pushed into a tight spot): head for the cheapest nearby cell
            cand = None
            for di in range(-4, 5):
                for dj in range(-4, 5):
                    ii, jj = i + di, j + dj
                    if (di or dj) and 0 <= ii < nx and 0 <= jj < ny:
                        val = min(float(cost[0][ii, jj]), float(cost[1][ii, jj])) + 1.5 * (abs(di) + abs(dj))
                        if math.isfinite(val) and (cand is None or val < cand[0]):
                            cand = (val, di, dj)
            if cand is None:
                return None, ()
            _, di, dj = cand
            if abs(di) >= abs(dj):
                return (0 if di > 0 else 1), ()
            return (2 if dj > 0 else 3), ()
        return (last if last in opts else opts[0]), tuple(opts)

    @staticmethod
    def _lookahead(field: LazyField, gi: int, gj: int, n: int = 6):
        """The cell n steps down the field from (gi, gj) (from the best nearby cell when blocked)."""
        if not (0 <= gi < _GNX and 0 <= gj < _GNY):
            return None, None
        i, j = gi, gj
        d0 = field.dist(i, j)
        if not math.isfinite(d0):
            best = None
            for di in range(-3, 4):
                for dj in range(-3, 4):
                    ii, jj = i + di, j + dj
                    if 0 <= ii < _GNX and 0 <= jj < _GNY:
                        dd = field.dist(ii, jj)
                        if math.isfinite(dd):
                            val = dd + abs(di) + abs(dj)
                            if best is None or val < best[0]:
                                best = (val, ii, jj, dd)
            if best is None:
                return None, None
            i, j, d0 = best[1], best[2], best[3]
        d = int(d0)
        for _ in range(n):
            nxt = field.step_down(i, j, d, _MOVES)
            if nxt is None:
                break
            i, j = nxt
            d -= 1
        return i, j

"""Scripted optimal expert for the multi-room domain (privileged full state, cached shortest paths).

Labels are **one deterministic action** per state, not a distribution: the learner's DAgger loss
is cross-entropy to that one label, and a fixed tie-break (lowest action id among the optimal
ones: up, left, right, down, pickup, drop) makes labels reproducible, so equal states always get
equal targets. ``action_values(env)`` gives the cost-to-go of every action for callers that want
the full set of optimal actions.

Planning. Walls and doors are the same in every task and objects / goals never block movement,
so the cost-to-go to a cell depends only on (target cell, which doors are open). Entering a
closed door costs 2 steps (the bump that opens it, then the move); entering any other cell costs
1. For each (target, door mask) met, a reverse Dijkstra over the 19x19 grid (edge weights 1 / 2,
a two-bucket BFS) yields the distance map and the best move at every cell; both are cached for
the process (at most 361 x 64 maps; a full sweep over the 3240 tasks builds a few thousand).

Policy from any state (all cases are optimal; rooms have one door each, so the leg to the
object never opens a door the leg to the goal does not also need):

- carrying the true object: on the goal -> ``pickup`` (a no-op with full hands: stay there, the
  task is solved); else the best move towards the goal;
- carrying a decoy: ``drop`` if the cell allows it (dropping now is never worse than later:
  one action either way, and the object never blocks anything); otherwise the first move of
  the cheapest plan "walk to a droppable cell c, drop, walk to the true object", minimised over
  c by a forward Dijkstra from the agent (rare: only on a door, goal or object cell);
- hands empty: on the true object -> ``pickup``; else best move towards the true object
  (wherever it lies: its room, the hallway after a drop elsewhere, ...).
"""

from __future__ import annotations

import heapq
from typing import Any

import numpy as np

from gpl_dist.envs.multiroom_core import (
    ACTION_DROP,
    ACTION_PICKUP,
    DOOR_INDEX_FLAT,
    K_DOOR,
    KIND_FLAT,
    NEIGHBOURS,
    NUM_CELLS,
    REGION_FLAT,
)

_INF = 1 << 20
_MAPS: dict[int, tuple[list[int], list[int]]] = {}


def _enter_cost(cell: int, mask: int) -> int:
    if KIND_FLAT[cell] == K_DOOR and not (mask >> DOOR_INDEX_FLAT[cell]) & 1:
        return 2
    return 1


def distance_map(target: int, mask: int) -> tuple[list[int], list[int]]:
    """(cost-to-go to ``target`` from every cell, best move at every cell) under door mask ``mask``.

    Cost counts actions (a closed door costs one extra). Best move: the lowest action id among
    the optimal moves; -1 at the target and at walls. Cached per (target, mask).
    """
    key = target * 64 + mask
    hit = _MAPS.get(key)
    if hit is not None:
        return hit
    dist = [_INF] * NUM_CELLS
    dist[target] = 0
    # reverse Dijkstra: the cost of p -> u is enter_cost(u), so every predecessor of u gets
    # dist[u] + enter_cost(u); with weights 1 and 2, a bucket queue is exact.
    buckets: list[list[int]] = [[target]]
    d = 0
    while d < len(buckets):
        for u in buckets[d]:
            if dist[u] != d:
                continue
            nd = d + _enter_cost(u, mask)
            for _, p in NEIGHBOURS[u]:
                if nd < dist[p]:
                    dist[p] = nd
                    while len(buckets) <= nd:
                        buckets.append([])
                    buckets[nd].append(p)
        d += 1
    best = [-1] * NUM_CELLS
    for c in range(NUM_CELLS):
        if c == target or dist[c] >= _INF:
            continue
        best_cost = _INF
        for a, n in NEIGHBOURS[c]:
            cost = _enter_cost(n, mask) + dist[n]
            if cost < best_cost:
                best_cost, best[c] = cost, a
    _MAPS[key] = (dist, best)
    return dist, best


def clear_cache() -> None:
    """Forget every cached distance map (for benchmarks of the cold path)."""
    _MAPS.clear()


def cache_size() -> int:
    """Distance maps cached so far, one per (target, door mask) (for tests and benchmarks)."""
    return len(_MAPS)


def _forward_costs(start: int, mask: int) -> tuple[list[int], list[int]]:
    """Cost from ``start`` to every cell and the first action of a cheapest path (Dijkstra)."""
    dist = [_INF] * NUM_CELLS
    first = [-1] * NUM_CELLS
    dist[start] = 0
    heap = [(0, start)]
    while heap:
        d, u = heapq.heappop(heap)
        if d != dist[u]:
            continue
        for a, n in NEIGHBOURS[u]:
            nd = d + _enter_cost(n, mask)
            if nd < dist[n]:
                dist[n] = nd
                first[n] = a if u == start else first[u]
                heapq.heappush(heap, (nd, n))
    return dist, first


class MultiRoomExpert:
    """Optimal multi-room expert: ``act(env) -> int`` for the env's current state."""

    soft_labels = False

    def label(self, env: Any) -> tuple[int, np.ndarray]:
        """The action and its one-hot distribution (shortest paths are followed deterministically)."""
        a = self.act(env)
        probs = np.zeros(6, dtype=np.float32)
        probs[a] = 1.0
        return a, probs

    def act(self, env: Any) -> int:
        u = getattr(env, "unwrapped", env)
        carrying = u._carrying
        pos = u._pos
        if carrying == 0:
            if pos == u._goal_cell:
                return ACTION_PICKUP
            return distance_map(u._goal_cell, u._door_mask)[1][pos]
        if carrying > 0:
            if u.can_drop_at(pos):
                return ACTION_DROP
            return self._decoy_move(u)
        target = u._obj_cell[0]
        if pos == target:
            return ACTION_PICKUP
        return distance_map(target, u._door_mask)[1][pos]

    def _decoy_move(self, u: Any) -> int:
        mask = u._door_mask
        to_target = distance_map(u._obj_cell[0], mask)[0]
        dist, first = _forward_costs(u._pos, mask)
        best, best_a = _INF, -1
        for c in range(NUM_CELLS):
            if dist[c] < _INF and c != u._pos and u.can_drop_at(c):
                total = dist[c] + 1 + to_target[c]
                if total < best or (total == best and first[c] < best_a):
                    best, best_a = total, first[c]
        return best_a

    def cost_to_go(self, env: Any) -> int:
        """Number of actions the expert needs from the current state to (re)solve the task."""
        u = getattr(env, "unwrapped", env)
        mask, pos = u._door_mask, u._pos
        goal = u._goal_cell
        if u._carrying == 0:
            return distance_map(goal, mask)[0][pos]
        target = u._obj_cell[0]
        # the door of the object's room is open after the first leg (if the object is in a room)
        mask2 = mask
        if REGION_FLAT[target] > 0:
            mask2 |= 1 << (REGION_FLAT[target] - 1)
        leg2 = 1 + distance_map(goal, mask2)[0][target]
        if u._carrying > 0:
            if u.can_drop_at(pos):
                return 1 + distance_map(target, mask)[0][pos] + leg2
            dist, _ = _forward_costs(pos, mask)
            to_target = distance_map(target, mask)[0]
            return min(dist[c] + 1 + to_target[c] for c in range(NUM_CELLS)
                       if dist[c] < _INF and c != pos and u.can_drop_at(c)) + leg2
        return distance_map(target, mask)[0][pos] + leg2

    def action_values(self, env: Any) -> np.ndarray:
        """Cost-to-go after each of the 6 actions (1 + cost from the next state); lower is better."""
        import copy

        out = np.empty(6, dtype=np.int64)
        for a in range(6):
            e = copy.deepcopy(getattr(env, "unwrapped", env))
            e.step(a)
            out[a] = 1 + self.cost_to_go(e)
        return out

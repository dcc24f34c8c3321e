"""Multi-room expert: solves every task optimally, from the start and from perturbed states."""

from __future__ import annotations

import pickle
from collections import deque

import gymnasium as gym
import numpy as np
import pytest

import gpl_dist  # noqa: F401
from gpl_dist.envs.multiroom import MAX_STEPS, MultiRoomEnv
from gpl_dist.envs.multiroom_core import DOOR_INDEX_FLAT, K_DOOR, KIND_FLAT, NUM_TASKS, STEP
from gpl_dist.experts import make_expert
from gpl_dist.experts.multiroom import MultiRoomExpert, distance_map

UP, LEFT, RIGHT, DOWN, PICKUP, DROP = range(6)
TASK = 727  # green triangle at (5, 4) in the blue room -> green goal (15, 9) in the purple room
EXPERT = MultiRoomExpert()


def go(env, x, y):
    u = env.unwrapped
    target = y * 19 + x
    while u._pos != target:
        env.step(distance_map(target, u._door_mask)[1][u._pos])


def run_expert(env, limit=300):
    """Steps the expert until success; returns the number of expert actions (or None)."""
    for n in range(1, limit + 1):
        env.step(EXPERT.act(env))
        if env.unwrapped.success:
            return n
    return None


def brute_force_cost(env) -> int:
    """Independent BFS over (cell, door mask, carrying the true object) with the env's rules.

    Only states with empty hands or holding the true object (dropping it or taking decoys never
    shortens a plan), the true object fixed at its cell until picked up.
    """
    u = env.unwrapped
    assert u.carrying in (-1, 0)
    goal, obj = u._goal_cell, u._obj_cell[0]
    start = (u._pos, u._door_mask, u.carrying == 0)
    seen = {start: 0}
    queue = deque([start])
    while queue:
        s = queue.popleft()
        pos, mask, held = s
        d = seen[s]
        if held and pos == goal:
            return d
        nexts = []
        for a in range(4):
            n = STEP[a][pos]
            if n < 0:
                continue
            if KIND_FLAT[n] == K_DOOR and not mask >> DOOR_INDEX_FLAT[n] & 1:
                nexts.append((pos, mask | 1 << DOOR_INDEX_FLAT[n], held))
            else:
                nexts.append((n, mask, held))
        if not held and pos == obj:
            nexts.append((pos, mask, True))
        for t in nexts:
            if t not in seen:
                seen[t] = d + 1
                queue.append(t)
    raise AssertionError("unsolvable")


def test_dispatch_and_wrapped_env():
    env = gym.make("gpl/MultiRoom-v0", task_id=TASK)
    env.reset(seed=0)
    expert = make_expert(env)
    assert isinstance(expert, MultiRoomExpert)
    a = expert.act(env)
    assert isinstance(a, int) and 0 <= a < 6
    for _ in range(MAX_STEPS):
        _, _, term, trunc, info = env.step(expert.act(env))
        if trunc:
            break
    assert info["success"] and info["completion"] == 1.0 and not term


def test_all_tasks_from_start_optimal():
    lengths = []
    for t in range(NUM_TASKS):
        env = MultiRoomEnv(t)
        env.reset()
        planned = EXPERT.cost_to_go(env)
        n = run_expert(env, limit=MAX_STEPS)
        assert n is not None and n == planned, t
        assert env.completion == 1.0
        lengths.append(n)
    assert max(lengths) <= 60 and min(lengths) >= 10


@pytest.mark.parametrize("task_id", [0, TASK, 1234, 2100, 3239])
def test_expert_matches_brute_force(task_id):
    rng = np.random.default_rng(task_id)
    env = MultiRoomEnv(task_id)
    env.reset()
    assert EXPERT.cost_to_go(env) == brute_force_cost(env)
    # perturbed states without a decoy in hand
    for _ in range(3):
        env.reset()
        for a in rng.integers(0, 4, size=int(rng.integers(5, 60))):
            env.step(a)
        if rng.random() < 0.5:
            go(env, *env.task.objects[0].xy)
            env.step(PICKUP)
            for a in rng.integers(0, 4, size=int(rng.integers(0, 30))):
                env.step(a)
        if env.success:
            continue
        cost = brute_force_cost(env)
        assert EXPERT.cost_to_go(env) == cost
        assert run_expert(env) == cost


def test_perturbed_states_sample():
    rng = np.random.default_rng(123)
    within = 0
    tasks = rng.choice(NUM_TASKS, size=500, replace=False)
    for t in tasks:
        env = MultiRoomEnv(int(t))
        env.reset()
        for a in rng.integers(0, 6, size=int(rng.integers(0, 61))):
            env.step(a)
        if env.success:
            within += 1
            continue
        planned = EXPERT.cost_to_go(env)
        n = run_expert(env)
        assert n == planned, int(t)
        within += env.steps <= MAX_STEPS
    assert within >= 0.97 * len(tasks)


def test_hard_states():
    env = MultiRoomEnv(TASK)
    env.reset()
    # holding a decoy (red triangle from the grey room) on a goal cell (grey decoy goal (4, 9)):
    # cannot drop here, so the expert steps off, drops, then fetches the true object
    go(env, 2, 9)
    env.step(PICKUP)
    assert env.carrying == 3
    go(env, 4, 9)
    assert EXPERT.act(env) != DROP
    alternatives = []
    for a in range(4):  # independent: step to a neighbour, drop there, brute-force the rest
        clone = pickle.loads(pickle.dumps(env))
        clone.step(a)
        clone.step(DROP)
        if clone.carrying == -1:
            alternatives.append(2 + brute_force_cost(clone))
    planned = EXPERT.cost_to_go(env)
    assert planned == min(alternatives)
    assert run_expert(env) == planned and env.success
    # holding a decoy on a legal cell: drop at once
    env.reset()
    go(env, 2, 9)
    env.step(PICKUP)
    go(env, 3, 10)
    assert EXPERT.act(env) == DROP
    # standing on the true goal without the object: goes for the object
    env.reset()
    go(env, 15, 9)
    assert EXPERT.act(env) != PICKUP
    cost = brute_force_cost(env)
    assert run_expert(env) == cost
    # the object dropped in the hallway: fetched from there
    env.reset()
    go(env, 5, 4)
    env.step(PICKUP)
    go(env, 9, 16)
    env.step(DROP)
    go(env, 2, 2)
    cost = brute_force_cost(env)
    assert run_expert(env) == cost
    # next to a closed door: the bump counts
    env.reset()
    go(env, 8, 3)
    assert EXPERT.cost_to_go(env) == brute_force_cost(env)
    assert EXPERT.act(env) == LEFT
    env.step(LEFT)
    assert env.agent_pos == (8, 3) and EXPERT.act(env) == LEFT
    vals = EXPERT.action_values(env)
    assert vals.shape == (6,) and vals.argmin() == LEFT and vals[LEFT] == EXPERT.cost_to_go(env)
    # after success the expert stays put
    env.reset()
    run_expert(env)
    pos = env.agent_pos
    for _ in range(3):
        env.step(EXPERT.act(env))
    assert env.agent_pos == pos and env.carrying == 0

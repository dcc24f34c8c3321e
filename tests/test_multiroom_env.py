"""Multi-room env: API checks, observation encoding, dynamics, reward, render, tasks and splits."""

from __future__ import annotations

import hashlib
import json
import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest

import gpl_dist  # noqa: F401  (registers the envs)
from gpl_dist.domains import get_domain
from gpl_dist.envs.multiroom import (
    DOMAIN,
    HELDOUT4_OBJECTS,
    HELDOUT_OBJECTS,
    MAX_STEPS,
    VOCABULARY,
    MultiRoomEnv,
    decoy_overlap,
    make_splits,
)
from gpl_dist.envs.multiroom_core import ITEM_CELLS, NUM_TASKS, XY, get_task
from gpl_dist.experts.multiroom import distance_map
from gpl_dist.language import split_words
from gpl_dist.splits import load_splits

UP, LEFT, RIGHT, DOWN, PICKUP, DROP = range(6)
# Paper example: "Move green triangle to green square"; object in the blue room at (5, 4), goal in
# the purple room at (15, 9); decoy goal yellow at (4, 4) (blue room); decoys in grey/red rooms.
TASK = 727


def go(env, x, y):
    """Walk (opening doors) to (x, y) along a shortest path; returns the last step's output."""
    u = env.unwrapped
    out = None
    target = y * 19 + x
    while u._pos != target:
        out = env.step(distance_map(target, u._door_mask)[1][u._pos])
    return out


def test_task_enumeration_and_layout():
    combos = set()
    for t in range(NUM_TASKS):
        task = get_task(t)
        key = (task.obj_colour, task.obj_shape, task.obj_room, task.goal_colour, task.goal_room)
        combos.add(key)
        assert task.obj_room != task.goal_room
        cells = [o.cell for o in task.objects] + [g.cell for g in task.goals]
        assert len(set(cells)) == 8
        assert task.objects[0].cell in ITEM_CELLS[task.obj_room]
        assert task.goals[0].cell in ITEM_CELLS[task.goal_room]
        for o in task.objects[1:]:
            assert (o.colour, o.shape) != (task.obj_colour, task.obj_shape)
            assert o.cell in ITEM_CELLS[o.room]
        assert len({(o.colour, o.shape) for o in task.objects}) == 4
        assert len({g.colour for g in task.goals}) == 4
    assert len(combos) == NUM_TASKS
    t = get_task(TASK)
    assert (t.obj_colour, t.obj_shape, t.obj_room_name, t.goal_colour, t.goal_room_name) == (
        "green", "triangle", "blue", "green", "purple")
    assert MultiRoomEnv(TASK).instruction == "Move green triangle to green square"


@pytest.mark.parametrize("bad", [-1, NUM_TASKS, 3240.0, "3", None, True])
def test_task_id_out_of_range(bad):
    with pytest.raises(ValueError, match="task_id"):
        MultiRoomEnv(bad)


def test_domain_spec_and_vocabulary():
    assert get_domain("multiroom") is DOMAIN
    env = DOMAIN.make_env(5)
    assert isinstance(env, MultiRoomEnv) and env.task_id == 5
    assert DOMAIN.trajectory_samples == 4 and DOMAIN.obs_shape == env.observation_space.shape
    from gpl_dist.corrections import make_corrector

    words = set(VOCABULARY.words)
    full = make_corrector("multiroom").full_information(env)
    assert len(split_words(full)) <= VOCABULARY.max_tokens
    for t in range(0, NUM_TASKS, 7):
        e = MultiRoomEnv(t)
        for text in (e.instruction, *e.subgoal_texts, make_corrector("multiroom").full_information(e)):
            assert set(split_words(text)) <= words, text
    assert VOCABULARY.decode(VOCABULARY.encode(full)) == full


def _sample_split_tasks():
    rng = np.random.default_rng(0)
    return [int(rng.choice(ids)) for name, ids in sorted(load_splits("multiroom").items()) for _ in range(2)]


def test_gymnasium_and_sb3_check_env():
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for t in _sample_split_tasks():
            check_env(MultiRoomEnv(t, render_mode="rgb_array"), skip_render_check=False)
            check_env(gym.make("gpl/MultiRoom-v0", task_id=t, render_mode="rgb_array").unwrapped)
            wrapped = gym.make("gpl/MultiRoom-v0", task_id=t)
            check_env(wrapped)
            assert wrapped.spec.max_episode_steps == MAX_STEPS
        sb3_check_env(MultiRoomEnv(TASK), warn=False)
        sb3_check_env(MultiRoomEnv(TASK, reward_mode="sparse"), warn=False)


def test_same_seed_same_episode_and_pickle():
    rng = np.random.default_rng(1)
    actions = rng.integers(0, 6, size=150)
    runs = []
    for _ in range(2):
        env = MultiRoomEnv(11)
        obs, info = env.reset(seed=3)
        traj = [obs]
        for a in actions:
            o, r, term, trunc, info = env.step(a)
            traj.append((o, r, term, trunc, info["completion"], info["success"]))
        runs.append(traj)
    for a, b in zip(*runs):
        if isinstance(a, np.ndarray):
            assert np.array_equal(a, b)
        else:
            assert np.array_equal(a[0], b[0]) and a[1:] == b[1:]
    # reset(seed) seeds np_random
    e1, e2 = MultiRoomEnv(1), MultiRoomEnv(1)
    e1.reset(seed=7)
    e2.reset(seed=7)
    assert e1.np_random.integers(1 << 30) == e2.np_random.integers(1 << 30)
    # pickle mid-episode: the copy continues identically
    env = MultiRoomEnv(TASK)
    env.reset(seed=0)
    go(env, 5, 4)
    env.step(PICKUP)
    clone = pickle.loads(pickle.dumps(env))
    assert clone.task == env.task and clone.carrying == 0
    for a in actions[:40]:
        o1, r1, *_ , i1 = env.step(a)
        o2, r2, *_ , i2 = clone.step(a)
        assert np.array_equal(o1, o2) and r1 == r2 and i1 == i2
    # reset restores the start state
    obs0, _ = MultiRoomEnv(TASK).reset()
    obs1, info1 = env.reset()
    assert np.array_equal(obs0, obs1) and info1["completion"] == 0.0 and env.door_open == (False,) * 6


def test_truncation_never_terminates():
    env = gym.make("gpl/MultiRoom-v0", task_id=3)
    raw = MultiRoomEnv(3)
    env.reset(seed=0)
    raw.reset(seed=0)
    for i in range(1, MAX_STEPS + 1):
        _, _, term, trunc, _ = env.step(i % 6)
        _, _, rterm, rtrunc, _ = raw.step(i % 6)
        assert not term and not rterm
        assert trunc == rtrunc == (i == MAX_STEPS)


def test_observation_encoding_doors_and_carry():
    env = MultiRoomEnv(TASK)
    obs, info = env.reset()
    assert obs.shape == (7, 7, 6) and obs.dtype == np.uint8
    assert env.agent_pos == (8, 12)
    # agent at [3, 3] is hallway floor; west (col 2) at y=12 is the wall x=7
    assert obs[3, 3, 0] == 1 and obs[3, 2, 0] == 2
    # row 0 = y 9: grey door at (7, 9) -> col 2, purple (11, 9) -> col 6; both closed
    assert tuple(obs[0, 2, :3]) == (3, 3, 1) and tuple(obs[0, 6, :3]) == (3, 4, 1)
    # grey room cells (5..6, 9..11) are hidden behind the closed door
    assert (obs[0:3, 0:2, :3] == 0).all()
    assert (obs[..., 3:] == 0).all()
    go(env, 8, 4)  # next to the blue door (7, 3), yellow decoy goal at (4, 4), object at (5, 4)
    obs = env.step(UP)[0]
    assert env.agent_pos == (8, 3)
    assert tuple(obs[3, 2, :3]) == (3, 1, 1)  # blue door, closed
    assert (obs[1:6, 0:2, :3] == 0).all()  # blue room x=5,6 hidden
    obs, *_ = env.step(LEFT)  # bump: opens, does not move
    assert env.agent_pos == (8, 3) and env.door_open[0]
    assert tuple(obs[3, 2, :3]) == (3, 1, 2)
    assert tuple(obs[4, 0, :2]) == (5, 2)  # green triangle at (5, 4): row 4, col 0
    assert (obs[1:6, 0:2, 0] >= 1).all()
    obs, *_ = env.step(LEFT)
    assert env.agent_pos == (7, 3)  # on the open door cell
    assert tuple(obs[3, 3, :3]) == (3, 1, 2)
    go(env, 5, 4)
    obs, *_ = env.step(PICKUP)
    assert env.carrying == 0
    assert tuple(obs[3, 3, :3]) == (1, 0, 0)  # floor under the agent now
    assert (obs[..., 3] == 5).all() and (obs[..., 4] == 2).all() and (obs[..., 5] == 1).all()
    assert tuple(obs[3, 2, :2]) == (7, 6)  # yellow goal at (4, 4)
    # inside the blue room, the grey room (through the wall y=6) is hidden even with its door open
    env.reset()
    go(env, 8, 9)
    env.step(LEFT)
    assert env.door_open[2]
    go(env, 6, 5)
    obs = env._obs()
    assert (obs[5:7, 0:4, :3] == 0).all()  # y=7..8, x=3..6: grey room interior
    assert (obs[4, :, 0][:4] == 2).all()  # the wall y=6
    # from the hallway both open rooms are visible at once
    go(env, 9, 6)
    obs = env._obs()
    assert (obs[0:3, 0, 0] >= 1).all() and (obs[4:7, 0, 0] >= 1).all()  # x=6: blue y=3..5, grey y=7..9
    # out-of-grid reads as wall
    go(env, 8, 1)
    obs = env._obs()
    assert (obs[0:2, :, 0] == 2).all()


def test_pickup_drop_rules():
    env = MultiRoomEnv(TASK)
    env.reset()
    env.step(DROP)
    env.step(PICKUP)  # nothing here
    assert env.carrying == -1
    go(env, 4, 4)  # yellow decoy goal
    go(env, 5, 4)
    env.step(PICKUP)
    assert env.carrying == 0 and env.object_positions[0] is None
    env.step(PICKUP)  # hands full: no-op
    assert env.carrying == 0
    go(env, 4, 4)
    env.step(DROP)  # a goal cell: refused
    assert env.carrying == 0
    go(env, 7, 3)
    env.step(DROP)  # a door cell: refused
    assert env.carrying == 0
    go(env, 8, 3)
    env.step(DROP)
    assert env.carrying == -1 and env.object_positions[0] == (8, 3)
    obs = env._obs()
    assert tuple(obs[3, 3, :2]) == (5, 2) and (obs[..., 3:] == 0).all()
    go(env, 2, 9)  # red triangle decoy in the grey room
    env.step(PICKUP)
    assert env.carrying == 3
    go(env, 8, 3)
    env.step(DROP)  # the true object lies here: refused
    assert env.carrying == 3


def test_completion_subgoals_and_dense_reward():
    env = MultiRoomEnv(TASK)
    _, info = env.reset()
    assert [t for t, _ in info["subgoals"]] == [
        "enter the blue room", "pick up the green triangle", "exit the blue room",
        "enter the purple room", "go to the green goal"]
    assert not any(d for _, d in info["subgoals"]) and info["completion"] == 0.0
    _, r, *_ = env.step(UP)  # (8, 11); waypoint = blue door (7, 3)
    assert r == pytest.approx(-0.01 * np.hypot(1, 8))
    go(env, 7, 3)
    _, r, _, _, info = env.step(LEFT)  # enter the blue room at (6, 3); waypoint the object (5, 4)
    assert r == pytest.approx(100 - 0.01 * np.hypot(1, 1)) and info["completion"] == 0.2
    assert [d for _, d in info["subgoals"]] == [True, False, False, False, False]
    _, r, *_ = env.step(RIGHT)  # back on the door (= the waypoint): L = 5 again, best-so-far stays
    assert r == 0.0 and env.completion == 0.2 and env.subgoals_left == 5
    go(env, 5, 4)
    _, r, _, _, info = env.step(PICKUP)  # waypoint: the blue door (exit)
    assert r == pytest.approx(100 - 0.01 * np.hypot(2, 1)) and info["completion"] == 0.4
    go(env, 7, 3)  # hallway with the object: +100
    assert env.completion == 0.6
    env.step(DROP)  # refused on a door; step into the hallway and drop there
    env.step(RIGHT)
    _, r, _, _, info = env.step(DROP)  # object on (8, 3), agent on it -> waypoint is the object
    assert r == pytest.approx(0.0) and info["completion"] == 0.6 and env.subgoals_left == 4
    env.step(PICKUP)
    go(env, 15, 9)
    assert env.success and env.completion == 1.0
    _, r, _, _, info = env.step(PICKUP)  # stays: no bonus, zero distance
    assert r == 0.0 and info["success"] and all(d for _, d in info["subgoals"])
    # sparse: 1.0 exactly once
    env = MultiRoomEnv(TASK, reward_mode="sparse")
    env.reset()
    go(env, 5, 4)
    rewards = [env.step(PICKUP)[1]]
    tail = go(env, 15, 9)
    assert tail[1] == 1.0 and rewards == [0.0]
    assert env.step(UP)[1] == 0.0 and env.step(DOWN)[1] == 0.0 and env.success


def test_render_rgb():
    env = MultiRoomEnv(TASK, render_mode="rgb_array")
    env.reset()
    img = env.render()
    assert img.shape == (19 * 32, 19 * 32, 3) and img.dtype == np.uint8
    assert MultiRoomEnv(TASK).render() is None

    def tile(im, x, y):
        return im[y * 32:(y + 1) * 32, x * 32:(x + 1) * 32]

    task = env.task
    tiles = [tile(img, *o.xy) for o in task.objects] + [tile(img, *g.xy) for g in task.goals]
    tiles.append(tile(img, 9, 9))  # plain floor
    tiles.append(tile(img, 0, 0))  # wall
    for i in range(len(tiles)):
        for j in range(i + 1, len(tiles)):
            assert not np.array_equal(tiles[i], tiles[j]), (i, j)
    closed = tile(img, 7, 3).copy()
    agent = tile(img, 8, 12).copy()
    assert not np.array_equal(agent, tile(img, 8, 13))
    go(env, 8, 3)
    env.step(LEFT)
    img2 = env.render()
    assert not np.array_equal(closed, tile(img2, 7, 3))
    go(env, 5, 4)
    before = tile(env.render(), 5, 4).copy()
    env.step(PICKUP)
    assert not np.array_equal(before, tile(env.render(), 5, 4))  # agent now carries a triangle


def test_splits_file_matches_generator():
    splits = make_splits(0)
    stored = json.loads((__import__("pathlib").Path(gpl_dist.__file__).parent / "splits" / "multiroom.json").read_text())
    assert stored["splits"] == splits
    assert set(DOMAIN.split_names) == set(splits)
    assert len(splits["train"]) == 1700 and len(splits["test"]) == 250
    assert not set(splits["train"]) & set(splits["test"])
    assert not set(splits["train"]) & set(splits["valid"]) and not set(splits["test"]) & set(splits["valid"])
    assert len(set(splits["train"]) | set(splits["test"]) | set(splits["valid"])) == NUM_TASKS
    held = set(HELDOUT_OBJECTS)
    assert len(splits["heldout_train"]) == 1700
    for t in splits["heldout_train"]:
        assert not any((o.colour, o.shape) in held for o in get_task(t).objects)
    assert splits["heldout_test"] and all(
        (get_task(t).obj_colour, get_task(t).obj_shape) in held for t in splits["heldout_test"])
    assert len(splits["heldout_test"]) == 180 * len(HELDOUT_OBJECTS)
    # version 2: the harder Table 5 adds splits and keeps every earlier one as it was
    assert len(HELDOUT4_OBJECTS) == 4 and set(HELDOUT_OBJECTS) <= set(HELDOUT4_OBJECTS)
    held4 = set(HELDOUT4_OBJECTS)
    seen = set(splits["heldout4_train"]) | set(splits["heldout4_indist_test"])
    assert len(splits["heldout4_indist_test"]) == 250 and not set(splits["heldout4_train"]) & set(splits["heldout4_indist_test"])
    assert all(not any((o.colour, o.shape) in held4 for o in get_task(t).objects) for t in seen)
    assert len(seen) == sum(not any((o.colour, o.shape) in held4 for o in get_task(t).objects) for t in range(NUM_TASKS))
    assert splits["heldout4_test"] == [t for t in range(NUM_TASKS) if (get_task(t).obj_colour, get_task(t).obj_shape) in held4]
    colour, shape = decoy_overlap(splits["heldout4_test"])
    assert 0 < colour < 1 and 0 < shape < 1
    # each earlier split exactly as version 2 stored it (sha256 of its JSON list)
    pinned = {"train": "8e5e2ed2b4ddaa09", "test": "90ac2bcfbf10e39b", "valid": "29ab99421ddfe65a",
              "heldout_train": "e36698da8a1beefd", "heldout_test": "fd0a34b61378f6fd",
              "heldout4_train": "7f903db6e55837a4", "heldout4_indist_test": "187ea3f9d65433be",
              "heldout4_test": "6df2c412ceaee0d9"}
    assert {k: hashlib.sha256(json.dumps(stored["splits"][k]).encode()).hexdigest()[:16] for k in pinned} == pinned
    # version 3: the held-out runs' valid split, every task of no heldout4 split (none trained on, none tested)
    assert stored["version"] == 3
    assert set(splits["heldout4_valid"]) == set(range(NUM_TASKS)) - seen - set(splits["heldout4_test"])
    assert all((get_task(t).obj_colour, get_task(t).obj_shape) not in held4
               and any((o.colour, o.shape) in held4 for o in get_task(t).objects) for t in splits["heldout4_valid"])
    assert DOMAIN.valid_splits == {"train": "valid", "heldout4_train": "heldout4_valid"}
    # the paper's condition: no test task's subgoal list appears in training
    train_lists = {MultiRoomEnv(t).subgoal_texts for t in splits["train"]}
    assert not any(MultiRoomEnv(t).subgoal_texts in train_lists for t in splits["test"])


def test_env_build_is_cheap_and_xy_consistent():
    import time

    MultiRoomEnv(100)
    t0 = time.perf_counter()
    envs = [MultiRoomEnv(100 + (i % 50)) for i in range(500)]
    assert time.perf_counter() - t0 < 1.0
    assert all(XY[e._pos] == (8, 12) for e in envs)

"""Multi-room correction oracles: golden corrections after hand-built attempts."""

from __future__ import annotations

import numpy as np
import pytest

from gpl_dist.corrections import make_corrector
from gpl_dist.corrections.multiroom import make_multiroom_corrector
from gpl_dist.envs.multiroom import VOCABULARY, MultiRoomEnv
from gpl_dist.envs.multiroom_core import compass
from gpl_dist.experts.multiroom import distance_map
from gpl_dist.language import split_words
from gpl_dist.records import Correction

UP, LEFT, RIGHT, DOWN, PICKUP, DROP = range(6)
# "Move green triangle to green square": object (5, 4) in the blue room (door (7, 3)), goal
# (15, 9) in the purple room (door (11, 9)); decoys: red triangle (2, 9) and yellow ball (3, 8)
# in the grey room, purple ball (2, 16) in the red room; decoy goals yellow (4, 4), red (13, 8),
# grey (4, 9).
TASK = 727
RNG = np.random.default_rng(0)


def go(env, x, y):
    u = env.unwrapped
    target = y * 19 + x
    while u._pos != target:
        env.step(distance_map(target, u._door_mask)[1][u._pos])


def texts(env):
    rng = np.random.default_rng(0)
    return {k: make_multiroom_corrector(k).correct(env, rng).text for k in ("subgoal", "directional", "binary", "reward")}


def fresh():
    env = MultiRoomEnv(TASK)
    env.reset()
    return env


def test_full_information_and_kinds():
    env = fresh()
    oracle = make_corrector("multiroom")
    assert oracle.full_information(env) == (
        "enter the blue room then pick up the green triangle then exit the blue room "
        "then enter the purple room then go to the green goal")
    assert make_corrector("multiroom", "default").correct(env, RNG) == Correction("enter the blue room", "subgoal")
    with pytest.raises(ValueError, match="kind"):
        make_multiroom_corrector("nonsense")


def test_idle_attempt():
    env = fresh()
    for _ in range(99):
        env.step(PICKUP)
    assert texts(env) == {
        "subgoal": "enter the blue room",
        "directional": "the object room is north",  # (8, 12) -> door (7, 3)
        "binary": "you are in the wrong room",
        "reward": "reward zero of five",
    }


def test_wrong_room_entered():
    env = fresh()
    go(env, 5, 9)  # inside the grey room
    assert env.agent_region == 3
    assert texts(env) == {
        "subgoal": "enter the blue room",
        "directional": "the object room is north",  # (5, 9) -> (7, 3): dx 2, dy -6 -> 71.6 deg
        "binary": "you are in the wrong room",
        "reward": "reward zero of five",
    }


def test_in_object_room_without_object():
    env = fresh()
    go(env, 2, 2)
    assert env.completion == 0.2
    assert texts(env) == {
        "subgoal": "pick up the green triangle",
        "directional": "the object is southeast",  # (2, 2) -> (5, 4)
        "binary": "you are in the right room",
        "reward": "reward one of five",
    }
    go(env, 8, 12)  # left again: still "pick up", now in the wrong room
    assert texts(env)["subgoal"] == "pick up the green triangle"
    assert texts(env)["binary"] == "you are in the wrong room"
    assert texts(env)["directional"] == "the object is north"  # (8,12)->(5,4): dx -3, dy -8


def test_decoy_picked():
    env = fresh()
    go(env, 2, 9)
    env.step(PICKUP)  # red triangle decoy
    go(env, 3, 3)  # carried into the object room
    assert env.carrying == 3 and env.completion == 0.2
    assert texts(env) == {
        "subgoal": "pick up the green triangle",
        "directional": "the object is southeast",
        "binary": "you have the wrong object",
        "reward": "reward one of five",
    }
    go(env, 5, 4)  # standing on the object, hands full
    assert texts(env)["directional"] == "the object is here"


def test_object_held_inside_room():
    env = fresh()
    go(env, 5, 4)
    env.step(PICKUP)
    go(env, 2, 2)
    assert texts(env) == {
        "subgoal": "exit the blue room",
        "directional": "the exit is east",  # (2, 2) -> (7, 3): dx 5, dy 1 -> -11.3 deg
        "binary": "you have the right object",
        "reward": "reward two of five",
    }


def test_exit_direction_exact():
    env = fresh()
    go(env, 5, 4)
    env.step(PICKUP)
    go(env, 2, 1)
    c = make_multiroom_corrector("directional").correct(env, RNG)
    assert c == Correction("the exit is east", "directional")  # dx 5, dy 2 -> 21.8 deg
    go(env, 6, 5)
    c = make_multiroom_corrector("directional").correct(env, RNG)
    assert c == Correction("the exit is northeast", "directional")  # dx 1, dy -2 -> 63.4 deg
    assert make_multiroom_corrector("binary").correct(env, RNG) == Correction("you have the right object", "binary")


def test_object_dropped_elsewhere():
    env = fresh()
    go(env, 5, 4)
    env.step(PICKUP)
    go(env, 9, 14)
    env.step(DROP)  # in the hallway
    go(env, 9, 12)
    assert env.carrying == -1 and env.completion == 0.6
    assert texts(env) == {
        "subgoal": "enter the purple room",
        "directional": "the goal room is northeast",  # (9, 12) -> (11, 9): dx 2, dy -3 -> 56 deg
        "binary": "you do not have the object",
        "reward": "reward three of five",
    }


def test_object_carried_into_wrong_room():
    env = fresh()
    go(env, 5, 4)
    env.step(PICKUP)
    go(env, 14, 16)  # the yellow room
    assert env.completion == 0.6 and env.subgoals_left == 3
    assert texts(env) == {
        "subgoal": "enter the purple room",
        "directional": "the goal room is northwest",  # (14, 16) -> (11, 9): dx -3, dy -7 -> 113.2 deg
        "binary": "you are in the wrong room",
        "reward": "reward three of five",
    }


def test_in_goal_room_with_object():
    env = fresh()
    go(env, 5, 4)
    env.step(PICKUP)
    go(env, 13, 10)
    assert env.completion == 0.8
    assert texts(env) == {
        "subgoal": "go to the green goal",
        "directional": "the goal is northeast",  # (13, 10) -> (15, 9): 26.6 deg
        "binary": "you are in the right room",
        "reward": "reward four of five",
    }
    go(env, 13, 8)  # on the red decoy goal
    assert texts(env)["directional"] == "the goal is southeast"  # dx 2, dy 1 -> -26.6 deg
    env.step(DROP)  # not allowed on a goal
    go(env, 12, 8)
    env.step(DROP)
    assert texts(env)["binary"] == "you do not have the object"


def test_goal_reached_without_object():
    env = fresh()
    go(env, 15, 9)
    assert not env.success and env.completion == 0.0
    assert texts(env) == {
        "subgoal": "enter the blue room",
        "directional": "the object room is northwest",  # (15, 9) -> (7, 3): dx -8, dy -6 -> 143 deg
        "binary": "you are in the wrong room",
        "reward": "reward zero of five",
    }


def test_success():
    env = fresh()
    go(env, 5, 4)
    env.step(PICKUP)
    go(env, 15, 9)
    assert env.success
    go(env, 9, 9)  # walking away afterwards: success is sticky
    assert env.success and env.completion == 1.0
    assert texts(env) == {
        "subgoal": "you are done",
        "directional": "you are done",
        "binary": "you are done",
        "reward": "reward five of five",
    }


def test_all_kind_uses_rng_and_words_in_vocabulary():
    env = fresh()
    go(env, 5, 9)
    oracle = make_multiroom_corrector("all")
    rng = np.random.default_rng(5)
    kinds = [oracle.correct(env, rng).kind for _ in range(300)]
    counts = {k: kinds.count(k) for k in ("subgoal", "directional", "binary")}
    assert sum(counts.values()) == 300 and min(counts.values()) > 70
    a = [oracle.correct(env, np.random.default_rng(9)).text for _ in range(3)]
    assert len(set(a)) == 1  # same rng state -> same correction
    # every word any oracle can say is in the vocabulary
    rng = np.random.default_rng(0)
    words = set(VOCABULARY.words)
    for t in range(0, 3240, 97):
        e = MultiRoomEnv(t)
        e.reset()
        for a in rng.integers(0, 6, size=99):
            e.step(a)
        for k in ("subgoal", "directional", "binary", "reward"):
            c = make_multiroom_corrector(k).correct(e, rng)
            assert set(split_words(c.text)) <= words, c.text
            assert c.kind == k


@pytest.mark.parametrize("dx,dy,word", [(0, -5, "north"), (5, 0, "east"), (0, 3, "south"), (-2, 0, "west"),
                                        (3, -3, "northeast"), (-3, 3, "southwest"), (4, 4, "southeast"),
                                        (-1, -1, "northwest"), (0, 0, "here"), (5, 2, "east"), (2, 5, "south")])
def test_compass(dx, dy, word):
    assert compass(dx, dy) == word


def test_goal_room_apart_words_the_goal_rooms_subgoal_unlike_the_object_rooms():
    """The kind differs from ``subgoal`` only where the goal room is next: there it says "go to"."""
    env = fresh()
    apart, subgoal = make_multiroom_corrector("subgoal_goal_room_apart"), make_multiroom_corrector("subgoal")
    said = []
    for x, y, act in ((8, 12, None), (5, 4, None), (5, 4, PICKUP), (9, 9, None), (13, 10, None), (15, 9, None)):
        go(env, x, y)
        if act is not None:
            env.step(act)
        said.append((subgoal.correct(env, RNG).text, apart.correct(env, RNG)))
    assert said == [
        ("enter the blue room", Correction("enter the blue room", "subgoal")),
        ("pick up the green triangle", Correction("pick up the green triangle", "subgoal")),
        ("exit the blue room", Correction("exit the blue room", "subgoal")),
        ("enter the purple room", Correction("go to the purple room", "subgoal")),
        ("go to the green goal", Correction("go to the green goal", "subgoal")),
        ("you are done", Correction("you are done", "subgoal")),
    ]
    assert set(split_words("go to the purple room")) <= set(VOCABULARY.words)
    assert make_corrector("multiroom", "subgoal_goal_room_apart").correct(env, RNG).text == "you are done"

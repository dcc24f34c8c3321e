"""Corrections in BabyAI's words: the first subgoal the attempt missed, where its object lies,
the retry control; seeded by the rng they are given; the full-information text."""

from __future__ import annotations

import numpy as np
import pytest
from babyai_helpers import sample_tasks
from minigrid.core.actions import Actions

from gpl_babyai import tasks as task_table
from gpl_babyai.corrections import DONE_TEXT, KINDS, RETRY_TEXT, WHERE, make_corrector, phrasings
from gpl_babyai.domain import CORRECTION_KINDS, STEPS, VOCABULARY
from gpl_babyai.env import BabyAIEnv
from gpl_babyai.expert import BotExpert


def _attempt(task_id: int, expert_steps: int, seed: int = 0) -> BabyAIEnv:
    """An attempt: the expert for ``expert_steps`` steps, then seeded random turns and moves."""
    env = BabyAIEnv(task_id)
    env.reset(seed=seed)
    expert, rng = BotExpert(), np.random.default_rng([task_id, seed])
    for t in range(STEPS):
        env.step(expert.act(env) if t < expert_steps else int(rng.integers(3)))
    return env


def test_kinds_match_the_spec_and_the_other_domains_naming():
    assert KINDS == CORRECTION_KINDS and "retry" in KINDS and KINDS[0] == "default"
    with pytest.raises(ValueError, match="unknown babyai correction kind"):
        make_corrector("binary")


def test_the_default_correction_is_the_first_subgoal_not_achieved():
    oracle = make_corrector("default")
    for task_id in sample_tasks(2):
        idle = BabyAIEnv(task_id)
        idle.reset(seed=0)
        for _ in range(STEPS):
            idle.step(Actions.done)
        assert idle.subgoals_done == 0 and oracle.correct(idle, np.random.default_rng(0)).text == idle.plan[0].text
        solved = _attempt(task_id, STEPS)
        assert solved.success and oracle.correct(solved, np.random.default_rng(0)).text == DONE_TEXT
        steps = task_table.task(task_id).bot_steps
        half = _attempt(task_id, steps // 2)
        if not half.success:
            k = min(half.subgoals_done, len(half.plan) - 1)
            said = oracle.correct(half, np.random.default_rng(0))
            assert said.text == half.plan[k].text and said.kind == "subgoal"


def test_subgoals_are_said_in_babyais_words():
    """The forms the issue names: go to / open / pick up / put next to, with colour and type."""
    said = {s.split(" the ")[0] for t in sample_tasks(6, "train") for s in BabyAIEnv(t).subgoal_texts}
    assert said >= {"go to", "open", "pick up", "put"}
    unlock = BabyAIEnv(next(t for t in task_table.tasks_of_level("Unlock")
                            if [s.kind for s in BabyAIEnv(t).plan] == ["pickup", "open"]))
    unlock.reset(seed=0)
    key, door = unlock.subgoal_texts
    assert key.startswith("pick up the ") and key.endswith(" key") and door == f"open the {key.split()[3]} door"
    putnext = BabyAIEnv(task_table.tasks_of_level("PutNextLocal")[0])
    assert putnext.subgoal_texts[-1].startswith("put the ") and " next to the " in putnext.subgoal_texts[-1]


def test_directional_hints_say_where_the_next_subgoals_object_is():
    oracle = make_corrector("directional")
    seen = set()
    for task_id in sample_tasks(3):
        for seed in range(3):
            env = _attempt(task_id, 0, seed)
            if env.success:
                continue
            text = oracle.correct(env, np.random.default_rng(seed)).text
            goal = env.plan[min(env.subgoals_done, len(env.plan) - 1)]
            if text != goal.text:  # else the object is in the agent's hands
                where = next(w for w in WHERE if text.endswith(" is " + w))
                seen.add(where)
    assert seen == set(WHERE)


def test_directional_geometry():
    """The agent faces a door two cells ahead: 'in front of you'; after turning: left, behind, right."""
    task_id = next(t for t in task_table.tasks_of_level("Open") if BabyAIEnv(t).plan[0].kind == "open")
    env = BabyAIEnv(task_id)
    env.reset(seed=0)
    expert = BotExpert()
    while True:  # walk with the expert until the door of the first subgoal is straight ahead
        x, y, _ = env.plan[0].args
        ax, ay = env.level.agent_pos
        dx, dy = env.level.dir_vec
        if (x - ax, y - ay) in {(dx, dy), (2 * dx, 2 * dy)}:
            break
        env.step(expert.act(env))
    oracle, rng = make_corrector("directional"), np.random.default_rng(0)
    colour = env.plan[0].args[2]
    said = []
    for turn in (None, Actions.right, Actions.right, Actions.right):
        if turn is not None:
            env.step(turn)
        said.append(oracle.correct(env, rng).text)
    assert said == [f"the {colour} door is {w}" for w in ("in front of you", "on your left", "behind you", "on your right")]


def test_every_kind_is_seeded_by_the_rng_and_said_in_listed_phrasings():
    known = set(phrasings())
    assert all(w in VOCABULARY.words for s in known for w in s.split())
    for kind in CORRECTION_KINDS:
        oracle = make_corrector(kind)
        texts = set()
        for task_id in sample_tasks(2):
            env = _attempt(task_id, 3, task_id)
            a = oracle.correct(env, np.random.default_rng(task_id))
            assert a == oracle.correct(env, np.random.default_rng(task_id))
            assert a.text in known
            texts.add(a.text)
        if kind == "retry":
            assert texts == {RETRY_TEXT}
        else:
            assert len(texts) > 5


def test_all_draws_its_kind_with_the_rng():
    oracle = make_corrector("all")
    env = _attempt(task_table.tasks_of_level("GoTo")[1], 0)
    kinds = {oracle.correct(env, np.random.default_rng(s)).kind for s in range(20)}
    assert kinds == {"subgoal", "directional"}


def test_full_information_is_the_plan_in_words():
    oracle = make_corrector("default")
    for task_id in sample_tasks(1):
        env = _attempt(task_id, 0)
        text = oracle.full_information(env)
        assert text == " then ".join(env.subgoal_texts) and text.split(" then ")[0] == env.plan[0].text

"""The env: BabyAI's own observation, success and reward, every attempt from the same start,
seeded determinism, completion's contract, silenced level generators."""

from __future__ import annotations

import pickle

import gymnasium
import numpy as np
import pytest
from babyai_helpers import reference_level, sample_tasks
from minigrid.core.actions import Actions

from gpl_babyai import tasks as task_table
from gpl_babyai.domain import DOMAIN, STEPS
from gpl_babyai.env import BabyAIEnv
from gpl_babyai.expert import BotExpert
from gpl_babyai.level import LevelCore
from gpl_dist.domains import get_domain


@pytest.mark.parametrize("task_id", sample_tasks(2))
def test_the_view_success_and_reward_are_minigrids_own_bit_for_bit(task_id):
    """Random actions (pick up / drop / toggle included) in the plug-in's env and in minigrid's own
    env of the same level and seed: equal images every step, in the first attempt and in a second
    one (started from the kept snapshot), success on the same step with the same reward."""
    task = task_table.task(task_id)
    env = BabyAIEnv(task_id)
    for attempt in range(2):
        ref, ref_obs = reference_level(task.level, task.seed)
        obs, _ = env.reset(seed=attempt)
        assert np.array_equal(obs, ref_obs) and ref.mission == env.instruction
        rng = np.random.default_rng([task_id, attempt])
        ref_solved = False
        for t in range(STEPS):
            a = int(rng.integers(6))
            obs, reward, terminated, truncated, info = env.step(a)
            ref_obs, ref_reward, ref_terminated, _, _ = ref.step(a)
            assert np.array_equal(obs, ref_obs["image"]), (task_id, attempt, t)
            if not ref_solved and t < ref.max_steps:
                ref_solved = ref_terminated and ref_reward > 0
                assert info["success"] == ref_solved and reward == pytest.approx(ref_reward if ref_solved else 0.0)
            assert not terminated and truncated == (t == STEPS - 1)


def test_every_attempt_starts_from_the_same_generated_level():
    env = BabyAIEnv(task_table.tasks_of_level("Unlock")[3])
    first = env.reset(seed=0)[0]
    grid = env.level.grid.encode()
    pose = (tuple(env.level.agent_pos), env.level.agent_dir)
    for _ in range(20):
        env.step(Actions.forward)
        env.step(Actions.toggle)
    again = env.reset(seed=99)[0]
    assert np.array_equal(first, again) and np.array_equal(grid, env.level.grid.encode())
    assert (tuple(env.level.agent_pos), env.level.agent_dir) == pose
    fresh = LevelCore("Unlock")
    fresh.generate(env.level_seed)
    assert np.array_equal(fresh.level.grid.encode(), grid) and fresh.mission == env.instruction


def _episode(task_id: int, seed: int) -> list:
    get_domain("babyai")  # registers the gymnasium id (gymnasium reads no entry points)
    env = gymnasium.make(DOMAIN.env_id, task_id=task_id)
    rng = np.random.default_rng(seed)
    obs, info = env.reset(seed=seed)
    out = [obs, info["completion"]]
    for _ in range(STEPS):
        obs, r, _, _, info = env.step(int(rng.integers(DOMAIN.num_actions)))
        out += [obs, r, info["completion"], info["success"]]
    return out


def test_seeded_determinism_and_pickling():
    task_id = task_table.splits()["test"][5]
    a, b = _episode(task_id, 3), _episode(task_id, 3)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    env = BabyAIEnv(task_id)
    env.reset(seed=1)
    expert = BotExpert()
    for _ in range(10):
        env.step(expert.act(env))
    clone = pickle.loads(pickle.dumps(env))
    for _ in range(30):  # the expert's bot travels with the env and goes on identically too
        a1, a2 = expert.act(env), expert.act(clone)
        assert a1 == a2
        o1, r1, *_, i1 = env.step(a1)
        o2, r2, *_, i2 = clone.step(a2)
        assert np.array_equal(o1, o2) and r1 == r2 and i1 == i2


@pytest.mark.parametrize("task_id", sample_tasks(1))
def test_completion_is_a_fraction_that_is_1_exactly_when_solved(task_id):
    """Random attempts, an expert attempt, and an attempt that lets the expert act only at times:
    completion stays in [0, 1], never falls, and is 1 exactly on success."""
    env = BabyAIEnv(task_id)
    expert = BotExpert()
    for mode in ("random", "expert", "mixed"):
        rng = np.random.default_rng(task_id)
        _, info = env.reset(seed=0)
        last = info["completion"]
        for t in range(STEPS):
            a = expert.act(env) if mode == "expert" or (mode == "mixed" and rng.random() < 0.7) else int(rng.integers(7))
            _, _, _, _, info = env.step(a)
            c = info["completion"]
            assert 0.0 <= c <= 1.0 and c >= last and (c == 1.0) == info["success"]
            last = c
        if mode == "expert":
            assert info["success"]


def test_completion_credits_the_plans_subgoals_in_order():
    """Unlock: the plan picks up the key, then opens the locked door; completion steps through it."""
    task_id = next(t for t in task_table.tasks_of_level("Unlock") if [s.kind for s in BabyAIEnv(t).plan] == ["pickup", "open"])
    env = BabyAIEnv(task_id)
    env.reset(seed=0)
    assert env.plan[0].args[0] == "key" and env.plan[0].args[1] == env.plan[1].args[2]  # its key, then its door
    assert env.completion == 0.0
    expert, seen = BotExpert(), []
    while not env.success:
        env.step(expert.act(env))
        seen.append(env.completion)
    assert sorted(set(seen)) == [0.0, 0.5, 1.0] and seen == sorted(seen)


def test_no_success_after_the_levels_own_time_limit():
    """GoToLocal's time limit is 64 steps: an attempt that idles 64 steps cannot succeed after."""
    task_id = task_table.tasks_of_level("GoToLocal")[0]
    env = BabyAIEnv(task_id)
    env.reset(seed=0)
    assert env.level.max_steps == 64
    for _ in range(64):
        env.step(Actions.done)
    expert = BotExpert()
    fresh = BabyAIEnv(task_id)
    fresh.reset(seed=0)
    bot_actions = []
    while not fresh.success:
        bot_actions.append(expert.act(fresh))
        fresh.step(bot_actions[-1])
    for a in bot_actions:  # the bot's winning actions, too late
        _, reward, _, _, info = env.step(a)
        assert not info["success"] and reward == 0.0 and info["completion"] < 1.0


def test_bad_task_ids_and_actions_fail_clearly():
    for bad in (-1, DOMAIN.num_tasks, "3", 2.5, None, True):
        with pytest.raises(ValueError, match="task_id"):
            BabyAIEnv(bad)
    env = BabyAIEnv(np.int64(DOMAIN.num_tasks - 1))
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.step(7)


def test_the_level_generators_print_nothing(capsys):
    for level in task_table.table()["levels"]:
        for t in task_table.tasks_of_level(level)[:3]:
            BabyAIEnv(t).reset(seed=0)
    assert capsys.readouterr().out == ""


def test_pictures():
    env = BabyAIEnv(task_table.tasks_of_level("GoTo")[0], render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.shape == (22 * 32, 22 * 32, 3)
    text_env = BabyAIEnv(task_table.tasks_of_level("GoTo")[0], render_mode="ansi")
    text_env.reset(seed=0)
    assert "0 steps" in text_env.render() and text_env.instruction in text_env.render()

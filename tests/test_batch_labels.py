"""Batched expert labels (``gpl_dist.roles.BatchExpert``): the same bits as one env at a time.

The rollout loop labels every step's envs with one ``label_batch`` call when the expert has it.
These tests collect the same tasks both ways, with the real env, expert, oracle and network, and
compare every array of the records.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from gpl_dist.config import load_config
from gpl_dist.domains import get_domain
from gpl_dist.envs.relocation import RelocationEnv
from gpl_dist.experts.relocation_learned import (
    ROW_BLOCK,
    LearnedRelocationExpert,
    action_probs,
    batch_probs,
    load_weights,
    policy_inputs,
    policy_inputs_batch,
)
from gpl_dist.models.build import build_model_from_config
from gpl_dist.roles import BatchExpert, Expert
from gpl_dist.splits import split_tasks
from workers.rollout import Rollout

ROOT_CONFIGS = Path(__file__).resolve().parents[1] / "configs"
RECORD_ARRAYS = ("observations", "actions", "expert_actions", "expert_probs", "instruction_ids", "correction_ids")
RECORD_FIELDS = ("task_id", "attempt_index", "seed", "completion", "success", "correction", "correction_kind", "reward_sum")


class PerEnvLabels:
    """The real expert without ``label_batch``: the rollout loop then labels one env at a time."""

    soft_labels = True

    def __init__(self, inner: LearnedRelocationExpert):
        self.inner = inner

    def act(self, env: Any) -> int:
        return self.inner.act(env)

    def label(self, env: Any) -> tuple[int, np.ndarray]:
        return self.inner.label(env)


def visited_envs(n: int, steps: int = 60) -> list:
    """``n`` relocation envs of different tasks, each some random steps past its reset."""
    d = get_domain("relocation")
    rng = np.random.default_rng(3)
    envs = []
    for i, task in enumerate(split_tasks("relocation", "train")[:n]):
        env = d.make_env(task)
        env.reset(seed=i)
        for _ in range(int(rng.integers(steps))):
            env.step(int(rng.integers(4)))
        envs.append(env)
    return envs


def test_batch_probs_rows_do_not_depend_on_the_batch():
    """Each row the same bits alone, in any batch size and at any place (the padding's point:
    the plain product differs in the last bits between a batch-1 and a batch-25 call here)."""
    weights = load_weights()
    x = np.random.default_rng(0).normal(size=(3 * ROW_BLOCK + 5, 33))
    whole = batch_probs(weights, x)
    for size in (1, 2, 3, 5, 7, ROW_BLOCK - 1, ROW_BLOCK, ROW_BLOCK + 1, 25, 2 * ROW_BLOCK + 3):
        parts = np.concatenate([batch_probs(weights, x[s:s + size]) for s in range(0, len(x), size)])
        assert parts.tobytes() == whole.tobytes(), size
    np.testing.assert_allclose(whole, action_probs(weights, x), rtol=0, atol=1e-12)  # the same network


def test_label_batch_is_label_of_each_env():
    expert = LearnedRelocationExpert()
    assert isinstance(expert, BatchExpert) and isinstance(expert, Expert)
    envs = visited_envs(21)
    x = policy_inputs_batch(envs)
    assert x.tobytes() == np.stack([policy_inputs(e) for e in envs]).tobytes()
    actions, probs = expert.label_batch(envs)
    assert actions.dtype == np.int64 and actions.shape == (21,) and probs.dtype == np.float32 and probs.shape == (21, 4)
    for j, env in enumerate(envs):
        a, p = expert.label(env)
        assert a == actions[j] == expert.act(env) and p.tobytes() == probs[j].tobytes()
    assert np.array_equal(actions, probs.argmax(1)) and len(set(actions.tolist())) > 1  # not one constant label


def _relocation_rollout(expert: Expert, domain=None) -> Rollout:
    cfg = load_config(ROOT_CONFIGS / "relocation.yaml")
    d = domain or get_domain("relocation")
    policy = build_model_from_config(d, cfg.model, seed=0).eval()
    return Rollout(d, policy, d.make_corrector(cfg.env.correction_kind), expert,
                   end_aligned=cfg.model.trajectory_ends_at_last_state)


def _assert_same_records(a, b) -> None:
    assert len(a.attempts) == len(b.attempts) > 0
    for x, y in zip(a.attempts, b.attempts):
        for name in RECORD_FIELDS:
            assert getattr(x, name) == getattr(y, name), name
        for name in RECORD_ARRAYS:
            u, v = getattr(x, name), getattr(y, name)
            assert u.dtype == v.dtype and u.shape == v.shape and u.tobytes() == v.tobytes(), name


def test_a_unit_collected_with_batched_labels_is_the_per_env_unit_bit_for_bit():
    """The shipped relocation config's network and oracle, 7 tasks, 2 corrections: every array
    of every attempt (observations, actions, expert actions and distributions, corrections)."""
    tasks = split_tasks("relocation", "train")[:7]
    expert = LearnedRelocationExpert()
    batched = _relocation_rollout(expert).run(tasks, 2, seed=11, round_index=1)
    per_env = _relocation_rollout(PerEnvLabels(expert)).run(tasks, 2, seed=11, round_index=1)
    _assert_same_records(batched, per_env)
    assert not batched.failures and len(batched.attempts) >= len(tasks) + 1  # some tasks were corrected
    labelled = np.concatenate([a.expert_actions for a in batched.attempts])
    assert (labelled >= 0).all() and len(np.unique(labelled)) == 4


class _BreaksAtStep(RelocationEnv):
    """A relocation env whose step raises once it has run ``BREAK_AT`` steps of an attempt."""

    BREAK_AT = 40

    def step(self, action):
        if self.steps >= self.BREAK_AT:
            raise RuntimeError("the simulator broke")
        return super().step(action)


def test_a_task_that_fails_mid_attempt_is_dropped_alike_in_both_paths():
    d = get_domain("relocation")
    tasks = split_tasks("relocation", "train")[:4]
    broken = dataclasses.replace(d, make_env=lambda t, **kw: _BreaksAtStep(t, **kw) if t == tasks[1] else d.make_env(t, **kw))
    expert = LearnedRelocationExpert()
    batched = _relocation_rollout(expert, broken).run(tasks, 1, seed=5)
    per_env = _relocation_rollout(PerEnvLabels(expert), broken).run(tasks, 1, seed=5)
    assert [f.task_id for f in batched.failures] == [f.task_id for f in per_env.failures] == [tasks[1]]
    assert tasks[1] not in {a.task_id for a in batched.attempts}
    _assert_same_records(batched, per_env)


class _ExpertCannotReadAtStep(RelocationEnv):
    """A relocation env the expert cannot read (``unwrapped`` raises) from step ``BREAK_AT`` on."""

    BREAK_AT = 40

    @property
    def unwrapped(self):
        if self.steps >= self.BREAK_AT:
            raise RuntimeError("the state cannot be read")
        return self


def test_a_task_the_expert_fails_on_is_found_in_the_batch_and_dropped_alone():
    """``label_batch`` raises for the whole batch: each env is labelled alone, only the one at
    fault fails, and the others' records are those of the per-env path."""
    d = get_domain("relocation")
    tasks = split_tasks("relocation", "train")[:4]
    broken = dataclasses.replace(
        d, make_env=lambda t, **kw: _ExpertCannotReadAtStep(t, **kw) if t == tasks[2] else d.make_env(t, **kw))
    expert = LearnedRelocationExpert()
    batched = _relocation_rollout(expert, broken).run(tasks, 1, seed=6)
    per_env = _relocation_rollout(PerEnvLabels(expert), broken).run(tasks, 1, seed=6)
    assert [(f.task_id, f.stage) for f in batched.failures] == [(f.task_id, f.stage) for f in per_env.failures] \
        == [(tasks[2], "step/expert")]
    _assert_same_records(batched, per_env)
    assert {a.task_id for a in batched.attempts} == set(tasks) - {tasks[2]}

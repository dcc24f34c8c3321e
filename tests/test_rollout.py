import dataclasses

import numpy as np
import pytest

from gpl_dist.config import CollectionConfig, EnvConfig, ModelConfig
from gpl_dist.domains import get_domain
from gpl_dist.metrics import completion_by_attempt
from gpl_dist.models.build import build_model, build_model_from_config, state_dict_to_numpy
from workers.worker import RolloutSettings, RolloutWorker

TASKS = (0, 5, 17, 400)


def worker_settings(domain_name="multiroom", label_states=True, **kw) -> RolloutSettings:
    """Worker settings from flat keywords, each put into the config section that owns it."""
    sections = {"env": EnvConfig, "collection": CollectionConfig, "model": ModelConfig}
    parts: dict = {name: {} for name in sections}
    parts["env"]["domain"] = domain_name
    for key, value in kw.items():
        owners = [n for n, c in sections.items() if key in {f.name for f in dataclasses.fields(c)}]
        if not owners:
            raise TypeError(f"no config section has a field '{key}'")
        parts[owners[0]][key] = value
    return RolloutSettings(**{n: c(**parts[n]) for n, c in sections.items()}, label_states=label_states)


def make_worker(domain_name="multiroom", seed=0, **kw):
    d = get_domain(domain_name)
    w = RolloutWorker(d, worker_settings(domain_name, **kw), worker_id="test")
    w.set_weights(state_dict_to_numpy(build_model(d, kw.get("variant", "gpl"), seed=seed)), 0)
    return w


def test_attempt_structure_and_labels():
    w = make_worker(num_corrections=3)
    d = w.domain
    attempts = w.collect(TASKS, "train", seed=1)
    by_task = {}
    for a in attempts:
        by_task.setdefault(a.task_id, []).append(a)
    assert sorted(by_task) == sorted(TASKS)
    for task_id, per in by_task.items():
        assert [a.attempt_index for a in per] == list(range(len(per)))
        assert 1 <= len(per) <= 4
        for a in per:
            assert a.observations.shape == (d.steps_per_attempt,) + d.obs_shape
            assert a.observations.dtype == np.dtype(d.obs_dtype)
            assert ((a.expert_actions >= 0) & (a.expert_actions < d.num_actions)).all()
            assert ((a.actions >= 0) & (a.actions < d.num_actions)).all()
            assert a.instruction.lower().startswith("move")
            assert 0.0 <= a.completion <= 1.0
        # corrections after every attempt but the last; none after a success
        for a in per[:-1]:
            assert a.correction and not a.success and a.correction_ids[0] != 0
        last = per[-1]
        assert last.correction == "" and (last.correction_ids == 0).all()
        assert last.success or len(per) == 4


def test_collection_is_reproducible_from_the_seed():
    a = make_worker(num_corrections=2).collect(TASKS, "train", seed=7)
    b = make_worker(num_corrections=2).collect(TASKS, "train", seed=7)
    c = make_worker(num_corrections=2).collect(TASKS, "train", seed=8)
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert np.array_equal(x.actions, y.actions) and np.array_equal(x.observations, y.observations)
        assert x.correction == y.correction and x.seed == y.seed
    assert any(not np.array_equal(x.actions, y.actions) for x, y in zip(a, c))


def test_expert_labels_match_a_fresh_expert_query():
    from gpl_dist.experts import make_expert

    w = make_worker(num_corrections=0)
    (att,) = w.collect((17,), "train", seed=3)
    env = w.domain.make_env(17)
    env.reset(seed=att.seed)
    expert = make_expert(env)
    for t, a in enumerate(att.actions):
        assert expert.act(env) == att.expert_actions[t]
        env.step(int(a))


@pytest.mark.parametrize("domain_name", ["multiroom", "relocation"])
def test_each_attempt_records_its_summed_reward_and_gpr_is_conditioned_on_it(domain_name):
    """An attempt's reward_sum is its env's dense reward summed over its steps (replayed from its
    seed and actions); it reaches the buffer and GPR's conditioning."""
    w = make_worker(domain_name, num_corrections=1, variant="gpr")
    attempts = w.collect(TASKS[:2], "train", seed=4)
    for att in attempts:
        env = w.domain.make_env(att.task_id)
        env.reset(seed=att.seed)
        total = sum(float(env.step(int(a))[1]) for a in att.actions)
        assert att.reward_sum == pytest.approx(total, rel=1e-9, abs=1e-9) and np.isfinite(att.reward_sum)
    from gpl_dist.records import WorkUnit
    from storage.schema import build_unit_tables

    tables = build_unit_tables("run", WorkUnit(0, 0, TASKS[:2], "train", 4, 0), attempts, "w")
    assert tables.attempts.column("reward_sum").to_pylist() == pytest.approx([a.reward_sum for a in attempts])


def test_variants_without_corrections_make_one_attempt():
    w = make_worker(num_corrections=5, variant="full_information")
    attempts = w.collect(TASKS, "train", seed=0)
    assert [a.attempt_index for a in attempts] == [0] * len(TASKS)
    assert all("then" in a.instruction for a in attempts)  # the full-information text


def test_failing_task_is_reported_and_others_continue():
    d = get_domain("multiroom")

    def make_env(task_id, **kw):
        if task_id == 5:
            raise RuntimeError("simulated broken task")
        return d.make_env(task_id, **kw)

    broken = dataclasses.replace(d, make_env=make_env)
    w = RolloutWorker(broken, worker_settings(num_corrections=1), worker_id="t")
    w.set_weights(state_dict_to_numpy(build_model(d, seed=0)), 0)
    attempts = w.collect(TASKS, "train", seed=0)
    assert {a.task_id for a in attempts} == set(TASKS) - {5}
    assert [f.task_id for f in w.failures] == [5]
    assert "task 5" in str(w.failures[0]) and "simulated broken task" in str(w.failures[0])


def test_completion_curve_carries_solved_tasks_forward():
    w = make_worker(num_corrections=1)
    attempts = w.collect((0,), "train", seed=0)
    curve = completion_by_attempt(attempts, 2)
    assert curve.shape == (2,)
    assert curve[0] == pytest.approx(attempts[0].completion)
    assert curve[1] == pytest.approx(attempts[-1].completion)


def test_sampled_actions_follow_the_softmax_and_greedy_takes_the_argmax():
    import torch

    from workers.rollout import sample_actions
    logits = torch.tensor([[0.0, 1.0, 2.0, -1.0], [3.0, 0.0, 0.0, 0.0]]).repeat(50_000, 1)
    actions = sample_actions(logits, np.random.default_rng(0), greedy=False).reshape(-1, 2)
    for row in range(2):
        freq = np.bincount(actions[:, row], minlength=4) / len(actions)
        assert np.abs(freq - torch.softmax(logits[row], 0).numpy()).max() < 0.01
    again = sample_actions(logits, np.random.default_rng(0), greedy=False).reshape(-1, 2)
    assert np.array_equal(actions, again)
    assert sample_actions(logits[:2], np.random.default_rng(0), greedy=True).tolist() == [2, 0]


def test_settings_from_config_carry_the_run_and_the_overrides():
    from pathlib import Path

    from gpl_dist.config import load_config

    cfg = load_config(Path(__file__).resolve().parents[1] / "configs" / "relocation.yaml", {"collection.num_corrections": "3"})
    s = RolloutSettings.of_run(cfg)
    assert (s.collection.num_corrections, s.env.expert, s.model.trajectory_ends_at_last_state, s.model.variant) == \
        (3, "learned", True, "gpl")
    assert s.model.policy_batchnorm
    # the worker builds the learner's architecture: the driver's weights load strictly
    learner_model = build_model_from_config(get_domain("relocation"), cfg.model, seed=0)
    RolloutWorker(get_domain("relocation"), s, worker_id="test").set_weights(state_dict_to_numpy(learner_model), 0)
    meta_test = dataclasses.replace(s, collection=dataclasses.replace(s.collection, num_corrections=5, greedy_actions=True),
                                    label_states=False)
    assert (meta_test.collection.num_corrections, meta_test.collection.greedy_actions, meta_test.label_states) == (5, True, False)
    assert meta_test.model.trajectory_ends_at_last_state  # evaluation conditions the policy as collection did
    with pytest.raises(TypeError):
        dataclasses.replace(s, not_a_setting=1)


def test_a_worker_collects_with_one_blas_thread_and_gives_the_process_its_own_back():
    """As in a 1-CPU Ray actor (``workers.worker.RolloutWorker``): the serial collector's worker
    lives in the driver, where a second BLAS thread stalls beside any busy process. The learned
    relocation expert labels on one BLAS thread; after the unit the process has its two again."""
    from threadpoolctl import threadpool_info, threadpool_limits

    def blas_threads() -> set[int]:
        return {p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"}

    w = make_worker("relocation", num_corrections=0, expert="learned")
    seen: list[set[int]] = []
    label_batch = w.rollout.expert.label_batch

    def watched(envs):
        seen.append(blas_threads())
        return label_batch(envs)

    w.rollout.expert.label_batch = watched
    with threadpool_limits(limits=2, user_api="blas"):
        attempts = w.collect([0, 1], "train", seed=3)
        after = blas_threads()
    assert attempts and seen and all(s == {1} for s in seen)
    assert after == {2}

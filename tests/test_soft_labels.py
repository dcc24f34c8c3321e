"""The expert's action distributions: produced by the experts, carried by worker and buffer,
fitted by the learner."""

import dataclasses

import numpy as np
import pyarrow.parquet as pq
import torch

from gpl_dist.config import TrainingConfig
from gpl_dist.domains import get_domain
from gpl_dist.experts import make_expert
from gpl_dist.models.build import build_model
from learner.batches import TensorView
from learner.trainer import Learner
from storage import BufferReader, ShardWriter, commit_round, load_manifest
from storage.synthetic import VECTOR, synthetic_unit
from tests.test_rollout import make_worker


def test_relocation_expert_labels_are_distributions_around_its_action():
    env = get_domain("relocation").make_env(11)
    env.reset(seed=4)
    expert = make_expert(env)
    soft = 0
    for _ in range(200):
        a, probs = expert.label(env)
        assert probs.shape == (4,) and probs.dtype == np.float32
        assert (probs >= 0).all() and abs(float(probs.sum()) - 1.0) < 1e-5
        assert probs[a] > 0  # the action the controller takes is always one of the good ones
        soft += probs.max() < 0.99
        env.step(a)
    assert soft > 20  # waypoints off the axes give mass to both axis actions


def test_multiroom_expert_labels_are_one_hot():
    env = get_domain("multiroom").make_env(3)
    env.reset(seed=0)
    expert = make_expert(env)
    for _ in range(30):
        a, probs = expert.label(env)
        assert a == expert.act(env) and probs[a] == 1.0 and probs.sum() == 1.0
        env.step(a)


def test_worker_attempts_carry_the_distributions():
    w = make_worker("relocation", num_corrections=1)
    for a in w.collect((2, 9), "train", seed=5):
        assert a.expert_probs.shape == (a.length, 4)
        np.testing.assert_allclose(a.expert_probs.sum(1), 1.0, atol=1e-5)
        assert (a.expert_probs[np.arange(a.length), a.expert_actions] > 0).all()
    unlabelled = make_worker("relocation", num_corrections=0, label_states=False).collect((2,), "test", seed=5)
    assert unlabelled[0].expert_probs is None


def test_buffer_round_trip_of_distributions(tmp_path):
    root = tmp_path / "run"
    writer = ShardWriter(root, "r")
    g = np.random.default_rng(0)
    expected = []
    records = []
    for u in range(2):
        unit, attempts = synthetic_unit(0, u, [10 * u + t for t in range(3)], VECTOR, 2, (5, 40), seed=u)
        with_probs = []
        for i, a in enumerate(attempts):
            probs = None
            if (u, i % 2) != (1, 1):  # some attempts store none: they must read back one-hot
                probs = g.dirichlet(np.ones(7), a.length).astype(np.float32)
                probs[np.arange(a.length), a.expert_actions] += 1.0
                probs /= probs.sum(1, keepdims=True)
            with_probs.append(dataclasses.replace(a, expert_probs=probs))
            if probs is None:
                probs = np.eye(7, dtype=np.float32)[a.expert_actions]
            expected.append(probs)
        records.append(writer.write_unit(unit, with_probs, worker_id="w"))
    commit_round(root, 0, records)
    view = BufferReader(root).load_training_view(capacity_tuples=10**9)
    np.testing.assert_array_equal(view.expert_probs, np.concatenate(expected))
    # analysts read the column with pyarrow
    tuples = BufferReader(root).read_table("tuples", columns=["expert_action", "expert_probs"])
    first = tuples.slice(0, 1).to_pylist()[0]
    assert len(first["expert_probs"]) == 7 and abs(sum(first["expert_probs"]) - 1) < 1e-5


def test_units_without_distributions_read_as_labels_only(tmp_path):
    root = tmp_path / "run"
    writer = ShardWriter(root, "r")
    unit, attempts = synthetic_unit(0, 0, [1, 2], VECTOR, 2, (5, 40), seed=0)
    rec = writer.write_unit(unit, attempts, worker_id="w")
    commit_round(root, 0, [rec])
    (tuples_file,) = load_manifest(root, 0).shards[0].files_of("tuples")
    assert "expert_probs" in pq.read_schema(root / tuples_file.path).names
    view = BufferReader(root).load_training_view()
    assert view.expert_probs is None and view.num_tuples > 0
    assert TensorView.from_view(view).expert_probs is None


def _relocation_view(tmp_path):
    w = make_worker("relocation", num_corrections=1)
    unit = dataclasses.replace(synthetic_unit(0, 0, [0], VECTOR, 1, (5, 6), seed=0)[0], task_ids=(3, 8))
    attempts = w.collect(unit.task_ids, "train", seed=1)
    rec = ShardWriter(tmp_path / "run", "r").write_unit(unit, attempts, worker_id="w")
    commit_round(tmp_path / "run", 0, [rec])
    return BufferReader(tmp_path / "run").load_training_view()


def test_learner_fits_the_distributions(tmp_path):
    tv = TensorView.from_view(_relocation_view(tmp_path))
    assert tv.expert_probs is not None and tv.expert_probs.shape == (tv.num_states, 4)
    torch.manual_seed(0)
    learner = Learner(build_model(get_domain("relocation"), seed=0),
                      TrainingConfig(num_epochs_per_round=1, batch_size=256, states_per_chunk=16, num_threads=1))
    idx = torch.arange(256)
    obs, _, cond, rows = tv.batch(idx)
    with torch.no_grad():
        logits = learner.model(obs, cond, rows)
    expected = float(-(tv.expert_probs[idx] * torch.log_softmax(logits, 1)).sum(1).mean())
    loss, _ = learner.step(tv, idx)
    assert abs(loss - expected) < 1e-4  # the step's loss is the cross-entropy to the distribution

    def kl() -> float:
        with torch.no_grad():
            logp = torch.log_softmax(learner.model(*[x for x in (obs, cond, rows)]), 1)
        p = tv.expert_probs[idx]
        return float((p * (torch.log(p.clamp(min=1e-12)) - logp)).sum(1).mean())

    before = kl()
    for _ in range(60):
        learner.step(tv, idx)
    learner.model.eval()
    assert kl() < 0.5 * before

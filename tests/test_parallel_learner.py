"""Data-parallel learner: real helper processes, a real gloo group, real views from real rollouts."""

from __future__ import annotations

import os
import signal
import threading
import time

import pytest
import torch

from gpl_dist.config import TrainingConfig
from gpl_dist.domains import get_domain
from gpl_dist.models.gpl import build_model, state_dict_to_numpy
from gpl_dist.records import WorkUnit
from learner.batches import TensorView
from learner.parallel import ModelSpec
from learner.trainer import Learner


def _collected_view(root, domain_name: str, num_tasks: int) -> TensorView:
    from gpl_dist.splits import split_tasks
    from storage import BufferReader, ShardWriter, commit_round
    from workers.rollout import RolloutSettings, RolloutWorker

    d = get_domain(domain_name)
    worker = RolloutWorker(d, RolloutSettings(num_corrections=2), ShardWriter(str(root), "t"), "t-0")
    worker.set_weights(state_dict_to_numpy(build_model(d, seed=1)), 0)
    tasks = tuple(int(t) for t in split_tasks(domain_name, "train")[:num_tasks])
    commit_round(str(root), 0, [worker.run_unit(WorkUnit(0, 0, tasks, "train", seed=0, policy_version=0))])
    return TensorView.from_view(BufferReader(str(root)).load_training_view(10**6, d.trajectory_stride))


@pytest.fixture(scope="module")
def views(tmp_path_factory):
    return {name: _collected_view(tmp_path_factory.mktemp(name), name, n)
            for name, n in (("multiroom", 24), ("relocation", 4))}


def _learner(domain_name: str, num_processes: int, **cfg) -> Learner:
    cfg = TrainingConfig(**{"num_epochs_per_round": 1, "batch_size": 256, "num_processes": num_processes, **cfg})
    return Learner(build_model(get_domain(domain_name), seed=0), cfg, seed=0,
                   spec=ModelSpec(domain_name, "gpl", 16))


def test_two_processes_take_the_same_steps_as_one(views):
    """Without BatchNorm, splitting every batch over two processes is the same gradient descent."""
    tv = views["multiroom"]
    one, two = _learner("multiroom", 1), _learner("multiroom", 2)
    try:
        for _ in range(2):  # the second round reuses the helper and resends the state
            s1, s2 = one.train_round(tv), two.train_round(tv)
            assert s2.num_steps == s1.num_steps > 0
            assert s2.loss == pytest.approx(s1.loss, rel=1e-4)
            assert s2.accuracy == pytest.approx(s1.accuracy, abs=1e-3)
        assert two.num_processes == 2  # no silent fallback to one process
        for a, b in zip(one.model.parameters(), two.model.parameters()):
            assert torch.allclose(a, b, atol=1e-4)
    finally:
        two.close()


def test_batchnorm_model_trains_data_parallel(views):
    """Relocation's state encoder normalises with BatchNorm: per-share statistics, loss still falls."""
    tv = views["relocation"]
    learner = _learner("relocation", 2)
    try:
        first = learner.train_round(tv)
        second = learner.train_round(tv)
        assert learner.num_processes == 2
        assert second.loss < first.loss
    finally:
        learner.close()


def _helper_pids(learner: Learner) -> list[int]:
    return [p.pid for p in learner._group._procs] if learner._group is not None else []


def test_killed_helper_falls_back_to_one_process_from_the_round_start(views):
    """SIGKILL a helper in the middle of a round: the round restarts in one process from its initial
    state, so the result equals a one-process learner's, and no helper process is left behind."""
    tv = views["multiroom"]
    expected = _learner("multiroom", 1, num_epochs_per_round=8).train_round(tv)
    learner = _learner("multiroom", 2, num_epochs_per_round=8)  # starts its helper process
    try:
        pids = _helper_pids(learner)
        assert len(pids) == 1

        def kill_soon():
            time.sleep(0.3)
            os.kill(pids[0], signal.SIGKILL)

        killer = threading.Thread(target=kill_soon)
        killer.start()
        stats = learner.train_round(tv)
        killer.join()
        assert learner.num_processes == 1 and learner._group is None
        assert stats.num_steps == expected.num_steps
        assert stats.loss == pytest.approx(expected.loss, rel=1e-4)
        with pytest.raises(ProcessLookupError):
            os.kill(pids[0], 0)
    finally:
        learner.close()

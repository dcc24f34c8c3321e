"""Data-parallel learners (``learner.parallel``): real processes, real gloo, the real model."""

import dataclasses
import os

import numpy as np
import pytest
import torch

from gpl_dist.config import ConfigError, TrainingConfig, load_config
from gpl_dist.domains import get_domain
from gpl_dist.models.build import build_model, state_dict_to_numpy
from gpl_dist.records import LearnerState
from learner.batches import TensorView
from learner.parallel import DataParallelLearner, LearnerFailed, make_learner, resolve_num_learners
from learner.trainer import Learner, available_cpus, threads_per_learner
from tests.test_safety import _is_loopback, _listening
from tests.test_trainer import _view


def _cfg(**kw):
    return TrainingConfig(**{"num_epochs_per_round": 2, "batch_size": 64, "num_threads": 1, "device": "cpu", **kw})


def test_two_learners_train_as_one_with_the_same_batch(tmp_path):
    """Same global batch, same epoch order: the weights after a round agree with one learner's up to
    float rounding, the statistics cover every state once per epoch, and rank 0 checkpoints alone."""
    tv = TensorView.from_view(_view(tmp_path, rounds=2))
    one = Learner(build_model(get_domain("multiroom"), seed=3), _cfg(), seed=5)
    s1 = one.train_round(tv)
    two = DataParallelLearner(build_model(get_domain("multiroom"), seed=3), _cfg(num_learners=2), 2, seed=5)
    try:
        procs = list(two._procs)
        s2 = two.train_round(tv)
        w1, w2 = state_dict_to_numpy(one.model), state_dict_to_numpy(two.model)
        for k in w1:
            np.testing.assert_allclose(w1[k], w2[k], rtol=1e-4, atol=2e-5, err_msg=k)
        assert s2.num_states == s1.num_states == tv.num_states
        assert s2.num_steps == s1.num_steps
        assert abs(s2.loss - s1.loss) < 1e-4 and abs(s2.accuracy - s1.accuracy) < 1e-3
        # a second round: the helper takes rank 0's state again and keeps in step
        s3 = two.train_round(tv)
        s4 = one.train_round(tv)
        assert abs(s3.loss - s4.loss) < 1e-3
        assert two.state().optimizer["state"][0]["step"] == s1.num_steps * 2
    finally:
        two.close()
    assert all(not p.is_alive() for p in procs)


def test_a_resumed_optimizer_reaches_the_helpers(tmp_path):
    """Rank 0 loads a checkpoint's Adam moments; the helper must take them, or the replicas part."""
    tv = TensorView.from_view(_view(tmp_path))
    first = Learner(build_model(get_domain("multiroom"), seed=1), _cfg(num_epochs_per_round=1))
    first.train_round(tv)
    saved = first.state()
    resumed_one = Learner(build_model(get_domain("multiroom")), _cfg(num_epochs_per_round=1), seed=9)
    resumed_two = DataParallelLearner(build_model(get_domain("multiroom")), _cfg(num_epochs_per_round=1), 2, seed=9)
    try:
        for learner in (resumed_one, resumed_two):
            learner.load_state(LearnerState(saved.model, saved.optimizer, learner.state().generator))
            learner.train_round(tv)
        w1, w2 = state_dict_to_numpy(resumed_one.model), state_dict_to_numpy(resumed_two.model)
        for k in w1:
            np.testing.assert_allclose(w1[k], w2[k], rtol=1e-4, atol=2e-5, err_msg=k)
    finally:
        resumed_two.close()


def test_learners_listen_on_loopback_only_and_a_dead_helper_fails_the_round_in_one_line(tmp_path):
    tv = TensorView.from_view(_view(tmp_path))
    learner = DataParallelLearner(build_model(get_domain("multiroom"), seed=0), _cfg(), 2)
    try:
        pids = [os.getpid(), *(p.pid for p in learner._procs)]
        learner.train_round(tv)
        sockets = _listening(pids)
        assert sockets and all(_is_loopback(ip) for _, ip, _ in sockets), sockets  # gloo listens, on loopback
        learner._procs[0].kill()
        learner._procs[0].join()
        with pytest.raises(LearnerFailed, match="exited"):
            learner.train_round(tv)
    finally:
        learner.close()


def test_how_many_learners_and_threads():
    cores = available_cpus()
    cpu = {"device": "cpu"}
    assert resolve_num_learners(TrainingConfig(num_learners=3, **cpu)) == 3
    assert resolve_num_learners(TrainingConfig(num_learners=0, **cpu)) == cores
    assert resolve_num_learners(TrainingConfig(num_learners=8, batch_size=6, **cpu)) == 3  # >= 2 states each
    assert resolve_num_learners(TrainingConfig(num_learners=1, **cpu)) == 1
    # threads: one per learner by default; 0 shares the cores out, never more threads than cores
    assert threads_per_learner(TrainingConfig()) == 1
    assert threads_per_learner(TrainingConfig(num_threads=0, num_learners=1)) == cores
    assert threads_per_learner(TrainingConfig(num_threads=0, num_learners=0)) == 1
    assert threads_per_learner(TrainingConfig(num_threads=0, num_learners=cores * 2)) == 1
    assert threads_per_learner(TrainingConfig(num_learners=2, num_threads=3)) == 3
    assert isinstance(make_learner(build_model(get_domain("multiroom")), TrainingConfig(num_learners=1, **cpu)), Learner)


def test_num_learners_is_checked_with_the_config(tmp_path):
    with pytest.raises(ConfigError, match="training.num_learners must be in 0..64"):
        load_config(None, {"training.num_learners": "-1"})
    cfg = load_config(None, {"training.num_learners": "0"})
    assert dataclasses.asdict(cfg.training)["num_learners"] == 0


def test_on_a_gpu_the_learner_is_one_process(monkeypatch):
    """The GPU itself cannot run here: only its presence is mocked."""
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert resolve_num_learners(TrainingConfig(device="cuda", num_learners=4)) == 1
    assert resolve_num_learners(TrainingConfig(device="auto", num_learners=0)) == 1
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert resolve_num_learners(TrainingConfig(device="auto", num_learners=2)) == 2


def test_where_the_learner_runs():
    from learner.remote import DRIVER, GPU_ACTOR, placement

    assert placement("cpu", driver_has_cuda=True, cluster_gpus=4) == DRIVER
    assert placement("cuda", driver_has_cuda=True, cluster_gpus=0) == DRIVER
    assert placement("auto", driver_has_cuda=True, cluster_gpus=8) == DRIVER
    assert placement("cuda", driver_has_cuda=False, cluster_gpus=1) == GPU_ACTOR
    assert placement("auto", driver_has_cuda=False, cluster_gpus=2) == GPU_ACTOR
    assert placement("auto", driver_has_cuda=False, cluster_gpus=0.5) == DRIVER  # no whole GPU anywhere
    with pytest.raises(ConfigError, match="neither this machine nor the Ray cluster has a GPU"):
        placement("cuda", driver_has_cuda=False, cluster_gpus=0)


@pytest.mark.ray
def test_a_learner_actor_trains_as_the_driver_would(tmp_path, ray_cluster):
    """The path a GPU node's learner takes (state out, view in, state back), on a CPU actor here:
    two rounds give the local learner's weights, Adam state and batch order."""
    from learner.remote import RemoteLearner

    view = _view(tmp_path, rounds=2)
    local = Learner(build_model(get_domain("multiroom"), seed=2), _cfg(), seed=4)
    remote = RemoteLearner(build_model(get_domain("multiroom"), seed=2), _cfg(), seed=4, num_gpus=0)
    try:
        assert remote.device() == "cpu"
        for _ in range(2):
            s_local, s_remote = local.train_round(view), remote.train_round(view)
            assert s_remote.loss == pytest.approx(s_local.loss, rel=1e-6)
        w1, w2 = local.weights(), remote.weights()
        for k in w1:
            np.testing.assert_allclose(w1[k], w2[k], rtol=1e-5, atol=1e-6, err_msg=k)
        assert torch.equal(local.state().generator, remote.state().generator)
        assert remote.state().optimizer["state"][0]["step"] == local.state().optimizer["state"][0]["step"]
    finally:
        remote.close()


@pytest.mark.ray
def test_cuda_on_a_cluster_without_a_gpu_fails_in_one_line_before_anything_is_written(tmp_path, ray_cluster,
                                                                                       monkeypatch):
    """With --address the GPU may be on another node, so the check waits until the cluster is
    joined; it must still come before the run dir gets a config (GPUs are mocked away, so the
    test means the same on a GPU machine)."""
    from learner import remote
    from learner.driver import run_training
    from tests.test_training_e2e import tiny

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    monkeypatch.setattr(remote, "cluster_gpus", lambda: 0.0)  # a GPU machine running this test has one
    run = tmp_path / "run"
    with pytest.raises(ConfigError, match="neither this machine nor the Ray cluster has a GPU"):
        run_training(tiny(**{"training.device": "cuda"}), run, serial=False, address="auto", progress=False)
    assert not (run / "config.yaml").exists() and not (run / "buffer" / "manifests").exists()
    assert ray_cluster.is_initialized()  # the shared cluster is left running

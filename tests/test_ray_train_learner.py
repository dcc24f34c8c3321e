"""Learners in a Ray Train group (``learner.ray_train``): real Ray Train, real gloo, the real model."""

import numpy as np
import pytest

from gpl_dist import roles
from gpl_dist.config import ConfigError, TrainingConfig, load_config
from gpl_dist.domains import get_domain
from gpl_dist.models.build import build_model, state_dict_to_numpy
from learner.parallel import LearnerFailed
from learner.trainer import Learner
from tests.test_trainer import _view


def _cfg(**kw):
    return TrainingConfig(**{"num_epochs_per_round": 2, "batch_size": 64, "num_threads": 1, "device": "cpu",
                             "engine": "ray-train", "num_learners": 2, **kw})


@pytest.mark.ray
def test_two_ray_train_learners_train_as_one_and_fail_in_one_line(ray_cluster, tmp_path):
    """One group for all rounds: each round's weights agree with one local learner's up to float
    rounding (same global batch, same epoch order), and Adam's state comes back to the driver. A
    learner that raises then ends the group, and the driver says so at once, not after a timeout."""
    from learner.ray_train import RayTrainLearner

    view = _view(tmp_path, rounds=2)
    one = Learner(build_model(get_domain("multiroom"), seed=3), _cfg(num_learners=1, engine="processes"), seed=5)
    group = RayTrainLearner(build_model(get_domain("multiroom"), seed=3), _cfg(), seed=5)
    try:
        assert len(group.nodes) == 2 and isinstance(group, roles.Learner)
        for _ in range(2):
            s1, s2 = one.train_round(view), group.train_round(view)
            w1, w2 = state_dict_to_numpy(one.model), state_dict_to_numpy(group.model)
            for k in w1:
                np.testing.assert_allclose(w1[k], w2[k], rtol=1e-3, atol=1e-4, err_msg=k)
            assert s2.num_states == s1.num_states and s2.num_steps == s1.num_steps
            assert abs(s2.loss - s1.loss) < 1e-3
        assert group.state().optimizer["state"][0]["step"] == 2 * s1.num_steps
        assert group.weights().keys() == one.weights().keys()
        with pytest.raises(LearnerFailed, match="Ray Train learners stopped .*no attribute 'observations'.*--resume"):
            group.train_round(object())  # not a view: every learner fails to read it
    finally:
        group.close()
    assert not group._fit.is_alive()


@pytest.mark.ray
def test_a_group_the_cluster_cannot_hold_is_refused_before_it_starts(ray_cluster):
    from learner.ray_train import RayTrainLearner

    with pytest.raises(ConfigError, match="no room for 64 learner"):
        RayTrainLearner(build_model(get_domain("multiroom")), _cfg(num_learners=64))


def test_gpu_choice_for_ray_train_learners():
    from learner.ray_train import group_cpus, learner_resources, wants_gpu

    assert wants_gpu("auto", cluster_gpus=4, num_learners=4)
    assert not wants_gpu("auto", cluster_gpus=1, num_learners=2)
    assert not wants_gpu("cpu", cluster_gpus=8, num_learners=2)
    with pytest.raises(ConfigError, match="cluster has 1 GPU"):
        wants_gpu("cuda", cluster_gpus=1, num_learners=2)
    assert learner_resources(_cfg(num_threads=3), use_gpu=True) == {"CPU": 3.0, "GPU": 1.0}
    assert group_cpus(_cfg(num_learners=3, num_threads=2)) == 6
    assert group_cpus(_cfg(engine="processes", num_learners=3)) == 0


def test_engine_is_checked_with_the_config():
    with pytest.raises(ConfigError, match="training.engine must be one of processes, ray-train, got 'ray'"):
        load_config(None, {"training.engine": "ray"})
    with pytest.raises(ConfigError, match="num_learners must be at least 1 with training.engine=ray-train"):
        load_config(None, {"training.engine": "ray-train", "training.num_learners": "0"})


def test_ray_train_without_a_cluster_is_refused_before_anything_is_written(tmp_path):
    """Ray Train's rendezvous listens on every interface: a run on one machine uses processes."""
    from learner.driver import run_training

    cfg = load_config(None, {"training.engine": "ray-train", "training.num_learners": "2"})
    for serial in (True, False):
        with pytest.raises(ConfigError, match="give its --address, or use training.engine=processes"):
            run_training(cfg, tmp_path / "run", serial=serial)
    assert not (tmp_path / "run").exists()

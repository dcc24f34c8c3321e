"""End-to-end DAgger runs on a tiny task set: serial, on Ray, resumed."""

import json

import numpy as np
import pytest

from gpl_dist.config import config_from_dict
from gpl_dist.errors import RunDirError
from learner.checkpoint import load_checkpoint
from learner.driver import run_training

TINY = {
    "seed": 3,
    "env": {"domain": "multiroom", "max_train_tasks": 6},
    "collection": {"num_workers": 2, "num_corrections": 2, "tasks_per_unit": 3},
    "training": {"num_rounds": 2, "num_epochs_per_round": 1, "batch_size": 256},
}


def tiny(**over):
    tree = json.loads(json.dumps(TINY))
    for dotted, value in over.items():
        node = tree
        *head, last = dotted.split(".")
        for k in head:
            node = node.setdefault(k, {})
        node[last] = value
    return config_from_dict(tree)


def tuples_per_round(run_dir):
    from storage import BufferReader

    reader = BufferReader(str(run_dir / "buffer"))
    return {r: reader.manifest(r).num_tuples for r in reader.committed_rounds()}


def test_serial_run_commits_every_round_and_checkpoints(tmp_path):
    result = run_training(tiny(), tmp_path / "serial", serial=True, progress=False)
    assert [m.round_index for m in result.history] == [0, 1]
    counts = tuples_per_round(tmp_path / "serial")
    assert sorted(counts) == [0, 1]
    # 6 tasks x at most 3 attempts x 100 states
    assert all(600 <= n <= 1800 and n % 100 == 0 for n in counts.values())
    ckpt = load_checkpoint(tmp_path / "serial" / "checkpoints")
    assert ckpt.round_index == 1 and ckpt.config["env"]["max_train_tasks"] == 6
    assert (tmp_path / "serial" / "config.yaml").is_file()
    lines = (tmp_path / "serial" / "metrics.jsonl").read_text().splitlines()
    assert len(lines) == 2 and len(json.loads(lines[0])["completion_by_corrections"]) == 3


def test_existing_run_is_not_overwritten_without_resume(tmp_path):
    run_training(tiny(**{"training.num_rounds": 1}), tmp_path / "r", serial=True, progress=False)
    with pytest.raises(RunDirError, match="--resume"):
        run_training(tiny(), tmp_path / "r", serial=True, progress=False)


def test_resume_continues_at_the_next_round(tmp_path):
    run_dir = tmp_path / "resumed"
    run_training(tiny(**{"training.num_rounds": 1}), run_dir, serial=True, progress=False)
    assert load_checkpoint(run_dir / "checkpoints").round_index == 0
    result = run_training(tiny(), run_dir, serial=True, progress=False, resume=True)
    assert [m.round_index for m in result.history] == [0, 1]
    assert load_checkpoint(run_dir / "checkpoints").round_index == 1
    assert sorted(tuples_per_round(run_dir)) == [0, 1]
    # same as an uninterrupted run, round for round
    straight = run_training(tiny(), tmp_path / "straight", serial=True, progress=False)
    assert tuples_per_round(run_dir) == tuples_per_round(tmp_path / "straight")
    assert np.allclose([m.loss for m in result.history], [m.loss for m in straight.history], rtol=1e-4)


@pytest.mark.ray
def test_ray_run_matches_serial_row_counts(tmp_path, ray_cluster):
    serial = run_training(tiny(), tmp_path / "serial", serial=True, progress=False)
    on_ray = run_training(tiny(), tmp_path / "ray", serial=False, progress=False)
    assert [m.round_index for m in on_ray.history] == [0, 1]
    assert tuples_per_round(tmp_path / "ray") == tuples_per_round(tmp_path / "serial")
    assert np.allclose([m.completion_by_corrections for m in on_ray.history],
                       [m.completion_by_corrections for m in serial.history])


def test_two_learner_processes_train_resume_and_stop(tmp_path, monkeypatch):
    """A run with training.num_learners=2, stopped after round 0 and resumed, trains round 0 like
    one learner (same batches, sums in another order: later rounds may part through sampling) and
    leaves no learner process behind."""
    import multiprocessing

    from learner import parallel

    helpers_seen = []
    real_train_round = parallel.DataParallelLearner.train_round

    def train_round(self, view, on_epoch=None):
        helpers_seen.append(sum(p.is_alive() for p in self._procs))
        return real_train_round(self, view, on_epoch)

    monkeypatch.setattr(parallel.DataParallelLearner, "train_round", train_round)
    two = {"training.num_learners": 2, "training.device": "cpu"}
    run_dir = tmp_path / "two"
    run_training(tiny(**two, **{"training.num_rounds": 1}), run_dir, serial=True, progress=False)
    resumed = run_training(tiny(**two), run_dir, serial=True, progress=False, resume=True)
    assert helpers_seen == [1, 1]  # each round trained with its helper process alive
    one = run_training(tiny(**{"training.num_rounds": 1}), tmp_path / "one", serial=True, progress=False)
    assert [m.round_index for m in resumed.history] == [0, 1]
    assert resumed.history[0].buffer_tuples == one.history[0].buffer_tuples
    assert abs(resumed.history[0].loss - one.history[0].loss) < 1e-4
    assert not [p for p in multiprocessing.active_children() if p.name.startswith("gpl-learner")]

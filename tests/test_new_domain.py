"""A domain from outside the package, added in one place: ``tests/domains/corridor.py`` defines
it whole, and a run's config names that file (``env.domain_module``), with no edit anywhere in
gpl-dist. It trains one DAgger round serially and on Ray and is evaluated: the steps of
``docs/adding-a-domain.md``. ``tests/test_env_contract.py`` runs the env contract over it too.
"""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from gpl_dist.config import ConfigError, config_from_dict
from gpl_dist.domains import domain_names, get_domain, load_domain_module, register_domain
from gpl_dist.errors import UserError

CORRIDOR_FILE = Path(__file__).parent / "domains" / "corridor.py"


@pytest.fixture
def corridor():
    assert load_domain_module(str(CORRIDOR_FILE)) == ("corridor",)
    return get_domain("corridor")


def _config(tmp_path, workers: int = 1) -> Path:
    config = tmp_path / "corridor.yaml"
    config.write_text(f"env: {{domain: corridor, domain_module: {CORRIDOR_FILE}}}\n"
                      f"collection: {{num_workers: {workers}, num_corrections: 2, tasks_per_unit: 4}}\n"
                      "training: {num_rounds: 1, num_epochs_per_round: 2, batch_size: 16}\neval: {seeds: [0, 1]}\n")
    return config


def test_a_domain_from_a_separate_file_trains_one_dagger_round_and_evaluates(corridor, tmp_path, capsys):
    from gpl_dist.cli import main
    from storage import BufferReader

    assert "corridor" in domain_names() and get_domain("corridor") is corridor
    assert gym.make("gpl-test/Corridor-v0", task_id=2).reset(seed=0)[0].shape == (3,)
    with pytest.raises(ConfigError, match="env.correction_kind must be one of default for corridor"):
        config_from_dict({"env": {"domain": "corridor", "correction_kind": "subgoal"}})

    # the domain's own defaults: its first expert ("walker", no "scripted") and its splits
    cfg = config_from_dict({"env": {"domain": "corridor"}})
    assert (cfg.env.expert, cfg.env.train_split, cfg.eval.split) == ("walker", "train", "test")
    config = _config(tmp_path)
    run = tmp_path / "run"
    assert main(["train", "--config", str(config), "--serial", "--run-dir", str(run), "--no-progress"]) == 0
    reader = BufferReader(run / "buffer")
    assert reader.committed_rounds() == [0]
    attempts = reader.read_table("attempts")
    assert sorted(set(attempts.column("task_id").to_pylist())) == [0, 1, 2, 3, 4, 5]
    assert set(attempts.column("correction").to_pylist()) <= {"", "go left", "go right"}
    tuples = reader.read_table("tuples")
    assert tuples.num_rows == corridor.steps_per_attempt * attempts.num_rows
    # every label is the expert's step towards the goal
    view = reader.load_training_view(trajectory_stride=corridor.trajectory_stride)
    cells = np.rint(view.observations[:, 0] * 6).astype(int)
    goals = np.array([corridor.make_env(t).goal for t in range(corridor.num_tasks)])[view.task_id[view.attempt_rows]]
    assert np.array_equal(view.expert_actions, (goals >= cells).astype(np.int64))

    assert main(["eval", "--run-dir", str(run)]) == 0
    out = capsys.readouterr().out
    assert "meta-test on 2 tasks x 2 seeds" in out
    report = json.loads((run / "eval.json").read_text())
    assert report["domain"] == "corridor" and len(report["completion"]) == 6
    assert all(0.0 <= c <= 1.0 for c in report["completion"])


@pytest.mark.ray
def test_the_same_domain_trains_on_ray_actors_that_import_the_file_themselves(corridor, tmp_path, ray_cluster):
    from gpl_dist.cli import main
    from storage import BufferReader

    run = tmp_path / "ray-run"
    assert main(["train", "--config", str(_config(tmp_path, workers=2)), "--run-dir", str(run), "--no-progress"]) == 0
    attempts = BufferReader(run / "buffer").read_table("attempts")
    assert sorted(set(attempts.column("task_id").to_pylist())) == [0, 1, 2, 3, 4, 5]
    manifest = json.loads((run / "buffer" / "manifests" / "round-000000.json").read_text())
    assert {shard["worker_id"] for shard in manifest["shards"]} <= {"actor-0", "actor-1"}  # written by the actors
    serial = tmp_path / "serial-run"
    assert main(["train", "--config", str(_config(tmp_path, workers=2)), "--serial", "--run-dir", str(serial),
                 "--no-progress"]) == 0
    assert attempts.num_rows == BufferReader(serial / "buffer").read_table("attempts").num_rows


def test_a_bad_domain_module_fails_in_one_line(tmp_path):
    with pytest.raises(ConfigError, match="env.domain_module: domain module .*nowhere.py: no such file"):
        config_from_dict({"env": {"domain": "corridor", "domain_module": str(tmp_path / "nowhere.py")}})
    empty = tmp_path / "empty.py"
    empty.write_text("X = 1\n")
    with pytest.raises(UserError, match="defines no DOMAIN"):
        load_domain_module(str(empty))


def test_a_spec_that_misses_a_required_part_is_refused(corridor):
    import dataclasses

    CORRIDOR = corridor
    with pytest.raises(ValueError, match="correction_kinds must include 'default'"):
        register_domain(dataclasses.replace(CORRIDOR, name="corridor-bad", correction_kinds=("left",)))
    with pytest.raises(ValueError, match="a different domain named 'multiroom'"):
        register_domain(dataclasses.replace(get_domain("multiroom"), num_tasks=3))
    assert "corridor-bad" not in domain_names()

"""Each artifact of an older shape is read, where it is read, as the current one: one test per era.

Checkpoints (``learner.checkpoint.load_checkpoint``), buffer shards
(``storage.reader.read_shard_table``), RL results (``gpl_dist.app.suite.rl.jobs.read_result``) and
suite run records (``gpl_dist.app.suite.one_run.read_record``); the eval, curve and swap files'
eras are tested with their records (``tests/test_suite_records.py``). An era found in the
archive under ``docs/paper-report/runs`` is read from there; the others are written here.
"""

import dataclasses
import io
import json
import shutil
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import torch
from torch import nn

from gpl_dist.config import TrainingConfig
from gpl_dist.domains import get_domain
from gpl_dist.models.build import build_model
from gpl_dist.records import WorkUnit
from learner.batches import TensorView
from learner.checkpoint import Checkpoint, capture_rng, learner_state, load_checkpoint
from learner.ppo import PPOSettings
from learner.trainer import Learner
from storage import BufferReader, ShardWriter, commit_round
from storage.fs import sha256_hex
from storage.schema import ATTEMPTS_SCHEMA, TUPLES_SCHEMA
from tests.test_rollout import make_worker

ARCHIVE = Path(__file__).resolve().parents[1] / "docs" / "paper-report" / "runs"


# -- checkpoints ------------------------------------------------------------------------------


def _buffer(root: Path, schema_version: int = 3):
    """A buffer of one round of real multi-room attempts whose shard is written as ``schema_version``
    wrote it (version 2 lacks the attempts' ``reward_sum``, version 1 also the tuples' ``expert_probs``)."""
    unit = WorkUnit(round_index=0, unit_index=0, task_ids=(1, 2, 3), split="train", seed=0, policy_version=0)
    attempts = make_worker("multiroom", num_corrections=2).collect(unit.task_ids, unit.split, seed=0, round_index=0)
    record = ShardWriter(root, "r").write_unit(unit, attempts, worker_id="w")
    lacks = {"attempts": ["reward_sum"] if schema_version < 3 else [],
             "tuples": ["expert_probs"] if schema_version < 2 else []}
    files = []
    for f in record.files:
        if lacks.get(f.role):
            table = pq.read_table(root / f.path)
            sink = io.BytesIO()
            pq.write_table(table.drop_columns(lacks[f.role]), sink)
            (root / f.path).write_bytes(sink.getvalue())
            f = dataclasses.replace(f, nbytes=len(sink.getvalue()), sha256=sha256_hex(sink.getvalue()))
        files.append(f)
    commit_round(root, 0, [dataclasses.replace(record, files=tuple(files))])
    return BufferReader(root)


def _cfg():
    return TrainingConfig(num_epochs_per_round=1, batch_size=64, num_threads=1, device="cpu")


def test_a_checkpoint_with_one_adam_state_per_tensor_continues_exactly(tmp_path):
    """Era 1: Adam's moments per parameter tensor (before the parameters were flattened), no run id."""
    tv = TensorView.from_view(_buffer(tmp_path / "run").load_training_view(trajectory_stride=25))
    idx = torch.randperm(tv.num_states, generator=torch.Generator().manual_seed(0))[:64]
    obs, labels, cond, rows = tv.batch(idx)
    model = build_model(get_domain("multiroom"), seed=0)
    old = torch.optim.Adam(model.parameters(), lr=1e-3, fused=True)
    for _ in range(3):
        old.zero_grad()
        nn.functional.cross_entropy(model(obs, cond, rows), labels).backward()
        old.step()
    assert len(old.state) == len(list(model.parameters()))  # every tensor has moments to carry over
    torch.save({"round_index": 0, "policy_version": 1, "model_state": model.state_dict(),
                "optimizer_state": old.state_dict(), "rng_state": capture_rng(torch.Generator().get_state()),
                "config": {}, "history": []}, tmp_path / "old.pt")
    ckpt = load_checkpoint(tmp_path / "old.pt")
    assert ckpt.run_id is None and ckpt.optimizer_state["param_groups"][0]["params"] == [0]
    learner = Learner(build_model(get_domain("multiroom")), _cfg())
    learner.load_state(learner_state(ckpt))
    old.zero_grad()
    nn.functional.cross_entropy(model(obs, cond, rows), labels).backward()
    old.step()
    learner.step(tv, idx)
    for a, b in zip(model.parameters(), learner.model.parameters()):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)


def _continues_like_itself(ckpt: Checkpoint) -> None:
    """The checkpoint's weights and moments go into a learner of its model as they are."""
    from gpl_dist.config import config_from_dict
    from gpl_dist.models.build import build_model_from_config

    cfg = config_from_dict(ckpt.config, "archived", plugins="none")
    learner = Learner(build_model_from_config(get_domain(cfg.env.domain), cfg.model), _cfg())
    learner.load_state(learner_state(ckpt))
    state = learner.optimizer.state_dict()
    assert torch.equal(state["state"][0]["exp_avg"], ckpt.optimizer_state["state"][0]["exp_avg"])


def test_an_archived_checkpoint_without_a_run_id_reads_it_as_not_recorded():
    """Era 2: flat moments, no run id (saved before run identities)."""
    path = ARCHIVE / "multiroom-gpl" / "seed0" / "checkpoints" / "latest.pt"
    assert "run_id" not in torch.load(path, map_location="cpu", weights_only=True)
    ckpt = load_checkpoint(path)
    assert ckpt.run_id is None and ckpt.optimizer_state["param_groups"][0]["params"] == [0]
    _continues_like_itself(ckpt)


def test_an_archived_current_checkpoint_reads_as_written():
    """Era 3, the current: flat moments and the run id."""
    path = ARCHIVE / "multiroom-gpl-long" / "seed0" / "checkpoints" / "latest.pt"
    ckpt = load_checkpoint(path)
    raw = torch.load(path, map_location="cpu", weights_only=True)
    assert ckpt.run_id == raw["run_id"] and ckpt.optimizer_state is not None
    assert torch.equal(ckpt.optimizer_state["state"][0]["exp_avg"], raw["optimizer_state"]["state"][0]["exp_avg"])
    _continues_like_itself(ckpt)


# -- buffer shards ----------------------------------------------------------------------------


def _views_equal(a, b, skip=()) -> None:
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if f.name in skip:
            continue
        if isinstance(x, np.ndarray):
            assert np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), f.name
        else:
            assert x == y, f.name


def test_a_version_1_shard_reads_its_labels_one_hot_and_its_reward_sums_as_not_recorded(tmp_path):
    """Schema 1: no ``expert_probs`` in the tuples, no ``reward_sum`` in the attempts."""
    now = _buffer(tmp_path / "now")
    old = _buffer(tmp_path / "old", schema_version=1)
    view, current = old.load_training_view(), now.load_training_view()
    assert np.isnan(view.reward_sum).all() and not np.isnan(current.reward_sum).any()
    _views_equal(view, current, skip=("reward_sum",))
    assert old.read_table("tuples").schema.names == TUPLES_SCHEMA.names
    assert old.read_table("tuples").column("expert_probs").null_count == view.num_tuples


def test_a_version_2_shard_reads_its_reward_sums_as_not_recorded(tmp_path):
    """Schema 2: no ``reward_sum`` in the attempts (null in the table, NaN in the training view)."""
    old = _buffer(tmp_path / "old", schema_version=2)
    view, current = old.load_training_view(), _buffer(tmp_path / "now").load_training_view()
    assert np.isnan(view.reward_sum).all()
    _views_equal(view, current, skip=("reward_sum",))
    table = old.read_table("attempts")
    assert table.schema.names == ATTEMPTS_SCHEMA.names and table.column("reward_sum").null_count == table.num_rows


def test_a_version_3_shard_reads_as_written(tmp_path):
    """Schema 3, the current: every column as written."""
    reader = _buffer(tmp_path / "now")
    view = reader.load_training_view()
    assert not np.isnan(view.reward_sum).any()
    assert reader.read_table("attempts").column("reward_sum").null_count == 0


# -- RL results -------------------------------------------------------------------------------


def test_an_archived_rl_result_from_before_the_later_ppo_settings_reads_them_as_their_defaults():
    """A curve result whose settings lack ``value_learning_rate``, ``target_kl``, ``max_grad_norm``
    and ``value_layers``: every such job ran with their defaults."""
    from gpl_dist.app.suite.rl.jobs import read_result
    from gpl_dist.app.suite.rl.per_task import made_with

    path = ARCHIVE / "rl" / "rl-finetune" / "relocation" / "task11-seed0.json"
    raw = json.loads(path.read_text())
    assert "value_layers" not in raw["settings"]
    data = read_result(path)
    defaults = dataclasses.asdict(PPOSettings())
    assert set(data["settings"]) == set(defaults)
    assert all(data["settings"][k] == defaults[k] for k in ("value_learning_rate", "target_kl", "max_grad_norm",
                                                           "value_layers"))
    assert made_with(data["settings"], PPOSettings(**data["settings"]))


def test_an_archived_current_rl_result_reads_as_written():
    from gpl_dist.app.suite.rl.jobs import read_result

    path = ARCHIVE / "rl" / "rl-finetune" / "multiroom" / "task1247-seed0.json"
    assert read_result(path) == json.loads(path.read_text())
    attempts = ARCHIVE / "rl" / "attempts" / "multiroom-gpl-seed0.json"
    assert read_result(attempts) == json.loads(attempts.read_text())


# -- suite run records ------------------------------------------------------------------------


def test_a_suite_record_whose_evaluations_lack_the_later_settings_reads_them_as_made(tmp_path):
    """Evaluation settings without ``max_tasks`` and ``phrasings`` (not in the archive: written here)."""
    from gpl_dist.app.suite.one_run import read_record

    src = ARCHIVE / "multiroom-gpl-long" / "seed0" / "suite-run.json"
    raw = json.loads(src.read_text())
    for ev in raw["evaluations"].values():
        del ev["settings"]["max_tasks"], ev["settings"]["phrasings"]
    (tmp_path / "suite-run.json").write_text(json.dumps(raw))
    assert read_record(tmp_path) == json.loads(src.read_text())


def test_an_archived_suite_record_without_numerics_reads_as_none_recorded(tmp_path):
    """Trained before numerics fingerprints were recorded."""
    from gpl_dist.app.suite.one_run import read_record

    src = ARCHIVE / "multiroom-gpl" / "seed0"
    assert "numerics" not in json.loads((src / "suite-run.json").read_text())
    shutil.copy(src / "suite-run.json", tmp_path / "suite-run.json")
    record = read_record(tmp_path)
    assert record["numerics"] == [] and record == {**json.loads((src / "suite-run.json").read_text()), "numerics": []}


def test_an_archived_current_suite_record_reads_as_written():
    from gpl_dist.app.suite.one_run import read_record

    run_dir = ARCHIVE / "multiroom-gpl-long" / "seed0"
    assert read_record(run_dir) == json.loads((run_dir / "suite-run.json").read_text())

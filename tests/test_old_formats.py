"""Each artifact of an older shape is read, where it is read, as the current one: one test per era.

Checkpoints (``learner.checkpoint.load_checkpoint``), buffer shards
(``storage.reader.read_shard_table``), RL results (``gpl_dist.app.suite.rl.jobs.read_result``),
suite run records (``gpl_dist.app.suite.one_run.read_record``), round records
(``learner.rounds.read_round``: ``metrics.jsonl`` and a checkpoint's history), teaching logs
(``gpl_dist.app.teaching.read_teaching_log``) and run dirs with or without ``run.json``
(``learner.identity.resolve_identity``); the eval, curve and swap files'
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
import pytest
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


# -- round records (metrics.jsonl, a checkpoint's history) ------------------------------------

LONG = ARCHIVE / "multiroom-gpl-long" / "seed0"


def _lines(path: Path = LONG / "metrics.jsonl") -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def _aged(row: dict, *, health: int | None = 6, spread: bool = True, resumed: bool = False) -> dict:
    """``row`` as an older driver wrote it: its health rows of ``health`` values (None: no key),
    without ``correction_spread`` unless ``spread``, and ``resumed``: a round committed before a
    restart (no tuples collected, no ``failed_tasks``)."""
    old = {k: v for k, v in row.items() if k not in ("encoder_health", "correction_spread")}
    if health is not None:
        old["encoder_health"] = [r[:health] for r in row["encoder_health"]]
    if spread:
        old["correction_spread"] = row["correction_spread"]
    if resumed:
        old["collected_tuples"] = None
        del old["failed_tasks"]
    return old


def _run_dir(tmp_path: Path, rows: list[dict]) -> Path:
    """The archived run (its config and checkpoint) with ``rows`` as its metrics.jsonl, no run.json."""
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    shutil.copy(LONG / "config.yaml", run / "config.yaml")
    shutil.copy(LONG / "checkpoints" / "latest.pt", run / "checkpoints" / "latest.pt")
    (run / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    return run


def test_a_round_without_correction_spread_and_a_resumed_round_without_failed_tasks_read_as_none_recorded(tmp_path):
    """The first shape: no ``correction_spread`` nor ``encoder_health``; a round committed before
    a restart has no ``failed_tasks`` (not in the archive: written here)."""
    from gpl_dist.app.suite.run_facts import run_budget, run_health
    from learner.rounds import read_round

    rows = _lines()
    old = [_aged(r, health=None, spread=False, resumed=r["round"] == 1) for r in rows]
    read = [read_round(r) for r in old]
    assert all(m.correction_spread is None and m.encoder_health == () for m in read)
    assert read[1].collected_tuples is None and read[1].failed_tasks == ()
    assert [m.loss for m in read] == [r["loss"] for r in rows] and read[2] == dataclasses.replace(
        read_round(rows[2]), correction_spread=None, encoder_health=())
    run = _run_dir(tmp_path, old)
    health, budget = run_health(run), run_budget(run)
    assert not health.instrumented and health.final == () and health.valid
    assert not budget.tuples_complete and budget.rounds == len(rows)
    assert budget.gradient_steps == sum(r["train_steps"] for r in rows)


def test_a_resumed_round_with_a_spread_but_without_failed_tasks_reads_them_as_none():
    """The second shape: ``correction_spread`` recorded, a resumed round still without ``failed_tasks``."""
    from learner.rounds import read_round

    row = _lines()[3]
    m = read_round(_aged(row, health=None, resumed=True))
    assert m.failed_tasks == () and m.collected_tuples is None and m.correction_spread == row["correction_spread"]


def test_a_round_without_encoder_health_reads_it_as_none_counted(tmp_path):
    """The third shape: every key but ``encoder_health``."""
    from gpl_dist.app.suite.run_facts import read_metrics
    from learner.rounds import read_round

    rows = _lines()
    assert read_round(_aged(rows[0], health=None)) == dataclasses.replace(read_round(rows[0]), encoder_health=())
    assert [m.encoder_health for m in read_metrics(_run_dir(tmp_path, [_aged(r, health=None) for r in rows]))] == \
        [()] * len(rows)


def test_health_rows_of_five_values_read_dead_layers_as_none_dead(tmp_path):
    """The fourth shape: ``encoder_health`` rows without ``dead_layers``; the report's health gate
    then counts no layer dead whole."""
    from gpl_dist.app.suite.run_facts import run_health
    from learner.health import EncoderHealth
    from learner.rounds import read_round

    rows = _lines()
    m = read_round(_aged(rows[-1], health=5))
    assert m.encoder_health == tuple(EncoderHealth(*r[:5], 0) for r in rows[-1]["encoder_health"])
    health = run_health(_run_dir(tmp_path, [_aged(r, health=5) for r in rows]))
    assert health.instrumented and health.dead_layers == () and health.valid


def test_archived_current_round_records_read_as_written():
    """The current shape (an instrumented GPL run, and a MIVOA run whose rounds counted no encoder),
    and a checkpoint's history, which repeats metrics.jsonl line for line."""
    from learner.rounds import read_metrics, read_round

    for run in (LONG, ARCHIVE / "relocation-mivoa-instruction" / "seed0"):
        rows = _lines(run / "metrics.jsonl")
        assert [read_round(r).to_dict() for r in rows] == rows
        assert [m.to_dict() for m in read_metrics(run).values()] == rows
        assert [read_round(r).to_dict() for r in load_checkpoint(run / "checkpoints" / "latest.pt").history] == rows


def test_a_resumes_config_changes_are_read_from_the_round_they_apply_to(tmp_path):
    """The current shape with ``config_changes`` (only on a round a ``--resume`` changed a setting
    from): ``config.yaml`` with them applied is the checkpoint's config, whatever the other rounds' shape."""
    from learner.identity import config_problems
    from learner.rounds import read_round

    rows = [_aged(r, health=None) for r in _lines()]
    run = _run_dir(tmp_path, rows)
    lr = load_checkpoint(run / "checkpoints" / "latest.pt").config["training"]["learning_rate"]
    text = (run / "config.yaml").read_text()
    assert f"learning_rate: {lr}" in text
    (run / "config.yaml").write_text(text.replace(f"learning_rate: {lr}", "learning_rate: 0.5"))
    assert "training.learning_rate" in config_problems(run)[0][1]
    rows[4]["config_changes"] = {"training.learning_rate": [0.5, lr]}
    (run / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    assert read_round(rows[4]).config_changes == (("training.learning_rate", 0.5, lr),)
    assert read_round(rows[3]).config_changes == ()
    assert config_problems(run) == []


def test_a_run_whose_metrics_are_older_than_its_checkpoints_history_is_still_its_own(tmp_path):
    """A run resumed by newer code: its checkpoint's history is of the current shape, its first
    lines of an older one. Both read alike, so the history still tells the run apart by its rounds."""
    from learner.identity import why_not_recorded_run

    rows = _lines()
    run = _run_dir(tmp_path, [_aged(r, health=5) if r["round"] < 6 else r for r in rows])
    ckpt_file = run / "checkpoints" / "latest.pt"
    ckpt = load_checkpoint(ckpt_file)
    assert why_not_recorded_run(run, ckpt, ckpt_file, str(run / "buffer")) is None
    other = [dict(r, train_seconds=r["train_seconds"] + 1) if r["round"] == 2 else r for r in rows]
    (run / "metrics.jsonl").write_text("".join(json.dumps(_aged(r, health=5)) + "\n" for r in other))
    assert "round 2 differs" in why_not_recorded_run(run, ckpt, ckpt_file, str(run / "buffer"))


# -- teaching logs ----------------------------------------------------------------------------


def _teaching_log(tmp_path: Path) -> Path:
    """A current teaching log of the archived run: three attempts, the second undone."""
    from gpl_dist.app.teaching import Teacher, write_episode_log

    episode = Teacher(LONG).episode(5, seed=2, source="test")
    episode.attempt()
    episode.attempt("enter the gry room")
    episode.undo()
    episode.attempt("enter the grey room", typed="go into the grey rom")
    return Path(write_episode_log(episode, tmp_path / "log"))


def _as_correction(path: Path, out: Path, keep: tuple[str, ...] = ("checkpoint", "greedy", "split")) -> Path:
    """The log at ``path`` as a log naming the sent correction ``correction`` wrote it (its rows
    not undone), keeping of the later columns only ``keep``."""
    import pyarrow.compute as pc

    table = pq.read_table(path)
    table = table.filter(pc.invert(table.column("undone")))
    table = table.rename_columns(["correction" if n == "correction_before" else n for n in table.column_names])
    drop = {"typed", "solved_at", "undone", "checkpoint", "greedy", "split"} - set(keep)
    out.mkdir(parents=True, exist_ok=True)
    pq.write_table(table.drop_columns(sorted(drop)), out / path.name)
    return out / path.name


def test_a_teaching_log_without_checkpoint_or_greedy_is_refused_in_one_line(tmp_path):
    """The first shape: ``correction``, and no record of the weights that acted nor how (not in the
    archive: written here). Nothing can replay it."""
    from gpl_dist.app.teaching import read_teaching_log
    from gpl_dist.errors import UsageError

    old = _as_correction(_teaching_log(tmp_path), tmp_path / "old", keep=())
    with pytest.raises(UsageError, match="records no checkpoint file") as err:
        read_teaching_log([old])
    assert "\n" not in str(err.value)


def test_a_teaching_log_naming_the_sent_correction_reads_it_as_sent_and_typed_and_exports(tmp_path, monkeypatch):
    """The second shape: ``correction`` (what the policy was sent), the checkpoint, greedy and the
    split; no ``typed``, ``solved_at`` or ``undone`` (not in the archive: written here). It reads
    as the current log's standing rows with what was typed taken as what was sent, and exports
    the same attempts as the current log, ``solved_at`` from their replays."""
    import minari

    from gpl_dist.app.export import export_teaching_minari
    from gpl_dist.app.teaching import read_teaching_log

    current = _teaching_log(tmp_path)
    now = [r for r in read_teaching_log([current]) if not r["undone"]]
    old = read_teaching_log([_as_correction(current, tmp_path / "old")])
    assert [r["typed"] for r in old] == [r["correction_before"] for r in now] != [r["typed"] for r in now]
    assert [r["solved_at"] for r in old] == [None] * len(now) and not any(r["undone"] for r in old)
    assert [{**r, "typed": None, "solved_at": None} for r in old] == [{**r, "typed": None, "solved_at": None} for r in now]
    metas = {}
    for name, folder in (("now", current.parent), ("old", tmp_path / "old")):
        export_teaching_minari(folder, tmp_path / "datasets", f"gpl-dist/{name}-v0")
        monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "datasets"))
        dataset = minari.load_dataset(f"gpl-dist/{name}-v0")
        metas[name] = [m for m in dataset.storage.get_episode_metadata(dataset.episode_indices) if not m["undone"]]
    drop = ("id", "typed_before")  # the current log also exports its undone attempt
    assert [{k: v for k, v in m.items() if k not in drop} for m in metas["old"]] == \
        [{k: v for k, v in m.items() if k not in drop} for m in metas["now"]]


def test_a_current_teaching_log_reads_as_written(tmp_path):
    import pyarrow.dataset as pads

    from gpl_dist.app.teaching import read_teaching_log

    log = _teaching_log(tmp_path)
    assert read_teaching_log([log]) == pads.dataset(str(log.parent), format="parquet").to_table().to_pylist()


# -- run.json ---------------------------------------------------------------------------------


def test_an_archived_run_dir_without_run_json_is_checked_as_the_run_its_files_name():
    """No ``run.json`` (made before the file was written, or copied without it): the id is inferred
    (a restored run has no buffer: its dir's name), and ``verify`` notes which id it checks the run
    as; its checkpoint, which records no run id, is the run's own."""
    from gpl_dist.app.rundir import run_checks
    from learner.identity import resolve_identity

    run = ARCHIVE / "multiroom-gpl" / "seed0"
    assert not (run / "run.json").exists()
    identity = resolve_identity(run, str(run / "buffer"))
    assert identity.inferred and identity.run_id == "seed0" and identity.created == ""
    checks = run_checks(str(run), str(run / "buffer"))
    assert checks.run_id == "seed0" and "has no run.json: checked as run seed0" in checks.note and checks.problems == ()


def test_an_archived_run_json_reads_as_written():
    from gpl_dist.app.rundir import run_checks
    from learner.identity import resolve_identity

    raw = json.loads((LONG / "run.json").read_text())
    identity = resolve_identity(LONG, str(LONG / "buffer"))
    assert (identity.run_id, identity.created, identity.inferred) == (raw["run_id"], raw["created"], False)
    assert run_checks(str(LONG), str(LONG / "buffer")).note is None

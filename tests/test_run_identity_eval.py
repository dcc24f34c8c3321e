"""A run without ``run.json`` (issue 65) still knows whose checkpoints are its own: ``eval`` (and
``teach``, ``serve``, ``render``) check another run's checkpoint of the same domain, model and seed
against what the run's files record (``learner.identity.why_not_recorded_run``): its buffer's
marker; without a buffer (a run restored from an archive), its other checkpoints and evaluation
files; and its training history (``metrics.jsonl``) even where no file records a run id. Two real
1-round runs with the same seed are trained once for the module."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import torch

from gpl_dist.cli import main
from gpl_dist.errors import CheckpointError
from learner.evaluate import read_eval


def _train(run: Path) -> Path:
    assert main(["train", "--config", "configs/multiroom-smoke.yaml", "--serial", "--no-progress", "--run-dir", str(run),
                 "--set", "training.num_rounds=1", "--set", "env.max_train_tasks=4", "--set",
                 "training.num_epochs_per_round=1", "--set", "seed=0"]) == 0
    return run


@pytest.fixture(scope="module")
def twins(tmp_path_factory) -> tuple[Path, Path]:
    """Two runs of the same domain, model and seed: only their identities (and wall times) differ."""
    base = tmp_path_factory.mktemp("twins")
    return _train(base / "a" / "run"), _train(base / "b" / "run")


def _id(run: Path) -> str:
    return json.loads((run / "run.json").read_text())["run_id"]


def _files(run: Path) -> dict[str, bytes]:
    return {str(p.relative_to(run)): p.read_bytes() for p in sorted(run.rglob("*"))
            if p.is_file() and not p.name.startswith("_lease")}


def _without_run_json(run: Path, dst: Path, *, buffer: bool = True) -> Path:
    ignore = ["_lease*", "tb", "run.json"] + ([] if buffer else ["buffer"])
    shutil.copytree(run, dst, ignore=shutil.ignore_patterns(*ignore))
    return dst


_EVAL = ["--max-tasks", "1", "--seeds", "0", "--corrections", "0"]


def _refused(capsys, argv: list[str], run: Path, *needles: str) -> str:
    before = _files(run)
    capsys.readouterr()
    assert main(argv) == 2, argv
    err = capsys.readouterr().err.strip()
    assert err.startswith("gpl-dist: error: ") and "\n" not in err and "--foreign-checkpoint" in err, err
    for needle in needles:
        assert needle in err, (needle, err)
    assert _files(run) == before  # nothing written into the run
    return err


def test_a_run_without_run_json_refuses_a_twins_checkpoint_by_its_buffer_marker(twins, tmp_path, capsys):
    a, b = twins
    run = _without_run_json(a, tmp_path / "run")
    foreign = str(b / "checkpoints" / "latest.pt")
    _refused(capsys, ["eval", "--run-dir", str(run), "--checkpoint", foreign, *_EVAL], run,
             f"is a checkpoint of run {_id(b)}, not of {run} (run {_id(a)}, as its buffer's marker records")
    with pytest.raises(CheckpointError, match=f"checkpoint of run {_id(b)}"):
        from gpl_dist.app.teaching import Teacher

        Teacher(run, foreign)
    # the twin's checkpoint put in place of the run's own: refused the same way
    shutil.copyfile(foreign, run / "checkpoints" / "latest.pt")
    _refused(capsys, ["eval", "--run-dir", str(run), *_EVAL], run, f"is a checkpoint of run {_id(b)}")
    # its own checkpoint still evaluates, into the run
    shutil.copyfile(a / "checkpoints" / "latest.pt", run / "checkpoints" / "latest.pt")
    assert main(["eval", "--run-dir", str(run), *_EVAL]) == 0
    assert read_eval(run / "eval-c0-seeds0-first1.json").run_id == _id(a)


def test_a_restored_run_without_run_json_or_buffer_is_checked_by_the_ids_its_files_record(twins, tmp_path, capsys):
    """What an archive restores: the config, metrics, eval files and latest.pt, no buffer."""
    a, b = twins
    run = _without_run_json(a, tmp_path / "run", buffer=False)
    for extra in (run / "checkpoints").glob("round-*.pt"):
        extra.unlink()
    assert main(["eval", "--run-dir", str(run), *_EVAL]) == 0  # its own: evaluated, recording its id
    shutil.copyfile(b / "checkpoints" / "latest.pt", run / "checkpoints" / "latest.pt")
    _refused(capsys, ["eval", "--run-dir", str(run), *_EVAL], run,
             f"is a checkpoint of run {_id(b)}, not of {run} (run {_id(a)}, as its other checkpoints and evaluation "
             "files record")


def test_a_run_that_records_no_id_at_all_is_checked_by_its_training_history(twins, tmp_path, capsys):
    """No run.json, no buffer, no evaluation file, and checkpoints saved before run ids: the
    twin's checkpoint (its run id removed too) is told apart by its record of round 0."""
    a, b = twins
    run = _without_run_json(a, tmp_path / "run", buffer=False)
    twin = tmp_path / "twin.pt"
    for src, dst in [(path, path) for path in (run / "checkpoints").glob("*.pt")] + [(b / "checkpoints" / "latest.pt", twin)]:
        raw = torch.load(src, weights_only=True)
        raw.pop("run_id")
        torch.save(raw, dst)
    _refused(capsys, ["eval", "--run-dir", str(run), "--checkpoint", str(twin), *_EVAL], run,
             f"{twin} is not a checkpoint of {run}: its record of round 0 differs from {run / 'metrics.jsonl'}'s")
    assert main(["eval", "--run-dir", str(run), *_EVAL]) == 0  # its own (no run id either) still evaluates

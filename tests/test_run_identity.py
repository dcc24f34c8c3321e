"""Runs that know who they are (issue 41): a run's UUID in its marker, manifests, checkpoints and
eval files; a round or checkpoint of another run refused by ``verify`` and ``train --resume``; a
foreign checkpoint refused by ``eval``, ``teach`` and ``serve`` (and, asked for, kept out of the
run dir); ``verify`` during a commit; ``metrics.jsonl`` rebuilt on resume; ``clean`` of dead
writers' temporary files. Two small real runs are trained once for the module."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pyarrow.parquet as pq
import pytest
import torch

from gpl_dist.app.rundir import run_checks
from gpl_dist.cli import main
from gpl_dist.errors import CheckpointError
from learner.checkpoint import load_checkpoint, save_checkpoint
from learner.identity import checkpoint_problems, resolve_identity
from storage import committed_rounds, load_manifest
from storage.verify import verify_buffer


def _train(run: Path, seed: int) -> Path:
    assert main(["train", "--config", "configs/multiroom-smoke.yaml", "--serial", "--no-progress", "--run-dir", str(run),
                 "--set", "training.num_rounds=2", "--set", "env.max_train_tasks=4", "--set",
                 "training.num_epochs_per_round=1", "--set", f"seed={seed}"]) == 0
    return run


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> tuple[Path, Path]:
    # both called "run": under the old naming they would have been the same run
    base = tmp_path_factory.mktemp("identity")
    return _train(base / "a" / "run", 0), _train(base / "b" / "run", 1)


def _copy(run: Path, dst: Path) -> Path:
    shutil.copytree(run, dst, ignore=shutil.ignore_patterns("_lease.lock", "tb"))
    return dst


def _id(run: Path) -> str:
    return json.loads((run / "run.json").read_text())["run_id"]


def _files(run: Path) -> dict[str, int]:
    return {str(p.relative_to(run)): p.stat().st_mtime_ns for p in run.rglob("*") if p.is_file()}


def test_a_run_gets_a_uuid_recorded_in_its_marker_manifests_checkpoints_and_eval_files(runs, capsys):
    a, b = runs
    run_id = _id(a)
    assert re.fullmatch(r"[0-9a-f]{32}", run_id) and run_id != _id(b)
    buffer = a / "buffer"
    assert json.loads((buffer / "_gpl-dist-buffer.json").read_text())["run_id"] == run_id
    for r in committed_rounds(buffer):
        m = load_manifest(buffer, r)
        assert m.run_id == run_id and {s.run_id for s in m.shards} == {run_id}
    attempts = pq.read_table(next((buffer / "data" / "attempts").rglob("*.parquet")))
    assert set(attempts.column("run_id").to_pylist()) == {run_id}
    for path in (a / "checkpoints").glob("*.pt"):
        assert load_checkpoint(path).run_id == run_id
    assert main(["eval", "--run-dir", str(a), "--max-tasks", "2", "--seeds", "0", "--corrections", "1"]) == 0
    assert json.loads((a / "eval-c1-seeds0-first2.json").read_text())["run_id"] == run_id


def test_a_round_of_another_run_is_refused_by_verify_and_resume(runs, tmp_path, capsys):
    """The issue's probe: round 1's manifest and data swapped for those of a run with another seed."""
    a, b = runs
    mixed = _copy(a, tmp_path / "run")
    for rel in ("manifests/round-000001.json", "data/attempts/round-000001", "data/tuples/round-000001",
                "data/obs/round-000001"):
        dst, src = mixed / "buffer" / rel, b / "buffer" / rel
        shutil.rmtree(dst) if dst.is_dir() else dst.unlink()
        shutil.copytree(src, dst) if src.is_dir() else shutil.copyfile(src, dst)
    capsys.readouterr()
    assert main(["verify", str(mixed)]) == 2
    assert "manifests/round-000001.json" in capsys.readouterr().out
    report = verify_buffer(mixed / "buffer")
    assert report.run_id == _id(a)
    assert ("manifests/round-000001.json", 1, "foreign") in [(p.path, p.round_index, p.kind) for p in report.problems]
    before = _files(mixed)
    assert main(["train", "--run-dir", str(mixed), "--resume", "--serial", "--no-progress",
                 "--set", "training.num_rounds=3"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and _id(a) in err and _id(b) in err
    assert {k: v for k, v in _files(mixed).items() if not k.endswith(".lock")} == \
        {k: v for k, v in before.items() if not k.endswith(".lock")}


def test_a_checkpoint_of_another_run_is_refused_by_verify_and_resume(runs, tmp_path, capsys):
    a, b = runs
    mixed = _copy(a, tmp_path / "run")
    shutil.copyfile(b / "checkpoints" / "latest.pt", mixed / "checkpoints" / "latest.pt")
    capsys.readouterr()
    assert main(["verify", str(mixed)]) == 2
    assert str(mixed / "checkpoints" / "latest.pt") in capsys.readouterr().out
    assert [p for p, _ in checkpoint_problems(mixed, _id(a))] == [str(mixed / "checkpoints" / "latest.pt")]
    before = _files(mixed)
    assert main(["train", "--run-dir", str(mixed), "--resume", "--serial", "--no-progress",
                 "--set", "training.num_rounds=3"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and _id(b) in err and _id(a) in err
    assert _files(mixed) == before


def test_eval_teach_and_serve_refuse_a_foreign_checkpoint_and_write_nothing_into_the_run(runs, tmp_path, capsys):
    a, b = runs
    foreign = str(b / "checkpoints" / "latest.pt")
    before = _files(a)
    capsys.readouterr()
    for argv in (["eval", "--run-dir", str(a), "--checkpoint", foreign, "--max-tasks", "2", "--seeds", "0"],
                 ["teach", "--run-dir", str(a), "--checkpoint", foreign, "--task", "263"],
                 ["serve", "--run-dir", str(a), "--checkpoint", foreign, "--port", "1"],
                 ["render", "--run-dir", str(a), "--checkpoint", foreign, "--task", "263", "--out", str(tmp_path / "x.gif")]):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and f"is a checkpoint of run {_id(b)}" in err and "--foreign-checkpoint" in err
    # another domain (the checkpoint's config says relocation): named as such
    other = tmp_path / "relocation.pt"
    ckpt = load_checkpoint(foreign)
    config = json.loads(json.dumps(ckpt.config))
    config["env"]["domain"] = "relocation"
    save_checkpoint(tmp_path / "ck", ckpt.__class__(**{**ckpt.__dict__, "config": config, "run_id": None}), False)
    shutil.move(tmp_path / "ck" / "latest.pt", other)
    from gpl_dist.app.teaching import Teacher

    with pytest.raises(CheckpointError, match="env.domain relocation"):
        Teacher(a, str(other))
    # asked for explicitly: --out is required, and only --out is written
    assert main(["eval", "--run-dir", str(a), "--checkpoint", foreign, "--foreign-checkpoint", "--max-tasks", "2"]) == 2
    assert "give --out" in capsys.readouterr().err
    assert main(["eval", "--run-dir", str(a), "--checkpoint", foreign, "--foreign-checkpoint", "--max-tasks", "2",
                 "--seeds", "0", "--corrections", "1", "--out", str(tmp_path / "side")]) == 0
    written = json.loads(next((tmp_path / "side").glob("eval*.json")).read_text())
    assert written["run_id"] == _id(b)
    assert _files(a) == before


def test_a_run_made_before_identities_is_legacy_and_keeps_working(runs, tmp_path, capsys):
    """No run.json and checkpoints without run ids (what the current code's runs hold): verify,
    eval and resume go on, naming the run by its marker."""
    a, _ = runs
    old = _copy(a, tmp_path / "old")
    (old / "run.json").unlink()
    for path in (old / "checkpoints").glob("*.pt"):
        raw = torch.load(path, weights_only=True)
        raw.pop("run_id")
        torch.save(raw, path)
    capsys.readouterr()
    assert main(["verify", str(old)]) == 0  # its marker and manifests name one run: the legacy id is the marker's
    identity = resolve_identity(old, str(old / "buffer"))
    assert identity.inferred and identity.run_id == _id(a)
    assert run_checks(str(old), str(old / "buffer")).problems == () and verify_buffer(old / "buffer").ok
    # a true legacy buffer: every id is the dir's name
    for path in [old / "buffer" / "_gpl-dist-buffer.json", *(old / "buffer" / "manifests").glob("round-*.json")]:
        path.write_text(path.read_text().replace(_id(a), "old"))
    assert main(["verify", str(old)]) == 0
    assert main(["eval", "--run-dir", str(old), "--max-tasks", "1", "--seeds", "0", "--corrections", "0"]) == 0
    assert json.loads((old / "eval-c0-seeds0-first1.json").read_text())["run_id"] == "old"


def test_resume_rebuilds_metrics_jsonl_from_the_checkpoints(runs, tmp_path):
    """A driver stopped between saving round 1's checkpoint and appending its line (and a line of a
    round no checkpoint kept): resume leaves the file as the checkpoints say."""
    a, _ = runs
    run = _copy(a, tmp_path / "run")
    metrics = run / "metrics.jsonl"
    whole = metrics.read_text()
    lines = whole.splitlines(keepends=True)
    assert len(lines) == 2
    metrics.write_text(lines[0])
    assert main(["train", "--run-dir", str(run), "--resume", "--serial", "--no-progress"]) == 0  # nothing to train
    assert metrics.read_text() == whole
    metrics.write_text(whole + lines[1].replace('"round": 1', '"round": 2'))
    assert main(["train", "--run-dir", str(run), "--resume", "--serial", "--no-progress"]) == 0
    assert metrics.read_text() == whole


def test_clean_removes_temporary_files_of_dead_writers_only(runs, tmp_path, capsys):
    a, _ = runs
    run = _copy(a, tmp_path / "run")
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    pid = int(dead.stdout)
    leftovers = [run / "checkpoints" / f".latest.pt.tmp-{pid}", run / "checkpoints" / f".round-000001.pt.tmp-{pid}",
                 run / f".eval.json.tmp-{pid}-123", run / f".metrics.jsonl.tmp-{pid}"]
    live = run / "checkpoints" / f".latest.pt.tmp-{os.getpid()}"
    for p in [*leftovers, live]:
        p.write_bytes(b"x" * 1000)
    capsys.readouterr()
    assert main(["clean", str(run), "--dry-run"]) == 0
    assert all(p.exists() for p in leftovers)
    assert main(["clean", str(run)]) == 0
    out = capsys.readouterr().out
    assert not any(p.exists() for p in leftovers) and live.exists()
    assert all(f"removed {p}" in out for p in leftovers)

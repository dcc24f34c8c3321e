"""No walk follows a symbolic link out of a run: ``clean``, ``verify``, the commit journal's moves
and the reader refuse a link at every level of the buffer (round, unit, try, file, manifest), name
it in one line, and leave what it points at untouched."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from test_storage import write_run

from gpl_dist.cli import main
from storage import BufferReader, clean_leftovers
from storage.errors import LinkError
from storage.fs import resolve
from storage.verify import verify_buffer


def _victim(tmp_path: Path) -> Path:
    """A folder outside the run, shaped like what a link replaces, full of someone's files."""
    victim = tmp_path / "victim"
    for rel in ("try-x/attempts.parquet", "try-x/tuples.parquet", "unit-00000/try-x/a.txt", "a.txt",
                "round-000000.json", "c/0"):
        (victim / rel).parent.mkdir(parents=True, exist_ok=True)
        (victim / rel).write_text("precious")
    return victim


def _files(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): p.read_text() for p in sorted(root.rglob("*")) if p.is_file()}


def _buffer(tmp_path: Path) -> Path:
    root = tmp_path / "run" / "buffer"
    write_run(root, rounds=1)  # round 0 committed
    write_run(root, rounds=range(1, 2), commit=False)  # round 1's tries left in staging
    return root


def _link(path: Path, target: Path) -> None:
    """Replace ``path`` (a file or folder of the buffer) by a symbolic link to ``target``."""
    if path.is_dir():
        import shutil

        shutil.rmtree(path)
    elif path.exists():
        path.unlink()
    path.symlink_to(target, target_is_directory=target.is_dir())


def _staging_try(root: Path) -> Path:
    return next((root / "staging" / "round-000001" / "unit-00000").iterdir())


LEVELS = {
    "round": lambda root: root / "staging" / "round-000001",
    "unit": lambda root: root / "staging" / "round-000001" / "unit-00000",
    "try": _staging_try,
    "file": lambda root: _staging_try(root) / "attempts.parquet",
    "manifest": lambda root: root / "manifests" / "_tmp-abc-round-000001.json",
    "staging": lambda root: root / "staging",
}


@pytest.mark.parametrize("level", sorted(LEVELS))
def test_clean_refuses_a_link_at_every_level_and_removes_nothing(tmp_path, capsys, level):
    root = _buffer(tmp_path)
    victim = _victim(tmp_path)
    target = victim / "a.txt" if level in ("file", "manifest") else victim
    link = LEVELS[level](root)
    link.parent.mkdir(parents=True, exist_ok=True)
    _link(link, target)
    before_victim, before_run = _files(victim), sorted(p for p in root.rglob("*"))
    for args in (["clean", str(tmp_path / "run" / "buffer")], ["clean", "--dry-run", str(root)]):
        assert main(args) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("gpl-dist: error:") and "\n" not in err, err
        assert "symbolic link" in err and str(link.relative_to(root)) in err, err
    assert _files(victim) == before_victim
    assert sorted(p for p in root.rglob("*")) == before_run
    with pytest.raises(LinkError):
        clean_leftovers(root)


@pytest.mark.parametrize("level", ["round", "unit", "file", "manifest", "marker"])
def test_verify_names_a_link_in_committed_data_and_follows_none(tmp_path, capsys, level):
    root = tmp_path / "run" / "buffer"
    write_run(root, rounds=1)
    victim = _victim(tmp_path)
    link = {"round": root / "data" / "attempts" / "round-000000",
            "unit": root / "data" / "obs" / "round-000000" / "unit-00000.zarr",
            "file": root / "data" / "tuples" / "round-000000" / "unit-00001.parquet",
            "manifest": root / "manifests" / "round-000000.json",
            "marker": root / "_gpl-dist-buffer.json"}[level]
    _link(link, victim / "a.txt" if level in ("file", "manifest", "marker") else victim)
    before = _files(victim)
    report = verify_buffer(root)
    rel = str(link.relative_to(root))
    assert [p.path for p in report.problems if p.kind == "link"] == [rel]
    assert main(["verify", str(root)]) == 2
    out, err = capsys.readouterr()
    # named as a problem, or (where the command cannot even tell it is a buffer) refused in one line
    assert f"BAD  {rel}: is a symbolic link" in out or (err.count("\n") == 1 and f"{rel} in " in err
                                                          and "symbolic link" in err), (out, err)
    if level != "marker":  # reading the buffer for training refuses too (the reader never reads the marker)
        with pytest.raises(LinkError):
            BufferReader(root).load_training_view()
    assert _files(victim) == before


def test_a_commit_journal_never_moves_through_a_link(tmp_path, capsys):
    root = _buffer(tmp_path)
    victim = _victim(tmp_path)
    unit = root / "staging" / "round-000001" / "unit-00000"
    _link(unit, victim)
    moves = [["staging/round-000001/unit-00000/try-x/attempts.parquet",
              "data/attempts/round-000001/unit-00000.parquet", 8]]
    manifest = (root / "manifests" / "round-000000.json").read_text().replace("round-000000", "round-000001")
    manifest = json.loads(manifest.replace('"round_index": 0', '"round_index": 1'))
    (root / "manifests" / "_pending-round-000001.json").write_text(json.dumps(
        {"manifest": manifest, "moves": moves, "staging_dirs": []}))
    before = _files(victim)
    assert main(["clean", str(root)]) == 2
    assert "symbolic link" in capsys.readouterr().err
    # a link in data/, where the journal moves to, is refused as well
    os.unlink(unit)
    unit.mkdir()
    data_round = root / "data" / "attempts" / "round-000001"
    data_round.parent.mkdir(parents=True, exist_ok=True)
    _link(data_round, victim)
    from storage.commit import recover_pending

    with pytest.raises(LinkError):
        recover_pending(resolve(root))
    assert _files(victim) == before


def test_a_run_dirs_own_temporaries_are_never_removed_through_a_linked_checkpoints_folder(tmp_path, capsys):
    root = _buffer(tmp_path)
    run = root.parent
    (run / "config.yaml").write_text("seed: 0\n")
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    victim = outside / ".latest.pt.tmp-999999999"  # named like a dead writer's temporary
    victim.write_text("precious")
    (run / "checkpoints").symlink_to(outside, target_is_directory=True)
    assert main(["clean", str(run)]) == 2
    err = capsys.readouterr().err
    assert "checkpoints" in err and "symbolic link" in err
    assert victim.read_text() == "precious"


def test_location_walks_list_a_link_and_never_descend(tmp_path):
    root = tmp_path / "root"
    (root / "d").mkdir(parents=True)
    (root / "d" / "f").write_text("x")
    victim = _victim(tmp_path)
    (root / "d" / "l").symlink_to(victim, target_is_directory=True)
    loc = resolve(root)
    assert loc.find("d") == ["d/f", "d/l"]
    assert loc.links() == ["d/l"]
    for op in (lambda: loc.remove("d/l"), lambda: loc.read_bytes("d/l/a.txt"), lambda: loc.move("d/l", "e"),
               lambda: loc.exists("d/l/a.txt"), lambda: loc.listdir("d/l")):
        with pytest.raises(LinkError, match="d/l in .* is a symbolic link"):
            op()
    loc.remove_empty_dirs("")
    assert (root / "d" / "l").is_symlink() and _files(victim)


def test_clean_removes_dead_teaching_temporaries_and_refuses_a_linked_teaching_folder(tmp_path, capsys):
    root = _buffer(tmp_path)
    run = root.parent
    (run / "config.yaml").write_text("seed: 0\n")
    log = run / "teaching" / "log"
    log.mkdir(parents=True)
    (log / "_tmp-abc-ep1.parquet").write_bytes(b"half")
    (log / "ep0.parquet").write_bytes(b"whole")
    assert main(["clean", "--dry-run", str(run)]) == 0
    assert (log / "_tmp-abc-ep1.parquet").exists() and "_tmp-abc-ep1.parquet" in capsys.readouterr().out
    assert main(["clean", str(run)]) == 0
    assert not (log / "_tmp-abc-ep1.parquet").exists() and (log / "ep0.parquet").read_bytes() == b"whole"
    victim = _victim(tmp_path)
    (victim / "_tmp-x-ep.parquet").write_text("precious")
    import shutil

    shutil.rmtree(run / "teaching")
    (run / "teaching").symlink_to(victim, target_is_directory=True)
    write_run(root, rounds=range(1, 2), commit=False)  # a leftover the refusal must keep too
    before = sorted(p for p in root.rglob("*"))
    assert main(["clean", str(run)]) == 2
    err = capsys.readouterr().err
    assert "teaching" in err and "symbolic link" in err and err.count("\n") == 1
    assert (victim / "_tmp-x-ep.parquet").read_text() == "precious" and sorted(p for p in root.rglob("*")) == before


def test_a_linked_folder_of_a_run_dir_is_refused_by_every_command_that_walks_it(tmp_path, capsys):
    """A run dir whose ``buffer`` (or ``checkpoints``, ``teaching``) is a link to another run's:
    verify, inspect, clean and train --resume refuse in one line and touch nothing there."""
    import shutil

    other = _buffer(tmp_path / "other")
    before = sorted(p for p in other.rglob("*"))
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.yaml").write_text("seed: 0\n")
    for name, target in (("buffer", other), ("checkpoints", tmp_path / "elsewhere"), ("teaching", tmp_path / "elsewhere")):
        target.mkdir(exist_ok=True)
        (run / name).symlink_to(target, target_is_directory=True)
        for args in (["verify", str(run)], ["verify", "--quarantine", str(run)], ["inspect", str(run)],
                     ["clean", str(run)], ["train", "--run-dir", str(run), "--resume", "--serial"]):
            assert main(args) == 2, (name, args)
            err = capsys.readouterr().err
            assert err.count("\n") == 1 and f"{run / name} is a symbolic link" in err, (name, args, err)
        (run / name).unlink()
    assert sorted(p for p in other.rglob("*")) == before
    shutil.rmtree(tmp_path / "elsewhere")


def test_quarantine_moves_nothing_when_the_buffer_holds_a_link(tmp_path, capsys):
    root = tmp_path / "run" / "buffer"
    write_run(root, rounds=2)
    victim = _victim(tmp_path)
    manifests = sorted(p.name for p in (root / "manifests").iterdir())
    link = root / "staging" / "round-000000" / "unit-00009"
    link.parent.mkdir(parents=True, exist_ok=True)
    link.symlink_to(victim, target_is_directory=True)
    assert main(["verify", "--quarantine", str(root)]) == 2
    assert "--quarantine moves nothing here" in capsys.readouterr().err
    assert sorted(p.name for p in (root / "manifests").iterdir()) == manifests and not (root / "quarantine").exists()


def test_clean_lists_dead_temporaries_of_any_suffix(tmp_path):
    from learner.checkpoint import dead_temporaries

    run = tmp_path / "run"
    run.mkdir()
    for name in (".eval-test.json.tmp-999999999-1.json", ".report.html.tmp-999999999-2", ".eval.png.tmp-999999999.png"):
        (run / name).write_text("half")
    assert sorted(p.name for p in dead_temporaries(run)) == sorted(p.name for p in run.iterdir())

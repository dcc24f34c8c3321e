"""Evidence that checks itself (issue 41): the report archive's checksums and each eval file's own
consistency, checked by ``suite report``, ``suite restore``, ``suite status`` and ``suite run``; a
second suite run refused while the first evaluates. On copies of the archive committed with the
report (``docs/paper-report/runs``), whose runs were trained by the current code."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from gpl_dist.app.suite.archive import check_archive
from gpl_dist.app.suite.evidence import CHECKSUMS, EvidenceError
from gpl_dist.cli import main
from gpl_dist.errors import RunDirError
from learner.evaluate import read_eval

REPO = Path(__file__).resolve().parents[1]
ARCHIVE = REPO / "docs" / "paper-report" / "runs"
SUITE = REPO / "configs" / "suites" / "paper.yaml"
ENTRY = "relocation-gpl"  # its archived runs match the suite file's entry as it is now


@pytest.fixture
def archive(tmp_path) -> Path:
    return Path(shutil.copytree(ARCHIVE, tmp_path / "runs"))


def _edit(path: Path, change) -> None:
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data, indent=1))


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


def test_the_committed_archive_carries_checksums_of_every_file_and_passes():
    sums = check_archive(ARCHIVE)
    assert sums is not None
    files = {p.relative_to(ARCHIVE).as_posix() for p in ARCHIVE.rglob("*") if p.is_file() and p.name != CHECKSUMS}
    assert set(sums) == files


def test_an_edited_completion_is_refused_by_report_and_restore(archive, tmp_path, capsys):
    """The issue's probe: completion[5] of multiroom-gpl seed 0 set to 0.999 (the headline moved
    from 0.912 to 0.929)."""
    bad = archive / "multiroom-gpl" / "seed0" / "eval.json"
    per_seed = read_eval(bad).per_seed
    mean = sum(row[5] for row in per_seed) / len(per_seed)
    _edit(bad, lambda d: d["completion"].__setitem__(5, 0.999))
    capsys.readouterr()
    assert main(["suite", "report", str(archive), "--out", str(tmp_path / "report")]) == 2
    err = _one_error_line(capsys)
    assert str(bad) in err and f"completion[5] is 0.999 but the mean of its per_seed values is {mean:.5f}" in err
    assert not (tmp_path / "report" / "report.md").exists()
    assert main(["suite", "restore", str(archive), "--out", str(tmp_path / "out")]) == 2
    assert str(bad) in _one_error_line(capsys)
    assert not (tmp_path / "out").exists()  # nothing copied


def test_a_consistent_edit_is_caught_by_the_checksums(archive, tmp_path, capsys):
    """per_seed and completion edited together: consistent, but not what was archived."""
    bad = archive / ENTRY / "seed1" / "eval-c10.json"

    def change(d):
        d["per_seed"][0][3] = 0.5
        d["completion"][3] = sum(row[3] for row in d["per_seed"]) / len(d["per_seed"])
    _edit(bad, change)
    capsys.readouterr()
    assert main(["suite", "restore", str(archive), "--out", str(tmp_path / "out")]) == 2
    err = _one_error_line(capsys)
    assert f"{bad}: checksum mismatch" in err
    # a file the archive never summed is not evidence either
    bad.write_bytes((ARCHIVE / ENTRY / "seed1" / "eval-c10.json").read_bytes())
    (archive / ENTRY / "seed1" / "eval-extra.json").write_text("{}")
    with pytest.raises(EvidenceError, match="eval-extra.json has no checksum"):
        check_archive(archive)


def test_restored_runs_check_themselves_in_status_and_suite_run(archive, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["suite", "restore", str(archive), "--out", str(out)]) == 0
    assert (out / ENTRY / "seed1" / CHECKSUMS).is_file()
    capsys.readouterr()
    assert main(["suite", "status", str(SUITE), "--out", str(out), "--only", ENTRY]) == 0
    assert capsys.readouterr().out.count(f"done     {ENTRY} seed") == 5
    bad = out / ENTRY / "seed1" / "eval-c10.json"

    def change(d):
        d["per_seed"][0][3] = 0.5
        d["completion"][3] = sum(row[3] for row in d["per_seed"]) / len(d["per_seed"])
    _edit(bad, change)
    assert main(["suite", "status", str(SUITE), "--out", str(out), "--only", ENTRY]) == 2
    printed = capsys.readouterr()
    assert f"refused  {ENTRY} seed 1  ({bad}: checksum mismatch" in printed.out
    assert printed.out.count(f"done     {ENTRY} seed") == 4 and "1 run(s) refused" in printed.err
    assert main(["suite", "run", str(SUITE), "--out", str(out), "--only", ENTRY, "--serial"]) == 2
    assert f"{bad}: checksum mismatch" in _one_error_line(capsys)
    # the checksums removed too: the file is still inconsistent with its own per_seed? no, consistent;
    # an inconsistent one is refused without any checksum
    (out / ENTRY / "seed1" / CHECKSUMS).unlink()
    _edit(bad, lambda d: d["completion"].__setitem__(2, 0.2))
    assert main(["suite", "status", str(SUITE), "--out", str(out), "--only", ENTRY]) == 2
    assert f"{bad}: completion[2] is 0.2" in capsys.readouterr().out
    # and it cannot be laundered into a new archive by a report
    assert main(["suite", "report", str(out), "--out", str(tmp_path / "report")]) == 2
    assert f"{bad}: completion[2] is 0.2" in _one_error_line(capsys)


def test_an_archive_from_before_checksums_restores_with_a_note(archive, tmp_path, capsys):
    (archive / CHECKSUMS).unlink()
    capsys.readouterr()
    assert main(["suite", "restore", str(archive), "--out", str(tmp_path / "out")]) == 0
    assert f"{archive} has no {CHECKSUMS} (archived before checksums existed)" in capsys.readouterr().out
    assert (tmp_path / "out" / ENTRY / "seed0" / "eval.json").is_file()


def test_a_second_suite_run_is_refused_while_the_first_evaluates(archive, tmp_path):
    from gpl_dist.app.suite.one_run import execute, read_record, run_state
    from gpl_dist.app.suite.spec import load_suite, plan
    from storage.lease import Lease

    out = tmp_path / "out"
    assert main(["suite", "restore", str(archive), "--out", str(out)]) == 0
    suite = load_suite(SUITE)
    run = next(r for r in plan(suite, out, (ENTRY,), (0,)))
    record = read_record(run.run_dir)
    del record["evaluations"]["test-c10"]
    (run.run_dir / "suite-run.json").write_text(json.dumps(record))
    (run.run_dir / CHECKSUMS).unlink()  # the run is no longer the archive's copy
    assert run_state(run, suite) == "evaluate"
    with Lease(run.run_dir, "gpl-dist suite run (evaluating)"):  # the first suite run, evaluating
        with pytest.raises(RunDirError, match="is in use by gpl-dist suite run"):
            execute(run, suite, serial=True, progress=False, log=lambda s: None)
    assert "test-c10" not in read_record(run.run_dir)["evaluations"]

"""A suite's evidence, kept beside its report: what a lost machine must not take with it.

A run dir holds a DAgger buffer (megabytes to hundreds of them) and a checkpoint per round; the
report needs none of that, and none of it should sit in git. ``archive_runs`` copies, of every run
with a ``suite-run.json`` that records an evaluation, the files its numbers trace to and the
weights they came from, into ``ARCHIVE/<entry>/seed<k>/``:

- ``suite-run.json`` (code commits, evaluation files and settings, wall times),
  ``config.yaml`` (the resolved config) and ``metrics.jsonl`` (every round's record);
- each ``eval*.json`` the record names;
- ``checkpoints/latest.pt``: the final weights with their Adam state (a few hundred kB to a few MB),
  so that the suite counts the run as trained and RL fine-tuning can start from it;

and every ``OUT/rl/**.json`` (the RL curves and attempt sets) and ``OUT/suite.yaml``. The archive
is itself a suite output: ``gpl-dist suite report ARCHIVE`` reads it, and ``gpl-dist suite restore
ARCHIVE --out OUT`` copies its runs into OUT, where ``gpl-dist suite run`` then skips them and
trains only the rest (a run dir already in OUT is never overwritten).
"""

from __future__ import annotations

import filecmp
import json
import shutil
from pathlib import Path

from gpl_dist.errors import RunDirError

#: A run's files the archive keeps, beside the evaluation files its record names.
RUN_FILES = ("suite-run.json", "config.yaml", "metrics.jsonl", "checkpoints/latest.pt")


def _evaluated_runs(suite_out: Path) -> list[Path]:
    """Run dirs under ``suite_out`` whose ``suite-run.json`` records at least one evaluation."""
    runs = []
    for record_path in sorted(suite_out.glob("*/seed*/suite-run.json")):
        try:
            record = json.loads(record_path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
            raise RunDirError(f"cannot read {record_path} ({type(err).__name__}: {err})") from None
        if isinstance(record, dict) and record.get("evaluations"):
            runs.append(record_path.parent)
    return runs


def _run_files(run_dir: Path) -> list[Path]:
    """The files of ``run_dir`` the archive keeps, relative to it; a missing one fails naming it."""
    record = json.loads((run_dir / "suite-run.json").read_text())
    names = list(RUN_FILES) + sorted({ev["file"] for ev in record["evaluations"].values()})
    for name in names:
        if not (run_dir / name).is_file():
            raise RunDirError(f"{run_dir / name} is missing: the run is not complete enough to archive")
    return [Path(n) for n in names]


def _copy_if_changed(src: Path, dst: Path) -> bool:
    """Copy ``src`` to ``dst`` (atomically: a killed copy leaves the old file) unless equal; True if copied."""
    if dst.is_file() and filecmp.cmp(src, dst, shallow=False):
        return False
    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp = dst.with_name(f".{dst.name}.tmp")
    shutil.copyfile(src, tmp)
    tmp.replace(dst)
    return True


def archive_runs(suite_out: str | Path, archive: str | Path) -> int:
    """Copy the evidence of every evaluated run (and the RL results) of ``suite_out`` into
    ``archive``; returns how many files changed. Runs already archived and absent from
    ``suite_out`` stay: the archive only grows or is brought up to date."""
    src_root, dst_root = Path(suite_out), Path(archive)
    if src_root.resolve() == dst_root.resolve():
        return 0
    changed = 0
    for run_dir in _evaluated_runs(src_root):
        rel = run_dir.relative_to(src_root)
        for name in _run_files(run_dir):
            changed += _copy_if_changed(run_dir / name, dst_root / rel / name)
    extra = sorted((src_root / "rl").rglob("*.json")) if (src_root / "rl").is_dir() else []
    if (src_root / "suite.yaml").is_file():
        extra.append(src_root / "suite.yaml")
    for path in extra:
        changed += _copy_if_changed(path, dst_root / path.relative_to(src_root))
    return changed


def restore_runs(archive: str | Path, suite_out: str | Path) -> list[Path]:
    """Copy every archived run dir (and RL result) that ``suite_out`` lacks into it; returns the
    run dirs restored. Nothing already in ``suite_out`` is overwritten."""
    src_root, dst_root = Path(archive), Path(suite_out)
    if not src_root.is_dir():
        raise RunDirError(f"no archive at {src_root}")
    restored = []
    for run_dir in _evaluated_runs(src_root):
        target = dst_root / run_dir.relative_to(src_root)
        if target.exists():
            continue
        staging = target.with_name(f".{target.name}.restoring")  # a killed restore leaves no half run dir
        shutil.rmtree(staging, ignore_errors=True)
        for name in _run_files(run_dir):
            _copy_if_changed(run_dir / name, staging / name)
        staging.replace(target)
        restored.append(target)
    for path in sorted((src_root / "rl").rglob("*.json")) if (src_root / "rl").is_dir() else []:
        target = dst_root / path.relative_to(src_root)
        if not target.exists():
            _copy_if_changed(path, target)
    return restored

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
import os
import shutil
from pathlib import Path

from gpl_dist.errors import RunDirError

#: A run's files the archive keeps, beside the evaluation files its record names.
RUN_FILES = ("suite-run.json", "config.yaml", "metrics.jsonl", "checkpoints/latest.pt")
#: Files kept when the run has them: its valid learning curve (``gpl_dist.app.suite.curves``).
OPTIONAL_RUN_FILES = ("curve-valid.json",)


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
    return [Path(n) for n in names + [o for o in OPTIONAL_RUN_FILES if (run_dir / o).is_file()]]


def _copy(src: Path, dst: Path) -> None:
    """Copy ``src`` to ``dst`` through a temporary name (a killed copy leaves no half file under ``dst``)."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp = dst.with_name(f".{dst.name}.tmp-{os.getpid()}")
    shutil.copyfile(src, tmp)
    tmp.replace(dst)


def _same_files(src: Path, dst: Path, names: list[Path]) -> bool:
    """Whether ``dst`` holds exactly ``names``, each equal to its file in ``src``."""
    held = sorted(p.relative_to(dst) for p in dst.rglob("*") if p.is_file()) if dst.is_dir() else []
    return held == sorted(names) and all(filecmp.cmp(src / n, dst / n, shallow=False) for n in names)


def _put_run(src: Path, dst: Path, names: list[Path]) -> None:
    """Make ``dst`` hold exactly ``names`` copied from ``src``, whole: staged beside it, then
    swapped in (a killed copy leaves the old run dir, or none, never a mix of two versions)."""
    staging, old = dst.with_name(f".{dst.name}.staging"), dst.with_name(f".{dst.name}.old")
    shutil.rmtree(staging, ignore_errors=True)
    for name in names:
        _copy(src / name, staging / name)
    if dst.exists():
        shutil.rmtree(old, ignore_errors=True)
        dst.replace(old)
    staging.replace(dst)
    shutil.rmtree(old, ignore_errors=True)


def archive_runs(suite_out: str | Path, archive: str | Path) -> int:
    """Copy the evidence of every evaluated run (and the RL results) of ``suite_out`` into
    ``archive``; returns how many runs and RL files changed. A run whose files differ from its
    archived copy replaces that copy whole (no file of the older version stays); runs and RL
    results archived before and absent from ``suite_out`` stay."""
    src_root, dst_root = Path(suite_out), Path(archive)
    if src_root.resolve() == dst_root.resolve():
        return 0
    changed = 0
    for run_dir in _evaluated_runs(src_root):
        target, names = dst_root / run_dir.relative_to(src_root), _run_files(run_dir)
        if not _same_files(run_dir, target, names):
            _put_run(run_dir, target, names)
            changed += 1
    extra = sorted((src_root / "rl").rglob("*.json")) if (src_root / "rl").is_dir() else []
    if (src_root / "suite.yaml").is_file():
        extra.append(src_root / "suite.yaml")
    for path in extra:
        target = dst_root / path.relative_to(src_root)
        if not (target.is_file() and filecmp.cmp(path, target, shallow=False)):
            _copy(path, target)
            changed += 1
    return changed


def restore_runs(archive: str | Path, suite_out: str | Path, log=print) -> list[Path]:
    """Copy every archived run dir (and RL result) that ``suite_out`` lacks into it; returns the
    run dirs restored. Nothing already in ``suite_out`` is overwritten (``log`` names what is kept)."""
    src_root, dst_root = Path(archive), Path(suite_out)
    if not src_root.is_dir():
        raise RunDirError(f"no archive at {src_root}")
    restored = []
    for run_dir in _evaluated_runs(src_root):
        target = dst_root / run_dir.relative_to(src_root)
        if target.exists():
            log(f"kept {target}: it exists (remove it to restore the archived run)")
            continue
        _put_run(run_dir, target, _run_files(run_dir))
        restored.append(target)
    for path in sorted((src_root / "rl").rglob("*.json")) if (src_root / "rl").is_dir() else []:
        target = dst_root / path.relative_to(src_root)
        if not target.exists():
            _copy(path, target)
    return restored

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

and every ``OUT/rl/**.json`` (the RL curves and attempt sets) and ``OUT/suite.yaml``; then
``checksums.json``, the sha256 of every archived file (``gpl_dist.app.suite.evidence``). A run is
checked before it is archived (its eval files' consistency; a restored run's own checksums), and
what the archive keeps from before is checked against its checksums before any file changes, so
an edited file is refused, never summed anew. The archive is itself a suite output: ``gpl-dist
suite report ARCHIVE`` reads it, and ``gpl-dist suite restore
ARCHIVE --out OUT`` copies its runs into OUT, where ``gpl-dist suite run`` then skips them and
trains only the rest (a run dir already in OUT is never overwritten).
"""

from __future__ import annotations

import filecmp
import json
import os
import shutil
import tempfile
from pathlib import Path

from gpl_dist.app.suite.evidence import (
    CHECKSUMS,
    RUN_EVIDENCE,
    EvidenceError,
    check_checksums,
    check_run,
    evidence_files,
    read_checksums,
    read_json,
    write_checksums,
)
from gpl_dist.app.suite.records import CURVE_FILE, SWAP_FILE
from gpl_dist.errors import RunDirError

#: A run's files the archive keeps, beside the evaluation files its record names (and ``run.json``).
RUN_FILES = RUN_EVIDENCE
#: Files kept when the run has them: its valid learning curve (``gpl_dist.app.suite.curves``) and
#: instruction-swap control (``gpl_dist.app.suite.swap``).
OPTIONAL_RUN_FILES = (CURVE_FILE, SWAP_FILE)


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
    names = evidence_files(run_dir, read_json(run_dir / "suite-run.json"))
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
    held = sorted(p.relative_to(dst) for p in dst.rglob("*") if p.is_file() and p.name != CHECKSUMS) if dst.is_dir() else []
    return held == sorted(names) and all(filecmp.cmp(src / n, dst / n, shallow=False) for n in names)


def _refuse_links(src: Path, names: list[Path]) -> None:
    """``EvidenceError`` when a file of ``names`` under ``src`` is, or passes through, a symbolic link."""
    linked = [n for n in names if any((src / p).is_symlink() for p in [n, *n.parents])]
    if linked:
        raise EvidenceError(f"{src / linked[0]} is (or passes through) a symbolic link: never followed, nothing copied")


def _put_run(src: Path, dst: Path, names: list[Path]) -> None:
    """Make ``dst`` hold exactly ``names`` copied from ``src``, whole: staged beside it, then
    swapped in (a killed copy leaves the old run dir, or none, never a mix of two versions)."""
    _refuse_links(src, names)
    for folder in (dst.parent.parent, dst.parent, dst):  # the archive (or suite output), the entry, the run
        if folder.is_symlink():
            raise EvidenceError(f"{folder} is a symbolic link: nothing is written through one")
    dst.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{dst.name}.staging-", dir=dst.parent))  # new: never a planted one
    old = dst.with_name(f".{dst.name}.old-{staging.name.rsplit('-', 1)[-1]}")
    try:
        for name in names:
            _copy(src / name, staging / name)
        if dst.exists():
            dst.replace(old)
        staging.replace(dst)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    shutil.rmtree(old, ignore_errors=True)


#: What an archive may hold: data only (records, configs, metrics, weights read with weights_only).
#: A plug-in's code (``.py``, compiled modules, ``.pth``), or anything else, is refused: reading an
#: archive must never be a way to bring code onto a machine.
ARCHIVE_SUFFIXES = (".json", ".jsonl", ".yaml", ".pt")


def _archived_files(root: Path, strict: bool = True) -> list[str]:
    """Every file of an archive, relative to it, but its checksums and temporaries; ``EvidenceError``
    for a symbolic link (never followed) or a file that is not data (``ARCHIVE_SUFFIXES``). Not
    ``strict`` (a suite's output folder, with its buffers and plots, read as an archive): every
    file but links, which are left out, never followed."""
    if not root.is_dir():
        return []
    out = []
    for dirpath, dirnames, filenames in os.walk(root, followlinks=False):
        for name in [*dirnames, *filenames]:
            path = Path(dirpath) / name
            rel = path.relative_to(root)
            if any(part.startswith(".") for part in rel.parts):
                continue
            if path.is_symlink():
                if not strict:
                    continue
                raise EvidenceError(f"{path} is a symbolic link: an archive holds real files only (never followed)")
            if name in filenames and name != CHECKSUMS:
                if strict and path.suffix not in ARCHIVE_SUFFIXES:
                    raise EvidenceError(f"{path} is not data an archive may carry (only {', '.join(ARCHIVE_SUFFIXES)} "
                                        "files: never code such as a domain plug-in)")
                out.append(rel.as_posix())
    return sorted(out)


def archive_runs(suite_out: str | Path, archive: str | Path, log=print) -> int:
    """Copy the evidence of every evaluated run (and the RL results) of ``suite_out`` into
    ``archive`` and write its ``checksums.json``; returns how many runs and RL files changed. A
    run whose files differ from its archived copy replaces that copy whole (no file of the older
    version stays); runs and RL results archived before and absent from ``suite_out`` stay, checked
    against the archive's checksums first (``EvidenceError`` naming a changed file)."""
    src_root, dst_root = Path(suite_out), Path(archive)
    if src_root.resolve() == dst_root.resolve():
        return 0
    runs = _evaluated_runs(src_root)
    for run_dir in runs:  # before anything changes: nothing inconsistent, edited or linked is archived
        check_run(run_dir)
        _refuse_links(run_dir, _run_files(run_dir))
    extra = sorted((src_root / "rl").rglob("*.json")) if (src_root / "rl").is_dir() else []
    if (src_root / "suite.yaml").is_file():
        extra.append(src_root / "suite.yaml")
    incoming = {(dst_root / r.relative_to(src_root)).relative_to(dst_root).as_posix() for r in runs}
    incoming_files = {p.relative_to(src_root).as_posix() for p in extra}
    old = read_checksums(dst_root)
    kept = [f for f in _archived_files(dst_root) if f not in incoming_files and not any(f.startswith(r + "/") for r in incoming)]
    if old is not None:
        missing = [f for f in kept if f not in old]
        if missing:
            raise EvidenceError(f"{dst_root / missing[0]} has no checksum in {dst_root / CHECKSUMS} (added after archiving?)")
        check_checksums(dst_root, {f: old[f] for f in kept})
    elif kept:
        log(f"note: {dst_root} has no {CHECKSUMS} (archived before checksums existed): the {len(kept)} file(s) kept "
            "from it are checked for consistency only, then summed")
    for run_dir in _evaluated_runs(dst_root):
        if run_dir.relative_to(dst_root).as_posix() not in incoming:
            check_run(run_dir, old, run_dir.relative_to(dst_root).as_posix() + "/") if old is not None else check_run(run_dir)
    changed = 0
    for run_dir in runs:
        target, names = dst_root / run_dir.relative_to(src_root), _run_files(run_dir)
        if not _same_files(run_dir, target, names):
            _put_run(run_dir, target, names)
            changed += 1
    for path in extra:
        target = dst_root / path.relative_to(src_root)
        if not (target.is_file() and filecmp.cmp(path, target, shallow=False)):
            _copy(path, target)
            changed += 1
    write_checksums(dst_root, _archived_files(dst_root))
    return changed


def check_archive(archive: Path, log=print) -> dict[str, str] | None:
    """Check an archive: every file its ``checksums.json`` lists, every file the report reads listed,
    and every run's evidence (``check_run``); returns its sums (None for an archive made before
    checksums existed, checked for consistency only, ``log`` says so)."""
    sums = read_checksums(archive)
    # an archive (it has checksums) holds data only and no link; a suite's output folder is read as is
    files = _archived_files(archive, strict=sums is not None)
    if sums is None:
        log(f"note: {archive} has no {CHECKSUMS} (archived before checksums existed): its eval files are checked "
            "for consistency only")
    else:
        check_checksums(archive, sums)
        unlisted = [f for f in files if f not in sums and f.endswith(ARCHIVE_SUFFIXES)]
        if unlisted:
            raise EvidenceError(f"{archive / unlisted[0]} has no checksum in {archive / CHECKSUMS} (added after archiving?)")
    for run_dir in _evaluated_runs(archive):
        check_run(run_dir, sums, run_dir.relative_to(archive).as_posix() + "/") if sums is not None else check_run(run_dir)
    return sums


def restore_runs(archive: str | Path, suite_out: str | Path, log=print) -> list[Path]:
    """Copy every archived run dir (and RL result) that ``suite_out`` lacks into it; returns the
    run dirs restored. The whole archive is checked first (``check_archive``: nothing is copied
    from an archive with a changed file); each restored run dir gets a ``checksums.json`` of its
    files, which ``suite status`` and ``suite run`` check. Nothing already in ``suite_out`` is
    overwritten (``log`` names what is kept)."""
    src_root, dst_root = Path(archive), Path(suite_out)
    if not src_root.is_dir():
        raise RunDirError(f"no archive at {src_root}")
    check_archive(src_root, log)  # data only, no link, every file as summed
    restored = []
    for run_dir in _evaluated_runs(src_root):
        target = dst_root / run_dir.relative_to(src_root)
        if target.exists():
            log(f"kept {target}: it exists (remove it to restore the archived run)")
            continue
        names = _run_files(run_dir)
        _put_run(run_dir, target, names)
        write_checksums(target, [n.as_posix() for n in names])
        restored.append(target)
    for path in sorted((src_root / "rl").rglob("*.json")) if (src_root / "rl").is_dir() else []:
        target = dst_root / path.relative_to(src_root)
        if not target.exists():
            _copy(path, target)
    return restored

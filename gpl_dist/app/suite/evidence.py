"""Evidence that checks itself: checksums of an archive's files, and each eval file's own consistency.

``suite report`` archives the runs' files beside the report and writes ``checksums.json`` at the
archive's root: the sha256 of every archived file. ``suite restore`` writes the same kind of file
into each run dir it restores (its files' sums, relative to the run dir). ``suite report``,
``suite restore`` and ``suite status`` (and ``suite run``, which reads run states the same way)
check, for every run they count:

- each of its files a checksum file covers, and that every file the report reads is covered;
- each eval file (read as ``learner.evaluate.EvalRecord``) agrees with itself: ``completion`` is
  the mean over seeds of ``per_seed``, ``completion_std`` their spread, one ``per_seed`` row per evaluation seed, every value a
  fraction; the settings it records are the ones its ``suite-run.json`` names; its ``run_id``
  (when it records one) is the run's own.

A mismatch fails in one line naming the file (``EvidenceError``), and nothing is counted. This
protects against accidents and edits: a file damaged, replaced or edited by hand after archiving.
It does not protect against someone who rewrites the checksums too (or deletes them, or edits an
eval file consistently before it is archived): the checksums are not signed.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
from pathlib import Path
from typing import Any, Mapping

from gpl_dist.errors import RunDirError
from learner.evaluate import EvalRecord
from learner.identity import RUN_FILE, read_identity

#: The checksum file of an archive (at its root) or of a restored run dir.
CHECKSUMS = "checksums.json"
#: Tolerance of the consistency check (the values are means of at most a few thousand fractions).
_TOLERANCE = 1e-9
#: Largest file hashed (an archived checkpoint is a few MB).
_MAX_BYTES = 1 << 30


class EvidenceError(RunDirError):
    """An archived or evaluated file fails its checksum or its own consistency."""


def sha256_file(path: Path) -> str:
    """The hex sha256 of the file at ``path``."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def write_checksums(root: Path, names: list[str]) -> Path:
    """Write ``root/checksums.json`` with the sha256 of each file ``names`` lists (relative to
    ``root``, ``/``-separated), atomically; returns its path."""
    files = {name: sha256_file(root / name) for name in sorted(set(names))}
    path = root / CHECKSUMS
    tmp = path.with_name(f".{CHECKSUMS}.tmp-{os.getpid()}")
    tmp.write_text(json.dumps({"format_version": 1, "algorithm": "sha256", "files": files}, indent=1) + "\n")
    tmp.replace(path)
    return path


def read_checksums(root: Path) -> dict[str, str] | None:
    """The sums ``root/checksums.json`` records ({relative path: sha256}), or None without one
    (an archive or run made before checksums existed); ``EvidenceError`` for a damaged one."""
    path = root / CHECKSUMS
    if not path.is_file():
        return None
    try:
        raw = json.loads(path.read_text()[: 64 << 20])
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as err:
        raise EvidenceError(f"{path} is unreadable ({type(err).__name__})") from None
    files = raw.get("files") if isinstance(raw, dict) else None
    if not isinstance(files, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in files.items()):
        raise EvidenceError(f"{path} is not a checksum file (no 'files' mapping of paths to sha256 sums)")
    return dict(files)


def check_checksums(root: Path, sums: Mapping[str, str]) -> None:
    """Every file ``sums`` lists exists under ``root`` with its recorded sha256."""
    for name, digest in sorted(sums.items()):
        path = root / name
        if ".." in Path(name).parts or Path(name).is_absolute():
            raise EvidenceError(f"{root / CHECKSUMS} lists {name[:120]!r}, which is not a path inside {root}")
        if not path.is_file():
            raise EvidenceError(f"{path} is missing (its checksum is in {root / CHECKSUMS})")
        if path.stat().st_size > _MAX_BYTES or sha256_file(path) != digest:
            raise EvidenceError(f"{path}: checksum mismatch (the file changed after it was archived; {root / CHECKSUMS})")


def check_covered(root: Path, sums: Mapping[str, str] | None, names: list[str]) -> None:
    """With ``sums`` (None: nothing recorded), each of ``names`` must be listed: a file added or
    named after archiving is not evidence."""
    if sums is None:
        return
    for name in names:
        if name not in sums:
            raise EvidenceError(f"{root / name} has no checksum in {root / CHECKSUMS} (added after archiving?)")


def _fraction(path: Path, what: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or not 0 <= value <= 1:
        raise EvidenceError(f"{path}: {what} is {str(value)[:40]}, not a fraction in [0, 1]")
    return float(value)


def read_eval_evidence(path: Path) -> EvalRecord:
    """The ``EvalRecord`` of the eval file at ``path``; ``EvidenceError`` naming it when it cannot
    be read or is not one."""
    try:
        return EvalRecord.from_json(path.read_text()[: 64 << 20])
    except (OSError, UnicodeDecodeError, ValueError, TypeError, RecursionError) as err:
        raise EvidenceError(f"{path}: not an evaluation record ({type(err).__name__}: {str(err)[:200]})") from None


def check_eval(path: Path, record: EvalRecord, settings: Mapping[str, Any] | None = None,
               run_id: str | None = None) -> None:
    """``EvidenceError`` naming ``path`` unless its eval record agrees with itself (see the module
    docstring), with the ``settings`` its ``suite-run.json`` names, and with ``run_id`` (when both
    record one)."""
    if not record.completion:
        raise EvidenceError(f"{path}: no completion curve")
    means = [_fraction(path, f"completion[{k}]", v) for k, v in enumerate(record.completion)]
    if not record.per_seed or not all(len(row) == len(means) for row in record.per_seed):
        raise EvidenceError(f"{path}: per_seed is not one curve of {len(means)} values per evaluation seed")
    rows = [[_fraction(path, f"per_seed[{s}][{k}]", v) for k, v in enumerate(row)] for s, row in enumerate(record.per_seed)]
    std = record.completion_std
    for k, mean in enumerate(means):
        column = [row[k] for row in rows]
        expected = sum(column) / len(column)
        if abs(expected - mean) > _TOLERANCE:
            raise EvidenceError(f"{path}: completion[{k}] is {mean:.6g} but the mean of its per_seed values is "
                                f"{expected:.6g} (the file was edited?)")
        if len(std) == len(means):
            spread = math.sqrt(sum((x - expected) ** 2 for x in column) / len(column))
            if abs(spread - std[k]) > 1e-6:
                raise EvidenceError(f"{path}: completion_std[{k}] is {str(std[k])[:20]} but its per_seed values spread "
                                    f"{spread:.6g}")
    if record.success and len(record.success) != len(means):
        raise EvidenceError(f"{path}: success has {len(record.success)} values, completion {len(means)}")
    for k, v in enumerate(record.success):
        _fraction(path, f"success[{k}]", v)
    if len(record.seeds) != len(rows):
        raise EvidenceError(f"{path}: {len(record.seeds)} evaluation seeds but {len(rows)} per_seed curves")
    for key, value in (settings or {}).items():
        if key in _EVAL_FIELDS and _plain(getattr(record, key)) != _plain(value):
            raise EvidenceError(f"{path}: {key} is {str(getattr(record, key))[:40]}, but its suite-run.json records "
                                f"{str(value)[:40]}")
    if run_id is not None and record.run_id is not None and record.run_id != run_id:
        raise EvidenceError(f"{path}: an evaluation of run {record.run_id[:64]}, not of this run {run_id[:64]}")


#: The eval record's fields a ``suite-run.json``'s settings may name.
_EVAL_FIELDS = frozenset(f.name for f in dataclasses.fields(EvalRecord))


def _plain(value: Any) -> Any:
    return list(value) if isinstance(value, tuple) else value


def read_json(path: Path) -> dict:
    """A record or eval file; a missing or damaged one fails in one line naming it."""
    try:
        value = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as err:
        raise RunDirError(f"cannot read {path} ({type(err).__name__}: {str(err)[:200]})") from None
    if not isinstance(value, dict):
        raise RunDirError(f"{path} does not hold a JSON object")
    return value


#: A run's files that evidence covers, beside the eval files its record names (``RUN_FILE`` when present).
RUN_EVIDENCE = ("suite-run.json", "config.yaml", "metrics.jsonl", "checkpoints/latest.pt")


def evidence_files(run_dir: Path, record: Mapping[str, Any]) -> list[str]:
    """The run's files a report's number traces to: its record, config, metrics, final weights,
    identity (when it has one) and every eval file its record names."""
    evaluations = record.get("evaluations")
    if not isinstance(evaluations, dict):
        raise EvidenceError(f"{run_dir / 'suite-run.json'}: 'evaluations' is not a mapping")
    names = list(RUN_EVIDENCE) + ([RUN_FILE] if (run_dir / RUN_FILE).is_file() else [])
    for name, ev in evaluations.items():
        file = ev.get("file") if isinstance(ev, dict) else None
        if not isinstance(file, str) or "/" in file or "\\" in file or not file.startswith("eval") or \
                not file.endswith(".json"):
            raise EvidenceError(f"{run_dir / 'suite-run.json'}: evaluation '{str(name)[:40]}' names no eval file in the run dir")
        names.append(file)
    return sorted(set(names))


def check_run(run_dir: Path, sums: Mapping[str, str] | None = None, prefix: str = "",
              files: tuple[str, ...] | None = None) -> None:
    """Check one run's evidence (see the module docstring). ``sums``: checksums covering its files,
    as ``prefix + name`` (an archive's, whose root is above the run dir), or None to use the run
    dir's own ``checksums.json`` if it has one. ``files``: only these of its files must exist
    (default every evidence file: a run still evaluating may lack later eval files)."""
    record = read_json(run_dir / "suite-run.json")
    if sums is None:
        sums, prefix = read_checksums(run_dir), ""
    names = evidence_files(run_dir, record)
    if sums is not None:
        own = {k[len(prefix):]: v for k, v in sums.items() if k.startswith(prefix)}
        check_covered(run_dir, own, [n for n in names if files is None or n in files])
        check_checksums(run_dir, {n: d for n, d in own.items() if n in names})
    identity = read_identity(run_dir)
    for name, ev in record["evaluations"].items():
        path = run_dir / ev["file"]
        settings = ev.get("settings") if isinstance(ev.get("settings"), dict) else None
        check_eval(path, read_eval_evidence(path), settings, identity.run_id if identity else None)

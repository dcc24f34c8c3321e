"""Who a run is: a unique id given when the run is created (``RUN_DIR/run.json``), never its dir's name.

The id is recorded in the buffer's marker, in every round manifest and shard record, in every
checkpoint and in every evaluation file, so that ``verify``, ``train --resume``, ``eval``,
``teach`` and ``serve`` can tell a file of this run from one of another run, naming both.

A run created before identities existed has no ``run.json``: it is *legacy*, and its id is the one
its buffer's marker and manifests record (its dir's name), so it keeps working as it was.
"""

from __future__ import annotations

import json
import os
import uuid
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from gpl_dist.errors import CheckpointError, RunDirError
from learner.checkpoint import load_checkpoint
from storage.manifest import buffer_run_id

#: The run's identity file, written once when the run is created.
RUN_FILE = "run.json"


@dataclass(frozen=True)
class RunIdentity:
    """A run's identity.

    Attributes:
        run_id: a UUID (hex) for a run created with identities; a legacy run's marker id or dir name.
        created: when the run was created (ISO 8601, UTC); empty for a legacy run.
        legacy: the run has no ``run.json`` (made before identities existed).
    """

    run_id: str
    created: str
    legacy: bool


def create_identity(run_dir: str | os.PathLike) -> RunIdentity:
    """Give a new run its identity (``run.json``, written atomically); ``RunDirError`` when it has one."""
    path = Path(run_dir) / RUN_FILE
    if path.exists():
        raise RunDirError(f"{path} exists: {run_dir} already holds a run")
    identity = RunIdentity(uuid.uuid4().hex, datetime.now(timezone.utc).isoformat(timespec="seconds"), legacy=False)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{RUN_FILE}.tmp-{os.getpid()}")
    tmp.write_text(json.dumps({"format_version": 1, "run_id": identity.run_id, "created": identity.created}) + "\n")
    tmp.replace(path)
    return identity


def read_identity(run_dir: str | os.PathLike) -> RunIdentity | None:
    """The identity ``run.json`` records, or None without one; ``RunDirError`` naming a damaged one."""
    path = Path(run_dir) / RUN_FILE
    try:
        text = path.read_text()[:4096]
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError) as err:
        raise RunDirError(f"cannot read {path} ({type(err).__name__})") from None
    try:
        raw = json.loads(text)
    except ValueError:
        raw = None
    run_id = raw.get("run_id") if isinstance(raw, dict) else None
    if not isinstance(run_id, str) or not 0 < len(run_id) <= 64:
        raise RunDirError(f"{path} is damaged (no run_id): the run's identity is lost; restore the file from a copy")
    return RunIdentity(run_id, str(raw.get("created", ""))[:40], legacy=False)


def resolve_identity(run_dir: str | os.PathLike, buffer_root: str) -> RunIdentity:
    """The run's identity: ``run.json``'s, else (a legacy run) the id its buffer's marker records,
    else its dir's name (what runs were called before identities existed)."""
    identity = read_identity(run_dir)
    if identity is not None:
        return identity
    return RunIdentity(buffer_run_id(buffer_root) or Path(run_dir).name, "", legacy=True)


def describe(run_id: str | None) -> str:
    """``run_id`` for a message (cut: a hand-edited file can hold anything)."""
    return "none recorded" if run_id is None else run_id[:64]


def checkpoint_problems(run_dir: str | os.PathLike, run_id: str) -> list[tuple[str, str]]:
    """``(path, what)`` for each checkpoint under ``RUN_DIR/checkpoints`` that is unreadable or of
    another run than ``run_id`` (a checkpoint saved before run ids existed is taken as the run's)."""
    problems = []
    for path in sorted((Path(run_dir) / "checkpoints").glob("*.pt")):
        try:
            ckpt = load_checkpoint(path)
        except CheckpointError as err:
            problems.append((str(path), str(err).replace(f"{path} ", "", 1)))
            continue
        if ckpt.run_id is not None and ckpt.run_id != run_id:
            problems.append((str(path), f"a checkpoint of run {ckpt.run_id[:64]}, not of this run {run_id[:64]}"))
    return problems

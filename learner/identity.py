"""Who a run is: a unique id given when the run is created (``RUN_DIR/run.json``), never its dir's name.

The id is recorded in the buffer's marker, in every round manifest and shard record, in every
checkpoint and in every evaluation file, so that ``verify``, ``train --resume``, ``eval``,
``teach`` and ``serve`` can tell a file of this run from one of another run, naming both.

A run dir without ``run.json`` (a run made before the file was written, or copied without it) is
read as a run all the same (``resolve_identity``, the one place that file's absence is handled):
its id is the one its buffer's marker and manifests record, else its dir's name, and its identity
says the id is *inferred*, which ``verify`` notes.

A checkpoint is of a run without ``run.json`` when nothing the run's own files record says
otherwise (``why_not_recorded_run``, which ``eval``, ``teach``, ``serve`` and ``render`` ask before
they use it or write into the run): the run id of its buffer's marker, as ``verify`` checks it;
without a buffer (a run restored from an archive carries none), the one run id its other
checkpoints and evaluation files record; and in every case the training history, which each
checkpoint carries and ``metrics.jsonl`` repeats round for round (both read by
``learner.rounds.read_round``, whichever shape they were written in), so that even a checkpoint or
a run that records no run id is told from another run of the same domain, model and seed (every
round's wall times differ). A run dir whose files record no id and no round (no buffer
marker, checkpoint, evaluation file or ``metrics.jsonl``) has nothing to check against: only its
config (domain, model, seed) is compared.
"""

from __future__ import annotations

import json
import os
import uuid
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from gpl_dist.errors import CheckpointError, RunDirError
from learner.checkpoint import Checkpoint, load_checkpoint
from learner.rounds import read_metrics, read_round
from storage.manifest import buffer_run_id

#: The run's identity file, written once when the run is created.
RUN_FILE = "run.json"


@dataclass(frozen=True)
class RunIdentity:
    """A run's identity.

    Attributes:
        run_id: the UUID (hex) ``run.json`` records; inferred, its buffer's marker id or its dir's name.
        created: when the run was created (ISO 8601, UTC); empty when inferred.
        inferred: the run has no ``run.json``: ``run_id`` is inferred (``resolve_identity``).
    """

    run_id: str
    created: str
    inferred: bool


#: The folders of a run dir that gpl-dist writes into and walks (``refuse_linked_folders``).
RUN_FOLDERS = ("buffer", "checkpoints", "teaching", "tb")


def refuse_linked_folders(run_dir: str | Path) -> None:
    """``RunDirError`` in one line when a folder of the run dir (``RUN_FOLDERS``) is a symbolic
    link: gpl-dist never writes, reads or removes through one (a buffer elsewhere is
    ``buffer.location``, which the run's identity then guards)."""
    for name in RUN_FOLDERS:
        path = Path(run_dir) / name
        if path.is_symlink():
            raise RunDirError(f"{path} is a symbolic link (to {os.readlink(path)[:200]!r}): gpl-dist never follows a "
                              "link inside a run (set buffer.location for a buffer elsewhere, or copy the real files in)")


def create_identity(run_dir: str | os.PathLike) -> RunIdentity:
    """Give a new run its identity (``run.json``, written atomically); ``RunDirError`` when it has one."""
    path = Path(run_dir) / RUN_FILE
    if path.exists():
        raise RunDirError(f"{path} exists: {run_dir} already holds a run")
    identity = RunIdentity(uuid.uuid4().hex, datetime.now(timezone.utc).isoformat(timespec="seconds"), inferred=False)
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
    return RunIdentity(run_id, str(raw.get("created", ""))[:40], inferred=False)


def resolve_identity(run_dir: str | os.PathLike, buffer_root: str) -> RunIdentity:
    """The run's identity: the one place a run dir of either shape is read.

    - no ``run.json`` (made before the file was written, or copied without it): the id its buffer's
      marker records, else its dir's name, ``inferred``;
    - ``run.json`` (``format_version`` 1, the current): its id and creation time.
    """
    identity = read_identity(run_dir)
    if identity is not None:
        return identity
    return RunIdentity(buffer_run_id(buffer_root) or Path(run_dir).name, "", inferred=True)


def describe(run_id: str | None) -> str:
    """``run_id`` for a message (cut: a hand-edited file can hold anything)."""
    return "none recorded" if run_id is None else run_id[:64]


def checkpoint_problems(run_dir: str | os.PathLike, run_id: str) -> list[tuple[str, str]]:
    """``(path, what)`` for each checkpoint under ``RUN_DIR/checkpoints`` that is unreadable or of
    another run than ``run_id`` (a checkpoint that records no run id is taken as the run's)."""
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


def config_problems(run_dir: str | os.PathLike) -> list[tuple[str, str]]:
    """``(path, what)`` when ``RUN_DIR/config.yaml`` is not the config the run was made with: its
    latest checkpoint holds the config its last round used, which is ``config.yaml`` with every
    ``--resume`` change that ``metrics.jsonl`` records up to that round (``learner.driver``). Read
    as data: no plug-in is imported. [] for a run without both files."""
    from gpl_dist.config import load_yaml_text

    run_dir = Path(run_dir)
    path, latest = run_dir / "config.yaml", run_dir / "checkpoints" / "latest.pt"
    if not path.is_file() or not latest.is_file():
        return []
    try:
        saved = load_yaml_text(path.read_text(), path)
        ckpt = load_checkpoint(latest)
    except (OSError, UnicodeDecodeError, RunDirError, CheckpointError, ValueError) as err:
        return [(str(path), f"cannot be checked against {latest.name} ({' '.join(str(err).split())[:200]})")]
    expected = _flat(saved if isinstance(saved, dict) else {})
    for r, m in sorted(read_metrics(run_dir, skip_damaged=True).items()):
        if r <= ckpt.round_index:
            expected.update({key: new for key, _, new in m.config_changes})
    held = _flat(ckpt.config if isinstance(ckpt.config, dict) else {})
    differ = sorted(k for k in set(expected) | set(held) if expected.get(k) != held.get(k))
    if not differ:
        return []
    key = differ[0]
    return [(str(path), f"says {key}: {str(expected.get(key))[:80]}, but the run's latest round was trained with "
                        f"{str(held.get(key))[:80]} ({len(differ)} key(s) differ; a resume's changes are recorded in "
                        "metrics.jsonl, never in config.yaml): the file was edited after the run wrote it")]


def _flat(tree: dict, prefix: str = "") -> dict:
    out: dict = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            out.update(_flat(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = list(value) if isinstance(value, tuple) else value
    return out


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == b.resolve()
    except OSError:
        return False


def recorded_run_ids(run_dir: str | os.PathLike, besides: str | os.PathLike | None = None) -> set[str]:
    """The run ids that the checkpoints under ``RUN_DIR/checkpoints`` (all but ``besides``) and the
    evaluation files ``RUN_DIR/eval*.json`` record (unreadable ones are ``verify``'s to name)."""
    run_dir = Path(run_dir)
    ids: set[str] = set()
    for path in sorted((run_dir / "checkpoints").glob("*.pt")):
        if besides is not None and _same_file(path, Path(besides)):
            continue
        try:
            run_id = load_checkpoint(path).run_id
        except CheckpointError:
            continue
        if run_id is not None:
            ids.add(run_id)
    for path in sorted(run_dir.glob("eval*.json")):
        try:
            raw = json.loads(path.read_text()[:1 << 24])
        except (OSError, UnicodeDecodeError, ValueError):
            continue
        if isinstance(raw, dict) and isinstance(raw.get("run_id"), str):
            ids.add(raw["run_id"])
    return ids


def _canonical(record) -> str:
    """A round's record in the current shape (``learner.rounds.read_round``), as JSON with sorted
    keys (NaN equals NaN there, as it does in the file); one that is no round's record, as it is."""
    try:
        return json.dumps(read_round(record).to_dict(), sort_keys=True)
    except (KeyError, TypeError, ValueError):
        return repr(record)


def why_not_recorded_run(run_dir: str | os.PathLike, ckpt: Checkpoint, ckpt_file: str | os.PathLike,
                         buffer_root: str) -> str | None:
    """Why ``ckpt`` (read from ``ckpt_file``) is not a checkpoint of the run in ``run_dir``, which has
    no ``run.json``, by what the run's own files record (module docstring), in one line; None when
    they record nothing against it."""
    run_dir = Path(run_dir)
    marked = buffer_run_id(buffer_root)
    if ckpt.run_id is not None:
        if marked is not None:
            ids, where = {marked}, "its buffer's marker records"
        else:
            ids, where = recorded_run_ids(run_dir, besides=ckpt_file), "its other checkpoints and evaluation files record"
        if len(ids) > 1:
            named = ", ".join(describe(i) for i in sorted(ids)[:3])
            return (f"{run_dir} has no run.json and {where.replace(' record', '')} name {len(ids)} runs ({named}): "
                    f"there is no telling whether {ckpt_file} (run {describe(ckpt.run_id)}) is its checkpoint")
        if ids and ckpt.run_id not in ids:
            return (f"{ckpt_file} is a checkpoint of run {describe(ckpt.run_id)}, not of {run_dir} (run "
                    f"{describe(next(iter(ids)))}, as {where}; it has no run.json)")
    rows = read_metrics(run_dir, skip_damaged=True)
    for theirs in ckpt.history:
        r = theirs.get("round") if isinstance(theirs, dict) else None
        if r in rows and _canonical(rows[r].to_dict()) != _canonical(theirs):
            return (f"{ckpt_file} is not a checkpoint of {run_dir}: its record of round {r} differs from "
                    f"{run_dir / 'metrics.jsonl'}'s (the run has no run.json; its training history tells it apart)")
    return None

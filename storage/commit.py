"""The driver's side of the commit protocol.

``commit_round`` (driver only):

1. roll forward any commit journal left by a crashed driver (``recover_pending``);
2. check every shard record (round, distinct units, one run id, one obs shape/dtype, staged files
   present with the recorded sizes);
3. write the journal ``manifests/_pending-round-R.json`` atomically: the manifest-to-be plus the
   list of moves ``staging/... -> data/...``; from here on the commit is decided and only rolls forward;
4. move each staged file to its fixed committed name (idempotent: a file already moved is skipped);
5. write ``manifests/round-R.json`` atomically (temp + rename) - the commit point for readers;
6. delete the journal and the emptied staging directories.

A crash before 3 leaves only staging debris; a crash after 3 is finished by the next
``commit_round``/``recover_pending``/``clean_leftovers``.
"""

from __future__ import annotations

import json
import os
from datetime import datetime, timezone
from typing import Any, Sequence

from gpl_dist.faults import fault_point
from storage.errors import BufferIntegrityError
from storage.fs import Location, resolve
from storage.layout import (
    DATA,
    MANIFESTS,
    OBS_DIR,
    STAGING,
    TRY_PREFIX,
    committed_path,
    manifest_path,
    parse_pending_name,
    pending_path,
    staging_unit_dir,
)
from storage.manifest import (
    RoundManifest,
    ShardFile,
    ShardRecord,
    committed_rounds,
    load_manifest,
    mark_buffer,
    parse_manifest,
)


def _committed_file_path(rec: ShardRecord, f: ShardFile) -> str:
    if f.role == "obs":
        key = f.path.split(f"/{OBS_DIR}/", 1)[1]
        return f"{committed_path('obs', rec.round_index, rec.unit_index)}/{key}"
    return committed_path(f.role, rec.round_index, rec.unit_index)


def _same_content(a: RoundManifest, records: Sequence[ShardRecord]) -> bool:
    def sig(rs: Sequence[ShardRecord]) -> set:
        return {(r.unit_index, r.try_id, tuple(sorted(f.sha256 for f in r.files))) for r in rs}

    return sig(a.shards) == sig(records)


def _validate(loc: Location, round_index: int, records: Sequence[ShardRecord]) -> tuple[str, tuple | None, str | None]:
    units = [r.unit_index for r in records]
    if len(set(units)) != len(units):
        dup = sorted({u for u in units if units.count(u) > 1})
        raise ValueError(f"round {round_index}: units {dup} appear in more than one shard record")
    run_ids = {r.run_id for r in records}
    if len(run_ids) > 1:
        raise ValueError(f"round {round_index}: shard records of several runs {sorted(run_ids)}")
    shapes = {(r.obs_shape, r.obs_dtype) for r in records if r.obs_shape is not None}
    if len(shapes) > 1:
        raise ValueError(f"round {round_index}: shards disagree on observation shape/dtype: {sorted(map(str, shapes))}")
    obs_shape, obs_dtype = next(iter(shapes)) if shapes else (None, None)
    prev = committed_rounds(loc)
    if prev and obs_shape is not None:
        last = load_manifest(loc, prev[-1])
        if last.obs_shape is not None and (last.obs_shape, last.obs_dtype) != (obs_shape, obs_dtype):
            raise ValueError(
                f"round {round_index}: observations {obs_shape} {obs_dtype} differ from round "
                f"{prev[-1]}'s {last.obs_shape} {last.obs_dtype}"
            )
    for r in records:
        if r.round_index != round_index:
            raise ValueError(f"shard of unit {r.unit_index} belongs to round {r.round_index}, not {round_index}")
        for f in r.files:
            try:
                size = loc.size(f.path)
            except FileNotFoundError:
                raise BufferIntegrityError(f"staged file {f.path} of unit {r.unit_index} is missing in {loc.url}",
                                           f.path) from None
            if size != f.nbytes:
                raise BufferIntegrityError(f"staged file {f.path} has {size} bytes, record says {f.nbytes}", f.path)
    run_id = next(iter(run_ids)) if run_ids else ""
    return run_id, obs_shape, obs_dtype


def _roll_forward(loc: Location, journal: dict[str, Any]) -> RoundManifest:
    manifest = RoundManifest.from_json(json.dumps(journal["manifest"]))
    first = True
    for src, dst, nbytes in journal["moves"]:
        if loc.exists(src):
            loc.move(src, dst)
            if first:
                fault_point("commit.between_moves", round=manifest.round_index)
                first = False
        elif not (loc.exists(dst) and loc.size(dst) == nbytes):
            raise BufferIntegrityError(
                f"cannot finish the commit of round {manifest.round_index}: neither {src} nor a "
                f"{nbytes}-byte {dst} exists in {loc.url}",
                dst,
            )
    # a committed zarr group holds exactly the files of its shard
    wanted = {dst for _, dst, _ in journal["moves"]}
    for rec in manifest.shards:
        obs_dir = committed_path("obs", rec.round_index, rec.unit_index)
        for rel in loc.find(obs_dir):
            if rel not in wanted:
                loc.remove(rel)
    loc.write_bytes_atomic(manifest_path(manifest.round_index), manifest.to_json().encode())
    loc.remove(pending_path(manifest.round_index))
    for src_dir in journal.get("staging_dirs", []):
        if not loc.find(src_dir):
            loc.remove(src_dir)
    return manifest


def load_journal(loc: Location, name: str) -> dict[str, Any]:
    """The commit journal ``manifests/<name>``, checked: it parses, has a manifest and moves, and
    every move goes from ``staging/`` to ``data/`` inside the root. ``BufferIntegrityError`` naming
    the journal otherwise (a damaged journal is never rolled forward)."""
    rel = f"{MANIFESTS}/{name}"
    try:
        journal = json.loads(loc.read_bytes(rel).decode())
    except (ValueError, UnicodeDecodeError) as err:
        raise BufferIntegrityError(f"commit journal {rel} in {loc.url} is unreadable ({type(err).__name__})", rel) from None
    if not isinstance(journal, dict) or not isinstance(journal.get("manifest"), dict) or \
            not isinstance(journal.get("moves"), list):
        raise BufferIntegrityError(f"commit journal {rel} in {loc.url} lacks its manifest or moves", rel)
    for move in journal["moves"]:
        ok = (isinstance(move, list) and len(move) == 3 and all(isinstance(p, str) for p in move[:2])
              and _inside(move[0], STAGING) and _inside(move[1], DATA))
        if not ok:
            raise BufferIntegrityError(f"commit journal {rel} in {loc.url} has a move outside staging/ -> data/: "
                                       f"{str(move)[:120]}", rel)
    dirs = journal.get("staging_dirs", [])
    if not isinstance(dirs, list) or not all(isinstance(d, str) and _inside(d, STAGING) for d in dirs):
        raise BufferIntegrityError(f"commit journal {rel} in {loc.url} names staging directories outside staging/", rel)
    r = parse_pending_name(name)
    try:
        parse_manifest(json.dumps(journal["manifest"]), -1 if r is None else r)
    except ValueError as err:
        raise BufferIntegrityError(f"commit journal {rel} in {loc.url} holds a manifest that {err}", rel) from None
    return journal


def _inside(path: str, top: str) -> bool:
    parts = path.split("/")
    return parts[0] == top and len(parts) > 1 and not any(p in ("", ".", "..") for p in parts)


def pending_journals(root: "str | Location") -> list[str]:
    """File names of the commit journals under ``manifests/`` (half-done commits)."""
    return [name for name in resolve(root).listdir(MANIFESTS) if parse_pending_name(name) is not None]


def recover_pending(root: "str | Location") -> list[int]:
    """Finish every commit a crashed driver left half done; returns the rounds it finished."""
    loc = resolve(root)
    done = []
    for name in pending_journals(loc):
        journal = load_journal(loc, name)
        _roll_forward(loc, journal)
        done.append(int(journal["manifest"]["round_index"]))
    return done


def commit_round(
    root: "str | os.PathLike[str] | Location",
    round_index: int,
    shard_records: Sequence[ShardRecord],
    extra: dict | None = None,
) -> RoundManifest:
    """Commit ``shard_records`` as round ``round_index``; returns the written manifest.

    Committing the same records again returns the existing manifest; committing different records
    for an already committed round raises ``ValueError``.
    """
    loc = resolve(root)
    recover_pending(loc)
    records = sorted(shard_records, key=lambda r: r.unit_index)
    if loc.exists(manifest_path(round_index)):
        existing = load_manifest(loc, round_index)
        if _same_content(existing, records):
            return existing
        raise ValueError(f"round {round_index} is already committed in {loc.url} with other shards")
    run_id, obs_shape, obs_dtype = _validate(loc, round_index, records)
    moves = []
    committed = []
    staging_dirs = []
    for r in records:
        files = []
        for f in r.files:
            dst = _committed_file_path(r, f)
            moves.append((f.path, dst, f.nbytes))
            files.append(ShardFile(path=dst, role=f.role, nbytes=f.nbytes, sha256=f.sha256))
        staging_dirs.append(f"{staging_unit_dir(r.round_index, r.unit_index)}/{TRY_PREFIX}{r.try_id}")
        committed.append(
            ShardRecord(
                run_id=r.run_id, round_index=r.round_index, unit_index=r.unit_index, worker_id=r.worker_id,
                try_id=r.try_id, num_attempts=r.num_attempts, num_tuples=r.num_tuples,
                obs_shape=r.obs_shape, obs_dtype=r.obs_dtype, files=tuple(files),
            )
        )
    manifest = RoundManifest(
        run_id=run_id,
        round_index=round_index,
        created=datetime.now(timezone.utc).isoformat(timespec="seconds"),
        shards=tuple(committed),
        obs_shape=obs_shape,
        obs_dtype=obs_dtype,
        extra=dict(extra or {}),
    )
    mark_buffer(loc, run_id)
    journal = {"manifest": json.loads(manifest.to_json()), "moves": moves, "staging_dirs": staging_dirs}
    loc.write_bytes_atomic(pending_path(round_index), json.dumps(journal).encode())
    return _roll_forward(loc, journal)

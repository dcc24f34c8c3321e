"""Shard records (what a writer returns) and round manifests (what the driver commits)."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from typing import Any

from storage.errors import BufferIntegrityError
from storage.fs import Location, resolve
from storage.layout import BUFFER_MARKER, MANIFESTS, manifest_path, parse_manifest_name


@dataclass(frozen=True)
class ShardFile:
    """One file of a shard: ``path`` relative to the run root, its role, size and sha256."""

    path: str
    role: str  # "attempts" | "tuples" | "obs"
    nbytes: int
    sha256: str


@dataclass(frozen=True)
class ShardRecord:
    """What ``ShardWriter.write_unit`` returns and ``commit_round`` consumes.

    Before commit, ``files`` are in ``staging/``; in a manifest they are the committed ``data/`` paths.
    ``obs_shape``/``obs_dtype`` are ``None`` for a unit without attempts.
    """

    run_id: str
    round_index: int
    unit_index: int
    worker_id: str
    try_id: str
    num_attempts: int
    num_tuples: int
    obs_shape: tuple[int, ...] | None
    obs_dtype: str | None
    files: tuple[ShardFile, ...]

    @property
    def nbytes(self) -> int:
        return sum(f.nbytes for f in self.files)

    def files_of(self, role: str) -> tuple[ShardFile, ...]:
        return tuple(f for f in self.files if f.role == role)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["obs_shape"] = list(self.obs_shape) if self.obs_shape is not None else None
        d["nbytes"] = self.nbytes
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "ShardRecord":
        return cls(
            run_id=d["run_id"],
            round_index=int(d["round_index"]),
            unit_index=int(d["unit_index"]),
            worker_id=d["worker_id"],
            try_id=d["try_id"],
            num_attempts=int(d["num_attempts"]),
            num_tuples=int(d["num_tuples"]),
            obs_shape=tuple(d["obs_shape"]) if d["obs_shape"] is not None else None,
            obs_dtype=d["obs_dtype"],
            files=tuple(ShardFile(**f) for f in d["files"]),
        )


@dataclass(frozen=True)
class RoundManifest:
    """The committed content of one round. Written last, atomically: it is the commit point."""

    run_id: str
    round_index: int
    created: str
    shards: tuple[ShardRecord, ...]
    obs_shape: tuple[int, ...] | None
    obs_dtype: str | None
    extra: dict[str, Any] = field(default_factory=dict)
    format_version: int = 1

    @property
    def num_attempts(self) -> int:
        return sum(s.num_attempts for s in self.shards)

    @property
    def num_tuples(self) -> int:
        return sum(s.num_tuples for s in self.shards)

    @property
    def nbytes(self) -> int:
        return sum(s.nbytes for s in self.shards)

    def to_json(self) -> str:
        return json.dumps(
            {
                "format_version": self.format_version,
                "run_id": self.run_id,
                "round_index": self.round_index,
                "created": self.created,
                "obs_shape": list(self.obs_shape) if self.obs_shape is not None else None,
                "obs_dtype": self.obs_dtype,
                "num_attempts": self.num_attempts,
                "num_tuples": self.num_tuples,
                "nbytes": self.nbytes,
                "extra": self.extra,
                "shards": [s.to_dict() for s in self.shards],
            },
            indent=1,
            sort_keys=False,
        )

    @classmethod
    def from_json(cls, text: str) -> "RoundManifest":
        d = json.loads(text)
        return cls(
            run_id=d["run_id"],
            round_index=int(d["round_index"]),
            created=d["created"],
            shards=tuple(ShardRecord.from_dict(s) for s in d["shards"]),
            obs_shape=tuple(d["obs_shape"]) if d["obs_shape"] is not None else None,
            obs_dtype=d["obs_dtype"],
            extra=d.get("extra") or {},
            format_version=int(d.get("format_version", 1)),
        )


def committed_rounds(root: "str | Location") -> list[int]:
    """Rounds that have a committed manifest, ascending."""
    loc = resolve(root)
    rounds = (parse_manifest_name(n) for n in loc.listdir(MANIFESTS))
    return sorted(r for r in rounds if r is not None)


def load_manifest(root: "str | Location", round_index: int) -> RoundManifest:
    """The committed manifest of ``round_index`` (``FileNotFoundError`` when not committed)."""
    loc = resolve(root)
    rel = manifest_path(round_index)
    try:
        text = loc.read_bytes(rel).decode()
    except FileNotFoundError:
        raise FileNotFoundError(f"round {round_index} is not committed in {loc.url} (no {rel})") from None
    try:
        return parse_manifest(text, round_index)
    except ValueError as err:
        raise BufferIntegrityError(f"manifest {rel} in {loc.url} {err}", rel) from None


def parse_manifest(text: str, round_index: int) -> RoundManifest:
    """The manifest of ``round_index`` from its JSON; ``ValueError`` saying why it is unreadable."""
    try:
        manifest = RoundManifest.from_json(text)
    except (ValueError, KeyError, TypeError) as err:  # truncated or hand-edited JSON
        raise ValueError(f"is unreadable ({type(err).__name__}: {err})") from None
    if manifest.round_index != round_index:
        raise ValueError(f"says round {manifest.round_index}")
    return manifest


def mark_buffer(root: "str | Location", run_id: str, replace: bool = False) -> None:
    """Mark ``root`` as a gpl-dist buffer of run ``run_id`` (once; ``clean`` acts only on marked or
    committed roots). ``replace``: mark it anew when another run's marker is there (a new run in a
    buffer location that holds no committed round)."""
    loc = resolve(root)
    if not loc.exists(BUFFER_MARKER) or (replace and buffer_run_id(loc) != run_id):
        from datetime import datetime, timezone

        created = datetime.now(timezone.utc).isoformat(timespec="seconds")
        loc.write_bytes_atomic(BUFFER_MARKER, json.dumps({"format_version": 1, "run_id": run_id, "created": created}).encode())


def buffer_run_id(root: "str | Location") -> str | None:
    """The run id the buffer's marker records (the run that created the buffer), or None without a
    marker; ``BufferIntegrityError`` naming the marker when it is unreadable."""
    loc = resolve(root)
    try:
        raw = loc.read_bytes(BUFFER_MARKER)
    except FileNotFoundError:
        return None
    try:
        run_id = json.loads(raw.decode()).get("run_id")
    except (ValueError, UnicodeDecodeError, AttributeError):
        run_id = None
    if not isinstance(run_id, str) or not run_id:
        raise BufferIntegrityError(f"{BUFFER_MARKER} in {loc.url} is unreadable (no run_id)", BUFFER_MARKER)
    return run_id


def is_buffer(root: "str | Location") -> bool:
    """Whether ``root`` is a gpl-dist buffer: marked by a driver, or holding a committed manifest
    (``manifests/round-NNNNNN.json``; a ``manifests/`` folder alone is not enough)."""
    loc = resolve(root)
    return loc.exists(BUFFER_MARKER) or bool(committed_rounds(loc))

"""Where every file of a run lives. A shard's name is a fixed function of (round, unit).

::

    ROOT/
      data/attempts/round-000003/unit-00017.parquet      committed, one row per attempt
      data/tuples/round-000003/unit-00017.parquet        committed, one row per labelled state
      data/obs/round-000003/unit-00017.zarr/             committed, zarr group, array ``obs``
      manifests/round-000003.json                        the commit point, written last
      manifests/_pending-round-000003.json               commit journal (only while committing)
      staging/round-000003/unit-00017/_tmp-<try>/        a writer's try in progress
      staging/round-000003/unit-00017/try-<try>/         a finished, not yet committed try
      quarantine/round-000003/<time>/...                 a round set aside by ``verify --quarantine``
      _gpl-dist-buffer.json                              marks the root as a gpl-dist buffer
      _lease.json, _lease.lock                           who holds the root (``storage.lease``)

All paths here are relative to ROOT and use ``/``.
"""

from __future__ import annotations

import re
import uuid

DATA = "data"
STAGING = "staging"
MANIFESTS = "manifests"
QUARANTINE = "quarantine"
BUFFER_MARKER = "_gpl-dist-buffer.json"
TMP_PREFIX = "_tmp-"
TRY_PREFIX = "try-"

ATTEMPTS_FILE = "attempts.parquet"
TUPLES_FILE = "tuples.parquet"
OBS_DIR = "obs.zarr"
OBS_ARRAY = "obs"

ROLES = ("attempts", "tuples", "obs")

_MANIFEST_RE = re.compile(r"^round-(\d{6,})\.json$")
_PENDING_RE = re.compile(r"^_pending-round-(\d{6,})\.json$")
_SAFE_RE = re.compile(r"[^A-Za-z0-9_.-]+")

MAX_UNITS = 100_000
MAX_ATTEMPTS_PER_UNIT = 100_000


def round_dir(round_index: int) -> str:
    """The directory name of round ``round_index``."""
    return f"round-{round_index:06d}"


def unit_name(unit_index: int) -> str:
    """The file stem of unit ``unit_index``."""
    return f"unit-{unit_index:05d}"


def committed_path(role: str, round_index: int, unit_index: int) -> str:
    """Committed location of a shard's ``attempts``/``tuples`` parquet file or ``obs`` zarr group."""
    base = f"{DATA}/{role}/{round_dir(round_index)}/{unit_name(unit_index)}"
    if role == "obs":
        return base + ".zarr"
    if role in ("attempts", "tuples"):
        return base + ".parquet"
    raise ValueError(f"unknown role {role!r}")


def staging_unit_dir(round_index: int, unit_index: int) -> str:
    """The staging directory of one unit's tries."""
    return f"{STAGING}/{round_dir(round_index)}/{unit_name(unit_index)}"


def new_try_id(worker_id: str) -> str:
    """A fresh id for one try of a unit: sanitised worker id plus random suffix."""
    safe = _SAFE_RE.sub("_", worker_id).strip("._")[:48] or "worker"
    return f"{safe}-{uuid.uuid4().hex[:12]}"


def manifest_path(round_index: int) -> str:
    """The committed manifest of a round (the commit point)."""
    return f"{MANIFESTS}/round-{round_index:06d}.json"


def pending_path(round_index: int) -> str:
    """The commit journal of a round."""
    return f"{MANIFESTS}/_pending-round-{round_index:06d}.json"


def parse_manifest_name(name: str) -> int | None:
    """The round of a manifest file name, or None."""
    m = _MANIFEST_RE.match(name)
    return int(m.group(1)) if m else None


def parse_pending_name(name: str) -> int | None:
    """The round of a commit journal's file name, or None."""
    m = _PENDING_RE.match(name)
    return int(m.group(1)) if m else None


def parse_round_dir(name: str) -> int | None:
    """The round of a round directory's name, or None."""
    m = re.match(r"^round-(\d{6,})$", name)
    return int(m.group(1)) if m else None


def attempt_key(round_index: int, unit_index: int, seq: int) -> int:
    """Stable int64 key of an attempt: decimal ``RRRRRR UUUUU SSSSS`` (round, unit, position)."""
    if not 0 <= unit_index < MAX_UNITS:
        raise ValueError(f"unit index {unit_index} out of range [0, {MAX_UNITS})")
    if not 0 <= seq < MAX_ATTEMPTS_PER_UNIT:
        raise ValueError(f"a unit holds at most {MAX_ATTEMPTS_PER_UNIT} attempts")
    if round_index < 0 or round_index >= 900_000_000:
        raise ValueError(f"round index {round_index} out of range")
    return (round_index * MAX_UNITS + unit_index) * MAX_ATTEMPTS_PER_UNIT + seq

"""``verify_buffer``: check every committed file of a buffer against its manifest, and set bad rounds aside.

What is checked, and reported per file (``gpl-dist verify``, ``gpl-dist inspect`` and ``train
--resume`` before any new work):

* every manifest parses and names its own round;
* every file a manifest lists exists, has the recorded size and (with ``checksums``) sha256;
* no round is missing below the newest committed one, unless it was quarantined;
* no data under ``data/`` belongs to a round without a manifest, or is unlisted in its round's
  manifest (a deleted manifest would otherwise drop its round silently).

``quarantine_round`` moves a round's manifest, journal and data under ``quarantine/round-R/<time>/``
(nothing is deleted): the round is then uncommitted, and ``train --resume`` collects it again if it
comes after the last checkpoint. A commit a driver left half done with a sound journal is not a
problem: ``train --resume``, ``clean`` or the next commit finish it. ``docs/buffer.md`` (Recovering) says when to use it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from datetime import datetime, timezone

from storage.commit import load_journal, pending_journals
from storage.errors import BufferIntegrityError
from storage.fs import Location, resolve, sha256_hex
from storage.layout import (
    DATA,
    MANIFESTS,
    QUARANTINE,
    ROLES,
    TMP_PREFIX,
    manifest_path,
    parse_manifest_name,
    parse_pending_name,
    parse_round_dir,
    pending_path,
    round_dir,
)
from storage.manifest import RoundManifest, parse_manifest

#: Written under ``quarantine/round-R/<time>/`` for a round of which nothing was left.
MISSING_NOTE = "MISSING.txt"


@dataclass(frozen=True)
class Problem:
    """One thing wrong with a committed buffer: ``path`` relative to the root, the round it belongs
    to (None when unknown), its ``kind`` and a one-line ``message``.

    Kinds: ``manifest`` (unreadable), ``file`` (a listed file missing, resized or changed),
    ``unlisted`` (data under ``data/`` that no manifest lists, or of a round without one),
    ``gap`` (a round below the newest is missing), ``journal`` (a damaged commit journal).
    """

    path: str
    round_index: int | None
    kind: str
    message: str


@dataclass(frozen=True)
class VerifyReport:
    """Outcome of ``verify_buffer``.

    Attributes:
        root: the buffer's URL or path.
        rounds: committed rounds whose manifest could be read, ascending.
        quarantined: rounds set aside under ``quarantine/``.
        in_progress: rounds whose commit a driver left half done with a sound journal (``train
            --resume``, ``clean`` or the next commit finish it); not a problem.
        num_files: committed files checked.
        num_bytes: bytes read (checksums) or stat'ed.
        checksums: whether sha256 sums were compared (else sizes only).
        problems: everything found wrong, in round order.
    """

    root: str
    rounds: tuple[int, ...]
    quarantined: tuple[int, ...]
    in_progress: tuple[int, ...]
    num_files: int
    num_bytes: int
    checksums: bool
    problems: tuple[Problem, ...]

    @property
    def ok(self) -> bool:
        return not self.problems

    @property
    def bad_rounds(self) -> tuple[int, ...]:
        return tuple(sorted({p.round_index for p in self.problems if p.round_index is not None}))

    def raise_if_bad(self, hint: str) -> None:
        """``BufferIntegrityError`` naming the first problem and how many there are."""
        if self.problems:
            first = self.problems[0]
            more = f" (and {len(self.problems) - 1} more)" if len(self.problems) > 1 else ""
            raise BufferIntegrityError(f"{self.root}: {first.path}: {first.message}{more}; {hint}", first.path)


def quarantined_rounds(root: "str | os.PathLike[str] | Location") -> tuple[int, ...]:
    """Rounds set aside under ``quarantine/``, ascending."""
    loc = resolve(root)
    return tuple(sorted(r for r in map(parse_round_dir, loc.listdir(QUARANTINE)) if r is not None))


def _check_files(loc: Location, m: RoundManifest, checksums: bool) -> tuple[list[Problem], int, int]:
    problems, files, nbytes = [], 0, 0
    for shard in m.shards:
        for f in shard.files:
            files += 1
            try:
                data = loc.read_bytes(f.path) if checksums else None
                size = len(data) if data is not None else loc.size(f.path)
            except FileNotFoundError:
                problems.append(Problem(f.path, m.round_index, "file", "missing"))
                continue
            except BufferIntegrityError:  # the manifest names a path outside the root
                problems.append(Problem(f.path, m.round_index, "file", "is not a path inside the buffer"))
                continue
            nbytes += size
            if size != f.nbytes:
                problems.append(Problem(f.path, m.round_index, "file", f"has {size} bytes, the manifest says {f.nbytes}"))
            elif data is not None and sha256_hex(data) != f.sha256:
                problems.append(Problem(f.path, m.round_index, "file",
                                        "checksum mismatch (the file changed after it was committed)"))
    return problems, files, nbytes


def _unlisted_data(loc: Location, listed: set[str], committed: set[int], skip: set[int]) -> list[Problem]:
    """Data of rounds without a manifest, and files their round's manifest does not list. The data
    of ``skip`` rounds is not judged: an unreadable manifest is the problem there, and a commit in
    progress has data but no manifest yet."""
    problems: list[Problem] = []
    orphan_rounds: set[tuple[str, int]] = set()
    for role in ROLES:
        for name in loc.listdir(f"{DATA}/{role}"):
            r = parse_round_dir(name)
            rel = f"{DATA}/{role}/{name}"
            if r is None:
                problems.append(Problem(rel, None, "unlisted", "not a round directory"))
            elif r in skip:
                continue
            elif r not in committed:
                orphan_rounds.add((rel, r))
            else:
                problems.extend(Problem(p, r, "unlisted", "not listed in its round's manifest")
                                for p in loc.find(rel) if p not in listed and not os.path.basename(p).startswith(TMP_PREFIX))
    problems.extend(Problem(rel, r, "unlisted", f"committed data of round {r}, but {manifest_path(r)} is missing (deleted?)")
                    for rel, r in sorted(orphan_rounds))
    return problems


def _journals(loc: Location) -> tuple[list[int], list[Problem]]:
    """Rounds whose commit is in progress with a sound journal, and the damaged journals."""
    in_progress, problems = [], []
    for name in pending_journals(loc):
        r = parse_pending_name(name)
        try:
            load_journal(loc, name)
        except BufferIntegrityError as err:
            problems.append(Problem(f"{MANIFESTS}/{name}", r, "journal",
                                    "commit journal " + str(err).split(f" in {loc.url} ", 1)[-1]))
            continue
        if r is not None:
            in_progress.append(r)
    return in_progress, problems


def verify_buffer(root: "str | os.PathLike[str] | Location", checksums: bool = True) -> VerifyReport:
    """Check the committed part of the buffer at ``root`` (see the module docstring)."""
    loc = resolve(root)
    problems: list[Problem] = []
    rounds: list[int] = []
    listed: set[str] = set()
    files = nbytes = 0
    for name in loc.listdir(MANIFESTS):
        r = parse_manifest_name(name)
        if r is None:
            continue
        try:
            m = parse_manifest(loc.read_bytes(manifest_path(r)).decode(errors="replace"), r)
        except ValueError as err:
            problems.append(Problem(manifest_path(r), r, "manifest", f"manifest {err}"))
            continue
        rounds.append(r)
        listed.update(f.path for s in m.shards for f in s.files)
        p, n, b = _check_files(loc, m, checksums)
        problems += p
        files += n
        nbytes += b
    in_progress, journal_problems = _journals(loc)
    problems += journal_problems
    quarantined = quarantined_rounds(loc)
    unreadable = {p.round_index for p in problems if p.kind in ("manifest", "journal") and p.round_index is not None}
    problems += _unlisted_data(loc, listed, set(rounds), unreadable | set(in_progress))
    accounted = set(rounds) | unreadable | set(quarantined) | set(in_progress)
    accounted |= {p.round_index for p in problems if p.round_index is not None}
    newest = max(accounted - set(quarantined), default=-1)
    problems += [Problem(manifest_path(r), r, "gap", f"round {r} is missing (rounds 0..{newest} should be committed)")
                 for r in range(newest) if r not in accounted]
    problems.sort(key=lambda p: (p.round_index if p.round_index is not None else -1, p.path))
    return VerifyReport(root=loc.url, rounds=tuple(sorted(rounds)), quarantined=quarantined,
                        in_progress=tuple(sorted(in_progress)), num_files=files, num_bytes=nbytes, checksums=checksums,
                        problems=tuple(problems))


def quarantine_round(root: "str | os.PathLike[str] | Location", round_index: int) -> list[str]:
    """Move round ``round_index``'s manifest, commit journal and data under ``quarantine/round-R/<time>/``;
    returns what moved. A round of which nothing is left is recorded there as missing (an empty
    list is returned), so that it counts as set aside."""
    loc = resolve(root)
    # one folder per quarantine, so that setting a round aside twice never overwrites the first
    stamp = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%S%fZ")
    dest = f"{QUARANTINE}/{round_dir(round_index)}/{stamp}"
    moved = []
    sources = [manifest_path(round_index), pending_path(round_index)]
    sources += [f"{DATA}/{role}/{round_dir(round_index)}" for role in ROLES]
    for rel in sources:
        if loc.exists(rel):
            loc.move(rel, f"{dest}/{rel}")
            moved.append(rel)
    if not moved:
        loc.write_bytes_atomic(f"{dest}/{MISSING_NOTE}", b"nothing of this round was left when it was quarantined\n")
    return moved

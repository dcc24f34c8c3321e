"""``verify_buffer``: check every committed file of a buffer against its manifest, and set bad rounds aside.

What is checked, and reported per file (``gpl-dist verify``, ``gpl-dist inspect`` and ``train
--resume`` before any new work):

* every manifest parses and names its own round;
* every file a manifest lists exists, has the recorded size and (with ``checksums``) sha256;
* no round is missing below the newest committed one, unless it was quarantined;
* no data under ``data/`` belongs to a round without a manifest, or is unlisted in its round's
  manifest (a deleted manifest would otherwise drop its round silently);
* nothing in the buffer is a symbolic link (each one is named; none is followed, and checking stops
  at the first path that would pass through one);
* every manifest and every shard record in it names the buffer's own run (the run id of its marker
  ``_gpl-dist-buffer.json``, or the one the caller expects): a round copied in from another run is
  refused, naming both runs.

It needs no lease: a round whose commit completes (or starts) while it reads is seen whole or not
at all. Data of a round found without a manifest is judged only after the manifests and journals
have been listed again: a round committed meanwhile is then checked like any other, one being
committed is in progress.

``quarantine_round`` moves a round's manifest, journal and data under ``quarantine/round-R/<time>/``
(nothing is deleted): the round is then uncommitted, and ``train --resume`` collects it again if it
comes after the last checkpoint. A commit a driver left half done with a sound journal is not a
problem: ``train --resume``, ``clean`` or the next commit finish it. ``docs/buffer.md`` (Recovering) says when to use it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from datetime import datetime, timezone

from gpl_dist.faults import fault_point
from storage.commit import load_journal, pending_journals
from storage.errors import BufferIntegrityError, LinkError
from storage.fs import Location, link_error, resolve, sha256_hex
from storage.layout import (
    BUFFER_MARKER,
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
from storage.manifest import RoundManifest, buffer_run_id, parse_manifest

#: Written under ``quarantine/round-R/<time>/`` for a round of which nothing was left.
MISSING_NOTE = "MISSING.txt"


@dataclass(frozen=True)
class Problem:
    """One thing wrong with a committed buffer: ``path`` relative to the root, the round it belongs
    to (None when unknown), its ``kind`` and a one-line ``message``.

    Kinds: ``manifest`` (unreadable), ``file`` (a listed file missing, resized or changed),
    ``unlisted`` (data under ``data/`` that no manifest lists, or of a round without one),
    ``gap`` (a round below the newest is missing), ``journal`` (a damaged commit journal),
    ``foreign`` (a round or shard of another run than the buffer's), ``link`` (a symbolic link).
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
        run_id: the run the buffer's rounds must belong to (None: no marker and no manifest).
    """

    root: str
    rounds: tuple[int, ...]
    quarantined: tuple[int, ...]
    in_progress: tuple[int, ...]
    num_files: int
    num_bytes: int
    checksums: bool
    problems: tuple[Problem, ...]
    run_id: str | None = None

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
            except LinkError as err:
                problems.append(Problem(f.path, m.round_index, "file", f"passes through the symbolic link {err.path}"))
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


def _unlisted_data(loc: Location, listed: set[str], committed: set[int], skip: set[int]) -> tuple[list[Problem], set[int]]:
    """Files of committed rounds that their manifest does not list, and the rounds that have data
    but no manifest (judged by the caller once it has listed the manifests again). The data of
    ``skip`` rounds is not judged: an unreadable manifest is the problem there, and a commit in
    progress has data but no manifest yet."""
    problems: list[Problem] = []
    orphans: set[int] = set()
    for role in ROLES:
        for name in loc.listdir(f"{DATA}/{role}"):
            r = parse_round_dir(name)
            rel = f"{DATA}/{role}/{name}"
            if r is None:
                problems.append(Problem(rel, None, "unlisted", "not a round directory"))
            elif r in skip:
                continue
            elif r not in committed:
                orphans.add(r)
            else:
                problems.extend(Problem(p, r, "unlisted", "not listed in its round's manifest")
                                for p in loc.find(rel) if p not in listed and not os.path.basename(p).startswith(TMP_PREFIX))
    return problems, orphans


def _orphan_problems(loc: Location, rounds: set[int]) -> list[Problem]:
    return [Problem(f"{DATA}/{role}/{round_dir(r)}", r, "unlisted",
                    f"committed data of round {r}, but {manifest_path(r)} is missing (deleted?)")
            for r in sorted(rounds) for role in ROLES if loc.exists(f"{DATA}/{role}/{round_dir(r)}")]


def _foreign(m: RoundManifest, run_id: str | None) -> list[Problem]:
    """The manifest, or shard records in it, of another run than ``run_id``."""
    if run_id is None:
        return []
    rel = manifest_path(m.round_index)
    if m.run_id != run_id:
        return [Problem(rel, m.round_index, "foreign",
                        f"round {m.round_index} belongs to run {m.run_id[:80]}, not to this buffer's run {run_id[:80]}")]
    return [Problem(rel, m.round_index, "foreign", f"unit {s.unit_index} of round {m.round_index} belongs to run "
                    f"{s.run_id[:80]}, not to this buffer's run {run_id[:80]}")
            for s in m.shards if s.run_id != run_id]


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


def verify_buffer(root: "str | os.PathLike[str] | Location", checksums: bool = True,
                  run_id: str | None = None) -> VerifyReport:
    """Check the committed part of the buffer at ``root`` (see the module docstring). ``run_id``:
    the run its rounds must belong to (default: its marker's; a buffer without one, made before
    markers existed, is held to its first manifest's)."""
    loc = resolve(root)
    problems: list[Problem] = [_link_problem(loc, link) for link in loc.links()]
    if problems:  # named each; checking on would only meet them again
        problems.sort(key=lambda p: (p.round_index if p.round_index is not None else -1, p.path))
        return VerifyReport(root=loc.url, rounds=(), quarantined=(), in_progress=(), num_files=0, num_bytes=0,
                            checksums=checksums, problems=tuple(problems), run_id=run_id)
    rounds: list[int] = []
    listed: set[str] = set()
    files = nbytes = 0
    try:
        marked = buffer_run_id(loc)
    except BufferIntegrityError as err:
        problems.append(Problem(err.path or "", None, "manifest", str(err)))
        marked = None
    expected = run_id or marked
    if run_id is not None and marked is not None and marked != run_id:
        problems.append(Problem(BUFFER_MARKER, None, "foreign",
                                f"the buffer belongs to run {marked[:80]}, not to this run {run_id[:80]}"))

    def check(r: int) -> None:
        nonlocal files, nbytes, expected
        try:
            m = parse_manifest(loc.read_bytes(manifest_path(r)).decode(errors="replace"), r)
        except ValueError as err:
            problems.append(Problem(manifest_path(r), r, "manifest", f"manifest {err}"))
            return
        rounds.append(r)
        expected = expected or m.run_id
        problems.extend(_foreign(m, expected))
        listed.update(f.path for s in m.shards for f in s.files)
        p, n, b = _check_files(loc, m, checksums)
        problems.extend(p)
        files += n
        nbytes += b

    for name in loc.listdir(MANIFESTS):
        r = parse_manifest_name(name)
        if r is not None:
            check(r)
    in_progress, journal_problems = _journals(loc)
    problems += journal_problems
    fault_point("verify.between_listings")
    quarantined = quarantined_rounds(loc)
    unreadable = {p.round_index for p in problems if p.kind in ("manifest", "journal") and p.round_index is not None}
    unlisted, orphans = _unlisted_data(loc, listed, set(rounds), unreadable | set(in_progress))
    problems += unlisted
    if orphans:  # list again: a round committed, or being committed, since the first listing is no orphan
        now_pending = {parse_pending_name(n) for n in pending_journals(loc)}
        for r in sorted(orphans):
            if loc.exists(manifest_path(r)):
                check(r)
            elif r in now_pending:
                in_progress.append(r)
            elif loc.exists(manifest_path(r)):  # committed between the two looks
                check(r)
            else:
                continue
            orphans.discard(r)
        problems += _orphan_problems(loc, orphans)
    for r in [r for r in in_progress if r not in rounds and loc.exists(manifest_path(r))
              and not loc.exists(pending_path(r))]:  # finished since its journal was listed
        in_progress.remove(r)
        check(r)
    accounted = set(rounds) | unreadable | set(quarantined) | set(in_progress)
    accounted |= {p.round_index for p in problems if p.round_index is not None}
    newest = max(accounted - set(quarantined), default=-1)
    problems += [Problem(manifest_path(r), r, "gap", f"round {r} is missing (rounds 0..{newest} should be committed)")
                 for r in range(newest) if r not in accounted]
    problems.sort(key=lambda p: (p.round_index if p.round_index is not None else -1, p.path))
    return VerifyReport(root=loc.url, rounds=tuple(sorted(rounds)), quarantined=quarantined,
                        in_progress=tuple(sorted(in_progress)), num_files=files, num_bytes=nbytes, checksums=checksums,
                        problems=tuple(problems), run_id=expected)


def _link_problem(loc: Location, link: str) -> Problem:
    rounds = [r for r in map(parse_round_dir, link.split("/")) if r is not None]
    if not rounds and link.startswith(f"{MANIFESTS}/"):
        name = link.split("/")[1]
        rounds = [r for r in (parse_manifest_name(name), parse_pending_name(name)) if r is not None]
    message = str(link_error(loc, link)).split(f" in {loc.url} ", 1)[-1]
    return Problem(link, rounds[0] if rounds else None, "link", message)


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

"""``clean_leftovers``: remove what dead writers and superseded tries left behind.

Acts only on a gpl-dist buffer (a root that a driver marked, or that holds committed manifests),
only while no driver holds it (``clean`` takes the buffer's lease for its duration, so no run can
start meanwhile either), and never on committed data: it removes staging tries and ``_tmp-``
files, nothing under ``data/``. A symbolic link anywhere it would look (a run dir copied or moved
with links in it) makes it refuse in one line, before anything is removed. Data under ``data/``
that no manifest lists (a deleted manifest) is reported by ``gpl-dist verify``, not removed.
"""

from __future__ import annotations

import os
import time

from gpl_dist.errors import RunDirError
from storage.commit import load_journal, pending_journals, recover_pending
from storage.fs import Location, link_error, resolve
from storage.layout import BUFFER_MARKER, MANIFESTS, STAGING, TMP_PREFIX, parse_round_dir
from storage.lease import Lease, lease_holder
from storage.manifest import committed_rounds, is_buffer


def clean_leftovers(root: "str | os.PathLike[str] | Location", dry_run: bool = False, min_age_s: float = 0.0) -> list[str]:
    """Remove leftovers under ``root``; returns their paths (relative to the root), sorted.

    Leftovers: every staging try (``_tmp-*`` in progress or dead, ``try-*`` superseded or never
    committed) and ``_tmp-*`` manifests. Staging of rounds newer than the last committed one is kept
    while younger than ``min_age_s`` seconds. With ``dry_run`` nothing is changed (half-done
    commits are not rolled forward either, and their files are not reported).

    Raises ``RunDirError`` when ``root`` is not a gpl-dist buffer or a process holds its lease.
    """
    loc = resolve(root)
    if not is_buffer(loc):
        raise RunDirError(f"{loc.url} is not a gpl-dist buffer (no {BUFFER_MARKER}, no committed manifest); nothing removed")
    _refuse_links(loc)
    if dry_run:
        holder = lease_holder(loc)
        if holder is not None:
            raise RunDirError(f"{loc.url} is in use by {holder.describe()}; nothing to clean while it runs")
        return _leftovers(loc, _pending_files(loc), min_age_s)
    with Lease(loc, "gpl-dist clean"):
        recover_pending(loc)
        out = _leftovers(loc, set(), min_age_s)
        for rel in out:
            loc.remove(rel)
        loc.remove_empty_dirs(STAGING)
    return out


def _refuse_links(loc: Location) -> None:
    """``LinkError`` naming the first symbolic link where ``clean`` would list or remove (staging,
    manifests): nothing is removed through a link, nor the link itself."""
    links = [link for top in (STAGING, MANIFESTS) for link in loc.links(top)]
    if links:
        more = f" (and {len(links) - 1} more)" if len(links) > 1 else ""
        err = link_error(loc, links[0])
        raise type(err)(f"{err}{more}; nothing removed", links[0])


def _pending_files(loc: Location) -> set[str]:
    """Files named by commit journals (a dry run leaves them where they are)."""
    files: set[str] = set()
    for name in pending_journals(loc):
        journal = load_journal(loc, name)
        files.update(dst for _, dst, _ in journal["moves"])
        files.update(src for src, _, _ in journal["moves"])
    return files


def _leftovers(loc: Location, pending_files: set[str], min_age_s: float) -> list[str]:
    rounds = committed_rounds(loc)
    last = rounds[-1] if rounds else -1
    out: list[str] = []
    now = time.time()
    for rdir in loc.listdir(STAGING):
        r = parse_round_dir(rdir)
        for udir in loc.listdir(f"{STAGING}/{rdir}"):
            for tdir in loc.listdir(f"{STAGING}/{rdir}/{udir}"):
                rel = f"{STAGING}/{rdir}/{udir}/{tdir}"
                files = loc.find(rel)
                if r is not None and r > last and min_age_s > 0:
                    newest = max((m for m in (loc.mtime(f) for f in files or [rel]) if m is not None), default=None)
                    if newest is not None and now - newest < min_age_s:
                        continue
                if any(f in pending_files for f in files):
                    continue
                out.append(rel)
    out.extend(f"{MANIFESTS}/{name}" for name in loc.listdir(MANIFESTS) if name.startswith(TMP_PREFIX))
    return sorted(out)

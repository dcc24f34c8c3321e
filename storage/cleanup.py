"""``clean_leftovers``: remove what dead writers and superseded tries left behind.

Never touches committed data: a file under ``data/`` is removed only when no committed manifest
lists it (after any half-done commit has been rolled forward).
"""

from __future__ import annotations

import os
import time

from storage.commit import recover_pending
from storage.fs import Location, resolve
from storage.layout import DATA, MANIFESTS, STAGING, TMP_PREFIX, parse_pending_name, parse_round_dir
from storage.manifest import committed_rounds, load_manifest


def clean_leftovers(root: "str | os.PathLike[str] | Location", dry_run: bool = False, min_age_s: float = 0.0) -> list[str]:
    """Remove leftovers under ``root``; returns their paths (relative to the root), sorted.

    Leftovers: every staging try (``_tmp-*`` in progress or dead, ``try-*`` superseded or never
    committed), ``_tmp-*`` files, and files under ``data/`` that no committed manifest lists.
    Staging of rounds newer than the last committed one is kept while younger than ``min_age_s``
    seconds (pass e.g. 3600 while writers of the next round may be running; the default 0 is for a
    stopped run). With ``dry_run`` nothing is changed (half-done commits are not rolled forward
    either, and their files are not reported).
    """
    loc = resolve(root)
    pending_files: set[str] = set()
    if dry_run:
        import json

        for name in loc.listdir(MANIFESTS):
            if parse_pending_name(name) is not None:
                j = json.loads(loc.read_bytes(f"{MANIFESTS}/{name}").decode())
                pending_files.update(dst for _, dst, _ in j["moves"])
                pending_files.update(src for src, _, _ in j["moves"])
    else:
        recover_pending(loc)
    rounds = committed_rounds(loc)
    last = rounds[-1] if rounds else -1
    committed: set[str] = set()
    for r in rounds:
        for shard in load_manifest(loc, r).shards:
            committed.update(f.path for f in shard.files)

    out: list[str] = []
    for rel in loc.find(DATA):
        if rel not in committed and rel not in pending_files:
            out.append(rel)
    now = time.time()
    for rdir in loc.listdir(STAGING):
        r = parse_round_dir(rdir)
        for udir in loc.listdir(f"{STAGING}/{rdir}"):
            for tdir in loc.listdir(f"{STAGING}/{rdir}/{udir}"):
                rel = f"{STAGING}/{rdir}/{udir}/{tdir}"
                if r is not None and r > last and min_age_s > 0:
                    mtimes = [loc.mtime(f) for f in loc.find(rel)] or [loc.mtime(rel)]
                    newest = max((m for m in mtimes if m is not None), default=None)
                    if newest is not None and now - newest < min_age_s:
                        continue
                if any(f in pending_files for f in loc.find(rel)):
                    continue
                out.append(rel)
    for name in loc.listdir(MANIFESTS):
        if name.startswith(TMP_PREFIX):
            out.append(f"{MANIFESTS}/{name}")
    out.sort()
    if not dry_run:
        for rel in out:
            loc.remove(rel)
        loc.remove_empty_dirs(DATA)
        loc.remove_empty_dirs(STAGING)
    return out

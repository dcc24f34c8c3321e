"""Versioned task splits, stored as JSON files in ``gpl_dist/splits/`` next to this module.

Each file maps a split name to a sorted list of task ids. The files are generated once by a fixed
function of a seed (each domain's ``make_splits``) and committed; a test checks that the files
still equal that function's output, so a split can never drift silently.
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

from gpl_dist.errors import UsageError

_DIR = Path(__file__).with_name("splits")


def load_splits(domain: str) -> dict[str, tuple[int, ...]]:
    """All splits of ``domain``: name -> task ids (given inline by its ``DomainSpec``, or its file)."""
    from gpl_dist.domains import get_domain

    inline = get_domain(domain).splits
    if inline is not None:
        return {name: tuple(int(i) for i in ids) for name, ids in inline.items()}
    return _load_split_file(domain)


@lru_cache(maxsize=None)
def _load_split_file(domain: str) -> dict[str, tuple[int, ...]]:
    """The ``splits`` of the domain's file. The files ship with the code and are read by the code
    they ship with (a test checks each equals its domain's ``make_splits``), so a file of another
    shape is never read: its ``version`` counts changes of its contents and is not read."""
    path = _DIR / f"{domain}.json"
    if not path.is_file():
        raise FileNotFoundError(f"no split file for domain '{domain}' at {path}")
    raw = json.loads(path.read_text())
    return {name: tuple(int(i) for i in ids) for name, ids in raw["splits"].items()}


def split_tasks(domain: str, split: str) -> tuple[int, ...]:
    """Task ids of ``split`` in ``domain``; an unknown split name fails naming the known ones."""
    splits = load_splits(domain)
    if split not in splits:
        raise UsageError(f"unknown split '{split}' for {domain} (known: {', '.join(sorted(splits))})")
    return splits[split]


def valid_split(domain: str, train_split: str) -> str | None:
    """The split runs trained on ``train_split`` are chosen on (``DomainSpec.valid_splits``);
    None when that training split has none."""
    from gpl_dist.domains import get_domain

    return get_domain(domain).valid_splits.get(train_split)


def split_of(domain: str, task_id: int, preferred: tuple[str, ...] = ("train", "test")) -> str:
    """Name of the first split among ``preferred`` that holds ``task_id`` (``"none"`` otherwise)."""
    splits = load_splits(domain)
    for name in preferred:
        if task_id in set(splits.get(name, ())):
            return name
    return "none"


def write_splits(domain: str, splits: dict[str, list[int]], seed: int, note: str, version: int = 1) -> Path:
    """Write a domain's split file (used by the domain's generator, then committed); ``version``
    counts changes of the file's contents (a split added)."""
    path = _DIR / f"{domain}.json"
    payload = {"domain": domain, "seed": seed, "note": note, **({"version": version} if version > 1 else {}),
               "splits": {k: sorted(int(i) for i in v) for k, v in splits.items()}}
    path.write_text(json.dumps(payload, indent=1) + "\n")
    _load_split_file.cache_clear()
    return path

"""Which code made a suite's files: the git commit this process runs, recorded in every run's
``suite-run.json`` and every RL result."""

from __future__ import annotations

import functools
import os
import subprocess
from pathlib import Path


@functools.cache
def code_commit() -> str:
    """The git commit of the code this process runs, read once, when first asked (``run_suite``
    asks before any run: a commit made while a suite runs does not relabel its runs), with
    ``+dirty`` when tracked files differ; ``$GPL_DIST_COMMIT`` where the code came without its
    ``.git`` (a Ray job's upload); else ``unknown``."""
    if os.environ.get("GPL_DIST_COMMIT"):
        return os.environ["GPL_DIST_COMMIT"][:64]
    here = Path(__file__).resolve().parent
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=here, capture_output=True, text=True,
                              timeout=10, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=here,
                               capture_output=True, text=True, timeout=10, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return head + ("+dirty" if dirty else "")

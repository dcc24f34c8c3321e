"""``gpl-dist train`` on the cluster this script runs on (for ``ray submit configs/cluster.yaml``).

``ray submit configs/cluster.yaml scripts/cluster_train.py -- --config configs/multiroom.yaml
--run-dir /mnt/shared/runs/mr`` runs it on the head node; it joins the running cluster
(``--address auto``) and passes every other argument to ``gpl-dist train``. Relative paths are
resolved against the repository copy that ``file_mounts`` put at ``~/gpl-dist``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

REPO = Path(os.environ.get("GPL_DIST_REPO", Path.home() / "gpl-dist"))


def main(argv: list[str]) -> int:
    if REPO.is_dir():
        os.chdir(REPO)
    from gpl_dist.cli import main as gpl_dist_main

    args = list(argv)
    if "--address" not in args:
        args += ["--address", "auto"]
    return gpl_dist_main(["train", *args])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

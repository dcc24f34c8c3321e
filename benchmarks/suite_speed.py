"""K seeds of an entry one after another against the same K seeds at once, side by side in one run.

    python benchmarks/suite_speed.py [--config configs/multiroom-smoke.yaml] [--seeds 5]
        [--set training.num_rounds=2 ...] [--repeats 1]

Rows:
- one seed alone: ``gpl-dist train`` with the config's own workers on a local Ray cluster (what
  one run costs on this machine);
- one after another: K such runs, back to back (today's ``suite run --one-at-a-time``);
- at once: ``gpl-dist train --seeds 0..K-1`` (``gpl_dist.app.suite.cluster.local_plan``: as many
  runs at once as cores, each with the cores left to it as rollout actors).

Each is a whole process, timed from start to exit (Ray's start-up included, as a user waits for
it), into a fresh folder. It then checks that every run at once equals its run alone (buffer
content, metrics, weights). Run it alone on the machine: the figures are the whole machine's.

Target (issue): K = 5 seeds at once in at most 3x the wall time of one seed alone on 2 cores.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
GPL_DIST = str(Path(sys.executable).parent / "gpl-dist")


def _train(args: list[str]) -> float:
    env = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", RAY_USAGE_STATS_ENABLED="0")
    t0 = time.perf_counter()
    done = subprocess.run([GPL_DIST, "train", "--no-progress", *args], capture_output=True, text=True, env=env)
    seconds = time.perf_counter() - t0
    if done.returncode != 0:
        raise SystemExit(f"gpl-dist train {' '.join(args)} failed:\n{done.stderr[-3000:]}")
    return seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--config", default=str(REPO / "configs" / "multiroom-smoke.yaml"))
    parser.add_argument("--seeds", type=int, default=5, help="K: the seeds of the entry")
    parser.add_argument("--set", action="append", default=["training.num_rounds=2"], metavar="KEY=VALUE")
    parser.add_argument("--repeats", type=int, default=1)
    args = parser.parse_args()
    sets = [a for kv in args.set for a in ("--set", kv)]
    sys.path.insert(0, str(REPO / "tests"))
    from test_at_once import _fingerprint, _same  # the equality the tests check

    rows: dict[str, list[float]] = {"one seed alone": [], "one after another": [], "at once": []}
    for _ in range(args.repeats):
        with tempfile.TemporaryDirectory(prefix="suite-speed-") as tmp:
            t = Path(tmp)
            alone = [_train(["--config", args.config, "--run-dir", str(t / f"alone{s}"), *sets, "--set", f"seed={s}"])
                     for s in range(args.seeds)]
            rows["one seed alone"].append(alone[0])
            rows["one after another"].append(sum(alone))
            seeds = ",".join(str(s) for s in range(args.seeds))
            rows["at once"].append(_train(["--config", args.config, "--run-dir", str(t / "at-once"), "--seeds", seeds,
                                           *sets]))
            unequal = [s for s in range(args.seeds)
                       if not _same(_fingerprint(t / "at-once" / f"seed{s}"), _fingerprint(t / f"alone{s}"))]
            if unequal:
                raise SystemExit(f"seeds {unequal}: at once differs from alone")
    one = min(rows["one seed alone"])
    print(f"{args.seeds} seeds of {Path(args.config).name} ({' '.join(args.set)}), {os.cpu_count()} cores; "
          f"min of {args.repeats}; every run at once equals its run alone")
    for name, values in rows.items():
        print(f"  {name:18s} {min(values):8.1f} s   {min(values) / one:5.2f}x one seed alone")
    print(f"  at once / one after another: {min(rows['at once']) / min(rows['one after another']):.2f}")


if __name__ == "__main__":
    main()

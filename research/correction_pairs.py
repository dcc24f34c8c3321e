"""Which pairs of corrections does a trained multi-room policy combine? Rolls a run's policy out on
the test tasks (evaluation seed 0, two corrections) and groups the tasks by the kinds of their first
two corrections ("enter room + enter room": the object's room, then the goal's), printing the mean
completion after one and after two corrections per group:

    .venv/bin/python research/correction_pairs.py RUN_DIR [RUN_DIR ...]

Made to explain Table 2's no-trajectory ablation (``docs/results.md``).
"""

from __future__ import annotations

import argparse
import collections
import re

from gpl_dist.splits import split_tasks
from learner.evaluate import load_trained_policy, meta_test_rollout


def correction_kind(text: str) -> str:
    """A correction without its colours and shapes: "enter the red room" -> "enter room"."""
    return re.sub(r"the \w+ (\w+ )?", "", text).strip()


def by_correction_pair(run_dir: str, seed: int = 0) -> dict[str, list[tuple[float, float]]]:
    """Correction-kind pair -> (completion after 1, after 2 corrections) of each test task."""
    cfg, model, _ = load_trained_policy(run_dir)
    model.eval()
    attempts = meta_test_rollout(cfg, model).run(split_tasks("multiroom", "test"), 2, seed, split="test").attempts
    per_task: dict[int, dict] = collections.defaultdict(dict)
    for a in attempts:
        per_task[a.task_id][a.attempt_index] = a
    groups: dict[str, list[tuple[float, float]]] = collections.defaultdict(list)
    for d in per_task.values():
        if 2 in d:  # solved before the second correction otherwise
            key = f"{correction_kind(d[0].correction)} + {correction_kind(d[1].correction)}"
            groups[key].append((d[1].completion, d[2].completion))
    return groups


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dirs", nargs="+")
    for run_dir in parser.parse_args().run_dirs:
        print(run_dir)
        for key, pairs in sorted(by_correction_pair(run_dir).items(), key=lambda kv: -len(kv[1])):
            after1, after2 = (sum(p[i] for p in pairs) / len(pairs) for i in (0, 1))
            print(f"  {key:40s} tasks {len(pairs):3d}  after 1: {after1:.3f}  after 2: {after2:.3f}")


if __name__ == "__main__":
    main()

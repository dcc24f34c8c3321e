"""Writes the versioned task table and splits, ``gpl_babyai/splits/babyai.json``.

    python -m gpl_babyai.generate            # rewrite the file (about 2 minutes on one core)
    python -m gpl_babyai.generate --check    # regenerate in memory and compare with the file

``make_table(seed)`` is a fixed function of its seed and of minigrid's level generators (the file
records the minigrid version it was made with):

- levels: ``TRAIN_LEVELS`` (trained on, and tested on other seeds of) and ``HELDOUT_LEVELS``
  (never trained on; their tasks are only in ``heldout_level_test``);
- candidate seeds of a level are 0, 1, 2, ... in order; a seed becomes a task when the BabyAI bot
  solves it from its start within ``BOT_STEP_CAP`` steps (the attempt is ``env.STEPS``: the
  rest is the margin a learner's detours need; minigrid's bot also spins forever on a few seeds,
  ``bot.PlanLoop``) and its mission has at most ``MAX_WORDS`` words; the first
  ``TRAIN + VALID + TEST`` accepted seeds of a trained level (``HELDOUT`` of a held-out one) are
  kept, and per level a seeded permutation deals them to ``train``, ``valid`` and ``test``: the
  splits never share a seed (nor a task);
- per-level test splits ``test_<Level>`` (the level's ``test`` tasks) and ``heldout_<Level>``
  let ``gpl-dist eval --split ...`` report one level at a time;
- the four mixed splits (``train``, ``valid``, ``test``, ``heldout_level_test``) list their
  tasks round-robin over the levels (the first task of each level, then the second, ...): gpl-dist
  takes a split's first N tasks for ``env.max_train_tasks`` and ``eval.max_tasks``, and those then
  span every level; the per-level splits are sorted;
- task ids run level by level, seeds ascending within a level;
- fresh tasks: per level, the first ``FRESH`` accepted seeds from ``FRESH_SEED_START`` on (far
  beyond every seed the splits above considered), by the same acceptance rule, in
  ``fresh_test`` (trained levels) and ``fresh_heldout_level_test`` (held-out levels): missions
  drawn from the level generators that no split above holds. Their rows follow every other row,
  so the ids above do not depend on them.
"""

from __future__ import annotations

import argparse
import json
import sys

import minigrid
import numpy as np

from gpl_babyai.plan import PlanError, compute_plan
from gpl_babyai.tasks import SPLIT_FILE

#: Levels trained on, from BabyAI's easiest to a long-horizon one (GoToSeq: up to four "go to" clauses).
TRAIN_LEVELS = ("GoToLocal", "PickupLoc", "PutNextLocal", "GoTo", "Pickup", "Open", "Unlock", "SynthLoc", "GoToSeq")
#: Levels never trained on: compositions of the trained skills (every clause kind, sequences,
#: locations, locked rooms), in a smaller maze (MiniBossLevel: 2x2 rooms of 5x5) and in BabyAI's
#: hardest level.
HELDOUT_LEVELS = ("MiniBossLevel", "BossLevel")
TRAIN, VALID, TEST, HELDOUT = 80, 20, 30, 50
#: A seed is a task only if the bot solves it from its start within this many steps.
BOT_STEP_CAP = 96
#: ... and its mission has at most this many words (the vocabulary's ``max_tokens``).
MAX_WORDS = 40
#: Fresh tasks per level, from seed ``FRESH_SEED_START`` on.
FRESH, FRESH_SEED_START = 20, 1_000_000
VERSION = 2


def _accepted(level: str, count: int, log, start: int = 0) -> tuple[list[tuple[int, str, int]], dict]:
    """The first ``count`` accepted seeds of ``level`` from ``start`` on: ``[(seed, mission, bot steps)]``,
    and why others were not."""
    from gpl_babyai.level import LevelCore
    from gpl_dist.language import split_words

    core = LevelCore(level)
    out, rejected, seed = [], {"bot failed": 0, "bot too long": 0, "mission too long": 0}, start
    while len(out) < count:
        core.generate(seed)
        mission = core.mission
        try:
            _, steps = compute_plan(level, seed)
        except PlanError:
            rejected["bot failed"] += 1
        else:
            if steps > BOT_STEP_CAP:
                rejected["bot too long"] += 1
            elif len(split_words(mission)) > MAX_WORDS:
                rejected["mission too long"] += 1
            else:
                out.append((seed, mission, steps))
        seed += 1
    log(f"{level}: {count} tasks from seeds {start}..{seed - 1} (rejected: {rejected})")
    return out, {"candidates": seed - start, **rejected}


def make_table(seed: int = 0, log=lambda s: None) -> dict:
    """The task table and splits (see the module docstring)."""
    levels = TRAIN_LEVELS + HELDOUT_LEVELS
    tasks: list[list] = []
    splits: dict[str, list[int]] = {"train": [], "valid": [], "test": [], "heldout_level_test": []}
    per_level: dict[str, list[int]] = {}
    stats = {}
    for index, level in enumerate(levels):
        held_out = level in HELDOUT_LEVELS
        accepted, stats[level] = _accepted(level, HELDOUT if held_out else TRAIN + VALID + TEST, log)
        first = len(tasks)
        tasks += [[index, s, mission, steps] for s, mission, steps in accepted]
        ids = list(range(first, len(tasks)))
        if held_out:
            splits["heldout_level_test"] += ids
            per_level[f"heldout_{level}"] = ids
            continue
        order = np.random.default_rng([seed, index]).permutation(len(ids))
        dealt = [ids[i] for i in order]
        splits["train"] += dealt[:TRAIN]
        splits["valid"] += dealt[TRAIN:TRAIN + VALID]
        splits["test"] += dealt[TRAIN + VALID:]
        per_level[f"test_{level}"] = dealt[TRAIN + VALID:]
    fresh: dict[str, list[int]] = {"fresh_test": [], "fresh_heldout_level_test": []}
    fresh_stats = {}
    for index, level in enumerate(levels):
        accepted, fresh_stats[level] = _accepted(level, FRESH, log, start=FRESH_SEED_START)
        first = len(tasks)
        tasks += [[index, s, mission, steps] for s, mission, steps in accepted]
        fresh["fresh_heldout_level_test" if level in HELDOUT_LEVELS else "fresh_test"] += range(first, len(tasks))
    splits = {name: _round_robin(ids, tasks) for name, ids in splits.items()}
    splits.update({name: sorted(ids) for name, ids in per_level.items()})
    splits.update({name: _round_robin(ids, tasks) for name, ids in fresh.items()})
    return {
        "domain": "babyai", "version": VERSION, "seed": seed, "minigrid": minigrid.__version__,
        "note": (f"gpl_babyai.generate.make_table({seed}): per trained level {TRAIN}/{VALID}/{TEST} train/valid/test "
                 f"tasks, per held-out level {HELDOUT} (heldout_level_test); a seed is a task when minigrid's BabyAI "
                 f"bot solves it from its start in at most {BOT_STEP_CAP} steps and its mission has at most "
                 f"{MAX_WORDS} words; the mixed splits list their tasks round-robin over the levels, the per-level "
                 "splits (test_<Level>, heldout_<Level>) are sorted; fresh_test and fresh_heldout_level_test: "
                 f"per level the first {FRESH} accepted seeds from {FRESH_SEED_START} on, rows after all others; "
                 "task rows: [level index, seed, mission, bot steps]"),
        "levels": list(levels),
        "acceptance": stats,
        "fresh_acceptance": fresh_stats,
        "tasks": tasks,
        "splits": {k: [int(t) for t in v] for k, v in splits.items()},
    }


def _round_robin(ids: list[int], tasks: list[list]) -> list[int]:
    """``ids`` ordered level by level in turn: each level's first (lowest) task, then each one's second, ..."""
    by_level: dict[int, list[int]] = {}
    for t in sorted(ids):
        by_level.setdefault(tasks[t][0], []).append(t)
    columns = [by_level[level] for level in sorted(by_level)]
    return [col[i] for i in range(max(map(len, columns))) for col in columns if i < len(col)]


def _dump(table: dict) -> str:
    head = {k: v for k, v in table.items() if k not in ("tasks", "splits")}
    lines = json.dumps(head, indent=1)[:-2] + ",\n \"tasks\": [\n"
    lines += ",\n".join("  " + json.dumps(row) for row in table["tasks"]) + "\n ],\n \"splits\": {\n"
    lines += ",\n".join(f"  {json.dumps(k)}: {json.dumps(v)}" for k, v in table["splits"].items()) + "\n }\n}\n"
    return lines


def main(argv: list[str] | None = None) -> int:
    """Write the split file (``--check``: compare instead)."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--check", action="store_true", help="compare a fresh table with the file instead of writing it")
    args = p.parse_args(argv)
    table = make_table(0, log=lambda s: print(s, flush=True))
    text = _dump(table)
    if args.check:
        same = SPLIT_FILE.read_text() == text
        print("the split file equals make_table(0)" if same else "the split file DIFFERS from make_table(0)")
        return 0 if same else 1
    SPLIT_FILE.parent.mkdir(exist_ok=True)
    SPLIT_FILE.write_text(text)
    print(f"wrote {SPLIT_FILE}: {len(table['tasks'])} tasks")
    return 0


if __name__ == "__main__":
    sys.exit(main())

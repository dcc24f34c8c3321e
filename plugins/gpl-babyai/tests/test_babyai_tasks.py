"""The task table and its splits (versioned in the plug-in), and the vocabulary's coverage of
BabyAI's grammar."""

from __future__ import annotations

import numpy as np
from minigrid.core.constants import COLOR_NAMES
from minigrid.envs.babyai.core.verifier import LOC_NAMES, OBJ_TYPES

from gpl_babyai import generate
from gpl_babyai import tasks as task_table
from gpl_babyai.coverage import coverage
from gpl_babyai.domain import DOMAIN, STEPS, VOCABULARY
from gpl_babyai.level import LevelCore
from gpl_babyai.plan import compute_plan
from gpl_dist.domains import get_domain
from gpl_dist.language import split_words
from gpl_dist.splits import load_splits


def test_the_domain_is_found_through_its_entry_point():
    spec = get_domain("babyai")
    assert spec is DOMAIN and spec.num_tasks == len(task_table.tasks()) == 1490
    assert load_splits("babyai") == task_table.splits()


def test_levels_and_split_sizes():
    table = task_table.table()
    assert table["levels"] == list(generate.TRAIN_LEVELS + generate.HELDOUT_LEVELS)
    assert {"GoToLocal", "PickupLoc", "PutNextLocal", "GoTo", "Pickup", "Open", "Unlock", "SynthLoc"} <= set(table["levels"])
    assert "GoToSeq" in generate.TRAIN_LEVELS and "BossLevel" in generate.HELDOUT_LEVELS
    splits = task_table.splits()
    fresh = set(splits["fresh_test"]) | set(splits["fresh_heldout_level_test"])
    for level in generate.TRAIN_LEVELS:
        ids = set(task_table.tasks_of_level(level)) - fresh
        assert [len(ids & set(splits[s])) for s in ("train", "valid", "test")] == [generate.TRAIN, generate.VALID, generate.TEST]
        assert sorted(ids & set(splits["test"])) == list(splits[f"test_{level}"])
    for level in generate.HELDOUT_LEVELS:
        ids = set(task_table.tasks_of_level(level)) - fresh
        assert ids == set(splits[f"heldout_{level}"]) and ids <= set(splits["heldout_level_test"])
        assert not ids & (set(splits["train"]) | set(splits["valid"]) | set(splits["test"]))


def test_splits_use_disjoint_seeds_and_never_train_on_a_test_task():
    splits = task_table.splits()
    seeds = {name: {(task_table.task(t).level, task_table.task(t).seed) for t in splits[name]}
             for name in ("train", "valid", "test", "heldout_level_test", "fresh_test", "fresh_heldout_level_test")}
    names = list(seeds)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            assert not seeds[a] & seeds[b], (a, b)
    assert len({(t.level, t.seed) for t in task_table.tasks()}) == len(task_table.tasks())
    assert DOMAIN.valid_splits == {"train": "valid"} and (DOMAIN.train_split, DOMAIN.eval_split) == ("train", "test")


def test_fresh_tasks_are_seeds_no_other_split_considered_and_follow_every_other_row():
    """``fresh_test`` / ``fresh_heldout_level_test``: per level ``FRESH`` seeds from ``FRESH_SEED_START``
    on, above every candidate seed the other splits looked at; their rows come last, so the other
    splits' task ids are those of a table without them."""
    table, splits = task_table.table(), task_table.splits()
    fresh = set(splits["fresh_test"]) | set(splits["fresh_heldout_level_test"])
    others = set().union(*(set(ids) for name, ids in splits.items() if not name.startswith("fresh_")))
    assert min(fresh) == max(others) + 1 and max(fresh) == len(task_table.tasks()) - 1
    for level in generate.TRAIN_LEVELS + generate.HELDOUT_LEVELS:
        name = "fresh_heldout_level_test" if level in generate.HELDOUT_LEVELS else "fresh_test"
        rows = [task_table.task(t) for t in splits[name] if task_table.task(t).level == level]
        assert len(rows) == generate.FRESH
        assert min(r.seed for r in rows) >= generate.FRESH_SEED_START > table["acceptance"][level]["candidates"]
        stats = table["fresh_acceptance"][level]
        assert stats["candidates"] == generate.FRESH + sum(n for k, n in stats.items() if k != "candidates")


def test_mixed_splits_take_every_level_in_turn():
    """gpl-dist takes a split's first N tasks (env.max_train_tasks, eval.max_tasks): any 9 in a row span the 9 levels."""
    for name, levels in (("train", generate.TRAIN_LEVELS), ("test", generate.TRAIN_LEVELS),
                         ("fresh_test", generate.TRAIN_LEVELS), ("fresh_heldout_level_test", generate.HELDOUT_LEVELS)):
        order = [task_table.task(t).level for t in task_table.splits()[name]]
        for start in range(0, len(order), len(levels)):
            assert sorted(order[start:start + len(levels)]) == sorted(levels)


def test_the_table_regenerates_on_a_sample_of_tasks():
    """A sample of rows equals what minigrid's generator and bot give now (the full check:
    ``python -m gpl_babyai.generate --check``, about a minute)."""
    rows = task_table.tasks()
    for task_id in np.linspace(0, len(rows) - 1, 25).round().astype(int):
        row = rows[task_id]
        core = LevelCore(row.level)
        core.generate(row.seed)
        _, steps = compute_plan(row.level, row.seed)
        assert (core.mission, steps) == (row.mission, row.bot_steps)
        assert steps <= generate.BOT_STEP_CAP < STEPS


def test_the_vocabulary_covers_babyais_grammar():
    """Every word minigrid's verifier can say (colours, object types, locations, clause and sequence
    words) and every word of 20 missions of each of the 96 BabyAI levels; the 100k-mission run is
    ``python -m gpl_babyai.coverage`` (minutes), whose result the README records."""
    locations = {w for loc in LOC_NAMES for w in ("in front of you behind you on your " + loc).split()}
    grammar = set(COLOR_NAMES) | set(OBJ_TYPES) | locations
    grammar |= set("go to pick up open put next to the a object and then after you".split())
    assert grammar <= set(VOCABULARY.words)
    out = coverage(20 * 96)
    assert out["missions"] == 20 * 96 and out["levels"] == 96
    assert not out["unknown"], out["unknown"]
    assert set(out["words"]) <= set(VOCABULARY.words)


def test_every_task_instruction_fits_the_vocabulary():
    for task in task_table.tasks():
        words = split_words(task.mission)
        assert len(words) <= VOCABULARY.max_tokens and all(VOCABULARY.token_id(w) != VOCABULARY.unk_id for w in words)

"""Buffer storage with real processes: SIGKILLed writers and drivers, concurrent writers."""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import time
from pathlib import Path

import numpy as np
import pyarrow.dataset as ds

from gpl_dist.faults import FAULT_ENV, PauseAt
from storage import BufferReader, ShardWriter, clean_leftovers, commit_round, committed_rounds, load_manifest
from storage.layout import attempt_key
from storage.synthetic import GRID, synthetic_unit

CTX = mp.get_context("spawn")


def _write_units(root: str, round_index: int, units: list[int], worker_id: str):
    writer = ShardWriter(root, "run-proc")
    out = []
    for u in units:
        unit, attempts = synthetic_unit(round_index, u, [10 * u, 10 * u + 1], GRID, 2, (20, 50))
        out.append(writer.write_unit(unit, attempts, worker_id))
    return out


def _commit(root: str, round_index: int, records) -> None:
    commit_round(root, round_index, records)


def _run_until_signal(target, args, signal_file: Path, point: str) -> None:
    """Start ``target`` in a spawned process that pauses at fault point ``point``; SIGKILL it there."""
    os.environ[FAULT_ENV] = PauseAt(point, str(signal_file)).spec()
    try:
        proc = CTX.Process(target=target, args=args)
        proc.start()
    finally:
        del os.environ[FAULT_ENV]
    deadline = time.monotonic() + 30
    while not signal_file.exists():
        assert proc.is_alive() and time.monotonic() < deadline, "child did not reach the hook"
        time.sleep(0.02)
    os.kill(proc.pid, signal.SIGKILL)
    proc.join(10)
    assert proc.exitcode == -signal.SIGKILL


def _tuples_in_data(root: Path) -> int:
    return ds.dataset(root / "data" / "tuples").count_rows()


def test_writer_killed_mid_shard_leaves_no_visible_debris(tmp_path):
    root = tmp_path / "run"
    rec0 = _write_units(str(root), 0, [0, 1], "w0")
    commit_round(root, 0, rec0)
    n0 = sum(r.num_tuples for r in rec0)
    _run_until_signal(_write_units, (str(root), 1, [0], "doomed"), tmp_path / "paused", "writer.before_publish")

    # the killed try left temp files in staging only; readers and datasets see round 0 alone
    debris = [p for p in (root / "staging").rglob("*") if p.is_file()]
    assert debris and all("/_tmp-doomed-" in str(p) for p in debris)
    assert _tuples_in_data(root) == n0 and ds.dataset(root / "data" / "attempts").count_rows() == 8
    assert committed_rounds(root) == [0]
    assert BufferReader(root).load_training_view().num_tuples == n0

    # the retried unit (plus a second unit) commits exactly one shard for unit 0
    rec1 = _write_units(str(root), 1, [0, 1], "retry")
    commit_round(root, 1, rec1)
    assert sorted(p.name for p in (root / "data" / "tuples" / "round-000001").iterdir()) == [
        "unit-00000.parquet", "unit-00001.parquet"]
    n1 = sum(r.num_tuples for r in rec1)
    view = BufferReader(root).load_training_view()
    assert view.num_tuples == _tuples_in_data(root) == n0 + n1
    assert len(np.unique(view.attempt_keys)) == view.num_attempts == 16

    removed = clean_leftovers(root)
    assert len(removed) == 1 and "/_tmp-doomed-" in removed[0]
    assert not [p for p in (root / "staging").rglob("*") if p.is_file()]
    assert clean_leftovers(root) == []
    assert BufferReader(root).load_training_view().num_tuples == n0 + n1


def test_driver_killed_between_moves_is_rolled_forward(tmp_path):
    root = tmp_path / "run"
    commit_round(root, 0, _write_units(str(root), 0, [0], "w"))
    rec1 = _write_units(str(root), 1, [0, 1], "w")
    _run_until_signal(_commit, (str(root), 1, rec1), tmp_path / "paused", "commit.between_moves")
    assert committed_rounds(root) == [0]
    assert (root / "manifests" / "_pending-round-000001.json").exists()
    assert BufferReader(root).load_training_view().rounds == (0,)
    # the next commit (or clean_leftovers / recover_pending) finishes round 1 first
    commit_round(root, 2, _write_units(str(root), 2, [0], "w"))
    assert committed_rounds(root) == [0, 1, 2]
    assert load_manifest(root, 1).num_tuples == sum(r.num_tuples for r in rec1)
    view = BufferReader(root).load_training_view()
    assert view.rounds == (0, 1, 2) and view.num_tuples == _tuples_in_data(root)
    assert clean_leftovers(root) == []
    assert not list((root / "manifests").glob("_*"))


def test_two_writer_processes_same_round(tmp_path):
    root = tmp_path / "run"
    with CTX.Pool(2) as pool:
        parts = pool.starmap(_write_units, [(str(root), 0, [0, 2, 4], "a"), (str(root), 0, [1, 3, 5], "b")])
    records = [r for part in parts for r in part]
    commit_round(root, 0, records)
    view = BufferReader(root).load_training_view()
    expected_keys = sorted(attempt_key(0, u, s) for u in range(6) for s in range(4))
    assert view.attempt_keys.tolist() == expected_keys
    assert view.num_tuples == sum(r.num_tuples for r in records) == _tuples_in_data(root)
    # every tuple exactly once: (attempt, t) pairs are unique and complete
    pairs = view.attempt_keys[view.attempt_rows] * 1000 + view.timesteps
    assert len(np.unique(pairs)) == view.num_tuples
    for u in range(6):  # content matches a fresh regeneration of each unit
        _, attempts = synthetic_unit(0, u, [10 * u, 10 * u + 1], GRID, 2, (20, 50))
        for s, a in enumerate(attempts):
            i = expected_keys.index(attempt_key(0, u, s))
            rows = view.attempt_rows == i
            np.testing.assert_array_equal(view.observations[rows], a.observations)
    assert clean_leftovers(root) == []


def test_an_installed_fault_hook_stops_a_commit_between_moves_and_recovery_finishes_it(tmp_path):
    """``faults.install`` in this process: a commit interrupted after its first move (here by an
    exception, as a crash would) leaves a sound journal; recovery finishes it exactly once."""
    from gpl_dist import faults
    from storage.commit import pending_journals, recover_pending

    class Crash(Exception):
        pass

    def crash_between_moves(point: str, context) -> None:
        if point == "commit.between_moves" and context["round"] == 0:
            raise Crash()

    root = tmp_path / "run"
    records = _write_units(str(root), 0, [0, 1], "w")
    faults.install(crash_between_moves)
    try:
        try:
            commit_round(root, 0, records)
            raise AssertionError("the hook did not stop the commit")
        except Crash:
            pass
    finally:
        faults.install(None)
    assert committed_rounds(root) == [] and len(pending_journals(root)) == 1
    assert recover_pending(root) == [0]
    assert committed_rounds(root) == [0] and pending_journals(root) == []
    assert _tuples_in_data(root) == load_manifest(root, 0).num_tuples

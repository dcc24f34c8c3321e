"""Buffer storage: round trips, integrity, analyst access, FIFO capacity, memory://, inspection."""

from __future__ import annotations

import re
import uuid

import duckdb
import fsspec
import numpy as np
import pyarrow.dataset as ds
import pyarrow.fs as pafs
import pytest
import zarr

from storage import (
    BufferIntegrityError,
    BufferReader,
    ShardWriter,
    clean_leftovers,
    commit_round,
    committed_rounds,
    format_inspection,
    load_manifest,
)
from storage.layout import attempt_key
from storage.synthetic import GRID, VECTOR, synthetic_unit


def write_run(root, kind=GRID, rounds=2, units=2, tasks=3, k=3, steps=(5, 60), commit=True, seed=0):
    """Write (and commit) ``rounds`` rounds; returns {attempt_key: (attempt, round, unit, seq)}."""
    writer = ShardWriter(root, "run-test")
    expected = {}
    for r in rounds if isinstance(rounds, range) else range(rounds):
        records = []
        for u in range(units):
            unit, attempts = synthetic_unit(r, u, [100 * u + t for t in range(tasks)], kind, k, steps, seed=seed)
            records.append(writer.write_unit(unit, attempts, worker_id=f"worker-{u}"))
            for seq, a in enumerate(attempts):
                expected[attempt_key(r, u, seq)] = (a, r, u, seq)
        if commit:
            commit_round(root, r, records, extra={"round": r})
    return expected


def check_view(view, expected, stride, end_aligned=False):
    """Every array of ``view`` against the attempts it was written from."""
    keys = view.attempt_keys
    assert (np.diff(keys) > 0).all()
    row_of = {int(key): i for i, key in enumerate(keys)}
    pos = 0
    for i, key in enumerate(keys):
        a, r, u, _ = expected[int(key)]
        assert view.round_index[i] == r and view.unit_index[i] == u and view.task_id[i] == a.task_id
        assert view.attempt_index[i] == a.attempt_index and view.lengths[i] == a.length
        np.testing.assert_array_equal(view.instruction_ids[i], a.instruction_ids)
        np.testing.assert_array_equal(view.correction_ids[i], a.correction_ids)
        assert view.completion[i] == np.float32(a.completion) and view.success[i] == a.success
        # context: attempts 0..k-1 of the same (round, task), in order, padded with -1
        ctx = view.context_rows[i]
        k = a.attempt_index
        assert (ctx[k:] == -1).all()
        for j in range(k):
            b, rb, _, _ = expected[int(keys[ctx[j]])]
            assert (rb, b.task_id, b.attempt_index) == (r, a.task_id, j)
        # trajectory samples, zero padded; end-aligned ones end at the attempt's last state
        n_s = -(-a.length // stride)
        assert view.trajectory_lengths[i] == n_s
        first = (a.length - 1) % stride if end_aligned else 0
        np.testing.assert_array_equal(view.trajectories[i, :n_s], a.observations[first::stride])
        if end_aligned:
            np.testing.assert_array_equal(view.trajectories[i, n_s - 1], a.observations[-1])
        assert not view.trajectories[i, n_s:].any()
        if view.in_window[i]:
            sl = slice(pos, pos + a.length)
            np.testing.assert_array_equal(view.observations[sl], a.observations)
            np.testing.assert_array_equal(view.expert_actions[sl], a.expert_actions)
            np.testing.assert_array_equal(view.actions[sl], a.actions)
            np.testing.assert_array_equal(view.timesteps[sl], np.arange(a.length))
            assert (view.attempt_rows[sl] == i).all()
            pos += a.length
    assert pos == view.num_tuples
    # every context attempt of a kept attempt is present
    kept = view.context_rows[view.in_window]
    assert set(kept[kept >= 0].tolist()) <= set(range(len(keys)))
    return row_of


@pytest.mark.parametrize("kind,end_aligned", [(GRID, False), (VECTOR, False), (VECTOR, True)])
def test_round_trip_both_domains(tmp_path, kind, end_aligned):
    root = tmp_path / "run"
    expected = write_run(root, kind)
    reader = BufferReader(root)
    assert reader.committed_rounds() == [0, 1]
    view = reader.load_training_view(capacity_tuples=10**9, trajectory_stride=7, trajectory_end_aligned=end_aligned)
    assert view.trajectory_end_aligned is end_aligned
    assert view.num_attempts == len(expected) and view.in_window.all()
    assert view.num_tuples == sum(a.length for a, *_ in expected.values())
    shape, dtype = ((7, 7, 6), np.uint8) if kind == GRID else ((28,), np.float32)
    assert view.observations.shape[1:] == shape and view.observations.dtype == dtype
    assert view.observations.flags.c_contiguous and view.trajectories.shape[2:] == shape
    assert view.expert_actions.dtype == np.int64 and view.attempt_rows.dtype == np.int64
    assert view.instruction_ids.dtype == np.int64 and view.completion.dtype == np.float32
    assert view.context_rows.shape[1] == 2
    check_view(view, expected, 7, end_aligned)
    # metadata columns come back exactly
    att = reader.read_table("attempts").to_pylist()
    assert len(att) == len(expected)
    for row in att:
        a, r, u, seq = expected[row["attempt_key"]]
        assert (row["round"], row["unit"], row["task_id"], row["attempt_index"]) == (r, u, a.task_id, a.attempt_index)
        assert (row["instruction"], row["correction"], row["correction_kind"]) == (a.instruction, a.correction, a.correction_kind)
        assert row["instruction_ids"] == a.instruction_ids.tolist() and row["correction_ids"] == a.correction_ids.tolist()
        assert row["completion"] == a.completion and row["success"] == a.success and row["seed"] == a.seed
        assert row["policy_version"] == a.policy_version and row["split"] == a.split and row["length"] == a.length
        assert row["worker_id"] == f"worker-{u}" and row["run_id"] == "run-test"
        ctx = [expected[c] for c in row["context_keys"]]
        assert [(c[1], c[0].task_id, c[0].attempt_index) for c in ctx] == [(r, a.task_id, j) for j in range(a.attempt_index)]
        # analyst path to the observations: zarr's own store on the committed group
        z = zarr.open_array(str(root / row["obs_path"]), path="obs", mode="r")
        np.testing.assert_array_equal(z[row["obs_start"] : row["obs_start"] + row["length"]], a.observations)
    m = load_manifest(root, 1)
    assert m.obs_shape == shape and m.obs_dtype == np.dtype(dtype).name and m.extra == {"round": 1}
    assert m.num_tuples == sum(a.length for a, r, *_ in expected.values() if r == 1)


def test_commit_is_idempotent_and_rejects_other_content(tmp_path):
    root = tmp_path / "run"
    writer = ShardWriter(root, "r")
    unit, attempts = synthetic_unit(0, 0, [1, 2], GRID, 2, 10)
    rec = writer.write_unit(unit, attempts, "w")
    m1 = commit_round(root, 0, [rec])
    assert commit_round(root, 0, [rec]) == m1
    rec2 = writer.write_unit(unit, attempts, "w")
    with pytest.raises(ValueError, match="already committed"):
        commit_round(root, 0, [rec2])
    with pytest.raises(ValueError, match="more than one"):
        commit_round(root, 1, [rec2, rec2])


def test_flipped_byte_is_reported_by_name(tmp_path):
    root = tmp_path / "run"
    write_run(root, GRID, rounds=1, units=2)
    m = load_manifest(root, 0)
    for role in ("obs", "tuples", "attempts"):
        f = max(m.shards[1].files_of(role), key=lambda f: f.nbytes)
        p = root / f.path
        data = bytearray(p.read_bytes())
        data[len(data) // 2] ^= 0x40
        p.write_bytes(bytes(data))
        with pytest.raises(BufferIntegrityError, match=re.escape(f.path)) as info:
            BufferReader(root).load_training_view()
        assert info.value.path == f.path
        data[len(data) // 2] ^= 0x40
        p.write_bytes(bytes(data))
    BufferReader(root).load_training_view()  # restored: loads again
    (root / f.path).unlink()
    with pytest.raises(BufferIntegrityError, match=re.escape(f.path)):
        BufferReader(root).load_training_view()


def test_pyarrow_and_duckdb_see_only_committed_data(tmp_path):
    root = tmp_path / "run"
    expected = write_run(root, GRID, rounds=2)
    write_run(root, GRID, rounds=range(2, 3), commit=False)  # staged, never committed
    n_tuples = sum(a.length for a, *_ in expected.values())
    tuples = ds.dataset(root / "data" / "tuples")
    attempts = ds.dataset(root / "data" / "attempts")
    assert tuples.count_rows() == n_tuples and attempts.count_rows() == len(expected)
    assert sorted(attempts.to_table(columns=["attempt_key"]).column(0).to_pylist()) == sorted(expected)
    con = duckdb.connect()
    assert con.sql(f"select count(*) from read_parquet('{root}/data/tuples/**/*.parquet')").fetchall()[0][0] == n_tuples
    assert con.sql(f"select count(*) from read_parquet('{root}/data/attempts/*/*.parquet')").fetchall()[0][0] == len(expected)
    rows = con.sql(
        f"""select a.attempt_index, count(*) as n, avg(a.completion) as c
            from read_parquet('{root}/data/tuples/*/*.parquet') t
            join read_parquet('{root}/data/attempts/*/*.parquet') a using (attempt_key)
            group by 1 order by 1"""
    ).fetchall()
    assert [r[1] for r in rows] == [sum(a.length for a, *_ in expected.values() if a.attempt_index == k) for k in range(3)]
    # the uncommitted round is staged, and clean_leftovers removes it
    removed = clean_leftovers(root)
    assert removed and all(p.startswith("staging/round-000002/") for p in removed)
    assert committed_rounds(root) == [0, 1] and tuples.count_rows() == n_tuples


@pytest.mark.parametrize("end_aligned", [False, True])
def test_fifo_capacity_keeps_newest_whole_attempts_and_context(tmp_path, end_aligned):
    root = tmp_path / "run"
    expected = write_run(root, GRID, rounds=3, units=2, tasks=4, k=3, steps=(5, 40))
    by_round = {}
    for key, (a, r, u, seq) in expected.items():
        by_round.setdefault(r, []).append(key)
    newest, partial = max(by_round), max(by_round) - 1
    newest_tuples = sum(expected[k][0].length for k in by_round[newest])
    capacity = newest_tuples + sum(expected[k][0].length for k in by_round[partial]) // 2
    view = BufferReader(root).load_training_view(capacity_tuples=capacity, trajectory_stride=5,
                                                 trajectory_end_aligned=end_aligned)
    kept = view.attempt_keys[view.in_window].tolist()
    kept_rounds = {expected[k][1] for k in kept}
    # the newest round whole, part of the one before, nothing older
    assert set(by_round[newest]) <= set(kept) and kept_rounds == {newest, partial}
    partial_kept = [k for k in kept if expected[k][1] == partial]
    assert 0 < len(partial_kept) < len(by_round[partial])
    assert view.num_tuples == sum(expected[k][0].length for k in kept) <= capacity
    # the partial round's attempts are spread over its units, not only its last one
    assert len({expected[k][2] for k in partial_kept}) == len({expected[k][2] for k in by_round[partial]})
    context_only = view.attempt_keys[~view.in_window]
    needed = {c for key in kept for c in _context_keys(expected, key)}
    assert set(context_only.tolist()) == needed - set(kept)
    assert view.rounds == tuple(sorted({expected[k][1] for k in view.attempt_keys.tolist()}))
    check_view(view, expected, 5, end_aligned)
    again = BufferReader(root).load_training_view(capacity_tuples=capacity, trajectory_stride=5)
    assert np.array_equal(again.attempt_keys, view.attempt_keys)  # the subset is a function of the round
    assert BufferReader(root).load_training_view(capacity_tuples=0).num_tuples == 0


def _context_keys(expected, key):
    a, r, u, seq = expected[key]
    return [k for k, (b, rb, ub, sb) in expected.items()
            if (rb, ub, b.task_id) == (r, u, a.task_id) and b.attempt_index < a.attempt_index and sb < seq]


def test_memory_filesystem_round_trip():
    url = f"memory://gpl-test-{uuid.uuid4().hex[:8]}/run"
    expected = write_run(url, VECTOR, rounds=2, units=2)
    write_run(url, VECTOR, rounds=range(2, 3), commit=False)
    fs, path = fsspec.core.url_to_fs(url)
    assert not any("/staging/" in p for p in fs.find(path + "/data"))
    view = BufferReader(url).load_training_view(trajectory_stride=10)
    assert view.num_attempts == len(expected)
    check_view(view, expected, 10)
    # analysts: pyarrow over the fsspec filesystem, zarr over its own URL support
    pyfs = pafs.PyFileSystem(pafs.FSSpecHandler(fs))
    assert ds.dataset(path + "/data/tuples", filesystem=pyfs).count_rows() == view.num_tuples
    m = load_manifest(url, 0)
    z = zarr.open_array(f"{url}/data/obs/round-000000/unit-00001.zarr", path="obs", mode="r")
    assert z.shape[0] == m.shards[1].num_tuples
    assert "committed rounds: 2" in format_inspection(url)
    assert all(p.startswith("staging/round-000002") for p in clean_leftovers(url))
    assert not fs.find(path + "/staging")
    assert BufferReader(url).load_training_view().num_tuples == view.num_tuples


def test_format_inspection_numbers(tmp_path):
    root = tmp_path / "run"
    expected = write_run(root, GRID, rounds=2, units=2, tasks=3, k=3)
    out = format_inspection(root, show_tasks=True)
    assert "committed rounds: 2 (0..1)" in out
    for r in (0, 1):
        n = sum(a.length for a, rr, *_ in expected.values() if rr == r)
        assert re.search(rf"^\s+{r}\s+2\s+18\s+{n}\s", out, re.M), out
    for k in range(3):
        comps = [a.completion for a, *_ in expected.values() if a.attempt_index == k]
        assert re.search(rf"^\s+{k}\s+12\s+{np.mean(comps):.4f}\s", out, re.M), out
    assert "attempt_key: int64" in out and "obs_row: int64" in out and "bytes/tuple" in out
    task = 101
    best = max(a.completion for a, *_ in expected.values() if a.task_id == task)
    assert re.search(rf"^\s+{task}\s+6\s+{best:.4f}\s", out, re.M), out
    assert "task" not in format_inspection(root).split("by attempt index")[1]


def test_empty_units_zero_length_attempts_and_dry_run(tmp_path):
    root = tmp_path / "run"
    writer = ShardWriter(root, "r")
    empty = writer.write_unit(synthetic_unit(0, 0, [], GRID)[0], [], "w")
    unit, attempts = synthetic_unit(0, 1, [5], GRID, 2, 30)
    attempts[0] = type(attempts[0])(**{**vars(attempts[0]), "observations": attempts[0].observations[:0],
                                       "actions": attempts[0].actions[:0], "expert_actions": attempts[0].expert_actions[:0]})
    rec = writer.write_unit(unit, attempts, "w")
    assert empty.obs_shape is None and empty.num_attempts == 0
    commit_round(root, 0, [empty, rec])
    view = BufferReader(root).load_training_view(trajectory_stride=25)
    assert view.num_attempts == 2 and view.num_tuples == 30
    assert view.trajectory_lengths.tolist() == [0, 2] and view.context_rows.tolist() == [[-1], [0]]
    assert not view.trajectories[0].any()
    stray = writer.write_unit(unit, attempts, "w")  # a superseded try
    assert clean_leftovers(root, dry_run=True) == [f"staging/round-000000/unit-00001/try-{stray.try_id}"]
    assert clean_leftovers(root) == [f"staging/round-000000/unit-00001/try-{stray.try_id}"]
    assert BufferReader(tmp_path / "nothing").load_training_view().num_tuples == 0


@pytest.mark.parametrize("commit_at", ["verify.between_listings", "commit.between_moves"])
def test_verify_during_a_commit_reports_no_problem(tmp_path, commit_at):
    """``verify`` lists the manifests, reads every file, then lists ``data/``: a round committed in
    between is no orphan (once: a deleted manifest). Driven with the fault points: the commit runs
    whole at ``verify.between_listings``; or verify runs inside a commit at ``commit.between_moves``."""
    from gpl_dist import faults
    from storage.verify import verify_buffer

    root = tmp_path / "run"
    write_run(root, GRID, rounds=1, units=2)
    writer = ShardWriter(root, "run-test")
    records = [writer.write_unit(*synthetic_unit(1, u, [7, 8], GRID, 2, 20), worker_id="w") for u in range(2)]
    seen = []

    def hook(name, context):
        if name == commit_at and not seen:
            seen.append(name)
            if commit_at == "verify.between_listings":
                commit_round(root, 1, records)
            else:
                seen.append(verify_buffer(root))

    faults.install(hook)
    try:
        if commit_at == "verify.between_listings":
            report = verify_buffer(root)
        else:
            commit_round(root, 1, records)
            report = seen[1]
    finally:
        faults.install(None)
    assert seen and report.ok, report.problems
    assert set(report.rounds) | set(report.in_progress) == {0, 1}
    # a deleted manifest is still reported
    (root / "manifests" / "round-000001.json").unlink()
    problems = verify_buffer(root).problems
    assert problems and all("round-000001.json is missing" in p.message for p in problems)


def test_verify_refuses_a_round_of_another_run(tmp_path):
    from storage.verify import verify_buffer

    root = tmp_path / "run"
    write_run(root, GRID, rounds=1, units=1)
    other = ShardWriter(root, "another-run")
    commit_round(root, 1, [other.write_unit(*synthetic_unit(1, 0, [7], GRID, 2, 20), worker_id="w")])
    report = verify_buffer(root)
    assert [(p.path, p.kind) for p in report.problems] == [("manifests/round-000001.json", "foreign")]
    assert "round 1 belongs to run another-run, not to this buffer's run run-test" in report.problems[0].message

"""``BufferReader``: the committed rounds of a run, verified, as in-memory training arrays.

Only files listed in committed manifests are read; every file's bytes are checked against the
manifest's sha256 before they are decoded (zarr chunks are decoded from the verified bytes, so no
file is read twice). ``load_training_view`` returns plain numpy arrays: the learner iterates them
for as many epochs as it likes without touching the disk again.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import zarr
from zarr.core.buffer import cpu
from zarr.storage import MemoryStore

from gpl_dist.roles import trajectory_times
from storage.errors import BufferIntegrityError
from storage.fs import Location, resolve, sha256_hex
from storage.layout import OBS_ARRAY
from storage.manifest import RoundManifest, ShardFile, ShardRecord, committed_rounds, load_manifest


@dataclass(frozen=True)
class TrainingView:
    """Contiguous in-memory arrays of the newest labelled states and the attempts they need.

    Per tuple (``N`` rows, newest ``capacity_tuples`` at most, whole attempts only):
        observations ``(N, *O)``, expert_actions int64 ``(N,)``, expert_probs float32 ``(N, A)``
        (the expert's action distributions; None when every stored label is one-hot by
        omission, as in schema-1 shards), actions int64 ``(N,)`` (executed),
        timesteps int64 ``(N,)``, attempt_rows int64 ``(N,)`` (row into the per-attempt arrays).
    Per attempt (``A`` rows: every attempt with tuples in the view, plus every earlier attempt a kept
    attempt is conditioned on, even when its own tuples fell out; ordered by ``attempt_keys``):
        attempt_keys, round_index, unit_index, task_id, attempt_index, lengths: int64 ``(A,)``;
        instruction_ids, correction_ids: int64 ``(A, L)``; completion float32 ``(A,)``; success bool;
        in_window bool ``(A,)`` (its tuples are in the view);
        context_rows int64 ``(A, Kmax)``: rows of attempts 0..k-1 of the same (round, task), in
        order, padded with -1; ``Kmax = max(1, max attempt_index)``;
        trajectories ``(A, S, *O)``: the attempt's observations at ``trajectory_times(length,
        stride, end_aligned)``: t = 0, stride, 2*stride, ..., or, end-aligned, ..., length-1-stride,
        length-1; ``S = max(1, ceil(max length / stride))``; samples past an attempt's count are
        zeros, and trajectory_lengths int64 ``(A,)`` = ``ceil(length / stride)`` counts the real ones.
    """

    observations: np.ndarray
    expert_actions: np.ndarray
    expert_probs: np.ndarray | None
    actions: np.ndarray
    timesteps: np.ndarray
    attempt_rows: np.ndarray
    attempt_keys: np.ndarray
    round_index: np.ndarray
    unit_index: np.ndarray
    task_id: np.ndarray
    attempt_index: np.ndarray
    lengths: np.ndarray
    instruction_ids: np.ndarray
    correction_ids: np.ndarray
    completion: np.ndarray
    success: np.ndarray
    in_window: np.ndarray
    context_rows: np.ndarray
    trajectories: np.ndarray
    trajectory_lengths: np.ndarray
    trajectory_stride: int
    trajectory_end_aligned: bool
    rounds: tuple[int, ...]

    @property
    def num_tuples(self) -> int:
        return int(self.expert_actions.shape[0])

    @property
    def num_attempts(self) -> int:
        return int(self.attempt_keys.shape[0])

    @property
    def trajectory_mask(self) -> np.ndarray:
        """bool ``(A, S)``: which trajectory samples are real states (not padding)."""
        return np.arange(self.trajectories.shape[1])[None, :] < self.trajectory_lengths[:, None]

    @property
    def nbytes(self) -> int:
        return sum(v.nbytes for v in vars(self).values() if isinstance(v, np.ndarray))


# ------------------------------------------------------------------------------------------------
def read_verified(loc: Location, f: ShardFile) -> bytes:
    """Bytes of a committed file, after checking its size and sha256 against the manifest."""
    try:
        data = loc.read_bytes(f.path)
    except FileNotFoundError:
        raise BufferIntegrityError(f"committed file {f.path} is missing in {loc.url}", f.path) from None
    if len(data) != f.nbytes:
        raise BufferIntegrityError(
            f"committed file {f.path} in {loc.url} has {len(data)} bytes, manifest says {f.nbytes}", f.path
        )
    digest = sha256_hex(data)
    if digest != f.sha256:
        raise BufferIntegrityError(
            f"checksum mismatch in committed file {f.path} in {loc.url}: sha256 {digest}, manifest says {f.sha256}",
            f.path,
        )
    return data


def read_shard_table(loc: Location, shard: ShardRecord, role: str, columns: Sequence[str] | None = None,
                     optional: Sequence[str] = ()) -> pa.Table:
    """The shard's ``role`` table; ``optional`` columns are read when the shard has them (older
    schema versions lack some)."""
    (f,) = shard.files_of(role)
    source = pa.BufferReader(read_verified(loc, f))
    if optional:
        names = set(pq.read_schema(source).names)
        columns = list(columns or []) + [c for c in optional if c in names]
    return pq.read_table(source, columns=list(columns) if columns else None)


def _probs_rows(col: pa.ChunkedArray | None) -> np.ndarray | None:
    """float32 ``(m, A)`` from an ``expert_probs`` column; null rows are NaN; None when all null."""
    if col is None or col.null_count == len(col):
        return None
    arr = col.combine_chunks()
    valid = ~arr.is_null().to_numpy(zero_copy_only=False)
    offsets = arr.offsets.to_numpy()
    widths = np.diff(offsets)[valid]
    width = int(widths[0])
    if not (widths == width).all():
        raise BufferIntegrityError(f"expert_probs lists have different lengths ({widths.min()}..{widths.max()})")
    values = arr.values.to_numpy(zero_copy_only=False)
    out = np.full((len(arr), width), np.nan, np.float32)
    out[valid] = values[offsets[:-1][valid, None] + np.arange(width)]
    return out


def open_shard_obs(loc: Location, shard: ShardRecord) -> zarr.Array:
    """The shard's observation array, decoded from verified bytes held in memory."""
    store: dict = {}
    for f in shard.files_of("obs"):
        key = f.path.split(".zarr/", 1)[1]
        store[key] = cpu.Buffer.from_bytes(read_verified(loc, f))
    return zarr.open_array(store=MemoryStore(store, read_only=True), path=OBS_ARRAY, mode="r")


def _fixed_lists(col: pa.ChunkedArray, name: str) -> np.ndarray:
    arr = col.combine_chunks()
    n = len(arr)
    if n == 0:
        return np.zeros((0, 0), np.int64)
    offsets = arr.offsets.to_numpy()
    widths = np.diff(offsets)
    if not (widths == widths[0]).all():
        raise BufferIntegrityError(f"{name} lists have different lengths ({widths.min()}..{widths.max()})")
    values = arr.values.to_numpy(zero_copy_only=False)[offsets[0] : offsets[-1]]
    return values.reshape(n, int(widths[0])).astype(np.int64, copy=False)


_ATTEMPT_COLUMNS = [
    "attempt_key", "round", "unit", "task_id", "attempt_index", "instruction_ids", "correction_ids",
    "context_keys", "completion", "success", "length", "obs_start",
]


def _assemble_probs(chunks: list[tuple[int, np.ndarray | None]], expert_actions: np.ndarray) -> np.ndarray | None:
    """One ``(N, A)`` array from per-shard rows; rows a shard did not store become one-hot."""
    width = next((c.shape[1] for _, c in chunks if c is not None), None)
    if width is None:
        return None
    out = np.zeros((len(expert_actions), width), np.float32)
    for pos, c in chunks:
        if c is not None:
            out[pos:pos + len(c)] = c
    missing = np.isnan(out).any(1) | ~(out.any(1))
    rows = np.flatnonzero(missing)
    out[rows] = 0.0
    out[rows, expert_actions[rows]] = 1.0
    return out


class BufferReader:
    """Reads the committed rounds of the run at ``root`` (local directory or fsspec URL)."""

    def __init__(self, root: "str | os.PathLike[str] | Location") -> None:
        self.location = resolve(root)

    def committed_rounds(self) -> list[int]:
        return committed_rounds(self.location)

    def manifest(self, round_index: int) -> RoundManifest:
        return load_manifest(self.location, round_index)

    def read_table(self, role: str, rounds: Iterable[int] | None = None, columns: Sequence[str] | None = None) -> pa.Table:
        """The verified ``attempts`` or ``tuples`` table of committed ``rounds`` (default: all)."""
        from storage.schema import ATTEMPTS_SCHEMA, TUPLES_SCHEMA

        schema = ATTEMPTS_SCHEMA if role == "attempts" else TUPLES_SCHEMA
        tables = []
        for r in self.committed_rounds() if rounds is None else rounds:
            for shard in sorted(self.manifest(r).shards, key=lambda s: s.unit_index):
                tables.append(read_shard_table(self.location, shard, role, columns))
        if not tables:
            return (schema if columns is None else pa.schema([schema.field(c) for c in columns])).empty_table()
        return pa.concat_tables(tables)

    # --------------------------------------------------------------------------------------------
    def load_training_view(self, capacity_tuples: int = 1_000_000, trajectory_stride: int = 25,
                           trajectory_end_aligned: bool = False) -> TrainingView:
        """Newest ``capacity_tuples`` labelled states (whole attempts, FIFO over committed rounds).

        ``trajectory_stride`` and ``trajectory_end_aligned`` pick each attempt's trajectory samples
        by ``gpl_dist.roles.trajectory_times``, as the rollout worker did when it acted on them.

        Rounds are kept newest first while they fit whole; of the first round that does not fit, a
        random subset of whole attempts (seeded by the round index) fills the rest.
        """
        if trajectory_stride < 1:
            raise ValueError("trajectory_stride must be at least 1")
        loc = self.location
        rounds = self.committed_rounds()
        obs_shape: tuple[int, ...] = ()
        obs_dtype: np.dtype = np.dtype(np.float32)
        manifests: list[RoundManifest] = []
        tables: list[pa.Table] = []
        remaining = int(capacity_tuples)
        keep_masks: list[np.ndarray] = []  # per loaded round: which of its attempts are in the window
        for r in reversed(rounds):
            if remaining <= 0:
                break
            m = self.manifest(r)
            if m.obs_shape is not None and not obs_shape:
                obs_shape, obs_dtype = tuple(m.obs_shape), np.dtype(m.obs_dtype)
            shards = sorted(m.shards, key=lambda s: s.unit_index)
            parts = [read_shard_table(loc, s, "attempts", _ATTEMPT_COLUMNS) for s in shards]
            t = pa.concat_tables(parts) if parts else None
            if t is None or t.num_rows == 0:
                continue
            lengths = t.column("length").to_numpy().astype(np.int64)
            keep = np.ones(t.num_rows, bool)
            if lengths.sum() > remaining:
                # The oldest round in the window does not fit whole. Its attempts are all equally
                # new, so keep a random subset of whole attempts (seeded by the round) rather than
                # its last units: otherwise the same tasks would be left out of training every round.
                order = np.random.default_rng([0x5EED, r]).permutation(t.num_rows)
                n_fit = int(np.searchsorted(np.cumsum(lengths[order]), remaining, side="right"))
                keep[:] = False
                keep[order[:n_fit]] = True
            remaining -= int(lengths[keep].sum())
            manifests.append(m)
            tables.append(t)
            keep_masks.append(keep)
            if not keep.all():
                break  # FIFO: part of this round did not fit, so nothing older is kept
        manifests.reverse()
        tables.reverse()
        keep_masks.reverse()
        for m in manifests:
            if m.obs_shape is not None and (tuple(m.obs_shape), np.dtype(m.obs_dtype)) != (obs_shape, obs_dtype):
                raise BufferIntegrityError(f"round {m.round_index}: observations {m.obs_shape} {m.obs_dtype} "
                                           f"differ from {obs_shape} {obs_dtype}")
        if not tables:
            return _empty_view(obs_shape, obs_dtype, trajectory_stride, trajectory_end_aligned, ())

        att = pa.concat_tables(tables)
        keys = att.column("attempt_key").to_numpy()
        if not (np.diff(keys) > 0).all():
            raise BufferIntegrityError("attempt keys of the committed rounds are not strictly increasing")
        in_window = np.concatenate(keep_masks)
        ctx_col = att.column("context_keys").combine_chunks()
        ctx_off = ctx_col.offsets.to_numpy()
        ctx_val = ctx_col.values.to_numpy()[ctx_off[0] : ctx_off[-1]]
        ctx_off = ctx_off - ctx_off[0]
        ctx_len = np.diff(ctx_off)
        # attempts referenced by the context of a kept attempt
        win_ctx = ctx_val[np.repeat(in_window, ctx_len)]
        ref_rows = np.searchsorted(keys, win_ctx)
        if len(win_ctx) and not ((ref_rows < len(keys)).all() and np.array_equal(keys[ref_rows], win_ctx)):
            raise BufferIntegrityError("an attempt's context_keys name an attempt missing from its round")
        needed = in_window.copy()
        needed[ref_rows] = True
        sel = np.flatnonzero(needed)  # rows of `att` that become view rows
        new_row = np.full(len(keys), -1, np.int64)
        new_row[sel] = np.arange(len(sel))

        a_keys = keys[sel]
        lengths = att.column("length").to_numpy().astype(np.int64)[sel]
        attempt_index = att.column("attempt_index").to_numpy().astype(np.int64)[sel]
        k_max = max(1, int(attempt_index.max()) if len(sel) else 1)
        context_rows = np.full((len(sel), k_max), -1, np.int64)
        for j, i in enumerate(sel):
            c = ctx_val[ctx_off[i] : ctx_off[i + 1]]
            if len(c):
                context_rows[j, : len(c)] = new_row[np.searchsorted(keys, c)]
        a_in_window = in_window[sel]

        # per tuple
        n = int(lengths[a_in_window].sum())
        observations = np.empty((n, *obs_shape), obs_dtype)
        expert_actions = np.empty(n, np.int64)
        actions = np.empty(n, np.int64)
        attempt_rows = np.repeat(np.flatnonzero(a_in_window).astype(np.int64), lengths[a_in_window])
        tuple_start = np.full(len(sel), -1, np.int64)
        tuple_start[a_in_window] = np.concatenate([[0], np.cumsum(lengths[a_in_window])[:-1]]).astype(np.int64)
        timesteps = np.arange(n, dtype=np.int64) - np.repeat(tuple_start[a_in_window], lengths[a_in_window])

        stride, end_aligned = int(trajectory_stride), bool(trajectory_end_aligned)
        # attempts share a handful of lengths: one index array per length
        unique_lengths, length_index = np.unique(lengths, return_inverse=True)
        times_of = {int(n): trajectory_times(int(n), stride, end_aligned) for n in unique_lengths}
        times = lambda length: times_of[int(length)]  # noqa: E731
        t_len = np.array([len(times_of[int(n)]) for n in unique_lengths], dtype=np.int64)[length_index.reshape(-1)]
        s_max = max(1, int(t_len.max()) if len(t_len) else 1)
        trajectories = np.zeros((len(sel), s_max, *obs_shape), obs_dtype)

        obs_start_all = att.column("obs_start").to_numpy().astype(np.int64)
        units_all = att.column("unit").to_numpy()
        rounds_all = att.column("round").to_numpy()
        pos = 0  # next tuple row
        off = 0
        probs_chunks: list[tuple[int, np.ndarray | None]] = []
        for m, t in zip(manifests, tables):
            shard_of_unit = {s.unit_index: s for s in m.shards}
            rows = np.arange(off, off + t.num_rows)
            for u in np.unique(units_all[rows]):
                shard_rows = rows[units_all[rows] == u]
                need = shard_rows[needed[shard_rows]]
                if len(need) == 0:
                    continue
                shard = shard_of_unit[int(u)]
                z = open_shard_obs(loc, shard)
                win = shard_rows[in_window[shard_rows]]
                lo = hi = 0
                if len(win):
                    lo = int(obs_start_all[win[0]])
                    hi = int(obs_start_all[win[-1]] + lengths[new_row[win[-1]]])
                    # rows of the kept attempts; one contiguous run unless the window cut a round
                    take = np.concatenate([obs_start_all[i] + np.arange(lengths[new_row[i]]) for i in win]) - lo
                    m_rows = len(take)
                    contiguous = m_rows == hi - lo
                    block = np.asarray(z[lo:hi])
                    observations[pos : pos + m_rows] = block if contiguous else block[take]
                    tup = read_shard_table(loc, shard, "tuples", ["attempt_key", "expert_action", "action"],
                                           optional=["expert_probs"]).slice(lo, hi - lo)
                    if not contiguous:
                        tup = tup.take(pa.array(take))
                    if not np.array_equal(tup.column("attempt_key").to_numpy(), np.repeat(keys[win], lengths[new_row[win]])):
                        tuples_path = shard.files_of("tuples")[0].path
                        raise BufferIntegrityError(f"tuples of {tuples_path} disagree with its attempts table")
                    expert_actions[pos : pos + m_rows] = tup.column("expert_action").to_numpy()
                    actions[pos : pos + m_rows] = tup.column("action").to_numpy()
                    probs = tup.column("expert_probs") if "expert_probs" in tup.column_names else None
                    probs_chunks.append((pos, _probs_rows(probs)))
                    for i in win:
                        j = new_row[i]
                        trajectories[j, : t_len[j]] = observations[tuple_start[j] + times(lengths[j])]
                    pos += m_rows
                ctx_only = need[~in_window[need]]
                if len(ctx_only):
                    js = new_row[ctx_only]
                    gather = np.concatenate([obs_start_all[i] + times(lengths[j]) for i, j in zip(ctx_only, js)])
                    got = np.asarray(z.oindex[gather]) if len(gather) else np.zeros((0, *obs_shape), obs_dtype)
                    g = 0
                    for j in js:
                        trajectories[j, : t_len[j]] = got[g : g + t_len[j]]
                        g += t_len[j]
            off += t.num_rows
        assert pos == n
        expert_probs = _assemble_probs(probs_chunks, expert_actions)

        inst = _fixed_lists(att.column("instruction_ids").take(pa.array(sel)), "instruction_ids")
        corr = _fixed_lists(att.column("correction_ids").take(pa.array(sel)), "correction_ids")
        return TrainingView(
            observations=observations,
            expert_actions=expert_actions,
            expert_probs=expert_probs,
            actions=actions,
            timesteps=timesteps,
            attempt_rows=attempt_rows,
            attempt_keys=a_keys.astype(np.int64),
            round_index=rounds_all[sel].astype(np.int64),
            unit_index=units_all[sel].astype(np.int64),
            task_id=att.column("task_id").to_numpy()[sel].astype(np.int64),
            attempt_index=attempt_index,
            lengths=lengths,
            instruction_ids=inst,
            correction_ids=corr,
            completion=att.column("completion").to_numpy()[sel].astype(np.float32),
            success=att.column("success").to_numpy(zero_copy_only=False)[sel].astype(bool),
            in_window=a_in_window,
            context_rows=context_rows,
            trajectories=trajectories,
            trajectory_lengths=t_len.astype(np.int64),
            trajectory_stride=stride,
            trajectory_end_aligned=end_aligned,
            rounds=tuple(m.round_index for m in manifests),
        )


def _empty_view(obs_shape: tuple[int, ...], dtype: np.dtype, stride: int, end_aligned: bool,
                rounds: tuple[int, ...]) -> TrainingView:
    z = lambda *s, dt=np.int64: np.zeros(s, dt)  # noqa: E731
    return TrainingView(
        observations=np.zeros((0, *obs_shape), dtype), expert_actions=z(0), expert_probs=None, actions=z(0), timesteps=z(0),
        attempt_rows=z(0), attempt_keys=z(0), round_index=z(0), unit_index=z(0), task_id=z(0),
        attempt_index=z(0), lengths=z(0), instruction_ids=z(0, 0), correction_ids=z(0, 0),
        completion=z(0, dt=np.float32), success=z(0, dt=bool), in_window=z(0, dt=bool),
        context_rows=z(0, 1), trajectories=np.zeros((0, 1, *obs_shape), dtype), trajectory_lengths=z(0),
        trajectory_stride=stride, trajectory_end_aligned=bool(end_aligned), rounds=rounds,
    )

"""``BufferReader``: the committed rounds of a run, verified, as in-memory training arrays.

Only files listed in committed manifests are read; every file's bytes are checked against the
manifest's sha256 before they are decoded (zarr chunks are decoded from the verified bytes, so no
file is read twice). ``load_training_view`` returns plain numpy arrays: the learner iterates them
for as many epochs as it likes without touching the disk again.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
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
from storage.schema import ADDED_COLUMNS, ATTEMPTS_SCHEMA, TUPLES_SCHEMA


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
        instruction_ids, correction_ids: int64 ``(A, L)``; completion, reward_sum float32 ``(A,)``
        (NaN where not recorded); success bool;
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
    reward_sum: np.ndarray
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


def read_shard_table(loc: Location, shard: ShardRecord, role: str, columns: Sequence[str] | None = None) -> pa.Table:
    """The shard's ``role`` table (``columns`` of it, default all), verified, in the current schema
    (``storage.schema``) whatever the schema version it was written with: the one place a shard of
    an older version is read. The versions:

    - 1: tuples without ``expert_probs``: read as null (every label one-hot, its ``expert_action``);
    - 2: attempts without ``reward_sum``: read as null (not recorded; NaN in a ``TrainingView``);
    - 3 (``SCHEMA_VERSION``): the current.
    """
    (f,) = shard.files_of(role)
    source = pa.BufferReader(read_verified(loc, f))
    names = pq.read_schema(source).names
    added = {c: spec for c, spec in ADDED_COLUMNS[role].items() if c not in names and (columns is None or c in columns)}
    if not added:
        return pq.read_table(source, columns=list(columns) if columns else None)
    current = (ATTEMPTS_SCHEMA if role == "attempts" else TUPLES_SCHEMA).names
    wanted = list(columns) if columns else [c for c in current if c in names or c in added]
    table = pq.read_table(source, columns=[c for c in wanted if c not in added])
    for c, spec in added.items():
        table = table.add_column(wanted.index(c), spec, pa.nulls(table.num_rows, spec.type))
    return table


def _probs_rows(col: pa.ChunkedArray) -> np.ndarray | None:
    """float32 ``(m, A)`` from an ``expert_probs`` column; null rows are NaN; None when all null."""
    if col.null_count == len(col):
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
    "context_keys", "completion", "reward_sum", "success", "length", "obs_start",
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
        random subset of whole attempts (seeded by the round index) fills the rest. Three steps:
        the window (``_window``), the attempt rows it needs (``_ViewRows``: the kept attempts and
        every earlier attempt they are conditioned on), and the per-shard gather (``_Gather``).
        """
        if trajectory_stride < 1:
            raise ValueError("trajectory_stride must be at least 1")
        window = self._window(int(capacity_tuples))
        stride, end_aligned = int(trajectory_stride), bool(trajectory_end_aligned)
        if not window.tables:
            return _empty_view(window.obs_shape, window.obs_dtype, stride, end_aligned, ())
        rows = _ViewRows.of(window)
        gathered = _Gather(self.location, window, rows, stride, end_aligned).run()
        att, sel = rows.att, rows.sel
        return TrainingView(
            observations=gathered.observations,
            expert_actions=gathered.expert_actions,
            expert_probs=gathered.expert_probs,
            actions=gathered.actions,
            timesteps=gathered.timesteps,
            attempt_rows=gathered.attempt_rows,
            attempt_keys=rows.keys[sel].astype(np.int64),
            round_index=att.column("round").to_numpy()[sel].astype(np.int64),
            unit_index=att.column("unit").to_numpy()[sel].astype(np.int64),
            task_id=att.column("task_id").to_numpy()[sel].astype(np.int64),
            attempt_index=rows.attempt_index,
            lengths=rows.lengths,
            instruction_ids=_fixed_lists(att.column("instruction_ids").take(pa.array(sel)), "instruction_ids"),
            correction_ids=_fixed_lists(att.column("correction_ids").take(pa.array(sel)), "correction_ids"),
            completion=att.column("completion").to_numpy()[sel].astype(np.float32),
            reward_sum=att.column("reward_sum").to_numpy(zero_copy_only=False)[sel].astype(np.float32),
            success=att.column("success").to_numpy(zero_copy_only=False)[sel].astype(bool),
            in_window=rows.in_window[sel],
            context_rows=rows.context_rows,
            trajectories=gathered.trajectories,
            trajectory_lengths=gathered.trajectory_lengths,
            trajectory_stride=stride,
            trajectory_end_aligned=end_aligned,
            rounds=tuple(m.round_index for m in window.manifests),
        )

    def _window(self, capacity: int) -> "_Window":
        """The committed rounds in the FIFO window, oldest first, and which attempts of each are kept."""
        loc = self.location
        window = _Window()
        remaining = capacity
        for r in reversed(self.committed_rounds()):
            if remaining <= 0:
                break
            m = self.manifest(r)
            if m.obs_shape is not None and not window.obs_shape:
                window.obs_shape, window.obs_dtype = tuple(m.obs_shape), np.dtype(m.obs_dtype)
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
            window.manifests.insert(0, m)
            window.tables.insert(0, t)
            window.keep_masks.insert(0, keep)
            if not keep.all():
                break  # FIFO: part of this round did not fit, so nothing older is kept
        for m in window.manifests:
            if m.obs_shape is not None and (tuple(m.obs_shape), np.dtype(m.obs_dtype)) != (window.obs_shape, window.obs_dtype):
                raise BufferIntegrityError(f"round {m.round_index}: observations {m.obs_shape} {m.obs_dtype} "
                                           f"differ from {window.obs_shape} {window.obs_dtype}")
        return window


@dataclass
class _Window:
    """The rounds of the FIFO window, oldest first: manifests, attempts tables, kept-attempt masks."""

    manifests: list[RoundManifest] = field(default_factory=list)
    tables: list[pa.Table] = field(default_factory=list)
    keep_masks: list[np.ndarray] = field(default_factory=list)
    obs_shape: tuple[int, ...] = ()
    obs_dtype: np.dtype = field(default_factory=lambda: np.dtype(np.float32))


@dataclass(frozen=True)
class _ViewRows:
    """Which rows of the window's attempts table (``att``) become view rows.

    ``keys``, ``in_window`` and ``needed`` are per row of ``att``; ``sel`` lists the needed rows
    (the kept attempts and every attempt one of them is conditioned on), ``new_row`` maps a row
    of ``att`` to its view row (-1 when not needed); ``lengths``, ``attempt_index`` and
    ``context_rows`` are per view row.
    """

    att: pa.Table
    keys: np.ndarray
    in_window: np.ndarray
    needed: np.ndarray
    sel: np.ndarray
    new_row: np.ndarray
    lengths: np.ndarray
    attempt_index: np.ndarray
    context_rows: np.ndarray

    @classmethod
    def of(cls, window: _Window) -> "_ViewRows":
        att = pa.concat_tables(window.tables)
        keys = att.column("attempt_key").to_numpy()
        if not (np.diff(keys) > 0).all():
            raise BufferIntegrityError("attempt keys of the committed rounds are not strictly increasing")
        in_window = np.concatenate(window.keep_masks)
        ctx_col = att.column("context_keys").combine_chunks()
        ctx_off = ctx_col.offsets.to_numpy()
        ctx_val = ctx_col.values.to_numpy()[ctx_off[0] : ctx_off[-1]]
        ctx_off = ctx_off - ctx_off[0]
        # attempts referenced by the context of a kept attempt
        win_ctx = ctx_val[np.repeat(in_window, np.diff(ctx_off))]
        ref_rows = np.searchsorted(keys, win_ctx)
        if len(win_ctx) and not ((ref_rows < len(keys)).all() and np.array_equal(keys[ref_rows], win_ctx)):
            raise BufferIntegrityError("an attempt's context_keys name an attempt missing from its round")
        needed = in_window.copy()
        needed[ref_rows] = True
        sel = np.flatnonzero(needed)
        new_row = np.full(len(keys), -1, np.int64)
        new_row[sel] = np.arange(len(sel))
        attempt_index = att.column("attempt_index").to_numpy().astype(np.int64)[sel]
        k_max = max(1, int(attempt_index.max()) if len(sel) else 1)
        context_rows = np.full((len(sel), k_max), -1, np.int64)
        for j, i in enumerate(sel):
            c = ctx_val[ctx_off[i] : ctx_off[i + 1]]
            if len(c):
                context_rows[j, : len(c)] = new_row[np.searchsorted(keys, c)]
        return cls(att=att, keys=keys, in_window=in_window, needed=needed, sel=sel, new_row=new_row,
                   lengths=att.column("length").to_numpy().astype(np.int64)[sel], attempt_index=attempt_index,
                   context_rows=context_rows)


@dataclass(frozen=True)
class _Gathered:
    """The per-tuple arrays and the trajectories of a view (see ``TrainingView``)."""

    observations: np.ndarray
    expert_actions: np.ndarray
    expert_probs: np.ndarray | None
    actions: np.ndarray
    timesteps: np.ndarray
    attempt_rows: np.ndarray
    trajectories: np.ndarray
    trajectory_lengths: np.ndarray


class _Gather:
    """Reads each needed shard once: the kept attempts' observations and labels, and the
    trajectory samples of every view row (from the observations just read, or, for attempts
    needed only as context, straight from the shard's zarr group)."""

    def __init__(self, loc: Location, window: _Window, rows: _ViewRows, stride: int, end_aligned: bool):
        self.loc, self.window, self.rows = loc, window, rows
        lengths, sel = rows.lengths, rows.sel
        a_in_window = rows.in_window[sel]
        obs_shape, obs_dtype = window.obs_shape, window.obs_dtype
        n = int(lengths[a_in_window].sum())
        self.observations = np.empty((n, *obs_shape), obs_dtype)
        self.expert_actions = np.empty(n, np.int64)
        self.actions = np.empty(n, np.int64)
        self.attempt_rows = np.repeat(np.flatnonzero(a_in_window).astype(np.int64), lengths[a_in_window])
        self.tuple_start = np.full(len(sel), -1, np.int64)
        self.tuple_start[a_in_window] = np.concatenate([[0], np.cumsum(lengths[a_in_window])[:-1]]).astype(np.int64)
        self.timesteps = np.arange(n, dtype=np.int64) - np.repeat(self.tuple_start[a_in_window], lengths[a_in_window])
        # attempts share a handful of lengths: one index array per length
        unique_lengths, length_index = np.unique(lengths, return_inverse=True)
        self.times_of = {int(k): trajectory_times(int(k), stride, end_aligned) for k in unique_lengths}
        self.t_len = np.array([len(self.times_of[int(k)]) for k in unique_lengths],
                              dtype=np.int64)[length_index.reshape(-1)]
        s_max = max(1, int(self.t_len.max()) if len(self.t_len) else 1)
        self.trajectories = np.zeros((len(sel), s_max, *obs_shape), obs_dtype)
        self.obs_start = rows.att.column("obs_start").to_numpy().astype(np.int64)
        self.units = rows.att.column("unit").to_numpy()
        self.pos = 0  # next tuple row
        self.probs_chunks: list[tuple[int, np.ndarray | None]] = []

    def run(self) -> _Gathered:
        off = 0
        needed = self.rows.needed
        for m, t in zip(self.window.manifests, self.window.tables):
            shard_of_unit = {s.unit_index: s for s in m.shards}
            rows = np.arange(off, off + t.num_rows)
            for u in np.unique(self.units[rows]):
                shard_rows = rows[self.units[rows] == u]
                if needed[shard_rows].any():
                    self._shard(shard_of_unit[int(u)], shard_rows)
            off += t.num_rows
        assert self.pos == len(self.expert_actions)
        return _Gathered(observations=self.observations, expert_actions=self.expert_actions,
                         expert_probs=_assemble_probs(self.probs_chunks, self.expert_actions), actions=self.actions,
                         timesteps=self.timesteps, attempt_rows=self.attempt_rows, trajectories=self.trajectories,
                         trajectory_lengths=self.t_len.astype(np.int64))

    def _times(self, length: int) -> np.ndarray:
        return self.times_of[int(length)]

    def _shard(self, shard: ShardRecord, shard_rows: np.ndarray) -> None:
        in_window = self.rows.in_window
        z = open_shard_obs(self.loc, shard)
        win = shard_rows[in_window[shard_rows]]
        if len(win):
            self._kept_attempts(shard, z, win)
        need = shard_rows[self.rows.needed[shard_rows]]
        ctx_only = need[~in_window[need]]
        if len(ctx_only):
            self._context_only(z, ctx_only)

    def _kept_attempts(self, shard: ShardRecord, z: zarr.Array, win: np.ndarray) -> None:
        """Observations, labels and trajectories of the shard's attempts in the window."""
        lengths, new_row, pos = self.rows.lengths, self.rows.new_row, self.pos
        lo = int(self.obs_start[win[0]])
        hi = int(self.obs_start[win[-1]] + lengths[new_row[win[-1]]])
        # rows of the kept attempts; one contiguous run unless the window cut a round
        take = np.concatenate([self.obs_start[i] + np.arange(lengths[new_row[i]]) for i in win]) - lo
        m_rows = len(take)
        contiguous = m_rows == hi - lo
        block = np.asarray(z[lo:hi])
        self.observations[pos : pos + m_rows] = block if contiguous else block[take]
        tup = read_shard_table(self.loc, shard, "tuples", ["attempt_key", "expert_action", "action", "expert_probs"]
                               ).slice(lo, hi - lo)
        if not contiguous:
            tup = tup.take(pa.array(take))
        if not np.array_equal(tup.column("attempt_key").to_numpy(), np.repeat(self.rows.keys[win], lengths[new_row[win]])):
            raise BufferIntegrityError(f"tuples of {shard.files_of('tuples')[0].path} disagree with its attempts table")
        self.expert_actions[pos : pos + m_rows] = tup.column("expert_action").to_numpy()
        self.actions[pos : pos + m_rows] = tup.column("action").to_numpy()
        self.probs_chunks.append((pos, _probs_rows(tup.column("expert_probs"))))
        for i in win:
            j = new_row[i]
            self.trajectories[j, : self.t_len[j]] = self.observations[self.tuple_start[j] + self._times(lengths[j])]
        self.pos += m_rows

    def _context_only(self, z: zarr.Array, ctx_only: np.ndarray) -> None:
        """Trajectory samples of attempts needed only as earlier context (their tuples fell out)."""
        lengths = self.rows.lengths
        js = self.rows.new_row[ctx_only]
        gather = np.concatenate([self.obs_start[i] + self._times(lengths[j]) for i, j in zip(ctx_only, js)])
        obs_shape, obs_dtype = self.window.obs_shape, self.window.obs_dtype
        got = np.asarray(z.oindex[gather]) if len(gather) else np.zeros((0, *obs_shape), obs_dtype)
        g = 0
        for j in js:
            self.trajectories[j, : self.t_len[j]] = got[g : g + self.t_len[j]]
            g += self.t_len[j]


def _empty_view(obs_shape: tuple[int, ...], dtype: np.dtype, stride: int, end_aligned: bool,
                rounds: tuple[int, ...]) -> TrainingView:
    z = lambda *s, dt=np.int64: np.zeros(s, dt)  # noqa: E731
    return TrainingView(
        observations=np.zeros((0, *obs_shape), dtype), expert_actions=z(0), expert_probs=None, actions=z(0), timesteps=z(0),
        attempt_rows=z(0), attempt_keys=z(0), round_index=z(0), unit_index=z(0), task_id=z(0),
        attempt_index=z(0), lengths=z(0), instruction_ids=z(0, 0), correction_ids=z(0, 0),
        completion=z(0, dt=np.float32), reward_sum=z(0, dt=np.float32), success=z(0, dt=bool), in_window=z(0, dt=bool),
        context_rows=z(0, 1), trajectories=np.zeros((0, 1, *obs_shape), dtype), trajectory_lengths=z(0),
        trajectory_stride=stride, trajectory_end_aligned=bool(end_aligned), rounds=rounds,
    )

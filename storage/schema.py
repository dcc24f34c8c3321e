"""Arrow schemas of the two tables, and the conversion of a unit's attempts into them.

Observations are not in either table: they live once, in the shard's zarr array ``obs``; a tuple
points at its observation by ``obs_row`` (row of that array), an attempt by ``obs_path`` (the
committed zarr group, relative to the run root) and ``obs_start`` (its first row).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import pyarrow as pa

from gpl_dist.records import Attempt, WorkUnit
from storage.layout import attempt_key, committed_path

#: The shards' schema: 2 added the tuples' ``expert_probs``, 3 the attempts' ``reward_sum``
#: (``storage.reader.read_shard_table`` reads a shard of an older version as this one).
SCHEMA_VERSION = 3

ATTEMPTS_SCHEMA = pa.schema(
    [
        pa.field("attempt_key", pa.int64(), nullable=False),
        pa.field("run_id", pa.string()),
        pa.field("round", pa.int32(), nullable=False),
        pa.field("unit", pa.int32(), nullable=False),
        pa.field("task_id", pa.int32(), nullable=False),
        pa.field("split", pa.string()),
        pa.field("attempt_index", pa.int32(), nullable=False),
        pa.field("instruction", pa.string()),
        pa.field("instruction_ids", pa.list_(pa.int64())),
        pa.field("correction", pa.string()),
        pa.field("correction_kind", pa.string()),
        pa.field("correction_ids", pa.list_(pa.int64())),
        # attempt_key of attempts 0..k-1 of the same (round, task) that conditioned this one, in order
        pa.field("context_keys", pa.list_(pa.int64())),
        pa.field("completion", pa.float64()),
        # the env's reward summed over the attempt (GPR's feedback)
        pa.field("reward_sum", pa.float64()),
        pa.field("success", pa.bool_()),
        pa.field("policy_version", pa.int64()),
        pa.field("worker_id", pa.string()),
        pa.field("seed", pa.int64()),
        pa.field("length", pa.int32(), nullable=False),
        pa.field("obs_path", pa.string()),
        pa.field("obs_start", pa.int64(), nullable=False),
    ],
    metadata={"gpl_dist.table": "attempts", "gpl_dist.schema_version": str(SCHEMA_VERSION)},
)

TUPLES_SCHEMA = pa.schema(
    [
        pa.field("attempt_key", pa.int64(), nullable=False),
        pa.field("round", pa.int32(), nullable=False),
        pa.field("unit", pa.int32(), nullable=False),
        pa.field("task_id", pa.int32(), nullable=False),
        pa.field("attempt_index", pa.int32(), nullable=False),
        pa.field("t", pa.int32(), nullable=False),
        pa.field("expert_action", pa.int64(), nullable=False),
        pa.field("action", pa.int64(), nullable=False),
        pa.field("obs_row", pa.int64(), nullable=False),
        # the expert's action distribution (the learner's target); null: one-hot of expert_action
        pa.field("expert_probs", pa.list_(pa.float32())),
    ],
    metadata={"gpl_dist.table": "tuples", "gpl_dist.schema_version": str(SCHEMA_VERSION)},
)


@dataclass(frozen=True)
class UnitTables:
    """One unit's attempts and tuples tables and its observations, ready to write."""

    attempts: pa.Table
    tuples: pa.Table
    observations: np.ndarray | None  # (N, *O); None when the unit has no attempts


def context_keys_of(unit: WorkUnit, attempts: Sequence[Attempt]) -> list[list[int]]:
    """For each attempt, the keys of attempts 0..k-1 of the same task that precede it in the unit.

    Attempts may come task by task or interleaved; attempt 0 of a task starts a new chain.
    Raises ``ValueError`` when attempt ``k`` arrives without attempts ``0..k-1`` before it.
    """
    chains: dict[int, list[int]] = {}
    out: list[list[int]] = []
    for seq, a in enumerate(attempts):
        key = attempt_key(unit.round_index, unit.unit_index, seq)
        k = int(a.attempt_index)
        if k == 0:
            chains[a.task_id] = []
        chain = chains.get(a.task_id)
        if chain is None or len(chain) != k:
            have = 0 if chain is None else len(chain)
            raise ValueError(
                f"unit {unit.unit_index} of round {unit.round_index}: attempt {k} of task {a.task_id} "
                f"(position {seq}) is preceded by {have} attempts of that task, expected {k}"
            )
        out.append(list(chain))
        chain.append(key)
    return out


def _probs_column(attempts: Sequence[Attempt], n: int) -> pa.Array:
    """``expert_probs`` as a list column. A row that is one-hot at ``expert_action`` (all of the
    multi-room expert's, most of the relocation expert's) or unlabelled is stored as null: the
    reader gives it back as one-hot, and the column costs bytes only where labels are soft."""
    width = next((a.expert_probs.shape[1] for a in attempts if a.expert_probs is not None), None)
    if width is None:
        return pa.nulls(n, pa.list_(pa.float32()))
    values = np.zeros((n, width), np.float32)
    soft = np.zeros(n, bool)
    pos = 0
    for a in attempts:
        if a.expert_probs is not None:
            if a.expert_probs.shape[1] != width:
                raise ValueError(f"task {a.task_id}: expert_probs over {a.expert_probs.shape[1]} actions, unit has {width}")
            p = a.expert_probs
            values[pos:pos + a.length] = p
            labelled = a.expert_actions >= 0
            one_hot = np.zeros(a.length, bool)
            one_hot[labelled] = p[labelled, a.expert_actions[labelled]] == 1.0
            soft[pos:pos + a.length] = labelled & ~one_hot
        pos += a.length
    offsets = np.zeros(n + 1, np.int32)
    np.cumsum(soft * width, out=offsets[1:])
    return pa.ListArray.from_arrays(pa.array(offsets), pa.array(values[soft].reshape(-1)), mask=pa.array(~soft))


def build_unit_tables(run_id: str, unit: WorkUnit, attempts: Sequence[Attempt], worker_id: str) -> UnitTables:
    """The tables and observation array of one unit's attempts."""
    n_att = len(attempts)
    ctx = context_keys_of(unit, attempts)
    lengths = np.array([a.length for a in attempts], dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64) if n_att else np.zeros(0, np.int64)
    obs_path = committed_path("obs", unit.round_index, unit.unit_index)
    keys = [attempt_key(unit.round_index, unit.unit_index, i) for i in range(n_att)]
    observations = None
    if n_att:
        shape, dtype = attempts[0].observations.shape[1:], attempts[0].observations.dtype
        for a in attempts:
            if a.observations.shape[1:] != shape or a.observations.dtype != dtype:
                raise ValueError(
                    f"task {a.task_id} attempt {a.attempt_index}: observations {a.observations.shape[1:]} "
                    f"{a.observations.dtype}, unit started with {shape} {dtype}"
                )
        observations = np.ascontiguousarray(np.concatenate([a.observations for a in attempts], axis=0))
    att = pa.Table.from_pydict(
        {
            "attempt_key": keys,
            "run_id": [run_id] * n_att,
            "round": [unit.round_index] * n_att,
            "unit": [unit.unit_index] * n_att,
            "task_id": [int(a.task_id) for a in attempts],
            "split": [a.split for a in attempts],
            "attempt_index": [int(a.attempt_index) for a in attempts],
            "instruction": [a.instruction for a in attempts],
            "instruction_ids": [np.asarray(a.instruction_ids, dtype=np.int64).tolist() for a in attempts],
            "correction": [a.correction for a in attempts],
            "correction_kind": [a.correction_kind for a in attempts],
            "correction_ids": [np.asarray(a.correction_ids, dtype=np.int64).tolist() for a in attempts],
            "context_keys": ctx,
            "completion": [float(a.completion) for a in attempts],
            "reward_sum": [float(a.reward_sum) for a in attempts],
            "success": [bool(a.success) for a in attempts],
            "policy_version": [int(a.policy_version) for a in attempts],
            "worker_id": [worker_id] * n_att,
            "seed": [int(a.seed) for a in attempts],
            "length": lengths.astype(np.int32),
            "obs_path": [obs_path] * n_att,
            "obs_start": starts,
        },
        schema=ATTEMPTS_SCHEMA,
    )
    n = int(lengths.sum())
    rep = lambda values, dt: np.repeat(np.asarray(values, dtype=dt), lengths)  # noqa: E731
    t = (np.arange(n, dtype=np.int64) - np.repeat(starts, lengths)).astype(np.int32)
    tup = pa.Table.from_arrays(
        [
            pa.array(rep(keys, np.int64)),
            pa.array(np.full(n, unit.round_index, np.int32)),
            pa.array(np.full(n, unit.unit_index, np.int32)),
            pa.array(rep([a.task_id for a in attempts], np.int32)),
            pa.array(rep([a.attempt_index for a in attempts], np.int32)),
            pa.array(t),
            pa.array(np.concatenate([a.expert_actions for a in attempts]).astype(np.int64) if n_att else np.zeros(0, np.int64)),
            pa.array(np.concatenate([a.actions for a in attempts]).astype(np.int64) if n_att else np.zeros(0, np.int64)),
            pa.array(np.arange(n, dtype=np.int64)),
            _probs_column(attempts, n),
        ],
        schema=TUPLES_SCHEMA,
    )
    return UnitTables(att, tup, observations)


#: The columns of each table that a shard of an older schema version may lack (read as null).
ADDED_COLUMNS = {"attempts": {"reward_sum": ATTEMPTS_SCHEMA.field("reward_sum")},
                 "tuples": {"expert_probs": TUPLES_SCHEMA.field("expert_probs")}}

"""A run's DAgger rounds as it records them: ``RoundMetrics``, one line of ``RUN_DIR/metrics.jsonl``
and one entry of every checkpoint's history.

``read_round`` is the one place a round's record is read, whichever shape it was written in;
``read_metrics`` reads ``metrics.jsonl`` through it. Everything past them reads ``RoundMetrics``.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from gpl_dist.errors import RunDirError
from learner.health import EncoderHealth

#: A run's round records, one JSON line per round (``RoundMetrics.to_dict``), under its run dir.
METRICS_FILE = "metrics.jsonl"


@dataclass(frozen=True)
class RoundMetrics:
    """One DAgger round, as written to ``metrics.jsonl`` (one JSON line, keys as below except
    ``round_index``, written ``round``) and kept in the checkpoint's history.

    Attributes:
        round_index: the round.
        collected_tuples: labelled states collected; None when the round was committed before a
            restart and not collected again.
        failed_tasks: tasks dropped because their env, expert or oracle raised.
        collection_seconds: wall time of collection and commit.
        load_seconds: wall time of loading the training view.
        completion_by_corrections: mean completion on the round's training tasks after 0..K corrections.
        buffer_tuples: labelled states in the training view.
        loss: cross-entropy to the expert over the last epoch.
        accuracy: agreement with the expert's action over the last epoch.
        train_seconds: wall time of the round's training.
        train_steps: gradient steps.
        correction_spread: see ``learner.trainer.RoundStats`` (None: not measured).
        encoder_health: see ``learner.trainer.RoundStats`` (``()``: no encoder counted).
        config_changes: ``(key, old, new)`` of each setting a ``--resume`` changed from this round
            on (dotted keys; written ``{key: [old, new]}``, and only when there are some).
    """

    round_index: int
    collected_tuples: int | None
    failed_tasks: tuple[int, ...]
    collection_seconds: float
    load_seconds: float
    completion_by_corrections: tuple[float, ...]
    buffer_tuples: int
    loss: float
    accuracy: float
    train_seconds: float
    train_steps: int
    correction_spread: float | None
    encoder_health: tuple[EncoderHealth, ...] = ()
    config_changes: tuple[tuple[str, Any, Any], ...] = ()

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d.update(failed_tasks=list(self.failed_tasks), completion_by_corrections=list(self.completion_by_corrections),
                 encoder_health=[h.to_list() for h in self.encoder_health])
        d.pop("config_changes")
        if self.config_changes:  # absent otherwise: a run without changes writes its lines as before
            d["config_changes"] = {key: [old, new] for key, old, new in self.config_changes}
        return {"round": d.pop("round_index"), **d}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "RoundMetrics":
        """The record ``to_dict`` writes (every key; ``config_changes`` only when there are some).
        A record of any shape is read by ``read_round``."""
        return cls(round_index=int(d["round"]), collected_tuples=d["collected_tuples"],
                   failed_tasks=tuple(d["failed_tasks"]), collection_seconds=float(d["collection_seconds"]),
                   load_seconds=float(d["load_seconds"]),
                   completion_by_corrections=tuple(d["completion_by_corrections"]), buffer_tuples=int(d["buffer_tuples"]),
                   loss=float(d["loss"]), accuracy=float(d["accuracy"]), train_seconds=float(d["train_seconds"]),
                   train_steps=int(d["train_steps"]), correction_spread=d["correction_spread"],
                   encoder_health=tuple(EncoderHealth.from_list(row) for row in d["encoder_health"]),
                   config_changes=tuple((str(k), v[0], v[1]) for k, v in d.get("config_changes", {}).items()))


def read_round(record: dict[str, Any]) -> RoundMetrics:
    """A round's record (a ``metrics.jsonl`` line, or an entry of a checkpoint's history) as
    ``RoundMetrics``: the one place a record of an older shape is read. The shapes, oldest first:

    - no ``correction_spread``, and a round committed before a restart (``collected_tuples``
      null) without ``failed_tasks``: they read as None (no spread recorded) and ``()``;
    - ``correction_spread`` recorded, a resumed round still without ``failed_tasks``: ``()``;
    - every key but ``encoder_health``: it reads as ``()`` (no encoder counted);
    - ``encoder_health`` rows of five values, without ``dead_layers``: it reads as 0;
    - the current (``RoundMetrics.to_dict``): every key, ``encoder_health`` rows of six values,
      and ``config_changes`` only for a round a ``--resume`` changed a setting from.

    ``KeyError``, ``TypeError`` or ``ValueError`` for a record that is no round's."""
    if not isinstance(record, dict):
        raise TypeError(f"a round's record is a JSON object, not {type(record).__name__}")
    health = record.get("encoder_health") or []
    upgraded = {"failed_tasks": [], "correction_spread": None, **record,
                "encoder_health": [list(row) + [0] if len(row) == 5 else row for row in health]}
    return RoundMetrics.from_dict(upgraded)


def read_metrics(run_dir: str | os.PathLike, *, skip_damaged: bool = False) -> dict[int, RoundMetrics]:
    """The last record of each round in ``RUN_DIR/metrics.jsonl`` (a resumed round is written once
    more), each read by ``read_round``; {} without the file. A line that is no round's record
    fails in one line naming the file and the line (``RunDirError``), or with ``skip_damaged`` is
    left out, as an unreadable file is then."""
    path = Path(run_dir) / METRICS_FILE
    try:
        text = path.read_text()
    except FileNotFoundError:
        return {}
    except (OSError, UnicodeDecodeError) as err:
        if skip_damaged:
            return {}
        raise RunDirError(f"cannot read {path} ({type(err).__name__})") from None
    rounds: dict[int, RoundMetrics] = {}
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        try:
            m = read_round(json.loads(line))
        except (ValueError, KeyError, TypeError) as err:
            if skip_damaged:
                continue
            raise RunDirError(f"{path}:{n}: not a round's metrics ({type(err).__name__}: {err})") from None
        rounds[m.round_index] = m
    return rounds

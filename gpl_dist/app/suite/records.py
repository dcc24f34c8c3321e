"""The suite's files in a run dir beside its evaluations, as frozen records: the learning curve on
the valid split (``CURVE_FILE``, written by ``curves``) and the instruction-swap control
(``SWAP_FILE``, written by ``swap``), and the settings both are measured with (``CurveSettings``).

Each record is written by ``to_json`` and read by ``from_json`` (or ``read_curve`` /
``read_swap``, which name the file when it is not one). A file carries its ``schema_version``; one
without it is of version 1 (the same keys; a version-1 curve file from before its settings were
recorded reads as measured on the unknown split ``?``), upgraded where it is read, here only.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gpl_dist.config import RunConfig
from gpl_dist.errors import RunDirError
from gpl_dist.splits import valid_split

#: The file the suite's per-round valid evaluation writes into a run dir.
CURVE_FILE = "curve-valid.json"
#: A run's instruction-swap control on the valid split (``gpl_dist.app.suite.swap``).
SWAP_FILE = "instruction-swap-valid.json"
#: The curve file's schema (``CurveRecord.schema_version``).
CURVE_SCHEMA = 2
#: The swap file's schema (``SwapRecord.schema_version``).
SWAP_SCHEMA = 2
#: Valid tasks a curve point is measured on (all of a smaller split).
CURVE_TASKS = 250
#: Evaluation seeds of a curve point.
CURVE_SEEDS = (0,)
#: Corrections at each curve point (the paper's meta-training count).
CURVE_CORRECTIONS = 5
#: The split a version-1 curve file without settings reads as measured on: none known.
UNKNOWN_SPLIT = "?"


@dataclass(frozen=True)
class CurveSettings:
    """What a curve point (and the swap control) measures; recorded in the file, and a file of
    other settings is measured again.

    Attributes:
        split: the split evaluated: the run's valid split, which ``for_run`` sets (``compute_curve``
            and ``swap.compute_swap`` call it, so a caller's value is replaced).
        tasks: how many of its tasks, spread evenly.
        seeds: evaluation seeds.
        num_corrections: corrections given (baselines without corrections make one attempt).
    """

    split: str = "valid"
    tasks: int = CURVE_TASKS
    seeds: tuple[int, ...] = CURVE_SEEDS
    num_corrections: int = CURVE_CORRECTIONS

    def for_run(self, cfg: RunConfig) -> CurveSettings | None:
        """These settings on the valid split of ``cfg``'s training split; None when it has none."""
        split = valid_split(cfg.env.domain, cfg.env.train_split)
        return None if split is None else dataclasses.replace(self, split=split)

    def to_dict(self) -> dict:
        """As the files hold them."""
        return {"split": self.split, "tasks": self.tasks, "seeds": list(self.seeds), "num_corrections": self.num_corrections}

    @classmethod
    def from_dict(cls, raw: Any) -> CurveSettings:
        """The settings a file holds; ``ValueError`` when they are not settings."""
        raw = _mapping(raw, "settings")
        return cls(_text(_key(raw, "split"), "settings.split"), _integer(_key(raw, "tasks"), "settings.tasks"),
                   tuple(_integer(s, "settings.seeds") for s in _list(_key(raw, "seeds"), "settings.seeds")),
                   _integer(_key(raw, "num_corrections"), "settings.num_corrections"))


@dataclass(frozen=True)
class CurveRecord:
    """A run's learning curve on its valid split: each round's weights evaluated (``CURVE_FILE``).

    Attributes:
        settings: what each point measures.
        rounds: the rounds measured, in the order measured.
        completion: each round's completion after 0..K corrections.
        success: each round's fraction of tasks solved after 0..K corrections.
        checkpoints: each round's checkpoint file name (``round-NNNNNN.pt``).
        schema_version: the file's schema (``CURVE_SCHEMA``, or the older one it was read from).
    """

    settings: CurveSettings
    rounds: tuple[int, ...] = ()
    completion: tuple[tuple[float, ...], ...] = ()
    success: tuple[tuple[float, ...], ...] = ()
    checkpoints: tuple[str, ...] = ()
    schema_version: int = CURVE_SCHEMA

    def with_point(self, round_index: int, completion: list[float], success: list[float], checkpoint: str) -> CurveRecord:
        """This curve with one more round's point, at the current schema."""
        return CurveRecord(self.settings, (*self.rounds, round_index), (*self.completion, tuple(completion)),
                           (*self.success, tuple(success)), (*self.checkpoints, checkpoint))

    def to_json(self) -> str:
        """The file's text (no newline at its end)."""
        return json.dumps({"settings": self.settings.to_dict(), "rounds": list(self.rounds),
                           "completion": [list(c) for c in self.completion], "success": [list(s) for s in self.success],
                           "checkpoints": list(self.checkpoints), "schema_version": self.schema_version}, indent=1)

    @classmethod
    def from_json(cls, text: str) -> CurveRecord:
        """The record of a file's text, of any schema version; ``ValueError`` naming what is wrong."""
        raw, version = _versioned(text, CURVE_SCHEMA)
        if version == 1 and "settings" not in raw:  # measured before its settings were recorded
            raw = {**raw, "settings": CurveSettings(split=UNKNOWN_SPLIT).to_dict()}
        return cls(CurveSettings.from_dict(_key(raw, "settings")),
                   tuple(_integer(r, "rounds") for r in _list(_key(raw, "rounds"), "rounds")),
                   _curves(_key(raw, "completion"), "completion"),
                   _curves(raw.get("success", []) if version == 1 else _key(raw, "success"), "success"),
                   tuple(_text(c, "checkpoints") for c in _list(raw.get("checkpoints", []) if version == 1
                                                                 else _key(raw, "checkpoints"), "checkpoints")),
                   version)


@dataclass(frozen=True)
class Measured:
    """Completion and success after 0..K corrections, on the control's tasks."""

    completion: tuple[float, ...]
    success: tuple[float, ...]

    def to_dict(self) -> dict:
        return {"completion": list(self.completion), "success": list(self.success)}

    @classmethod
    def from_dict(cls, raw: Any, what: str) -> Measured:
        raw = _mapping(raw, what)
        return cls(_numbers(_key(raw, "completion"), f"{what}.completion"),
                   _numbers(_key(raw, "success"), f"{what}.success"))


@dataclass(frozen=True)
class SwapRecord:
    """A run's instruction-swap control on its valid split (``SWAP_FILE``): the final weights with
    the tasks' own instructions and told another task's.

    Attributes:
        settings: what was measured (``CurveSettings``, on the run's valid split).
        rule: how partners were chosen (``learner.evaluate.SWAP_RULE``).
        round: the round the weights end.
        weights_sha256: the SHA-256 of the weights measured (``checkpoints/latest.pt`` then).
        variant: the run's model variant.
        num_tasks: tasks measured.
        own: with their own instructions.
        swapped: each task told another task's instruction.
        schema_version: the file's schema (``SWAP_SCHEMA``, or the older one it was read from).
    """

    settings: CurveSettings
    rule: str
    round: int
    weights_sha256: str
    variant: str
    num_tasks: int
    own: Measured
    swapped: Measured
    schema_version: int = SWAP_SCHEMA

    def measures(self, settings: CurveSettings, rule: str, round_index: int, weights_sha256: str) -> bool:
        """It was measured with these settings and partner rule on these weights."""
        return (self.settings, self.rule, self.round, self.weights_sha256) == (settings, rule, round_index, weights_sha256)

    def to_json(self) -> str:
        """The file's text (no newline at its end)."""
        return json.dumps({"settings": self.settings.to_dict(), "rule": self.rule, "round": self.round,
                           "weights_sha256": self.weights_sha256, "variant": self.variant, "num_tasks": self.num_tasks,
                           "own": self.own.to_dict(), "swapped": self.swapped.to_dict(),
                           "schema_version": self.schema_version}, indent=1)

    @classmethod
    def from_json(cls, text: str) -> SwapRecord:
        """The record of a file's text, of any schema version; ``ValueError`` naming what is wrong."""
        raw, version = _versioned(text, SWAP_SCHEMA)
        return cls(CurveSettings.from_dict(_key(raw, "settings")), _text(_key(raw, "rule"), "rule"),
                   _integer(_key(raw, "round"), "round"), _text(_key(raw, "weights_sha256"), "weights_sha256"),
                   _text(_key(raw, "variant"), "variant"), _integer(_key(raw, "num_tasks"), "num_tasks"),
                   Measured.from_dict(_key(raw, "own"), "own"), Measured.from_dict(_key(raw, "swapped"), "swapped"),
                   version)


def read_curve(path: Path) -> CurveRecord:
    """The ``CurveRecord`` of the file at ``path``; ``RunDirError`` naming it when it is not one."""
    try:
        return CurveRecord.from_json(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as err:
        raise RunDirError(f"{path}: not a learning curve ({type(err).__name__}: {str(err)[:200]}); "
                          "delete it to measure it again") from None


def read_swap(path: Path) -> SwapRecord:
    """The ``SwapRecord`` of the file at ``path``; ``RunDirError`` naming it when it is not one."""
    try:
        return SwapRecord.from_json(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as err:
        raise RunDirError(f"{path}: not an instruction-swap record ({type(err).__name__}: {str(err)[:200]}); "
                          "delete it to measure it again") from None


def _versioned(text: str, current: int) -> tuple[dict, int]:
    """A file's JSON object and its schema version (1 without one); ``ValueError`` for a version
    this code does not read."""
    raw = _mapping(json.loads(text), "the file")
    version = raw.get("schema_version", 1)
    if isinstance(version, bool) or version not in range(1, current + 1):
        raise ValueError(f"schema_version {str(version)[:20]}; this code reads versions 1 to {current}")
    return raw, version


def _key(raw: dict, key: str) -> Any:
    if key not in raw:
        raise ValueError(f"no {key!r}")
    return raw[key]


def _mapping(value: Any, what: str) -> dict:
    if not isinstance(value, dict):
        raise ValueError(f"{what} is not a mapping")
    return value


def _list(value: Any, what: str) -> list:
    if not isinstance(value, list):
        raise ValueError(f"{what} is not a list")
    return value


def _text(value: Any, what: str) -> str:
    if not isinstance(value, str):
        raise ValueError(f"{what} is not a string")
    return value


def _integer(value: Any, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{what} holds {str(value)[:40]}, not an integer")
    return value


def _numbers(value: Any, what: str) -> tuple[float, ...]:
    out = tuple(_list(value, what))
    if any(isinstance(x, bool) or not isinstance(x, (int, float)) for x in out):
        raise ValueError(f"{what} holds a value that is not a number")
    return out


def _curves(value: Any, what: str) -> tuple[tuple[float, ...], ...]:
    return tuple(_numbers(c, what) for c in _list(value, what))

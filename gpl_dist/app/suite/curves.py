"""Learning curves on the valid split: each DAgger round's weights, evaluated (``gpl-dist suite curves``).

A run keeps every round's weights (``checkpoints/round-NNNNNN.pt``) until it is archived, and the
archive keeps only the last; so the curve is computed from a suite's run dirs, after training, and
written into each run dir as ``curve-valid.json`` (``evidence.CURVE_FILE``), which the archive
keeps and the report draws. Whether a baseline was still improving at its last round is read
here, never on the test split.

Each run is measured on its own valid split (``splits.valid_split`` of its training split: ``valid``
for ``train``, ``heldout4_valid`` for ``heldout4_train``), which holds no task it trained on and no
test task; a run on a training split with no valid split has no curve. The curve is cheaper than
the suite's evaluations: ``CURVE_TASKS`` valid tasks spread evenly over the split (every k-th, so
no block of task ids is favoured), one evaluation seed, the run's own
number of corrections (5). A run dir's file is filled in round by round, so a killed command
resumes where it stopped, and a finished curve is not computed again.
"""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gpl_dist.app.suite.rundata import CURVE_FILE
from gpl_dist.config import RunConfig, config_from_dict
from gpl_dist.errors import RunDirError
from gpl_dist.splits import split_tasks, valid_split
from learner.checkpoint import load_checkpoint
from learner.evaluate import evaluate_policy, load_trained_policy

#: Valid tasks a curve point is measured on (all of a smaller split).
CURVE_TASKS = 250
#: Evaluation seeds of a curve point.
CURVE_SEEDS = (0,)
#: Corrections at each curve point (the paper's meta-training count).
CURVE_CORRECTIONS = 5


@dataclass(frozen=True)
class CurveSettings:
    """What a curve point measures (recorded in the file; a file of other settings is recomputed).

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
        return {"split": self.split, "tasks": self.tasks, "seeds": list(self.seeds), "num_corrections": self.num_corrections}


def curve_tasks(domain: str, settings: CurveSettings) -> tuple[int, ...]:
    """``settings.tasks`` tasks of the split, every k-th of its sorted ids."""
    tasks = split_tasks(domain, settings.split)
    step = max(1, len(tasks) // settings.tasks)
    return tuple(tasks[::step][:settings.tasks])


def round_checkpoints(run_dir: Path) -> list[Path]:
    """The run's per-round weights, in round order."""
    return sorted((run_dir / "checkpoints").glob("round-*.pt"))


def run_config(checkpoint: Path) -> RunConfig:
    """The config a checkpoint was trained under (without building its model)."""
    return config_from_dict(load_checkpoint(checkpoint).config, f"{checkpoint} (its config)")


def compute_curve(run_dir: str | Path, settings: CurveSettings = CurveSettings(), log=print) -> Path | None:
    """Fill ``run_dir/curve-valid.json`` with every round's completion on the run's valid split
    (resumes a partial file of the same settings; a file of other settings, another split among
    them, is measured again); None when the run dir keeps no per-round weights or its training
    split has no valid split."""
    run_dir = Path(run_dir)
    ckpts = round_checkpoints(run_dir)
    if not ckpts:
        return None
    resolved = settings.for_run(run_config(ckpts[-1]))
    if resolved is None:
        return None
    settings = resolved
    path = run_dir / CURVE_FILE
    payload: dict[str, Any] = {"settings": settings.to_dict(), "rounds": [], "completion": [], "success": [], "checkpoints": []}
    if path.is_file():
        try:
            old = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as err:
            raise RunDirError(f"cannot read {path} ({type(err).__name__}: {err}); delete it to recompute") from None
        if isinstance(old, dict) and old.get("settings") == payload["settings"]:
            payload = old
    done = set(payload["checkpoints"])
    for ckpt in ckpts:
        if ckpt.name in done:
            continue
        cfg, model, round_index = load_trained_policy(run_dir, str(ckpt))
        result = evaluate_policy(cfg, model, num_corrections=settings.num_corrections, seeds=settings.seeds,
                                 split=settings.split, tasks=curve_tasks(cfg.env.domain, settings))
        payload["rounds"].append(round_index)
        payload["completion"].append(result.completion)
        payload["success"].append(result.success)
        payload["checkpoints"].append(ckpt.name)
        tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
        tmp.write_text(json.dumps(payload, indent=1))
        os.replace(tmp, path)
        log(f"{run_dir}: round {round_index} valid completion "
            + " ".join(f"c{k}={v:.3f}" for k, v in enumerate(result.completion)))
    return path


def suite_run_dirs(suite_out: str | Path, entries: set[str] | None = None, seeds: set[int] | None = None) -> list[Path]:
    """The run dirs ``suite_out/<entry>/seed<k>`` that have a ``suite-run.json``, in order;
    optionally only ``entries`` and ``seeds``. A folder with no such run fails in one line that
    says what layout is expected (``RunDirError``)."""
    root = Path(suite_out)
    if not root.is_dir():
        raise RunDirError(f"no suite output at {root}")
    records = sorted(root.glob("*/seed*/suite-run.json"))
    if not records:
        raise RunDirError(f"no suite runs under {root}: expected {root}/<entry>/seed<k>/ run dirs, each with the "
                          "suite-run.json, config.yaml, metrics.jsonl and checkpoints/ that `gpl-dist suite run SUITE "
                          "--out OUT` writes")
    chosen = [record.parent for record in records
              if (entries is None or record.parent.parent.name in entries)
              and (seeds is None or int(record.parent.name.removeprefix("seed")) in seeds)]
    if not chosen:
        held = ", ".join(sorted({r.parent.parent.name for r in records}))
        wanted = (f"entries {', '.join(sorted(entries or ())) or 'any'}, "
                  f"seeds {', '.join(map(str, sorted(seeds or ()))) or 'any'}")
        raise RunDirError(f"no suite run under {root} is of the selected {wanted}: it holds entries {held}")
    return chosen


def compute_curves(suite_out: str | Path, entries: set[str] | None = None, seeds: set[int] | None = None,
                   settings: CurveSettings = CurveSettings(), log=print) -> list[Path]:
    """``compute_curve`` for every trained run of ``suite_run_dirs``."""
    return [out for run_dir in suite_run_dirs(suite_out, entries, seeds)
            if (out := compute_curve(run_dir, settings, log)) is not None]

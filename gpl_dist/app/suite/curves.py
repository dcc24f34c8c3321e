"""Learning curves on the valid split: each DAgger round's weights, evaluated (``gpl-dist suite curves``).

A run keeps every round's weights (``checkpoints/round-NNNNNN.pt``) until it is archived, and the
archive keeps only the last; so the curve is computed from a suite's run dirs, after training, and
written into each run dir as ``curve-valid.json`` (``records.CURVE_FILE``, a ``CurveRecord``), which the archive
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

from pathlib import Path

from gpl_dist.app.suite.records import CURVE_FILE, CurveRecord, CurveSettings, read_curve
from gpl_dist.atomic import write_atomic
from gpl_dist.config import RunConfig, config_from_dict
from gpl_dist.errors import RunDirError
from gpl_dist.splits import split_tasks
from learner.checkpoint import load_checkpoint
from learner.evaluate import evaluate_policy, load_trained_policy


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


def compute_curve(run_dir: str | Path, settings: CurveSettings = CurveSettings(), log=print,
                  replace_other: bool = True) -> Path | None:
    """Fill ``run_dir/curve-valid.json`` with every round's completion on the run's valid split
    (resumes a partial file of the same settings; a file of other settings, another split among
    them, is measured again, or with ``replace_other=False`` kept as it is; a file that is no
    ``CurveRecord`` fails in one line naming it); None when the run dir keeps no per-round weights
    or its training split has no valid split."""
    run_dir = Path(run_dir)
    ckpts = round_checkpoints(run_dir)
    if not ckpts:
        return None
    resolved = settings.for_run(run_config(ckpts[-1]))
    if resolved is None:
        return None
    settings = resolved
    path = run_dir / CURVE_FILE
    record = CurveRecord(settings)
    if path.is_file():
        old = read_curve(path)
        if old.settings == settings:
            record = old
        elif not replace_other:
            return path
    done = set(record.checkpoints)
    for ckpt in ckpts:
        if ckpt.name in done:
            continue
        cfg, model, round_index = load_trained_policy(run_dir, str(ckpt))
        result = evaluate_policy(cfg, model, num_corrections=settings.num_corrections, seeds=settings.seeds,
                                 split=settings.split, tasks=curve_tasks(cfg.env.domain, settings))
        record = record.with_point(round_index, result.completion, result.success, ckpt.name)
        write_atomic(path, record.to_json())
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

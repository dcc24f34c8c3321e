"""The instruction-swap control on the valid split, for every run of a suite (``gpl-dist suite swap``).

Does a trained policy read its instruction? The health count (``learner.health``) cannot say:
under LeakyReLU a layer whose units are all "never positive" still passes its input at slope 0.01.
The direct check is to tell each task another task's instruction
(``learner.evaluate.swapped_instructions``) and compare completion with the completion the same
weights reach with their own instructions, on the same tasks with the same seed: a policy blind to
its instruction scores the same. Measured with the learning curve's settings
(``records.CurveSettings``: ``CURVE_TASKS`` valid tasks spread evenly, one evaluation seed, 5
corrections, the run's own valid split) on the run's final weights, and written into the run dir as
``SWAP_FILE`` (a ``records.SwapRecord``), which the
archive keeps and the report tabulates. Runs whose variant reads no instruction, and runs not
evaluated yet (still training), are skipped; a file of the same settings, partner rule and weights
(their SHA-256) is not computed again, and the report leaves out a file whose weights are not the
run's.
"""

from __future__ import annotations

from pathlib import Path

from gpl_dist.app.suite.curves import curve_tasks, suite_run_dirs
from gpl_dist.app.suite.evidence import read_json, sha256_file
from gpl_dist.app.suite.records import SWAP_FILE, CurveSettings, Measured, SwapRecord, read_swap
from gpl_dist.atomic import write_atomic
from gpl_dist.variants import READS_INSTRUCTION
from learner.checkpoint import LATEST
from learner.evaluate import SWAP_RULE, evaluate_policy, load_trained_policy


def compute_swap(run_dir: str | Path, settings: CurveSettings = CurveSettings(), log=print) -> Path | None:
    """Write ``run_dir/SWAP_FILE``: completion with the tasks' own instructions and with swapped
    ones, on the run's valid split (``settings.split`` is replaced by it); None for a run whose
    variant reads no instruction, whose training split has no valid split, or that is not
    evaluated yet (its ``suite-run.json`` records no evaluation: it may still be training). A file
    measured with the same settings and partner rule on the same weights is kept; one that is no
    ``SwapRecord`` fails in one line naming it."""
    run_dir = Path(run_dir)
    ckpt = run_dir / "checkpoints" / LATEST
    if not ckpt.is_file() or not read_json(run_dir / "suite-run.json").get("evaluations"):
        return None
    path = run_dir / SWAP_FILE
    cfg, model, round_index = load_trained_policy(run_dir, str(ckpt))
    if cfg.model.variant not in READS_INSTRUCTION:
        return None
    resolved = settings.for_run(cfg)
    if resolved is None:  # as its curve: the control reads a run's valid split only
        log(f"{run_dir}: trained on '{cfg.env.train_split}', which has no valid split: no instruction-swap control")
        return None
    settings = resolved
    weights = sha256_file(ckpt)
    if path.is_file() and read_swap(path).measures(settings, SWAP_RULE, round_index, weights):
        return path
    tasks = curve_tasks(cfg.env.domain, settings)
    measured = {}
    for told, swap in (("own", False), ("swapped", True)):
        result = evaluate_policy(cfg, model, num_corrections=settings.num_corrections, seeds=settings.seeds,
                                 split=settings.split, tasks=tasks, swap_instructions=swap)
        measured[told] = Measured(tuple(result.completion), tuple(result.success))
    record = SwapRecord(settings, SWAP_RULE, round_index, weights, cfg.model.variant, len(tasks),
                        measured["own"], measured["swapped"])
    write_atomic(path, record.to_json())
    own, swapped = record.own.completion, record.swapped.completion
    log(f"{run_dir}: valid completion after the last attempt {own[-1]:.3f} with its own instructions, "
        f"{swapped[-1]:.3f} told another task's (first attempt {own[0]:.3f}, {swapped[0]:.3f})")
    return path


def compute_swaps(suite_out: str | Path, entries: set[str] | None = None, seeds: set[int] | None = None,
                  settings: CurveSettings = CurveSettings(), log=print) -> list[Path]:
    """``compute_swap`` for every run of ``curves.suite_run_dirs`` (optionally only ``entries``
    and ``seeds``); a folder without ``<entry>/seed<k>/suite-run.json`` run dirs, or a selection of
    none of them, fails in one line saying so (``RunDirError``)."""
    return [out for run_dir in suite_run_dirs(suite_out, entries, seeds)
            if (out := compute_swap(run_dir, settings, log)) is not None]

"""Sections of the report about the runs themselves, for any suite: health, each training seed's
numbers, budgets, correction effort, evaluation settings and provenance. Each builds Markdown
from results and what ``report_data`` read, with no I/O of its own.
"""

from __future__ import annotations

import statistics
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from gpl_dist.app.suite.report_data import RunResult
from gpl_dist.app.suite.run_facts import RunBudget, RunHealth


def shown(run_dir: Path, report_dir: Path) -> Path:
    """``run_dir`` relative to the report's folder where it lies inside it."""
    return run_dir.relative_to(report_dir) if run_dir.is_relative_to(report_dir) else run_dir


def health_markdown(health: Mapping[Path, RunHealth], report_dir: Path) -> str:
    """Every run's conditioning encoders at its final round (dead / units per encoder: i
    instruction, c correction, t trajectory, p pair) and the rounds any layer of them was dead
    whole; a run dead at its final round is not valid and is out of every mean."""
    lines = ["| run | rounds | final round: dead units; layers dead whole | valid |", "|---|---|---|---|"]
    for run_dir, h in health.items():
        valid = "yes" if h.valid and h.instrumented else "yes (not instrumented)" if h.valid else "**no**"
        lines.append(f"| `{shown(run_dir, report_dir)}` | {h.rounds} | {h.text()} | {valid} |")
    bad = sum(not h.valid for h in health.values())
    lines.append(f"\n{len(health)} runs; {bad} not valid; "
                 f"{sum(bool(h.dead_layers) for h in health.values())} with a layer dead whole in some round; "
                 f"{sum(not h.instrumented for h in health.values())} not instrumented.")
    return "\n".join(lines)


def per_seed_markdown(results: Sequence[RunResult], health: Mapping[Path, RunHealth]) -> str:
    """Each entry's evaluations, one line a training seed: completion after each k, success after
    the first and the last, and whether the run is valid."""
    lines = ["| entry | evaluation | seed | completion c0 .. cK | success c0, cK | valid |", "|---|---|---|---|---|---|"]
    for r in sorted(results, key=lambda r: (r.entry, r.evaluation, r.seed)):
        comp = " ".join(f"{x:.3f}" for x in r.completion)
        succ = f"{r.success[0]:.3f}, {r.success[-1]:.3f}" if r.success else "—"
        lines.append(f"| {r.entry} | {r.evaluation} | {r.seed} | {comp} | {succ} | "
                     f"{'yes' if health[r.run_dir].valid else '**no**'} |")
    return "\n".join(lines)


def budgets_markdown(results: Sequence[RunResult], budgets: Mapping[Path, RunBudget]) -> str:
    """Per entry, mean over its runs: rounds, tuples collected, gradient steps, trained parameters,
    the learner's and collection's wall time."""
    runs: dict[str, dict[Path, RunBudget]] = {}
    for r in results:
        runs.setdefault(r.entry, {})[r.run_dir] = budgets[r.run_dir]
    lines = ["| entry | runs | rounds | tuples collected | gradient steps | parameters | train min | collect min |",
             "|---|---|---|---|---|---|---|---|"]
    for entry in sorted(runs):
        b = list(runs[entry].values())
        params = sorted({x.parameters for x in b if x.parameters is not None})
        tuples = f"{statistics.fmean(x.tuples for x in b):,.0f}" + (
            "" if all(x.tuples_complete for x in b) else " (≥: a resumed round)")
        lines.append(f"| {entry} | {len(b)} | {statistics.fmean(x.rounds for x in b):.0f} | {tuples} | "
                     f"{statistics.fmean(x.gradient_steps for x in b):,.0f} | {', '.join(f'{p:,}' for p in params) or '—'} | "
                     f"{statistics.fmean(x.train_seconds for x in b) / 60:.1f} | "
                     f"{statistics.fmean(x.collection_seconds for x in b) / 60:.1f} |")
    return "\n".join(lines)


_EFFORT = (("corrections_to_solve", "corrections per solved task"), ("words_per_solved_task", "words per solved task"),
           ("unsolved_fraction", "unsolved"), ("completion_auc", "completion AUC"))


def effort_markdown(results: Sequence[RunResult], evaluation: str = "test") -> str:
    """Correction effort of every entry's ``evaluation``, mean over training seeds."""
    lines = ["| entry | " + " | ".join(label for _, label in _EFFORT) + " | training seeds |",
             "|---|" + "---|" * (len(_EFFORT) + 1)]
    for entry in sorted({r.entry for r in results if r.evaluation == evaluation}):
        mine = [r for r in results if r.entry == entry and r.evaluation == evaluation and r.effort]
        cells = []
        for key, _ in _EFFORT:
            values = [getattr(r.effort, key) for r in mine if getattr(r.effort, key) is not None]
            cells.append(f"{statistics.fmean(values):.3f}" if values else "—")
        seeds = str(len(mine)) if mine else "none: evaluated before the effort was recorded (`gpl-dist eval` again)"
        lines.append(f"| {entry} | " + " | ".join(cells) + f" | {seeds} |")
    return "\n".join(lines)


def evaluations_markdown(results: Sequence[RunResult]) -> str:
    """Each evaluation's settings, as every run recorded them (identical: ``report_data._check_same_settings``)."""
    lines = ["| evaluation | split | evaluation seeds | corrections | actions | tasks |", "|---|---|---|---|---|---|"]
    for name in sorted({r.evaluation for r in results}):
        s: dict[str, Any] = dict(next(r for r in results if r.evaluation == name).settings)
        lines.append(f"| {name} | {s['split']} | {', '.join(map(str, s['seeds']))} | {s['num_corrections']} | "
                     f"{'greedy' if s['greedy_actions'] else 'sampled'} | {s['max_tasks'] or 'all'} |")
    return "\n".join(lines)


#: What the provenance table's numerics column means for a person re-training a run.
REPRODUCING = ("**Re-training a run.** `gpl-dist suite run SUITE --out DIR --only ENTRY --seeds S` trains a run "
               "again from its seed. Where `gpl-dist suite status` marks it `numerics as here` (its recorded "
               "fingerprint is this machine's: trained on the CPU, one thread per learner, not on a cluster), it "
               "writes the same metrics and eval files, bit for bit. Under another fingerprint (another CPU model or "
               "thread count, another torch, numpy or MuJoCo version) MKL and oneDNN sum in another order, the last "
               "bits differ, training amplifies them, and the run lands at another point of its entry's seed "
               "spread: compare it with the per-seed table, not with one file. `gpu`, `threads>1`, `cluster`: no "
               "bitwise reproduction on offer; \"not recorded\": trained before fingerprints were recorded.")


def provenance_markdown(results: Sequence[RunResult], report_dir: Path, left_out: Sequence[RunResult] = ()) -> str:
    """Per run, every archived one (``results`` the valid, ``left_out`` those the health gate left
    out, marked so): its archived dir (relative to ``report_dir``), config, code commits, the numerics
    fingerprint of the machine that trained it, wall times and evaluation files."""
    lines = ["| entry | seed | archived run dir (config: `config.yaml` there) | code commit(s) | numerics | train min | "
             "evaluations (file, min) |",
             "|---|---|---|---|---|---|---|"]
    invalid = {r.run_dir for r in left_out}
    results = [*results, *left_out]
    runs = sorted({(r.entry, r.seed, r.run_dir) for r in results})
    for entry, seed, run_dir in runs:
        mine = [r for r in results if r.run_dir == run_dir]
        evals = ", ".join(f"{r.evaluation}: `{r.eval_file.name}` ({r.eval_seconds / 60:.1f})" for r in mine)
        first = mine[0]
        commits = ", ".join(first.commits)
        numerics = ", ".join(first.numerics) or "not recorded"
        seed_cell = f"{seed} (not valid: left out of the means)" if run_dir in invalid else str(seed)
        lines.append(f"| {entry} | {seed_cell} | `{shown(run_dir, report_dir)}` | {commits} | {numerics} | "
                     f"{first.train_seconds / 60:.1f} | {evals} |")
    train_s = sum({r.run_dir: r.train_seconds for r in results}.values())
    eval_s = sum(r.eval_seconds for r in results)
    lines.append(f"\nWall time of these runs: {train_s / 3600:.1f} h training, {eval_s / 3600:.2f} h evaluation, "
                 "as each run's process measured it on the machine it ran on.")
    lines.append("\n" + REPRODUCING)
    return "\n".join(lines)

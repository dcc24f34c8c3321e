"""A suite's own comparison, for any suite: per evaluation, every entry's completion after each
correction (mean over training seeds ± the half-width of its 95 % t interval) with its domain and
rounds as its runs' configs say, the success rate beside it, and Welch's test of every entry
against the suite's reference entry (the suite file's top-level ``reference``). The builders
here read no file: they take results and what ``report_data`` read.
"""

from __future__ import annotations

import re
import statistics
from collections.abc import Mapping, Sequence
from typing import Any

from gpl_dist.app.suite.report_data import RunResult, SuitePlan, cell, status
from gpl_dist.app.suite.report_plots import PlotRow
from gpl_dist.app.suite.run_facts import RunSetup
from gpl_dist.app.suite.stats import welch


def evaluation_names(results: Sequence[RunResult], plan: SuitePlan) -> list[str]:
    """The evaluations with results: in the suite file's order, then any other by name."""
    had = {r.evaluation for r in results}
    named = [n for names in plan.evaluations.values() for n in names]
    order = list(dict.fromkeys(n for n in named if n in had))
    return order + sorted(had - set(order))


def entries_of(results: Sequence[RunResult], plan: SuitePlan, evaluation: str) -> list[str]:
    """The entries that name ``evaluation`` in the suite file (in its order) or have results on it."""
    listed = [e for e, names in plan.evaluations.items() if evaluation in names]
    return listed + sorted({r.entry for r in results if r.evaluation == evaluation} - set(listed))


def columns_of(results: Sequence[RunResult], evaluation: str) -> tuple[int, ...]:
    """Corrections 0..K the evaluation's runs have values for (K the most any has)."""
    return tuple(range(max((len(r.completion) for r in results if r.evaluation == evaluation), default=1)))


def _label(entry: str, reference: str | None) -> str:
    return f"{entry} (reference)" if entry == reference else entry


def _settings(results: Sequence[RunResult], evaluation: str) -> str:
    s: dict[str, Any] = dict(next(r for r in results if r.evaluation == evaluation).settings)
    return (f"split {s['split']}, {len(s['seeds'])} evaluation seed(s), {s['num_corrections']} corrections, "
            f"{'greedy' if s['greedy_actions'] else 'sampled'} actions")


def _joined(values: set) -> str:
    return ", ".join(map(str, sorted(values))) or "—"


def completion_markdown(results: Sequence[RunResult], every: Sequence[RunResult], evaluation: str, plan: SuitePlan,
                        setups: Mapping[str, Sequence[RunSetup]]) -> str:
    """Every entry of ``evaluation``: its domain and rounds (its runs' configs), completion after
    each correction over its valid runs (``results``; ``every``: valid or not), and which seeds."""
    columns = columns_of(every, evaluation)
    excluded = [r for r in every if r not in results]
    lines = [f"**Evaluation '{evaluation}' ({_settings(every, evaluation)}).** Each cell: mean completion over "
             "training seeds after k corrections ± the half-width of its 95 % t interval (one seed: no ±); '—': no "
             "valid run; blank: the entry takes no corrections (its one number is the first attempt's).", "",
             "| entry | domain | rounds | " + " | ".join(f"c{k}" for k in columns) + " | runs |",
             "|" + "---|" * (len(columns) + 4)]
    for entry in entries_of(every, plan, evaluation):
        own = [r for r in every if r.entry == entry and r.evaluation == evaluation]
        width = max((len(r.completion) for r in own), default=len(columns))
        cells = []
        for k in columns:
            ours = cell(results, entry, evaluation, k)
            cells.append("" if k >= width else ours.text() if ours else "—")
        mine = setups.get(entry, ())
        lines.append(f"| {_label(entry, plan.reference)} | {_joined({s.domain for s in mine})} | "
                     f"{_joined({s.rounds for s in mine})} | " + " | ".join(cells)
                     + f" | {status(results, entry, evaluation, plan.seeds, excluded)} |")
    return "\n".join(lines)


def success_markdown(results: Sequence[RunResult], every: Sequence[RunResult], evaluation: str, plan: SuitePlan) -> str:
    """The success rates (fraction of tasks solved after k corrections) of the same runs."""
    columns = columns_of(every, evaluation)
    lines = ["Success rate (tasks solved), the same runs, mean ± 95 % half-width:", "",
             "| entry | " + " | ".join(f"c{k}" for k in columns) + " | training seeds |",
             "|" + "---|" * (len(columns) + 2)]
    for entry in entries_of(every, plan, evaluation):
        width = max((len(r.success) for r in every if r.entry == entry and r.evaluation == evaluation), default=len(columns))
        cells = []
        for k in columns:
            ours = cell(results, entry, evaluation, k, "success")
            cells.append("" if k >= width else ours.text() if ours else "—")
        seeds = len({r.seed for r in results if r.entry == entry and r.evaluation == evaluation})
        lines.append(f"| {_label(entry, plan.reference)} | " + " | ".join(cells) + f" | {seeds} |")
    return "\n".join(lines)


def _by_seed(results: Sequence[RunResult], entry: str, evaluation: str) -> list[RunResult]:
    return sorted((r for r in results if r.entry == entry and r.evaluation == evaluation), key=lambda r: r.seed)


def welch_markdown(results: Sequence[RunResult], evaluation: str, plan: SuitePlan, wanted: Mapping[str, int]) -> str:
    """Welch's two-sided t-test of every entry against the reference on ``evaluation``: after the
    first attempt (c0 against c0) and after the last correction each side has (a baseline without
    corrections: its c0 against the reference's last), over the valid runs' training seeds."""
    reference = plan.reference
    if reference is None:
        return ("No reference entry: the suite file names none (a top-level `reference: <entry>`), so no entry is "
                "tested against another.")
    ref = _by_seed(results, reference, evaluation)
    if not ref:
        return f"The reference `{reference}` has no valid run on evaluation '{evaluation}': no entry is tested here."
    lines = [f"Welch's two-sided t-test of each entry against the reference `{reference}` over training seeds (the "
             "valid runs): after the first attempt, and after the last correction each has; 'tie' when p >= 0.05; "
             "provisional while a side has fewer valid runs than the suite file plans.", "",
             "| entry | compared | reference (mean, seeds) | entry (mean, seeds) | difference | Welch t | df | p | "
             "verdict |", "|---|---|---|---|---|---|---|---|---|"]
    ref_last = min(len(r.completion) for r in ref) - 1
    for entry in entries_of(results, plan, evaluation):
        mine = _by_seed(results, entry, evaluation)
        if entry == reference or not mine:
            continue
        last = min(len(r.completion) for r in mine) - 1
        for k, ref_k in dict.fromkeys([(0, 0), (last, ref_last)]):
            a = [r.completion[k] for r in mine]
            b = [r.completion[ref_k] for r in ref]
            w = welch(a, b)
            verdict = w.verdict(entry, reference)
            short = [f"{name} {len(got)} of {want} seeds" for name, got in ((reference, b), (entry, a))
                     if len(got) < (want := wanted.get(name, 0))]
            if short and w.p is not None:
                verdict += f" (provisional: {'; '.join(short)})"
            lines.append(f"| {entry} | c{k} vs c{ref_k} | {statistics.fmean(b):.3f} ({len(b)}) | "
                         f"{statistics.fmean(a):.3f} ({len(a)}) | {w.difference:+.3f} | {_fmt(w.t, '.2f')} | "
                         f"{_fmt(w.df, '.1f')} | {_fmt(w.p, '.3g')} | {verdict} |")
    if len(lines) == 4:
        return f"No entry but the reference `{reference}` has a valid run on evaluation '{evaluation}'."
    return "\n".join(lines)


def _fmt(value: float | None, spec: str) -> str:
    return "—" if value is None else format(value, spec)


def plot_rows(results: Sequence[RunResult], every: Sequence[RunResult], evaluation: str, plan: SuitePlan) -> list[PlotRow]:
    """Every entry of ``evaluation`` as a line of ``report_plots.plot_completion``."""
    rows = []
    for entry in entries_of(every, plan, evaluation):
        width = max((len(r.completion) for r in every if r.entry == entry and r.evaluation == evaluation), default=0)
        ks = tuple(range(width))
        rows.append(PlotRow(_label(entry, plan.reference), ks, tuple(cell(results, entry, evaluation, k) for k in ks)))
    return rows


def plot_name(evaluation: str) -> str:
    """The file of ``evaluation``'s plot: its name with anything but letters, digits, '-' and '_' replaced."""
    return "evaluation-" + re.sub(r"[^A-Za-z0-9_-]", "_", evaluation) + ".png"

"""Sections of the report that check the runs, for any suite: does each policy read its
instruction (the instruction-swap control), and was each entry still improving at its last round
(its valid learning curve). Each builds Markdown from results and what ``report_data`` read
(``RunFacts``), with no I/O of its own.
"""

from __future__ import annotations

import statistics
from collections.abc import Mapping, Sequence
from pathlib import Path

from gpl_dist.app.suite.report_data import RunFacts, RunResult
from gpl_dist.app.suite.run_facts import InstructionSwap, LearningCurve, RunHealth
from gpl_dist.app.suite.stats import ALPHA, MeanCI, mean_ci, t_two_sided_p
from learner.evaluate import SWAP_RULE


def paired(own: list[float], swapped: list[float]) -> tuple[MeanCI, float | None]:
    """The paired difference ``swapped - own`` over training seeds: its mean with the 95 % t
    interval, and the two-sided p of the one-sample t test against 0 (None for one seed)."""
    diff = mean_ci([s - o for o, s in zip(own, swapped)])
    if diff.sd is None:
        return diff, None
    if diff.sd == 0.0:
        return diff, 1.0 if diff.mean == 0.0 else 0.0
    return diff, t_two_sided_p(diff.mean / (diff.sd / diff.n ** 0.5), diff.n - 1)


def paired_text(diff: MeanCI, p: float | None) -> str:
    """``+0.012 ± 0.034, p 0.42``: a paired difference with its interval and p ('—' for one seed)."""
    ci = f"{diff.mean:+.3f}" + ("" if diff.half_width is None else f" ± {diff.half_width:.3f}")
    return f"{ci}, p {'—' if p is None else f'{p:.2g}'}"


#: The largest change of the swap control's completion (own minus told another's, after the last
#: attempt) of any run at the 0.02-0.03 floor, where the control cannot tell (0.019 in the archive):
#: a run that drops less does not measurably read its instruction.
FLOOR_CHANGE = 0.02
#: A drop that shows a run reads its instruction: five times ``FLOOR_CHANGE``. Where some runs of an
#: entry drop this much, its runs that drop less than ``FLOOR_CHANGE`` are named as not reading theirs.
READ_DROP = 0.1


def swap_table(results: Sequence[RunResult], health: Mapping[Path, RunHealth], facts: Mapping[Path, RunFacts]) -> str:
    """The instruction-swap control (``gpl_dist.app.suite.swap``, each run's valid split) per entry, over its
    valid runs: completion with the tasks' own instructions and told another task's, after the
    first and the last attempt, each with the paired difference (swapped minus own) over training
    seeds, its 95 % t interval and two-sided p. Below the table, one a line: runs that are not
    valid, runs measured on other weights, with another partner rule or on another split than the
    run's valid split (left out), valid runs not
    measured yet, and the valid runs that drop less than ``FLOOR_CHANGE`` told another task's
    instruction after the last attempt where some of the entry's runs drop by ``READ_DROP`` or more
    (those runs do not read their instruction; the entry's mean drop can hide them)."""
    runs: dict[str, dict[int, Path]] = {}
    for r in results:
        runs.setdefault(r.entry, {})[r.seed] = r.run_dir
    lines = ["| entry | runs | first attempt: own, told another's | first: swapped − own (95 % t), p | "
             "last attempt: own, told another's | last: swapped − own (95 % t), p | reads its instruction |",
             "|---|---|---|---|---|---|---|"]
    notes: list[str] = []
    for entry in sorted(runs):
        unmeasured: list[int] = []
        by_seed: dict[int, InstructionSwap] = {}
        for seed, run_dir in sorted(runs[entry].items()):
            f = facts[run_dir]
            sw = f.swap
            if sw is None:
                unmeasured.append(seed)
                continue
            own_split = f.swap_split
            if sw.split != own_split:
                notes.append(f"- `{entry}` seed {seed}: measured on `{sw.split}`, "
                             + (f"not the run's valid split (`{own_split}`); left out (measure it again with "
                                "`gpl-dist suite swap`)" if own_split else "but its training split has no valid split; left out"))
            elif sw.rule != SWAP_RULE or not f.swap_current:
                notes.append(f"- `{entry}` seed {seed}: measured other weights or with another partner rule "
                             f"than `{SWAP_RULE}`; left out (measure it again with `gpl-dist suite swap`)")
            elif not health[run_dir].valid:
                notes.append(f"- `{entry}` seed {seed} (not valid, left out): first attempt {sw.own[0]:.3f} with its "
                             f"own instructions, {sw.swapped[0]:.3f} told another task's; last {sw.own[-1]:.3f}, "
                             f"{sw.swapped[-1]:.3f}")
            else:
                by_seed[seed] = sw
        measured = list(by_seed.values())
        if unmeasured and measured:
            notes.append(f"- `{entry}`: seed(s) {', '.join(map(str, unmeasured))} not measured yet")
        if not measured:
            continue
        drop = {seed: sw.own[-1] - sw.swapped[-1] for seed, sw in by_seed.items()}  # after the last attempt
        blind = [seed for seed, d in drop.items() if d < FLOOR_CHANGE]
        if blind and max(drop.values()) >= READ_DROP:
            notes.append(f"- `{entry}` seed(s) {', '.join(map(str, blind))}: told another task's "
                         f"instruction, less than {FLOOR_CHANGE} lower after the last attempt ("
                         + ", ".join(f"{by_seed[s].own[-1]:.3f} own, {by_seed[s].swapped[-1]:.3f} told another's"
                                     for s in blind)
                         + f"), where some of the entry's runs drop by {READ_DROP} or more: these runs do not "
                         "read their instruction")
        cells, verdicts = [], []
        for k in ((0, -1) if len(measured[0].own) > 1 else (0,)):
            own, swapped = [sw.own[k] for sw in measured], [sw.swapped[k] for sw in measured]
            diff, p = paired(own, swapped)
            cells += [f"{statistics.fmean(own):.3f}, {statistics.fmean(swapped):.3f}", paired_text(diff, p)]
            verdicts.append(None if p is None else p < ALPHA and diff.mean < 0)
        if len(cells) == 2:
            cells += ["(one attempt)", "(one attempt)"]
        reads = "—" if None in verdicts else "yes" if any(verdicts) else "no measurable drop"
        lines.append(f"| {entry} | {len(measured)} | {' | '.join(cells)} | {reads} |")
    if len(lines) == 2:
        return "No run has its instruction-swap control yet (`gpl-dist suite swap OUT`)."
    return "\n".join(lines + ([""] + notes if notes else []))


def plateau_table(results: Sequence[RunResult], planned: Mapping[str, tuple[int, ...]],
                  curves: Mapping[Path, LearningCurve], longer: Mapping[str, tuple[str, ...]]) -> str:
    """Whether each entry was still improving at its last round, on the valid split: per run, the
    valid completion after the last attempt at its last round minus that at the round before
    (``curve-valid.json``, ``gpl-dist suite curves``); over the entry's valid runs, the mean gain
    with its 95 % t interval and the two-sided p of the t test against 0. 'still rising' when the
    gain is significantly above 0, 'flat' when it is a tie with 0. The suite trains an entry that
    was still rising for more rounds under another entry (``longer``: the same definition with more
    rounds, ``report_data.trained_longer``), and both are reported. Beside
    it, each run's best round on the valid curve and the mean of those best values, so that a curve
    that peaked and fell (flat at its end, below its best) shows; descriptive only (a maximum over
    rounds is biased upwards), and the reported weights stay the last round's."""
    lines = ["| entry | runs with a curve | last round | valid completion there | gain over the last round "
             "(95 % t), p | verdict | best round per run: valid there (mean) | trained longer |",
             "|---|---|---|---|---|---|---|---|"]
    runs: dict[str, set[Path]] = {}
    for r in results:
        runs.setdefault(r.entry, set()).add(r.run_dir)
    uncurved: list[str] = []
    off: list[str] = []
    for entry in sorted(runs):
        dirs = sorted(runs[entry])
        every = [curves[d] for d in dirs]
        kept = [c for c in every  # a curve computed to the last round
                if len(c.valid) >= 2 and c.rounds and c.valid_rounds[-1] == c.rounds[-1]]
        if len(kept) < len(dirs):
            uncurved.append(f"`{entry}` {len(dirs) - len(kept)} of {len(dirs)}")
        off.extend(f"`{entry}` {d.name} (`{c.off_split}`)" for d, c in zip(dirs, every) if c.off_split)
        if not kept:
            continue
        finals = [[v[-1] for v in c.valid] for c in kept]  # each round's completion after the last attempt
        last = [f[-1] for f in finals]
        diff, p = paired([f[-2] for f in finals], last)
        verdict = ("— (one run)" if p is None else "still rising" if p < ALPHA and diff.mean > 0
                   else "falling" if p < ALPHA else "flat")
        had = []
        for name in longer.get(entry, ()):
            n_long = len(runs.get(name, ()))
            had.append(f"`{name}` ({n_long} run{'' if n_long == 1 else 's'})" if n_long else
                       f"`{name}` (not run yet)" if name in planned else "")
        rounds = sorted({c.rounds[-1] for c in kept})
        best = [f.index(max(f)) for f in finals]  # the first best on a tie
        best_text = (f"{', '.join(str(c.valid_rounds[i]) for c, i in zip(kept, best))}: "
                     f"{statistics.fmean(f[i] for f, i in zip(finals, best)):.3f}")
        lines.append(f"| {entry} | {len(kept)} | {', '.join(map(str, rounds))} | {statistics.fmean(last):.3f} | "
                     f"{paired_text(diff, p)} | {verdict} | {best_text} | {', '.join(h for h in had if h) or '—'} |")
    if uncurved:
        lines.append("\nRuns without a valid curve to their last round, not checked here (`gpl-dist suite curves` "
                     "computes one from a run's per-round weights, which these runs no longer have): "
                     + ", ".join(uncurved) + ".")
    if off:
        lines.append("\nOf those, curves measured on a split that is not the run's valid split (it may hold tasks "
                     "the run trained on, or test tasks), so left out: " + ", ".join(off) + ".")
    return "\n".join(lines)

"""The paper's Tables 1-5 (and the controls beside them) from a suite's runs, beside the paper's numbers.

The tables are data, ``configs/suites/paper-tables.yaml`` (``load_paper``): each entry they read
named once with its domain and rounds, each table's rows naming an entry, the evaluation it reads
and the paper's numbers (GPL's from each domain's ``DomainSpec.paper_completion``); nothing of the
paper is typed here. A suite is the paper's (``is_paper_suite``) when its entries include every
entry the tables read and its runs have the domains the tables give them: only then does the
report show these tables. A cell is the mean over **training** seeds of the run's mean completion
over its evaluation seeds, ± the half-width of its 95 % t interval over training seeds (the last
column says which seeds; one seed has no ±). Rows of methods not built, or entries not run yet,
are kept with the paper's number and a dash, so the report always shows every row of the paper.
The builders here read no file: ``load_paper`` and ``decoy_note`` do.
"""

from __future__ import annotations

import statistics
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

from gpl_dist.app.suite.report_data import RunResult, cell, status
from gpl_dist.app.suite.report_plots import PlotRow
from gpl_dist.app.suite.stats import Welch, welch
from gpl_dist.config import ConfigError, load_yaml_text

#: The paper's tables, beside the paper's suite file.
PAPER_TABLES_FILE = Path(__file__).resolve().parents[3] / "configs" / "suites" / "paper-tables.yaml"


@dataclass(frozen=True)
class PaperRow:
    """One row of a paper table and the suite entry that reproduces it."""

    label: str
    entry: str | None
    """Suite entry name; None when the method is not built (the reason is in ``note``)."""
    evaluation: str
    """Which of the entry's evaluations the row reads."""
    columns: tuple[int, ...]
    """Corrections (``c_k``) the row has values for; a baseline without corrections has ``(0,)``."""
    paper: tuple[float | None, ...]
    """The paper's values, one per column (None: '-' in the paper)."""
    note: str = ""


@dataclass(frozen=True)
class PaperTable:
    """One paper table: its caption and rows over columns ``c_k``."""

    key: str
    caption: str
    columns: tuple[int, ...]
    rows: tuple[PaperRow, ...]
    heading: str = ""
    gains: bool = False
    """Also test gains over attempts (after k minus before any) against the reference's."""
    note: str = ""
    """A paragraph the report computes below the table (``NOTES``), by name."""


@dataclass(frozen=True)
class PaperEntry:
    """An entry the tables read: its domain and DAgger rounds; ``reference``: GPL, which the
    other rows are tested against."""

    domain: str
    rounds: int
    reference: bool = False


@dataclass(frozen=True)
class Paper:
    """The paper's tables and the entries they read."""

    entries: dict[str, PaperEntry]
    tables: tuple[PaperTable, ...]


def _expect(ok: bool, where: str, message: str) -> None:
    if not ok:
        raise ConfigError(f"{where}: {message}")


def _paper_values(where: str, raw: Any, columns: tuple[int, ...], domain: str | None,
                  numbers: Mapping[str, list]) -> tuple[float | None, ...]:
    if raw is None:
        return (None,) * len(columns)
    if raw == "gpl":
        _expect(domain is not None, where, "'gpl' needs an entry (whose domain's GPL numbers to show)")
        from gpl_dist.domains import get_domain  # the paper's domains are built in

        completion = get_domain(str(domain)).paper_completion
        return tuple(completion.get(k) for k in columns)
    if isinstance(raw, str):
        _expect(raw in numbers, where, f"no list '{raw}' under numbers (known: {', '.join(numbers)})")
        raw = numbers[raw]
    _expect(isinstance(raw, list) and len(raw) == len(columns), where, f"expected {len(columns)} numbers, one a column")
    return tuple(None if v is None else float(v) for v in raw)


def parse_paper(raw: Any, where: str) -> Paper:
    """The ``Paper`` of a tables file's parsed YAML; a bad key fails in one line naming it."""
    _expect(isinstance(raw, dict) and set(raw) <= {"entries", "numbers", "tables"}, where,
            "expected a mapping of entries, numbers and tables")
    entries = {}
    for name, spec in (raw.get("entries") or {}).items():
        _expect(isinstance(spec, dict) and isinstance(spec.get("domain"), str) and isinstance(spec.get("rounds"), int),
                f"{where}: entries.{name}", "expected {domain: NAME, rounds: N}")
        entries[name] = PaperEntry(spec["domain"], spec["rounds"], bool(spec.get("reference", False)))
    numbers = raw.get("numbers") or {}
    tables = []
    for i, t in enumerate(raw.get("tables") or []):
        at = f"{where}: tables[{i}]"
        _expect(isinstance(t, dict) and {"key", "caption", "columns", "rows"} <= set(t), at,
                "expected key, caption, columns and rows")
        columns = tuple(t["columns"])
        rows = []
        for j, r in enumerate(t["rows"]):
            row_at = f"{at}.rows[{j}]"
            entry = r.get("entry")
            _expect(entry is None or entry in entries, row_at, f"entry '{entry}' is not under entries")
            cols = tuple(r.get("columns", columns))
            _expect(set(cols) <= set(columns), row_at, f"columns {list(cols)} outside the table's {list(columns)}")
            paper = _paper_values(row_at, r.get("paper"), cols, entries[entry].domain if entry else None, numbers)
            rows.append(PaperRow(str(r["label"]), entry, str(r.get("evaluation", "test")), cols, paper, str(r.get("note", ""))))
        tables.append(PaperTable(str(t["key"]), str(t["caption"]), columns, tuple(rows), str(t.get("heading", t["key"])),
                                 bool(t.get("gains", False)), str(t.get("note", ""))))
    return Paper(entries, tuple(tables))


@lru_cache(maxsize=4)
def load_paper(path: Path = PAPER_TABLES_FILE) -> Paper | None:
    """The paper's tables (``PAPER_TABLES_FILE``); None where that file is not beside this checkout."""
    if not path.is_file():
        return None
    return parse_paper(load_yaml_text(path.read_text(), path), str(path))


def is_paper_suite(paper: Paper, suite_entries: Sequence[str], domains: Mapping[str, set[str]]) -> bool:
    """Whether a suite's entries are the paper's: every entry the tables read is one of the
    suite's, and no run of one says (in its config) another domain than the tables give it."""
    return set(paper.entries) <= set(suite_entries) and all(
        domains.get(name, set()) <= {e.domain} for name, e in paper.entries.items())


def decoy_note() -> str:
    """How far the held-out combinations' words were seen on a task's other objects (the decoys)."""
    from gpl_dist.envs.multiroom import decoy_overlap
    from gpl_dist.splits import split_tasks

    parts = []
    for split, label in (("heldout4_test", "held-out"), ("heldout4_indist_test", "in-distribution")):
        colour, shape = decoy_overlap(split_tasks("multiroom", split))
        parts.append(f"{label} tasks: {colour:.0%} have a decoy of the true object's colour, {shape:.0%} one of its shape")
    return "Decoy overlap (from the split file): " + "; ".join(parts) + "."


#: The paragraphs a table may name (``PaperTable.note``), each computed when the report is written.
NOTES = {"decoy-overlap": decoy_note}


def _status(results: Sequence[RunResult], row: PaperRow, planned: Mapping[str, tuple[int, ...]],
            excluded: Sequence[RunResult] | None = None) -> str:
    return row.note if row.entry is None else status(results, row.entry, row.evaluation, planned, excluded)


def table_markdown(results: Sequence[RunResult], table: PaperTable, planned: Mapping[str, tuple[int, ...]],
                   excluded: Sequence[RunResult] | None = None) -> str:
    """One table: a row per paper row, each cell 'ours (paper)'; ``results``: the healthy runs'
    (``healthy``), ``excluded``: the others'; ``planned``: each entry's training seeds in the
    suite file, for the seeds not run yet."""
    head = "| method | " + " | ".join(f"c{k}" for k in table.columns) + " | runs |"
    lines = [f"**{table.caption}.** Each cell: ours, mean over training seeds ± the half-width of its 95 % "
             "t interval (paper; where the paper's number lies outside our interval, which way ours lies).", "", head,
             "|" + "---|" * (len(table.columns) + 2)]
    for row in table.rows:
        cells = []
        for k in table.columns:
            if k not in row.columns:
                cells.append("")
                continue
            ours = cell(results, row.entry, row.evaluation, k) if row.entry else None
            paper = row.paper[row.columns.index(k)]
            cells.append(f"{ours.text()} ({ours.against(paper)})" if ours else f"— ({'-' if paper is None else paper})")
        lines.append(f"| {row.label} | " + " | ".join(cells) + f" | {_status(results, row, planned, excluded)} |")
    return "\n".join(lines)


def success_markdown(results: Sequence[RunResult], table: PaperTable) -> str:
    """The table's success rates (fraction of tasks solved after k corrections), the same runs as
    ``table_markdown``'s completion."""
    lines = ["Success rate (tasks solved), the same runs, mean ± 95 % half-width:", "",
             "| method | " + " | ".join(f"c{k}" for k in table.columns) + " | training seeds |",
             "|" + "---|" * (len(table.columns) + 2)]
    for row in table.rows:
        cells = []
        for k in table.columns:
            ours = cell(results, row.entry, row.evaluation, k, "success") if row.entry and k in row.columns else None
            cells.append("" if k not in row.columns else ours.text() if ours else "—")
        seeds = len({r.seed for r in results if r.entry == row.entry and r.evaluation == row.evaluation})
        lines.append(f"| {row.label} | " + " | ".join(cells) + f" | {seeds if row.entry else ''} |")
    return "\n".join(lines)


def plot_rows(results: Sequence[RunResult], table: PaperTable) -> list[PlotRow]:
    """The table's rows as lines of ``report_plots.plot_completion``."""
    return [PlotRow(row.label, row.columns, tuple(cell(results, row.entry, row.evaluation, k) if row.entry else None
                                                  for k in row.columns), row.paper) for row in table.rows]


@dataclass(frozen=True)
class Comparison:
    """One ordering the report tests: ``entry`` after ``k`` corrections against ``other`` after ``other_k``."""

    label: str
    entry: str
    evaluation: str
    k: int
    other: str
    other_evaluation: str
    other_k: int
    gain: bool = False
    """Compare gains over attempts (after k minus before any) instead of levels."""


def comparisons(paper: Paper) -> tuple[Comparison, ...]:
    """Each row of the paper's tables against its table's reference row (GPL) of the same domain
    and evaluation with the fewest rounds (the reference after the table's last column against the
    row's last column), and where the table has one, against the reference trained as many rounds
    as the row (equal budgets); in a table with ``gains``, gains over attempts too."""
    out: dict[tuple, Comparison] = {}
    for table in paper.tables:
        refs = [g for g in table.rows if g.entry and paper.entries[g.entry].reference]
        for row in table.rows:
            if row.entry is None:
                continue
            mine = paper.entries[row.entry]
            same = [g for g in refs if paper.entries[str(g.entry)].domain == mine.domain and g.evaluation == row.evaluation]
            base = min(same, key=lambda g: paper.entries[str(g.entry)].rounds, default=None)
            if base is None or base is row:
                continue
            pairs = [("GPL", base)]
            if not mine.reference and mine.rounds != paper.entries[str(base.entry)].rounds:
                equal = next((g for g in same if paper.entries[str(g.entry)].rounds == mine.rounds), None)
                if equal is not None:
                    pairs.append((f"GPL {mine.rounds} rounds", equal))
            for name, gpl in pairs:
                for gain in (False, True) if table.gains else (False,):
                    c = Comparison(f"{table.heading}: {name} c{gpl.columns[-1]} vs {row.label} c{row.columns[-1]}"
                                   + (", gain over c0" if gain else ""), str(gpl.entry), gpl.evaluation, gpl.columns[-1],
                                   row.entry, row.evaluation, row.columns[-1], gain)
                    out.setdefault((c.entry, c.evaluation, c.k, c.other, c.other_evaluation, c.other_k, gain), c)
    return tuple(out.values())


def _values(results: Sequence[RunResult], entry: str, evaluation: str, k: int, gain: bool) -> list[float]:
    runs = [r for r in results if r.entry == entry and r.evaluation == evaluation and k < len(r.completion)]
    return [r.completion[k] - r.completion[0] if gain else r.completion[k] for r in sorted(runs, key=lambda r: r.seed)]


def fmt(value: float | None, spec: str) -> str:
    """``value`` formatted by ``spec``, '—' for None."""
    return "—" if value is None else format(value, spec)


def comparisons_markdown(results: Sequence[RunResult], wanted: Mapping[str, int] | None = None,
                         paper: Paper | None = None) -> str:
    """Welch's t-test (two-sided, p < 0.05) of every ``comparisons`` pair with runs on both sides.
    ``wanted``: each entry's valid runs the suite aims at (``report_data.wanted_runs``); a side with
    fewer marks the verdict provisional (the README counts one or two seeds as no evidence)."""
    paper = paper or load_paper()
    lines = ["| comparison | GPL (mean, seeds) | other (mean, seeds) | difference | Welch t | df | p | verdict |",
             "|---|---|---|---|---|---|---|---|"]
    for c in comparisons(paper) if paper else ():
        a = _values(results, c.entry, c.evaluation, c.k, c.gain)
        b = _values(results, c.other, c.other_evaluation, c.other_k, c.gain)
        if not a or not b:
            continue
        w: Welch = welch(a, b)
        verdict = w.verdict("GPL", "other")
        short = [f"{name} {len(got)} of {want} seeds" for name, got in ((c.entry, a), (c.other, b))
                 if len(got) < (want := (wanted or {}).get(name, 0))]
        if short and w.p is not None:
            verdict += f" (provisional: {'; '.join(short)})"
        lines.append(f"| {c.label} | {statistics.fmean(a):.3f} ({len(a)}) | {statistics.fmean(b):.3f} ({len(b)}) | "
                     f"{w.difference:+.3f} | {fmt(w.t, '.2f')} | {fmt(w.df, '.1f')} | {fmt(w.p, '.3g')} | "
                     f"{verdict} |")
    return "\n".join(lines)

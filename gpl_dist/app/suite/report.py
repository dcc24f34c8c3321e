"""The paper's Tables 1-5 from a suite's runs, beside the paper's numbers (``gpl-dist suite report``).

Every number is read from the runs' ``eval*.json`` files (through each run's ``suite-run.json``,
which names the file of each evaluation); none is typed here except the paper's own, in
``PAPER_TABLES`` (GPL's from each domain's ``DomainSpec.paper_completion``). A cell is the mean
over **training** seeds of the run's mean completion over its evaluation seeds, ± the half-width
of its 95 % t interval over training seeds (the last column says which seeds; one seed has no ±).
The instruction-swap section reads each run's ``instruction-swap-valid.json`` instead
(``gpl_dist.app.suite.swap``, each run's valid split). Rows of
methods not built, or entries not run yet, are kept with the paper's number and a dash, so the
report always shows every row of the paper.

Writes ``report.md`` (plots beside it as PNG) and ``report.html`` (the same, plots inline), and
first archives the runs' evidence beside them in ``runs/`` (``gpl_dist.app.suite.archive``): the report
is computed from that archive, so every number traces to a file kept with the report, and a report
written into the same folder again keeps the runs archived before (a lost machine loses no row).
"""

from __future__ import annotations

import base64
import html
import statistics
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gpl_dist.app.suite.archive import archive_runs, check_archive
from gpl_dist.app.suite.evidence import read_json, sha256_file
from gpl_dist.app.suite.rl_jobs import plan_of_copy
from gpl_dist.app.suite.rl_report import sample_complexity_section
from gpl_dist.app.suite.rundata import (
    InstructionSwap,
    LearningCurve,
    RunBudget,
    RunHealth,
    instruction_swap,
    learning_curve,
    run_budget,
    run_health,
    run_valid_split,
)
from gpl_dist.app.suite.runs import RECORD_VERSION
from gpl_dist.app.suite.spec import EVAL_DEFAULTS, check_seeds
from gpl_dist.app.suite.stats import ALPHA, MeanCI, Welch, mean_ci, t_two_sided_p, welch
from gpl_dist.config import load_yaml_text
from gpl_dist.domains import get_domain
from gpl_dist.errors import RunDirError
from learner.checkpoint import LATEST
from learner.evaluate import SWAP_RULE

#: The report folder's archive of the runs it reads (``gpl_dist.app.suite.archive``).
ARCHIVE_DIR = "runs"


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


_C05 = (0, 1, 2, 3, 4, 5)


def _gpl(domain: str, columns: tuple[int, ...] = _C05) -> tuple[float, ...]:
    """The paper's GPL completions of ``domain`` (its ``DomainSpec.paper_completion``) at ``columns``."""

    paper = get_domain(domain).paper_completion
    return tuple(paper[k] for k in columns)


PAPER_TABLES = (
    PaperTable("table1-multiroom", "Table 1, multi-room: mean completion on the test tasks (baselines act without "
               "corrections: their one number is the first attempt's)", _C05, (
        PaperRow("Instruction", "multiroom-instruction", "test", (0,), (0.075,)),
        PaperRow("Full Info", "multiroom-full-info", "test", (0,), (0.73,)),
        PaperRow("Full Info, 12 rounds", "multiroom-full-info-long", "test", (0,), (0.73,)),
        PaperRow("MIVOA (Instr.)", "multiroom-mivoa-instruction", "test", (0,), (0.067,)),
        PaperRow("MIVOA (Full Info)", "multiroom-mivoa-full-info", "test", (0,), (0.63,)),
        PaperRow("MIVOA (Full Info), 12 rounds", "multiroom-mivoa-full-info-long", "test", (0,), (0.63,)),
        PaperRow("GPL", "multiroom-gpl", "test", _C05, _gpl("multiroom")),
        PaperRow("GPL, 12 rounds", "multiroom-gpl-long", "test", _C05, _gpl("multiroom")),
    )),
    PaperTable("table1-relocation", "Table 1, object relocation: mean completion on the test tasks (1 - final / "
               "initial block distance)", _C05, (
        PaperRow("Instruction", "relocation-instruction", "test", (0,), (0.64,)),
        PaperRow("Full Info", "relocation-full-info", "test", (0,), (0.96,)),
        PaperRow("MIVOA (Instr.)", "relocation-mivoa-instruction", "test", (0,), (0.65,)),
        PaperRow("MIVOA (Full Info)", None, "test", (0,), (None,), "not in the paper either"),
        PaperRow("GPL", "relocation-gpl", "test", _C05, _gpl("relocation")),
    )),
    PaperTable("table2", "Table 2, multi-room ablations", _C05, (
        PaperRow("Base (GPL)", "multiroom-gpl", "test", _C05, _gpl("multiroom")),
        PaperRow("Base (GPL), 12 rounds", "multiroom-gpl-long", "test", _C05, _gpl("multiroom")),
        PaperRow("No instruction", "multiroom-no-instruction", "test", _C05, (0.059, 0.45, 0.62, 0.72, 0.78, 0.79)),
        PaperRow("No instruction, 12 rounds", "multiroom-no-instruction-long", "test", _C05,
                 (0.059, 0.45, 0.62, 0.72, 0.78, 0.79)),
        PaperRow("No trajectory", "multiroom-no-trajectory", "test", _C05, (0.077, 0.44, 0.62, 0.70, 0.76, 0.77)),
        PaperRow("Only immediate correction", "multiroom-latest-correction", "test", _C05,
                 (0.067, 0.49, 0.44, 0.58, 0.59, 0.63)),
        PaperRow("Only immediate correction, 12 rounds", "multiroom-latest-correction-long", "test", _C05,
                 (0.067, 0.49, 0.44, 0.58, 0.59, 0.63)),
    )),
    PaperTable("table2-wording", "Table 2's no-trajectory row and the wording of the goal room (not in the paper): "
               "the paper's text says 'enter the <room> room' for the object's room and the goal's alike, so two "
               "corrections are often the same words and an order-free mean over them cannot tell which room is "
               "which without the trajectory; the authors' code words the goal room's subgoal apart ('carry <room> "
               "door'; here 'go to the <room> room', env.correction_kind subgoal_goal_room_apart). The paper's "
               "numbers are those of its Table 2", _C05, (
        PaperRow("GPL, 'enter' for both rooms", "multiroom-gpl", "test", _C05, _gpl("multiroom")),
        PaperRow("No trajectory, 'enter' for both rooms", "multiroom-no-trajectory", "test", _C05,
                 (0.077, 0.44, 0.62, 0.70, 0.76, 0.77)),
        PaperRow("GPL, goal room worded apart", "multiroom-gpl-goal-room-apart", "test", _C05, _gpl("multiroom")),
        PaperRow("No trajectory, goal room worded apart", "multiroom-no-trajectory-goal-room-apart", "test", _C05,
                 (0.077, 0.44, 0.62, 0.70, 0.76, 0.77)),
    )),
    PaperTable("table3", "Table 3, more corrections at meta-test than in training (5)", (5, 7, 10), (
        PaperRow("Multi-room", "multiroom-gpl", "test-c10", (5, 7, 10), _gpl("multiroom", (5, 7, 10))),
        PaperRow("Obj Relocation", "relocation-gpl", "test-c10", (5, 7, 10), _gpl("relocation", (5, 7, 10))),
    )),
    PaperTable("table4", "Table 4, multi-room correction types (GPL trained and tested with that kind)", (1, 2, 3, 4, 5), (
        PaperRow("Directional", "multiroom-directional", "test", (1, 2, 3, 4, 5), (0.242, 0.343, 0.43, 0.51, 0.56)),
        PaperRow("Binary", "multiroom-binary", "test", (1, 2, 3, 4, 5), (0.073, 0.078, 0.08, 0.089, 0.09)),
        PaperRow("All", "multiroom-all-corrections", "test", (1, 2, 3, 4, 5), (0.236, 0.363, 0.44, 0.538, 0.606)),
    )),
    PaperTable("table5", "Table 5, multi-room, objects held out of training: 4 of the 18 colour-shape combinations "
               "(the paper's held out fewer), trained on the 779 tasks without them; each model tested on the tasks "
               "whose true object is held out and, in distribution, on 250 tasks without a held-out object that it "
               "never trained on", _C05, (
        PaperRow("Full Info, held out", "multiroom-heldout-full-info", "heldout", (0,), (0.57,)),
        PaperRow("Full Info, in distribution", "multiroom-heldout-full-info", "heldout-indist", (0,), (None,)),
        PaperRow("MIVOA (Full Info), held out", "multiroom-heldout-mivoa-full-info", "heldout", (0,), (0.62,)),
        PaperRow("MIVOA (Full Info), in distribution", "multiroom-heldout-mivoa-full-info", "heldout-indist", (0,), (None,)),
        PaperRow("Full Info, 12 rounds, held out", "multiroom-heldout-full-info-long", "heldout", (0,), (0.57,)),
        PaperRow("Full Info, 12 rounds, in distribution", "multiroom-heldout-full-info-long", "heldout-indist", (0,),
                 (None,)),
        PaperRow("MIVOA (Full Info), 12 rounds, held out", "multiroom-heldout-mivoa-full-info-long", "heldout", (0,),
                 (0.62,)),
        PaperRow("MIVOA (Full Info), 12 rounds, in distribution", "multiroom-heldout-mivoa-full-info-long",
                 "heldout-indist", (0,), (None,)),
        PaperRow("GPL, held out", "multiroom-heldout-gpl", "heldout", _C05, (0.073, 0.44, 0.58, 0.65, 0.73, 0.75)),
        PaperRow("GPL, in distribution", "multiroom-heldout-gpl", "heldout-indist", _C05, (None,) * 6),
        PaperRow("GPL, 12 rounds, held out", "multiroom-heldout-gpl-long", "heldout", _C05,
                 (0.073, 0.44, 0.58, 0.65, 0.73, 0.75)),
        PaperRow("GPL, 12 rounds, in distribution", "multiroom-heldout-gpl-long", "heldout-indist", _C05, (None,) * 6),
    )),
    PaperTable("gpr", "GPR, the reward-guided variant, beside GPL (the paper draws both in its sample-complexity figure "
               "and prints no numbers: GPR 'performs poorly on the multi-room domain but obtains reasonable performance "
               "for the robotic domain')", _C05, (
        PaperRow("Multi-room GPL", "multiroom-gpl", "test", _C05, _gpl("multiroom")),
        PaperRow("Multi-room GPR", "multiroom-gpr", "test", _C05, (None,) * 6),
        PaperRow("Relocation GPL", "relocation-gpl", "test", _C05, _gpl("relocation")),
        PaperRow("Relocation GPR", "relocation-gpr", "test", _C05, (None,) * 6),
    )),
    PaperTable("retry", "The retry control (not in the paper): GPL trained and tested with one fixed, uninformative "
               "sentence after every attempt (env.correction_kind retry), so it still sees its earlier trajectories; "
               "its gain over attempts is what retrying alone buys, GPL's gain above it what the corrections say", _C05, (
        PaperRow("Multi-room GPL", "multiroom-gpl", "test", _C05, _gpl("multiroom")),
        PaperRow("Multi-room retry control", "multiroom-retry", "test", _C05, (None,) * 6),
        PaperRow("Relocation GPL", "relocation-gpl", "test", _C05, _gpl("relocation")),
        PaperRow("Relocation retry control", "relocation-retry", "test", _C05, (None,) * 6),
    )),
    PaperTable("paraphrases", "Paraphrased language (not in the paper): GPL meta-tested with the oracle's own "
               "sentences and with held-out phrasings (new sentences of training words), trained with the canonical "
               "phrasings or with the training paraphrases (model.paraphrases)", _C05, (
        PaperRow("Multi-room GPL, canonical phrasings", "multiroom-gpl", "test", _C05, _gpl("multiroom")),
        PaperRow("Multi-room GPL, held-out phrasings", "multiroom-gpl", "test-heldout-phrasings", _C05, (None,) * 6),
        PaperRow("Multi-room GPL + paraphrases, canonical", "multiroom-paraphrases", "test", _C05, (None,) * 6),
        PaperRow("Multi-room GPL + paraphrases, held-out", "multiroom-paraphrases", "test-heldout-phrasings", _C05,
                 (None,) * 6),
    )),
)


@dataclass(frozen=True)
class RunResult:
    """One finished evaluation of one training seed, as its files say."""

    entry: str
    seed: int
    run_dir: Path
    evaluation: str
    completion: tuple[float, ...]
    """Mean completion after k corrections, k = 0.. (over the evaluation's seeds)."""
    eval_file: Path
    settings: tuple[tuple[str, object], ...]
    """The evaluation's settings as recorded (split, seeds, corrections, actions, tasks)."""
    commits: tuple[str, ...]
    train_seconds: float
    eval_seconds: float
    effort: dict | None = None
    """The evaluation's ``correction_effort`` (``learner.evaluate.CorrectionEffort``), None in older files."""
    success: tuple[float, ...] = ()
    """Fraction of tasks solved after k corrections (over the evaluation's seeds); () in older files."""
    numerics: tuple[str, ...] = ()
    """The numerics fingerprints (``learner.cpu.numerics_fingerprint``) of the machines that trained
    it; () for a run trained before they were recorded."""


@dataclass(frozen=True)
class Cell:
    """A table cell: the mean over training seeds with its 95 % t interval (``stats.mean_ci``)."""

    ci: MeanCI

    @property
    def mean(self) -> float:
        return self.ci.mean

    @property
    def std(self) -> float | None:
        return self.ci.sd

    @property
    def n(self) -> int:
        return self.ci.n

    def text(self) -> str:
        """``0.912 ± 0.063`` (± the interval's half-width), or the one seed's value."""
        return f"{self.mean:.3f}" if self.ci.half_width is None else f"{self.mean:.3f} ± {self.ci.half_width:.3f}"

    def against(self, paper: float | None) -> str:
        """The paper's number, and which way ours lies when the paper's is outside our interval."""
        if paper is None:
            return "-"
        where = self.ci.relation(paper)
        return f"{paper}" if where in ("inside", "unknown") else f"{paper}; ours {where}"


def collect_results(suite_out: str | Path, log=print) -> list[RunResult]:
    """Every evaluation recorded under ``suite_out/<entry>/seed<k>/suite-run.json``, once the
    whole folder's evidence has been checked (``archive.check_archive``: checksums, each eval
    file's consistency; ``EvidenceError`` naming the first bad file)."""
    root = Path(suite_out)
    if not root.is_dir():
        raise RunDirError(f"no suite output at {root}")
    check_archive(root, log)
    results = []
    for record_path in sorted(root.glob("*/seed*/suite-run.json")):
        record = _read_json(record_path)
        if record.get("version") != RECORD_VERSION:
            raise RunDirError(f"{record_path} is a suite record of version {record.get('version')}; this report "
                              f"reads version {RECORD_VERSION}")
        run_dir = record_path.parent
        for name, ev in record.get("evaluations", {}).items():
            payload = _read_json(run_dir / ev["file"])
            recorded = {**EVAL_DEFAULTS, **ev["settings"]}  # a setting added later: its default
            settings = tuple(sorted((k, tuple(v) if isinstance(v, list) else v) for k, v in recorded.items()))
            results.append(RunResult(record["entry"], int(record["seed"]), run_dir, name,
                                     tuple(float(x) for x in payload["completion"]), run_dir / ev["file"], settings,
                                     tuple(record.get("commits", ())), float(record.get("train_seconds", 0.0)),
                                     float(ev.get("seconds", 0.0)), payload.get("correction_effort"),
                                     tuple(float(x) for x in payload.get("success") or ()),
                                     tuple(record.get("numerics", ()))))
    _check_same_settings(results)
    return results


_read_json = read_json


def _check_same_settings(results: list[RunResult]) -> None:
    """One evaluation name must mean one set of settings across the suite: a cell never mixes."""
    seen: dict[str, RunResult] = {}
    for r in results:
        first = seen.setdefault(r.evaluation, r)
        if first.settings != r.settings:
            raise RunDirError(f"evaluation '{r.evaluation}' has other settings in {r.run_dir} than in {first.run_dir} "
                              f"({dict(r.settings)} vs {dict(first.settings)}): the suite file changed between runs")


def seed_values(results: list[RunResult], entry: str, evaluation: str, k: int, measure: str = "completion") -> list[float]:
    """Each training seed's ``measure`` (completion or success) after ``k`` corrections."""
    return [getattr(r, measure)[k] for r in results
            if r.entry == entry and r.evaluation == evaluation and k < len(getattr(r, measure))]


def cell(results: list[RunResult], entry: str, evaluation: str, k: int, measure: str = "completion") -> Cell | None:
    """``measure`` after ``k`` corrections of ``entry``'s ``evaluation``, over its training seeds."""
    values = seed_values(results, entry, evaluation, k, measure)
    return Cell(mean_ci(values)) if values else None


def healthy(results: list[RunResult], health: dict[Path, RunHealth]) -> list[RunResult]:
    """The results of runs that pass the health gate (``evidence.RunHealth.valid``): every mean is over these."""
    return [r for r in results if health[r.run_dir].valid]


def health_of(results: list[RunResult]) -> dict[Path, RunHealth]:
    """Each result's run's ``RunHealth``."""
    return {d: run_health(d) for d in sorted({r.run_dir for r in results})}


def _row_cells(results: list[RunResult], table: PaperTable, row: PaperRow) -> list[tuple[Cell | None, float | None] | None]:
    """Per table column: (ours, paper), or None where the row has no value in that column."""
    out: list[tuple[Cell | None, float | None] | None] = []
    for k in table.columns:
        if k not in row.columns:
            out.append(None)
            continue
        ours = cell(results, row.entry, row.evaluation, k) if row.entry else None
        out.append((ours, row.paper[row.columns.index(k)]))
    return out


def _seeds_of(results: list[RunResult], row: PaperRow) -> list[int]:
    return sorted({r.seed for r in results if r.entry == row.entry and r.evaluation == row.evaluation})


def planned_seeds(suite_yaml: Path) -> dict[str, tuple[int, ...]]:
    """Each entry's training seeds in a suite file's copy (``OUT/suite.yaml``, written by ``suite
    run``), read without resolving base configs (relative to where the original lies); {} when
    there is no copy."""
    raw = load_yaml_text(suite_yaml.read_text(), suite_yaml) if suite_yaml.is_file() else None
    entries = raw.get("entries") if isinstance(raw, dict) else None
    if not isinstance(entries, dict):
        return {}
    return {name: check_seeds(f"{suite_yaml}: entries.{name}.seeds", spec.get("seeds") if isinstance(spec, dict) else None)
            for name, spec in entries.items()}


def _status(results: list[RunResult], row: PaperRow, planned: dict[str, tuple[int, ...]],
            excluded: list[RunResult] | None = None) -> str:
    if row.entry is None:
        return row.note
    seeds = _seeds_of(results, row)
    out = sorted({r.seed for r in excluded or () if r.entry == row.entry and r.evaluation == row.evaluation})
    missing = [s for s in planned.get(row.entry, ()) if s not in seeds and s not in out]
    dropped = f"; not valid (a layer dead at the final round), left out: {', '.join(map(str, out))}" if out else ""
    if not seeds:
        return ("not run yet" if not out else "no valid run") + dropped
    done = f"{len(seeds)} training seed(s): {', '.join(map(str, seeds))}" + dropped
    return f"{done}; not run yet: {', '.join(map(str, missing))}" if missing else done


def not_run(results: list[RunResult], planned: dict[str, tuple[int, ...]]) -> list[tuple[str, list[int]]]:
    """The suite's entries with training seeds that no result in the report comes from."""
    have = {(r.entry, r.seed) for r in results}
    return [(entry, missing) for entry, seeds in planned.items() if (missing := [s for s in seeds if (entry, s) not in have])]


_NOT_RUN_INTRO = ("Runs of the suite file (its latest copy, `runs/suite.yaml`) that this report holds no result of yet "
                  "(`gpl-dist suite run SUITE --out OUT --only ENTRY --seeds S`):")


def table_markdown(results: list[RunResult], table: PaperTable, planned: dict[str, tuple[int, ...]],
                   excluded: list[RunResult] | None = None) -> str:
    """One table: a row per paper row, each cell 'ours (paper)', and the success rates beside;
    ``results``: the healthy runs' (``healthy``), ``excluded``: the others'; ``planned``: each
    entry's training seeds in the suite file (``planned_seeds``), for the seeds not run yet."""
    head = "| method | " + " | ".join(f"c{k}" for k in table.columns) + " | runs |"
    lines = [f"**{table.caption}.** Each cell: ours, mean over training seeds ± the half-width of its 95 % "
             "t interval (paper; where the paper's number lies outside our interval, which way ours lies).", "", head,
             "|" + "---|" * (len(table.columns) + 2)]
    for row in table.rows:
        cells = []
        for c in _row_cells(results, table, row):
            if c is None:
                cells.append("")
                continue
            ours, paper = c
            cells.append(f"{ours.text()} ({ours.against(paper)})" if ours else f"— ({'-' if paper is None else paper})")
        lines.append(f"| {row.label} | " + " | ".join(cells) + f" | {_status(results, row, planned, excluded)} |")
    return "\n".join(lines)


def success_markdown(results: list[RunResult], table: PaperTable) -> str:
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
        lines.append(f"| {row.label} | " + " | ".join(cells) + f" | {len(_seeds_of(results, row)) if row.entry else ''} |")
    return "\n".join(lines)


def plot_table(results: list[RunResult], table: PaperTable, path: Path) -> bool:
    """Completion against corrections for the table's rows (ours solid with the band of the 95 %
    interval over training seeds, the paper's dashed where it has numbers; a row without
    corrections, a baseline, as a level line across); False when no row has more than one column."""
    if not any(len(r.columns) > 1 for r in table.rows):
        return False
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.2, 3.6), dpi=110)
    span = (min(table.columns), max(table.columns))
    for i, row in enumerate(table.rows):
        color = f"C{i}"
        flat = len(row.columns) == 1
        if any(p is not None for p in row.paper):
            xs = span if flat else row.columns
            ys = [float("nan") if p is None else p for p in ((row.paper[0],) * 2 if flat else row.paper)]
            ax.plot(xs, ys, ":" if flat else "--", color=color, alpha=0.7, label=f"{row.label} (paper)")
        cells = [cell(results, row.entry, row.evaluation, k) if row.entry else None for k in row.columns]
        if not any(c is not None for c in cells):
            continue
        ks = [k for k, c in zip(row.columns, cells) if c is not None]
        means = [c.mean for c in cells if c is not None]
        half = [c.ci.half_width or 0.0 for c in cells if c is not None]
        if flat:
            ks, means, half = list(span), means * 2, half * 2
        seeds = max(c.n for c in cells if c is not None)
        ax.plot(ks, means, "-" if flat else "o-", color=color, label=f"{row.label} (ours, {seeds} seeds)")
        ax.fill_between(ks, [m - h for m, h in zip(means, half)], [m + h for m, h in zip(means, half)], color=color, alpha=0.15)
    ax.set_xlabel("corrections")
    ax.set_ylabel("completion")
    ax.set_ylim(0, 1)
    ax.set_xticks(table.columns)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), title="band: 95 % interval", title_fontsize=7)
    ax.set_title(_heading(table), fontsize=9)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return True


def _heading(table: PaperTable) -> str:
    """The table's caption up to its first colon or comma, with the domain where the key names one."""
    head = table.caption.split(":")[0].split(",")[0]
    return head + (", " + table.key.split("-")[1] if "-" in table.key else "")


def _decoys() -> str:
    """How far the held-out combinations' words were seen on a task's other objects (the decoys)."""
    from gpl_dist.envs.multiroom import decoy_overlap
    from gpl_dist.splits import split_tasks

    parts = []
    for split, label in (("heldout4_test", "held-out"), ("heldout4_indist_test", "in-distribution")):
        colour, shape = decoy_overlap(split_tasks("multiroom", split))
        parts.append(f"{label} tasks: {colour:.0%} have a decoy of the true object's colour, {shape:.0%} one of its shape")
    return "Decoy overlap (from the split file): " + "; ".join(parts) + "."


def health_markdown(health: dict[Path, RunHealth], report_dir: Path) -> str:
    """Every run's conditioning encoders at its final round (dead / units per encoder: i
    instruction, c correction, t trajectory, p pair) and the rounds any layer of them was dead
    whole; a run dead at its final round is not valid and is out of every mean."""
    lines = ["| run | rounds | final round: dead units; layers dead whole | valid |", "|---|---|---|---|"]
    for run_dir, h in health.items():
        where = run_dir.relative_to(report_dir) if run_dir.is_relative_to(report_dir) else run_dir
        valid = "yes" if h.valid and h.instrumented else "yes (not instrumented)" if h.valid else "**no**"
        lines.append(f"| `{where}` | {h.rounds} | {h.text()} | {valid} |")
    bad = sum(not h.valid for h in health.values())
    lines.append(f"\n{len(health)} runs; {bad} not valid; "
                 f"{sum(bool(h.dead_layers) for h in health.values())} with a layer dead whole in some round; "
                 f"{sum(not h.instrumented for h in health.values())} not instrumented.")
    return "\n".join(lines)


def per_seed_markdown(results: list[RunResult], health: dict[Path, RunHealth]) -> str:
    """Each entry's evaluations, one line a training seed: completion after each k, success after
    the first and the last, and whether the run is valid."""
    lines = ["| entry | evaluation | seed | completion c0 .. cK | success c0, cK | valid |", "|---|---|---|---|---|---|"]
    for r in sorted(results, key=lambda r: (r.entry, r.evaluation, r.seed)):
        comp = " ".join(f"{x:.3f}" for x in r.completion)
        succ = f"{r.success[0]:.3f}, {r.success[-1]:.3f}" if r.success else "—"
        lines.append(f"| {r.entry} | {r.evaluation} | {r.seed} | {comp} | {succ} | "
                     f"{'yes' if health[r.run_dir].valid else '**no**'} |")
    return "\n".join(lines)


def _paired(own: list[float], swapped: list[float]) -> tuple[MeanCI, float | None]:
    """The paired difference ``swapped - own`` over training seeds: its mean with the 95 % t
    interval, and the two-sided p of the one-sample t test against 0 (None for one seed)."""
    diff = mean_ci([s - o for o, s in zip(own, swapped)])
    if diff.sd is None:
        return diff, None
    if diff.sd == 0.0:
        return diff, 1.0 if diff.mean == 0.0 else 0.0
    return diff, t_two_sided_p(diff.mean / (diff.sd / diff.n ** 0.5), diff.n - 1)


def _paired_text(diff: MeanCI, p: float | None) -> str:
    ci = f"{diff.mean:+.3f}" + ("" if diff.half_width is None else f" ± {diff.half_width:.3f}")
    return f"{ci}, p {'—' if p is None else f'{p:.2g}'}"


#: The largest change of the swap control's completion (own minus told another's, after the last
#: attempt) of any run at the 0.02-0.03 floor, where the control cannot tell (0.019 in the archive):
#: a run that drops less does not measurably read its instruction.
FLOOR_CHANGE = 0.02
#: A drop that shows a run reads its instruction: five times ``FLOOR_CHANGE``. Where some runs of an
#: entry drop this much, its runs that drop less than ``FLOOR_CHANGE`` are named as not reading theirs.
READ_DROP = 0.1


def swap_markdown(results: list[RunResult], health: dict[Path, RunHealth]) -> str:
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
            sw = instruction_swap(run_dir)
            if sw is None:
                unmeasured.append(seed)
                continue
            own_split = run_valid_split(run_dir)
            if sw.split != own_split:
                notes.append(f"- `{entry}` seed {seed}: measured on `{sw.split}`, "
                             + (f"not the run's valid split (`{own_split}`); left out (measure it again with "
                                "`gpl-dist suite swap`)" if own_split else "but its training split has no valid split; left out"))
            elif sw.rule != SWAP_RULE or sw.weights_sha256 != sha256_file(run_dir / "checkpoints" / LATEST):
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
            diff, p = _paired(own, swapped)
            cells += [f"{statistics.fmean(own):.3f}, {statistics.fmean(swapped):.3f}", _paired_text(diff, p)]
            verdicts.append(None if p is None else p < ALPHA and diff.mean < 0)
        if len(cells) == 2:
            cells += ["(one attempt)", "(one attempt)"]
        reads = "—" if None in verdicts else "yes" if any(verdicts) else "no measurable drop"
        lines.append(f"| {entry} | {len(measured)} | {' | '.join(cells)} | {reads} |")
    if len(lines) == 2:
        return "No run has its instruction-swap control yet (`gpl-dist suite swap OUT`)."
    return "\n".join(lines + ([""] + notes if notes else []))


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


def _comparisons() -> tuple[Comparison, ...]:
    """Each row of the paper's tables against its table's GPL row of the same domain and
    evaluation (GPL after the table's last column against the row's last column), and the retry
    control's gain over attempts against GPL's. A row trained 12 rounds (``-long``) is also set
    against the table's GPL trained 12 rounds (``-gpl-long``), where there is one: equal budgets."""
    out: dict[tuple, Comparison] = {}

    def reference(table: PaperTable, row: PaperRow, suffix: str) -> PaperRow | None:
        domain = (row.entry or "").split("-")[0] + "-"
        return next((g for g in table.rows if g.entry and g.entry.endswith(suffix) and g.entry.startswith(domain)
                     and g.evaluation == row.evaluation), None)

    for table in PAPER_TABLES:
        for row in table.rows:
            if row.entry is None or row.entry.endswith("-gpl"):
                continue
            pairs = [("GPL", reference(table, row, "-gpl"))]
            if row.entry.endswith("-long") and not row.entry.endswith("-gpl-long"):
                pairs.append(("GPL 12 rounds", reference(table, row, "-gpl-long")))
            for name, gpl in pairs:
                if gpl is None or gpl.entry is None:
                    continue
                for gain in (False, True) if table.key == "retry" else (False,):
                    c = Comparison(f"{_heading(table)}: {name} c{gpl.columns[-1]} vs {row.label} c{row.columns[-1]}"
                                   + (", gain over c0" if gain else ""), gpl.entry, gpl.evaluation, gpl.columns[-1],
                                   row.entry, row.evaluation, row.columns[-1], gain)
                    out.setdefault((c.entry, c.evaluation, c.k, c.other, c.other_evaluation, c.other_k, gain), c)
    return tuple(out.values())


def _values(results: list[RunResult], entry: str, evaluation: str, k: int, gain: bool) -> list[float]:
    runs = [r for r in results if r.entry == entry and r.evaluation == evaluation and k < len(r.completion)]
    return [r.completion[k] - r.completion[0] if gain else r.completion[k] for r in sorted(runs, key=lambda r: r.seed)]


def comparisons_markdown(results: list[RunResult], wanted: Mapping[str, int] | None = None) -> str:
    """Welch's t-test (two-sided, p < 0.05) of every ``_comparisons`` pair with runs on both sides.
    ``wanted``: each entry's valid runs the suite aims at (``wanted_runs``); a side with fewer marks
    the verdict provisional (the README counts one or two seeds as no evidence)."""
    lines = ["| comparison | GPL (mean, seeds) | other (mean, seeds) | difference | Welch t | df | p | verdict |",
             "|---|---|---|---|---|---|---|---|"]
    for c in _comparisons():
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
                     f"{w.difference:+.3f} | {_fmt(w.t, '.2f')} | {_fmt(w.df, '.1f')} | {_fmt(w.p, '.3g')} | "
                     f"{verdict} |")
    return "\n".join(lines)


def wanted_runs(planned: Mapping[str, tuple[int, ...]], left_out: Sequence[RunResult]) -> dict[str, int]:
    """Each entry's valid runs the suite aims at: its planned seeds less those the health gate left
    out (the suite file gives such an entry a seed more in its place)."""
    return {entry: len(seeds) - len({r.seed for r in left_out if r.entry == entry and r.seed in seeds})
            for entry, seeds in planned.items()}


def _fmt(value: float | None, spec: str) -> str:
    return "—" if value is None else format(value, spec)


def run_curves(results: list[RunResult]) -> dict[Path, LearningCurve]:
    """Each run's ``LearningCurve``, read once for every table and plot of a report."""
    return {d: learning_curve(d) for d in sorted({r.run_dir for r in results})}


def plateau_markdown(results: list[RunResult], planned: dict[str, tuple[int, ...]],
                     by_run: Mapping[Path, LearningCurve] | None = None) -> str:
    """Whether each entry was still improving at its last round, on the valid split: per run, the
    valid completion after the last attempt at its last round minus that at the round before
    (``curve-valid.json``, ``gpl-dist suite curves``); over the entry's valid runs, the mean gain
    with its 95 % t interval and the two-sided p of the t test against 0. 'still rising' when the
    gain is significantly above 0, 'flat' when it is a tie with 0. The suite trains an entry that
    was still rising for more rounds under the name ``<entry>-long``, and both are reported. Beside
    it, each run's best round on the valid curve and the mean of those best values, so that a curve
    that peaked and fell (flat at its end, below its best) shows; descriptive only (a maximum over
    rounds is biased upwards), and the reported weights stay the last round's."""
    lines = ["| entry | runs with a curve | last round | valid completion there | gain over the last round "
             "(95 % t), p | verdict | best round per run: valid there (mean) | trained longer |",
             "|---|---|---|---|---|---|---|---|"]
    by_run = run_curves(results) if by_run is None else by_run
    runs: dict[str, set[Path]] = {}
    for r in results:
        runs.setdefault(r.entry, set()).add(r.run_dir)
    uncurved: list[str] = []
    off: list[str] = []
    for entry in sorted(runs):
        dirs = sorted(runs[entry])
        every = [by_run[d] for d in dirs]
        curves = [c for c in every  # a curve computed to the last round
                  if len(c.valid) >= 2 and c.rounds and c.valid_rounds[-1] == c.rounds[-1]]
        if len(curves) < len(dirs):
            uncurved.append(f"`{entry}` {len(dirs) - len(curves)} of {len(dirs)}")
        off.extend(f"`{entry}` {d.name} (`{c.off_split}`)" for d, c in zip(dirs, every) if c.off_split)
        if not curves:
            continue
        finals = [[v[-1] for v in c.valid] for c in curves]  # each round's completion after the last attempt
        last = [f[-1] for f in finals]
        diff, p = _paired([f[-2] for f in finals], last)
        verdict = ("— (one run)" if p is None else "still rising" if p < ALPHA and diff.mean > 0
                   else "falling" if p < ALPHA else "flat")
        longer = f"{entry}-long"
        n_long = len(runs.get(longer, ()))
        had = f"`{longer}` ({n_long} run{'' if n_long == 1 else 's'})" if n_long else \
            f"`{longer}` (not run yet)" if longer in planned else "—"
        rounds = sorted({c.rounds[-1] for c in curves})
        best = [f.index(max(f)) for f in finals]  # the first best on a tie
        best_text = (f"{', '.join(str(c.valid_rounds[i]) for c, i in zip(curves, best))}: "
                     f"{statistics.fmean(f[i] for f, i in zip(finals, best)):.3f}")
        lines.append(f"| {entry} | {len(curves)} | {', '.join(map(str, rounds))} | {statistics.fmean(last):.3f} | "
                     f"{_paired_text(diff, p)} | {verdict} | {best_text} | {had} |")
    if uncurved:
        lines.append("\nRuns without a valid curve to their last round, not checked here (`gpl-dist suite curves` "
                     "computes one from a run's per-round weights, which these runs no longer have): "
                     + ", ".join(uncurved) + ".")
    if off:
        lines.append("\nOf those, curves measured on a split that is not the run's valid split (it may hold tasks "
                     "the run trained on, or test tasks), so left out: " + ", ".join(off) + ".")
    return "\n".join(lines)


def budgets_markdown(results: list[RunResult], report_dir: Path) -> str:
    """Per entry, mean over its runs: rounds, tuples collected, gradient steps, trained parameters,
    the learner's and collection's wall time."""
    runs: dict[str, dict[Path, RunBudget]] = {}
    for r in results:
        runs.setdefault(r.entry, {})
        if r.run_dir not in runs[r.entry]:
            runs[r.entry][r.run_dir] = run_budget(r.run_dir)
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


def plot_curves(results: list[RunResult], domain: str, path: Path,
                by_run: Mapping[Path, LearningCurve] | None = None) -> bool:
    """Completion over DAgger rounds of each ``domain`` entry, mean over its runs: on the training
    tasks during collection (after the last correction), and on the valid split where computed."""
    entries = sorted({r.entry for r in results if r.entry.startswith(domain + "-")})
    if not entries:
        return False
    by_run = run_curves(results) if by_run is None else by_run
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9.5, 3.6), dpi=110, sharey=True)
    for i, entry in enumerate(entries):
        runs = [by_run[d] for d in sorted({r.run_dir for r in results if r.entry == entry})]
        for ax, part in zip(axes, ("train", "valid")):
            series = [(c.rounds if part == "train" else c.valid_rounds, getattr(c, part)) for c in runs]
            series = [(rs, v) for rs, v in series if v]
            if not series:
                continue
            n = min(len(v) for _, v in series)
            ys = [statistics.fmean(v[j][-1] for _, v in series) for j in range(n)]
            ax.plot(series[0][0][:n], ys, marker="o", ms=3, color=f"C{i % 10}", ls="-" if i < 10 else "--",
                    label=f"{entry} ({len(series)})")
    axes[0].set_title("training tasks, during collection (last attempt)", fontsize=8)
    axes[1].set_title("valid split, each round's weights (last attempt)", fontsize=8)
    for ax in axes:
        ax.set_xlabel("DAgger round")
        ax.grid(alpha=0.3)
        ax.set_ylim(0, 1)
    axes[0].set_ylabel("completion")
    axes[1].legend(*axes[0].get_legend_handles_labels(), fontsize=6, loc="upper left", bbox_to_anchor=(1.01, 1.0),
                   title="entry (runs)", title_fontsize=6)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return True


#: What the provenance table's numerics column means for a person re-training a run.
REPRODUCING = ("**Re-training a run.** `gpl-dist suite run SUITE --out DIR --only ENTRY --seeds S` trains a run "
               "again from its seed. Where `gpl-dist suite status` marks it `numerics as here` (its recorded "
               "fingerprint is this machine's: trained on the CPU, one thread per learner, not on a cluster), it "
               "writes the same metrics and eval files, bit for bit. Under another fingerprint (another CPU model or "
               "thread count, another torch, numpy or MuJoCo version) MKL and oneDNN sum in another order, the last "
               "bits differ, training amplifies them, and the run lands at another point of its entry's seed "
               "spread: compare it with the per-seed table, not with one file. `gpu`, `threads>1`, `cluster`: no "
               "bitwise reproduction on offer; \"not recorded\": trained before fingerprints were recorded.")


def provenance_markdown(results: list[RunResult], report_dir: Path, left_out: Sequence[RunResult] = ()) -> str:
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
        where = run_dir.relative_to(report_dir) if run_dir.is_relative_to(report_dir) else run_dir
        numerics = ", ".join(first.numerics) or "not recorded"
        seed_cell = f"{seed} (not valid: left out of the means)" if run_dir in invalid else str(seed)
        lines.append(f"| {entry} | {seed_cell} | `{where}` | {commits} | {numerics} | {first.train_seconds / 60:.1f} | "
                     f"{evals} |")
    train_s = sum({r.run_dir: r.train_seconds for r in results}.values())
    eval_s = sum(r.eval_seconds for r in results)
    lines.append(f"\nWall time of these runs: {train_s / 3600:.1f} h training, {eval_s / 3600:.2f} h evaluation, "
                 "as each run's process measured it on the machine it ran on.")
    lines.append("\n" + REPRODUCING)
    return "\n".join(lines)


_EFFORT = (("corrections_to_solve", "corrections per solved task"), ("words_per_solved_task", "words per solved task"),
           ("unsolved_fraction", "unsolved"), ("completion_auc", "completion AUC"))


def effort_markdown(results: list[RunResult], evaluation: str = "test") -> str:
    """Correction effort of every entry's ``evaluation``, mean over training seeds."""
    lines = ["| entry | " + " | ".join(label for _, label in _EFFORT) + " | training seeds |",
             "|---|" + "---|" * (len(_EFFORT) + 1)]
    for entry in sorted({r.entry for r in results if r.evaluation == evaluation}):
        mine = [r for r in results if r.entry == entry and r.evaluation == evaluation and r.effort]
        cells = []
        for key, _ in _EFFORT:
            values = [r.effort[key] for r in mine if r.effort and r.effort.get(key) is not None]  # type: ignore[index]
            cells.append(f"{statistics.fmean(values):.3f}" if values else "—")
        seeds = str(len(mine)) if mine else "none: evaluated before the effort was recorded (`gpl-dist eval` again)"
        lines.append(f"| {entry} | " + " | ".join(cells) + f" | {seeds} |")
    return "\n".join(lines)


def evaluations_markdown(results: list[RunResult]) -> str:
    """Each evaluation's settings, as every run recorded them (identical: ``_check_same_settings``)."""
    lines = ["| evaluation | split | evaluation seeds | corrections | actions | tasks |", "|---|---|---|---|---|---|"]
    for name in sorted({r.evaluation for r in results}):
        s: dict[str, Any] = dict(next(r for r in results if r.evaluation == name).settings)
        lines.append(f"| {name} | {s['split']} | {', '.join(map(str, s['seeds']))} | {s['num_corrections']} | "
                     f"{'greedy' if s['greedy_actions'] else 'sampled'} | {s['max_tasks'] or 'all'} |")
    return "\n".join(lines)


def write_report(suite_out: str | Path, out: str | Path) -> tuple[Path, Path]:
    """Write ``out/report.md`` (with PNG plots) and ``out/report.html`` (plots inline)."""

    suite_out, out = Path(suite_out), Path(out)
    if not suite_out.is_dir():
        raise RunDirError(f"no suite output at {suite_out}")
    archive = out / ARCHIVE_DIR
    archive.mkdir(parents=True, exist_ok=True)
    archive_runs(suite_out, archive)
    every = collect_results(archive)
    health = health_of(every)
    results = healthy(every, health)  # every mean and test is over the valid runs only
    excluded = [r for r in every if r not in results]
    planned = planned_seeds(archive / "suite.yaml")  # the suite's latest copy: archived from suite_out just above
    parts, html_parts = [_INTRO.format(suite_out=suite_out)], [f"<p>{html.escape(_INTRO_HTML.format(suite_out=suite_out))}</p>"]
    if missing := not_run(every, planned):  # a run left out as not valid was run
        items = [f"`{entry}`: training seed(s) {', '.join(map(str, seeds))}" for entry, seeds in missing]
        parts += ["## Not run yet", _NOT_RUN_INTRO + "\n\n" + "\n".join(f"- {item}" for item in items)]
        html_parts += ["<h2>Not run yet</h2>", f"<p>{html.escape(_NOT_RUN_INTRO.replace('`', ''))}</p><ul>"
                       + "".join(f"<li>{html.escape(item.replace('`', ''))}</li>" for item in items) + "</ul>"]
    for table in PAPER_TABLES:
        md = table_markdown(results, table, planned, excluded)
        success = success_markdown(results, table)
        png = out / f"{table.key}.png"
        has_plot = plot_table(results, table, png)
        parts += [f"## {_heading(table)}", md, success]
        html_parts += [f"<h2>{html.escape(_heading(table))}</h2>", _md_table_html(md), _md_table_html(success)]
        if table.key == "table5":
            parts.append(_decoys())
            html_parts.append(f"<p>{html.escape(_decoys())}</p>")
        if has_plot:
            parts.append(f"![{table.key}]({png.name})")
            data = base64.b64encode(png.read_bytes()).decode()
            html_parts.append(f'<img alt="{table.key}" src="data:image/png;base64,{data}">')
    wanted = wanted_runs(planned, excluded)
    curves = run_curves(results)
    sections = [("Comparisons", "Every row against its table's GPL row (same domain and evaluation), and every "
                 "12-round row against GPL trained 12 rounds where the table has it, over the valid "
                 "runs' training seeds: Welch's two-sided t-test; 'tie' when p >= 0.05.", comparisons_markdown(results, wanted)),
                ("Budgets", "What each entry's runs spent (mean over its valid runs): the no-correction baselines "
                 "collect one attempt a task, so fewer tuples and gradient steps than GPL.", budgets_markdown(results, out)),
                ("Still improving at the last round?", "Completion on each run's valid split (after the last "
                 "attempt) gained over each run's last DAgger round, from the learning curves above, paired by "
                 "training seed: an entry "
                 "still rising is trained on under `<entry>-long` until its curve is flat, and both are reported. "
                 "Each run's best round on its valid curve stands beside, so that a curve which peaked and fell "
                 "shows (descriptive: a maximum over rounds flatters; the reported weights are the last round's).",
                 plateau_markdown(results, planned, curves)),
                ("Run health", "Each run's conditioning encoders at its final round (dead / units: i instruction, "
                 "c correction, t trajectory, p pair; MIVOA's LSTM: constant units) and the rounds where a layer of "
                 "them was dead whole. A run with a layer dead at its final round is not valid and is left out of "
                 "every mean above.", health_markdown(health, out)),
                ("Does each policy read its instruction?", "The instruction-swap control on each run's valid split "
                 "(`gpl-dist suite swap`, its settings in each run's `instruction-swap-valid.json`): each run's final "
                 "weights with the tasks' own instructions and with each task told the most different instruction of "
                 "another task; a policy blind to its instruction scores the same. Means over the entry's valid runs; "
                 "each difference is paired by training seed ('yes' when one is significantly below 0; '—': one "
                 "seed, no test).",
                 swap_markdown(every, health)),
                ("Per training seed", "Each run's own numbers (the mean over its evaluation seeds).",
                 per_seed_markdown(every, health))]
    for title, intro, md in sections:
        parts += [f"## {title}", intro, md]
        html_parts += [f"<h2>{html.escape(title)}</h2>", f"<p>{html.escape(intro)}</p>", _md_table_html(md)]
        if title == "Budgets":
            parts.append("## Learning curves")
            html_parts.append("<h2>Learning curves</h2>")
            for domain in sorted({r.entry.split("-")[0] for r in results}):
                png = out / f"curves-{domain}.png"
                if plot_curves(results, domain, png, curves):
                    parts.append(f"![learning curves, {domain}]({png.name})")
                    data = base64.b64encode(png.read_bytes()).decode()
                    html_parts.append(f'<img alt="learning curves, {domain}" src="data:image/png;base64,{data}">')

    plan = plan_of_copy(archive / "suite.yaml")
    rl_md, rl_png = sample_complexity_section(suite_out, out, read_from=archive, plan=plan)
    if rl_md:
        parts += ["## Sample complexity: RL per task against GPL and GPR (the paper's figure)", rl_md]
        html_parts += ["<h2>Sample complexity</h2>", _md_table_html(rl_md)]
    if rl_png is not None:
        parts.append(f"![sample complexity]({rl_png.name})")
        data = base64.b64encode(rl_png.read_bytes()).decode()
        html_parts.append(f'<img alt="sample complexity" src="data:image/png;base64,{data}">')
    effort = effort_markdown(results)
    settings = evaluations_markdown(results)
    prov = provenance_markdown(results, out, excluded)
    effort_intro = ("What the corrections cost on the test tasks (evaluation 'test'): corrections and words of "
                    "correction before the first success, over the solved tasks; the fraction never solved within "
                    "the budget; the area under the completion curve over its length.")
    parts += ["## Correction effort", effort_intro, effort, "## Evaluation settings", settings, "## Runs", prov]
    html_parts += ["<h2>Correction effort</h2>", f"<p>{html.escape(effort_intro)}</p>", _md_table_html(effort),
                   "<h2>Evaluation settings</h2>", _md_table_html(settings), "<h2>Runs</h2>", _md_table_html(prov)]
    md_path, html_path = out / "report.md", out / "report.html"
    md_path.write_text("# The paper's experiments, reproduced\n\n" + "\n\n".join(parts) + "\n")
    html_path.write_text("<!doctype html><meta charset='utf-8'><title>gpl-dist: the paper's experiments</title>"
                         "<style>body{font-family:sans-serif;max-width:60em;margin:auto}td,th{border:1px solid #ccc;"
                         "padding:2px 6px}table{border-collapse:collapse}</style>"
                         "<h1>The paper's experiments, reproduced</h1>" + "\n".join(html_parts) + "\n")
    return md_path, html_path


_INTRO = ("Written by `gpl-dist suite report {suite_out}` from the runs' `eval*.json` files, archived beside this "
          "report in `runs/` with each run's config, metrics and final weights (with those archived by earlier "
          "reports into this folder). Each cell: our mean "
          "completion over training seeds (each seed's own value is its mean over the evaluation seeds, see Evaluation "
          "settings), ± the half-width of its 95 % t interval over training seeds, and the paper's number in "
          "parentheses. '—': not run yet or not built; the last column says which. The instruction-swap control "
          "reads each run's `instruction-swap-valid.json` (the run's valid split), archived beside its eval files.")
_INTRO_HTML = _INTRO.replace("`", "")


def _md_table_html(md: str) -> str:
    """The Markdown table in ``md`` (its first paragraph kept as a caption) as HTML, escaped."""
    lines = md.splitlines()
    caption = [ln for ln in lines if ln and not ln.startswith("|")]
    rows = [ln.strip("|").split("|") for ln in lines if ln.startswith("|") and not ln.startswith("|---")]
    tags = ["th"] + ["td"] * len(rows)  # the first row is the header
    body = "".join("<tr>" + "".join(f"<{tag}>{html.escape(c.strip().strip('`*'))}</{tag}>" for c in row) + "</tr>"
                   for tag, row in zip(tags, rows))
    return "".join(f"<p>{html.escape(c.replace('**', ''))}</p>" for c in caption) + f"<table>{body}</table>"

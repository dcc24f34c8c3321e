"""``gpl-dist suite report``: a suite's runs as a report, Markdown and HTML, for any suite.

Every number is read from the runs' ``eval*.json`` files (through each run's ``suite-run.json``,
which names the file of each evaluation) and their own files (``report_data``); none is typed in
the code. Where the suite's entries are the paper's (``report_paper.is_paper_suite``), the report
is "The paper's experiments, reproduced": the paper's tables (``configs/suites/paper-tables.yaml``)
with ours beside the paper's numbers and Welch's test of every row against its table's GPL row.
For any other suite it is that suite's own comparison (``report_own``): per evaluation, every
entry's mean ± 95 % t interval over training seeds after each correction, the success rate beside
it, and Welch's test of every entry against the suite's ``reference`` entry. Either way follow
the budgets, learning curves, the plateau check, run health, the instruction-swap control, the
per-seed numbers, correction effort, evaluation settings and provenance (``report_runs``,
``report_controls``).

The parts, one job each: ``report_data`` reads (once); ``report_paper``, ``report_own``,
``report_runs`` and ``report_controls`` build sections' text from results with no I/O;
``report_plots`` draws; ``report_render`` writes one list of sections as Markdown and as HTML.
``build_report`` reads a suite output or archive and writes the report; archiving the runs
beside it (``archive.archive_runs`` into ``OUT/runs``) is the command's, before it: then the
report is computed from that archive, so every number traces to a file kept with the report.
``write_report`` does both, as ``gpl-dist suite report`` did.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from pathlib import Path

from gpl_dist.app.suite import report_own
from gpl_dist.app.suite.archive import archive_runs
from gpl_dist.app.suite.report_controls import plateau_table, swap_table
from gpl_dist.app.suite.report_data import (
    Cell,
    ReportData,
    RunResult,
    cell,
    collect_results,
    health_of,
    healthy,
    not_run,
    planned_seeds,
    read_facts,
    read_report_data,
    run_curves,
    wanted_runs,
)
from gpl_dist.app.suite.report_paper import (
    NOTES,
    Paper,
    PaperRow,
    PaperTable,
    comparisons_markdown,
    is_paper_suite,
    load_paper,
    plot_rows,
    success_markdown,
    table_markdown,
)
from gpl_dist.app.suite.report_plots import plot_completion, plot_curves
from gpl_dist.app.suite.report_render import Bullets, Document, Image, Section, Table, Text, write_document
from gpl_dist.app.suite.report_runs import (
    budgets_markdown,
    effort_markdown,
    evaluations_markdown,
    health_markdown,
    per_seed_markdown,
    provenance_markdown,
    shown,
)
from gpl_dist.app.suite.rl.jobs import plan_of_copy
from gpl_dist.app.suite.rl.report import sample_complexity_section
from gpl_dist.app.suite.run_facts import RunHealth
from gpl_dist.errors import RunDirError

__all__ = ["ARCHIVE_DIR", "Cell", "PaperRow", "PaperTable", "RunResult", "build_report", "cell", "collect_results",
           "comparisons_markdown", "effort_markdown", "health_of", "healthy", "planned_seeds", "provenance_markdown",
           "run_curves", "swap_markdown", "table_markdown", "wanted_runs", "write_report"]

#: The report folder's archive of the runs it reads (``gpl_dist.app.suite.archive``).
ARCHIVE_DIR = "runs"

_PAPER_INTRO = ("Written by `gpl-dist suite report {source}` from the runs' `eval*.json` files, archived beside this "
                "report in `runs/` with each run's config, metrics and final weights (with those archived by earlier "
                "reports into this folder). Each cell: our mean "
                "completion over training seeds (each seed's own value is its mean over the evaluation seeds, see "
                "Evaluation settings), ± the half-width of its 95 % t interval over training seeds, and the paper's "
                "number in parentheses. '—': not run yet or not built; the last column says which. The "
                "instruction-swap control reads each run's `instruction-swap-valid.json` (the run's valid split), "
                "archived beside its eval files.")
_OWN_INTRO = ("Written by `gpl-dist suite report {source}` from the runs' `eval*.json` files{where}. The suite's "
              "entries are not the paper's, so the paper's tables are not shown: per evaluation, each entry's mean "
              "completion over training seeds (each seed's own value is its mean over the evaluation seeds, see "
              "Evaluation settings) after each correction, ± the half-width of its 95 % t interval over training "
              "seeds, and {tests}. A run with a layer of its conditioning encoder dead whole at its final round is "
              "not valid and is left out of every mean and test (Run health).")
_NOT_RUN_INTRO = ("Runs of the suite file (its latest copy, `{copy}`) that this report holds no result of yet "
                  "(`gpl-dist suite run SUITE --out OUT --only ENTRY --seeds S`):")
_EFFORT_INTRO = ("What the corrections cost on the test tasks (evaluation 'test'): corrections and words of "
                 "correction before the first success, over the solved tasks; the fraction never solved within "
                 "the budget; the area under the completion curve over its length.")


def _not_run_section(data: ReportData) -> list[Section]:
    missing = not_run(data.every, data.plan.seeds)  # a run left out as not valid was run
    items = tuple(f"`{entry}`: training seed(s) {', '.join(map(str, seeds))}" for entry, seeds in missing)
    intro = _NOT_RUN_INTRO.format(copy=shown(data.root / "suite.yaml", data.report_dir))
    return [Section("Not run yet", (Bullets(intro, items),))] if missing else []


def paper_sections(data: ReportData, paper: Paper, out: Path) -> list[Section]:
    """The paper's tables, each with its success rates, its note and its plot (drawn here)."""
    sections = []
    for table in paper.tables:
        blocks: list = [Table(table_markdown(data.results, table, data.plan.seeds, data.excluded)),
                        Table(success_markdown(data.results, table))]
        if table.note:
            blocks.append(Text(NOTES[table.note]()))
        png = out / f"{table.key}.png"
        if plot_completion(plot_rows(data.results, table), table.columns, table.heading, png):
            blocks.append(Image(png, table.key))
        sections.append(Section(table.heading, tuple(blocks)))
    return sections


def own_sections(data: ReportData, out: Path) -> list[Section]:
    """The suite's own comparison: per evaluation, completion, success, Welch against the reference, plot."""
    setups = {entry: data.entry_setups(entry) for entry in {r.entry for r in data.every}}
    wanted = wanted_runs(data.plan.seeds, data.excluded)
    sections = []
    for name in report_own.evaluation_names(data.every, data.plan):
        blocks: list = [Table(report_own.completion_markdown(data.results, data.every, name, data.plan, setups)),
                        Table(report_own.success_markdown(data.results, data.every, name, data.plan))]
        blocks.append(Table(report_own.welch_markdown(data.results, name, data.plan, wanted)))
        png = out / report_own.plot_name(name)
        columns = tuple(range(max(len(r.completion) for r in data.every if r.evaluation == name)))
        rows = report_own.plot_rows(data.results, data.every, name, data.plan)
        if plot_completion(rows, columns, f"Evaluation '{name}'", png, ours=""):
            blocks.append(Image(png, f"evaluation {name}"))
        sections.append(Section(f"Evaluation '{name}': every entry" + (" against the reference" if data.plan.reference
                                                                         else ""), tuple(blocks)))
    return sections


def _curve_images(data: ReportData, out: Path) -> tuple[Image, ...]:
    """A learning-curve plot per domain (as the runs' configs say), of the valid runs' entries."""
    images = []
    for domain in sorted({data.domain(r.run_dir) for r in data.results}):
        entries = sorted({r.entry for r in data.results if data.domain(r.run_dir) == domain})
        curves = {e: [data.facts[d].curve for d in sorted({r.run_dir for r in data.results if r.entry == e})]
                  for e in entries}
        png = out / f"curves-{domain}.png"
        if plot_curves(curves, png):
            images.append(Image(png, f"learning curves, {domain}"))
    return tuple(images)


def run_sections(data: ReportData, out: Path, source: str, paper: Paper | None) -> list[Section]:
    """What follows the tables, for any suite: comparisons (the paper's), budgets, curves, plateau,
    health, the swap control, per-seed numbers, sample complexity, effort, settings and provenance."""
    results, health = data.results, data.health
    wanted = wanted_runs(data.plan.seeds, data.excluded)
    curves = {d: f.curve for d, f in data.facts.items()}
    sections = []
    if paper is not None:
        sections.append(Section("Comparisons", (
            Text("Every row against its table's GPL row (same domain and evaluation), and every 12-round row against "
                 "GPL trained 12 rounds where the table has it, over the valid runs' training seeds: Welch's two-sided "
                 "t-test; 'tie' when p >= 0.05."), Table(comparisons_markdown(results, wanted, paper)))))
    sections += [
        Section("Budgets", (Text("What each entry's runs spent (mean over its valid runs): the no-correction baselines "
                                 "collect one attempt a task, so fewer tuples and gradient steps than GPL." if paper else
                                 "What each entry's runs spent (mean over its valid runs): an entry that takes no "
                                 "corrections collects one attempt a task, so fewer tuples and gradient steps."),
                            Table(budgets_markdown(results, {d: f.budget for d, f in data.facts.items()})))),
        Section("Learning curves", _curve_images(data, out)),
        Section("Still improving at the last round?", (
            Text("Completion on each run's valid split (after the last attempt) gained over each run's last DAgger "
                 "round, from the learning curves above, paired by training seed: an entry still rising is trained on "
                 + ("under `<entry>-long` until its curve is flat" if paper else "as another entry of the suite file "
                    "(its base and overrides with a larger `training.num_rounds`: 'trained longer')")
                 + ", and both are reported. Each run's best round on its "
                 "valid curve stands beside, so that a curve which peaked and fell shows (descriptive: a maximum over "
                 "rounds flatters; the reported weights are the last round's)."),
            Table(plateau_table(results, data.plan.seeds, curves, data.longer())))),
        Section("Run health", (
            Text("Each run's conditioning encoders at its final round (dead / units: i instruction, c correction, t "
                 "trajectory, p pair; MIVOA's LSTM: constant units) and the rounds where a layer of them was dead whole. "
                 "A run with a layer dead at its final round is not valid and is left out of every mean above."),
            Table(health_markdown(health, data.report_dir)))),
        Section("Does each policy read its instruction?", (
            Text("The instruction-swap control on each run's valid split (`gpl-dist suite swap`, its settings in each "
                 "run's `instruction-swap-valid.json`): each run's final weights with the tasks' own instructions and "
                 "with each task told the most different instruction of another task; a policy blind to its "
                 "instruction scores the same. Means over the entry's valid runs; each difference is paired by "
                 "training seed ('yes' when one is significantly below 0; '—': one seed, no test)."),
            Table(swap_table(data.every, health, data.facts)))),
        Section("Per training seed", (Text("Each run's own numbers (the mean over its evaluation seeds)."),
                                      Table(per_seed_markdown(data.every, health)))),
    ]
    rl_md, rl_png = sample_complexity_section(source, out, read_from=data.root, plan=plan_of_copy(data.root / "suite.yaml"))
    if rl_md:
        sections.append(Section("Sample complexity: RL per task against GPL and GPR (the paper's figure)",
                                (Table(rl_md),) + ((Image(rl_png, "sample complexity"),) if rl_png else ()),
                                html_title="Sample complexity"))
    if paper is not None:
        effort: tuple = (Text(_EFFORT_INTRO), Table(effort_markdown(results)))
    else:
        effort = (Text("What the corrections cost on each evaluation's tasks: corrections and words of correction "
                       "before the first success, over the solved tasks; the fraction never solved within the budget; "
                       "the area under the completion curve over its length."),) + tuple(
            Table(f"**Evaluation '{name}'.**\n\n" + effort_markdown(results, name))
            for name in report_own.evaluation_names(results, data.plan))
    sections += [Section("Correction effort", effort),
                 Section("Evaluation settings", (Table(evaluations_markdown(results)),)),
                 Section("Runs", (Table(provenance_markdown(results, data.report_dir, data.excluded)),))]
    return sections


def build_report(runs: str | Path, out: str | Path, source: str | Path | None = None,
                 report_dir: str | Path | None = None, log=print) -> tuple[Path, Path]:
    """Write ``out/report.md`` (with PNG plots) and ``out/report.html`` (plots inline) from the suite
    output or archive ``runs``, which it does not change. ``source``: the folder the command was
    given, as the report names it (default ``runs``); ``report_dir``: the folder whose relative
    paths the report shows (default ``out``, where the command archives the runs)."""
    runs, out = Path(runs), Path(out)
    if not runs.is_dir():
        raise RunDirError(f"no suite output at {runs}")
    out.mkdir(parents=True, exist_ok=True)
    shown_from = Path(report_dir) if report_dir is not None else out
    data = read_report_data(runs, shown_from, log)
    source = str(Path(source) if source is not None else runs)
    paper = load_paper()
    entries = list(data.plan.seeds) or sorted({r.entry for r in data.every})
    domains = {e: {s.domain for s in data.entry_setups(e)} for e in entries}
    if paper is not None and is_paper_suite(paper, entries, domains):
        intro = _PAPER_INTRO.format(source=source)
        doc = Document("The paper's experiments, reproduced", "gpl-dist: the paper's experiments",
                       (Text(intro, intro.replace("`", "")),),
                       tuple(_not_run_section(data) + paper_sections(data, paper, out)
                             + (own_sections(data, out) if data.plan.reference else [])
                             + run_sections(data, out, source, paper)))
    else:
        where = (", archived beside this report in `runs/` with each run's config, metrics and final weights"
                 if runs.resolve() == (shown_from / ARCHIVE_DIR).resolve() else f" in `{runs}`")
        tests = (f"Welch's two-sided t-test of every entry against the suite's reference entry `{data.plan.reference}`"
                 if data.plan.reference else "no test between entries: the suite file names no reference entry "
                 "(a top-level `reference: <entry>`)")
        intro = _OWN_INTRO.format(source=source, where=where, tests=tests)
        doc = Document("The suite's experiments", "gpl-dist: the suite's experiments", (Text(intro, intro.replace("`", "")),),
                       tuple(_not_run_section(data) + own_sections(data, out) + run_sections(data, out, source, None)))
    return write_document(doc, out)


def write_report(suite_out: str | Path, out: str | Path) -> tuple[Path, Path]:
    """Archive the runs of ``suite_out`` into ``out/runs`` (``archive.archive_runs``), then write the
    report from that archive (``build_report``): what ``gpl-dist suite report`` does. A missing
    ``suite_out``, or an archive folder that is a symbolic link, fails in one line (``RunDirError``)."""
    suite_out, out = Path(suite_out), Path(out)
    if not suite_out.is_dir():
        raise RunDirError(f"no suite output at {suite_out}")
    archive = out / ARCHIVE_DIR
    if archive.is_symlink():
        raise RunDirError(f"{archive} is a symbolic link: the report's archive is written in place, never through one")
    archive.mkdir(parents=True, exist_ok=True)
    archive_runs(suite_out, archive)
    return build_report(archive, out, source=suite_out)


def rebuild_report(report_dir: str | Path, out: str | Path, log=print) -> tuple[Path, Path]:
    """The report in ``report_dir`` written again into ``out`` from its own archive
    (``report_dir/runs``): naming the suite output its ``report.md`` names and showing paths as from
    ``report_dir``, so that the files equal the committed ones byte for byte when the code that
    wrote them is the code here. A ``report.md`` without that line fails in one line (``RunDirError``)."""
    report_dir = Path(report_dir)
    md = report_dir / "report.md"
    found = re.search(r"Written by `gpl-dist suite report (\S+)`", md.read_text()) if md.is_file() else None
    if found is None:
        raise RunDirError(f"{md} names no suite output it was written from")
    return build_report(report_dir / ARCHIVE_DIR, out, source=found.group(1), report_dir=report_dir, log=log)


def swap_markdown(results: Sequence[RunResult], health: Mapping[Path, RunHealth]) -> str:
    """The instruction-swap section of ``results``' runs (``report_controls.swap_table``), reading their files."""
    return swap_table(results, health, read_facts(results))


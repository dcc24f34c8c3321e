"""Everything the suite's report reads, read once: the runs' evaluations, each run's own files,
and the suite file's copy. The sections (``report_paper``, ``report_own``, ``report_runs``,
``report_controls``) build their rows from what this module returns, with no I/O of their own.

- ``collect_results``: every evaluation recorded under ``<entry>/seed<k>/suite-run.json``, as
  ``RunResult`` (the numbers of its ``eval*.json``, read as ``learner.evaluate.EvalRecord``), once
  the folder's evidence has been checked;
- ``read_facts``: per run, its ``RunSetup`` (domain, rounds and splits from its ``config.yaml``,
  read without importing a plug-in), health, budget, learning curve and instruction-swap control;
- ``read_plan``: the suite file's copy (``OUT/suite.yaml``, written by ``suite run``): each entry's
  training seeds, evaluations and definition, and the suite's ``reference`` entry.

A cell of the report is the mean over **training** seeds of each run's mean over its evaluation
seeds, with its 95 % t interval (``Cell``, ``stats.mean_ci``), over the valid runs only (``healthy``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from gpl_dist.app.suite.archive import check_archive
from gpl_dist.app.suite.evidence import sha256_file
from gpl_dist.app.suite.one_run import RECORD_VERSION, read_record
from gpl_dist.app.suite.run_facts import (
    InstructionSwap,
    LearningCurve,
    RunBudget,
    RunHealth,
    RunSetup,
    instruction_swap,
    learning_curve,
    run_budget,
    run_health,
    run_setup,
)
from gpl_dist.app.suite.spec import check_seeds
from gpl_dist.app.suite.stats import MeanCI, mean_ci
from gpl_dist.config import ConfigError, bounded_repr, load_yaml_text
from gpl_dist.errors import RunDirError
from learner.checkpoint import LATEST
from learner.evaluate import CorrectionEffort, read_eval


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
    effort: CorrectionEffort | None = None
    """What the corrections cost (the eval record's ``correction_effort``); None where not recorded."""
    success: tuple[float, ...] = ()
    """Fraction of tasks solved after k corrections (over the evaluation's seeds); () where not recorded."""
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
        record = read_record(record_path.parent) or {}
        if record.get("version") != RECORD_VERSION:
            raise RunDirError(f"{record_path} is a suite record of version {record.get('version')}; this report "
                              f"reads version {RECORD_VERSION}")
        run_dir = record_path.parent
        for name, ev in record.get("evaluations", {}).items():
            evaluation = read_eval(run_dir / ev["file"])
            settings = tuple(sorted((k, tuple(v) if isinstance(v, list) else v) for k, v in ev["settings"].items()))
            results.append(RunResult(record["entry"], int(record["seed"]), run_dir, name,
                                     tuple(float(x) for x in evaluation.completion), run_dir / ev["file"], settings,
                                     tuple(record.get("commits", ())), float(record.get("train_seconds", 0.0)),
                                     float(ev.get("seconds", 0.0)), evaluation.correction_effort,
                                     tuple(float(x) for x in evaluation.success),
                                     tuple(record.get("numerics", ()))))
    _check_same_settings(results)
    return results


def _check_same_settings(results: list[RunResult]) -> None:
    """One evaluation name must mean one set of settings across the suite: a cell never mixes."""
    seen: dict[str, RunResult] = {}
    for r in results:
        first = seen.setdefault(r.evaluation, r)
        if first.settings != r.settings:
            raise RunDirError(f"evaluation '{r.evaluation}' has other settings in {r.run_dir} than in {first.run_dir} "
                              f"({dict(r.settings)} vs {dict(first.settings)}): the suite file changed between runs")


def seed_values(results: Sequence[RunResult], entry: str, evaluation: str, k: int, measure: str = "completion") -> list[float]:
    """Each training seed's ``measure`` (completion or success) after ``k`` corrections."""
    return [getattr(r, measure)[k] for r in results
            if r.entry == entry and r.evaluation == evaluation and k < len(getattr(r, measure))]


def cell(results: Sequence[RunResult], entry: str, evaluation: str, k: int, measure: str = "completion") -> Cell | None:
    """``measure`` after ``k`` corrections of ``entry``'s ``evaluation``, over its training seeds."""
    values = seed_values(results, entry, evaluation, k, measure)
    return Cell(mean_ci(values)) if values else None


def healthy(results: Sequence[RunResult], health: Mapping[Path, RunHealth]) -> list[RunResult]:
    """The results of runs that pass the health gate (``evidence.RunHealth.valid``): every mean is over these."""
    return [r for r in results if health[r.run_dir].valid]


def health_of(results: Sequence[RunResult]) -> dict[Path, RunHealth]:
    """Each result's run's ``RunHealth``."""
    return {d: run_health(d) for d in sorted({r.run_dir for r in results})}


def run_curves(results: Sequence[RunResult]) -> dict[Path, LearningCurve]:
    """Each run's ``LearningCurve``, read once for every table and plot of a report."""
    return {d: learning_curve(d) for d in sorted({r.run_dir for r in results})}


@dataclass(frozen=True)
class RunFacts:
    """What the report reads of one run beside its evaluations."""

    setup: RunSetup
    health: RunHealth
    budget: RunBudget
    curve: LearningCurve
    swap: InstructionSwap | None
    """Its instruction-swap control (``SWAP_FILE``); None when not measured."""
    swap_split: str | None = None
    """The split the control must have measured: the run's valid split (the measured one where the
    run's domain is not known here)."""
    swap_current: bool = False
    """The control measured the run's final weights (``checkpoints/latest.pt``, by SHA-256)."""


def read_facts(results: Sequence[RunResult]) -> dict[Path, RunFacts]:
    """``RunFacts`` of every run of ``results``, each file read once."""
    facts = {}
    for d in sorted({r.run_dir for r in results}):
        setup, sw = run_setup(d), instruction_swap(d)
        split = None if sw is None else setup.valid_split if setup.known else sw.split
        current = sw is not None and sw.weights_sha256 == sha256_file(d / "checkpoints" / LATEST)
        facts[d] = RunFacts(setup, run_health(d), run_budget(d), learning_curve(d, setup), sw, split, current)
    return facts


@dataclass(frozen=True)
class SuitePlan:
    """The suite file's copy (``OUT/suite.yaml``) as the report reads it: without resolving base
    configs (relative to where the original lies) and without importing any domain."""

    seeds: dict[str, tuple[int, ...]]
    """Each entry's training seeds, in file order."""
    evaluations: dict[str, tuple[str, ...]]
    """Each entry's evaluations (names)."""
    definitions: dict[str, tuple[str, dict]]
    """Each entry's ``base`` (as written) and ``set`` overrides."""
    reference: str | None = None
    """The entry every other is tested against (the suite file's optional top-level ``reference``)."""


def read_plan(suite_yaml: Path) -> SuitePlan:
    """The ``SuitePlan`` of a suite file's copy; an empty one when there is no copy. A
    ``reference`` that names no entry fails in one line."""
    raw = load_yaml_text(suite_yaml.read_text(), suite_yaml) if suite_yaml.is_file() else None
    entries = raw.get("entries") if isinstance(raw, dict) else None
    if not isinstance(raw, dict) or not isinstance(entries, dict):
        return SuitePlan({}, {}, {})
    seeds, evaluations, definitions = {}, {}, {}
    for name, spec in entries.items():
        spec = spec if isinstance(spec, dict) else {}
        seeds[name] = check_seeds(f"{suite_yaml}: entries.{name}.seeds", spec.get("seeds"))
        names = spec.get("evaluations")
        evaluations[name] = tuple(n for n in names if isinstance(n, str)) if isinstance(names, list) else ()
        sets = spec.get("set")
        definitions[name] = (str(spec.get("base")), dict(sets) if isinstance(sets, dict) else {})
    reference = raw.get("reference")
    if reference is not None and (not isinstance(reference, str) or reference not in entries):
        raise ConfigError(f"{suite_yaml}: reference: expected the name of one of its entries "
                          f"({', '.join(map(str, entries))}), got {bounded_repr(reference)}")
    return SuitePlan(seeds, evaluations, definitions, reference)


def planned_seeds(suite_yaml: Path) -> dict[str, tuple[int, ...]]:
    """Each entry's training seeds in a suite file's copy (``read_plan``); {} when there is no copy."""
    return read_plan(suite_yaml).seeds


_ROUNDS = "training.num_rounds"


def trained_longer(plan: SuitePlan, rounds: Mapping[str, int]) -> dict[str, tuple[str, ...]]:
    """Each entry's entries that train the same thing for more rounds: the same base and overrides
    but for ``training.num_rounds``, which they set above the entry's ``rounds`` (its runs'
    configs say how many it trained)."""
    out: dict[str, tuple[str, ...]] = {}
    for name, (base, sets) in plan.definitions.items():
        if name not in rounds:
            continue
        same = {k: v for k, v in sets.items() if k != _ROUNDS}
        out[name] = tuple(other for other, (b, s) in plan.definitions.items()
                          if other != name and b == base and {k: v for k, v in s.items() if k != _ROUNDS} == same
                          and isinstance(s.get(_ROUNDS), int) and s[_ROUNDS] > rounds[name])
    return out


def status(results: Sequence[RunResult], entry: str, evaluation: str, planned: Mapping[str, tuple[int, ...]],
           excluded: Sequence[RunResult] | None = None) -> str:
    """Which training seeds of ``entry`` a cell stands on, which the health gate left out and
    which the suite file plans but no result has yet."""
    seeds = sorted({r.seed for r in results if r.entry == entry and r.evaluation == evaluation})
    out = sorted({r.seed for r in excluded or () if r.entry == entry and r.evaluation == evaluation})
    missing = [s for s in planned.get(entry, ()) if s not in seeds and s not in out]
    dropped = f"; not valid (a layer dead at the final round), left out: {', '.join(map(str, out))}" if out else ""
    if not seeds:
        return ("not run yet" if not out else "no valid run") + dropped
    done = f"{len(seeds)} training seed(s): {', '.join(map(str, seeds))}" + dropped
    return f"{done}; not run yet: {', '.join(map(str, missing))}" if missing else done


def not_run(results: Sequence[RunResult], planned: Mapping[str, tuple[int, ...]]) -> list[tuple[str, list[int]]]:
    """The suite's entries with training seeds that no result in the report comes from."""
    have = {(r.entry, r.seed) for r in results}
    return [(entry, missing) for entry, seeds in planned.items() if (missing := [s for s in seeds if (entry, s) not in have])]


def wanted_runs(planned: Mapping[str, tuple[int, ...]], left_out: Sequence[RunResult]) -> dict[str, int]:
    """Each entry's valid runs the suite aims at: its planned seeds less those the health gate left
    out (the suite file gives such an entry a seed more in its place)."""
    return {entry: len(seeds) - len({r.seed for r in left_out if r.entry == entry and r.seed in seeds})
            for entry, seeds in planned.items()}


@dataclass(frozen=True)
class ReportData:
    """All a report is built from."""

    every: list[RunResult]
    """Every archived evaluation, valid or not."""
    results: list[RunResult]
    """Those of valid runs: every mean and test is over these."""
    facts: dict[Path, RunFacts]
    plan: SuitePlan
    root: Path
    """The suite output or archive read (where the runs' folders lie)."""
    report_dir: Path
    """The folder whose relative paths the report shows (where the report lies)."""

    @property
    def excluded(self) -> list[RunResult]:
        return [r for r in self.every if r not in self.results]

    @property
    def health(self) -> dict[Path, RunHealth]:
        return {d: f.health for d, f in self.facts.items()}

    def domain(self, run_dir: Path) -> str:
        return self.facts[run_dir].setup.domain

    def entry_setups(self, entry: str) -> list[RunSetup]:
        """The setups of ``entry``'s runs, valid or not."""
        return [self.facts[d].setup for d in sorted({r.run_dir for r in self.every if r.entry == entry})]

    def longer(self) -> dict[str, tuple[str, ...]]:
        """``trained_longer`` for the entries with runs (their rounds from their runs' configs)."""
        rounds = {}
        for entry in {r.entry for r in self.every}:
            counts = {s.rounds for s in self.entry_setups(entry)}
            if len(counts) == 1:
                rounds[entry] = counts.pop()
        return trained_longer(self.plan, rounds)


def read_report_data(runs: Path, report_dir: Path, log=print) -> ReportData:
    """Read everything the report needs from the suite output (or archive) ``runs``."""
    every = collect_results(runs, log)
    facts = read_facts(every)
    results = [r for r in every if facts[r.run_dir].health.valid]
    return ReportData(every, results, facts, read_plan(runs / "suite.yaml"), runs, report_dir)

"""Experiment suites: the paper's experiments as named overlays of base configs, run and resumed.

A suite file (``configs/suites/paper.yaml``) names

- ``evaluations``: the meta-test settings (split, evaluation seeds, sampled or greedy actions,
  corrections, tasks), each under a name, fixed for every entry that names it;
- ``entries``: each a base config, ``set`` overrides (the method), the training ``seeds`` and the
  ``evaluations`` to run on its final checkpoint (the first one becomes the run's ``eval`` section).

``gpl-dist suite run`` trains and evaluates every (entry, training seed) into
``OUT/<entry>/seed<k>/`` (an ordinary run dir), as many at once as keep this machine's cores
busy (``gpl_dist.app.suite.schedule``), or on a Ray cluster. Each run's state is read from
its files, so a killed suite loses at most the round in flight: a run with checkpoints resumes
(``train --resume``), a trained run is only evaluated, a finished one is skipped. A run whose entry
changed since it ran is refused, never mixed. ``OUT/<entry>/seed<k>/suite-run.json`` records the
code commit, the suite, the entry, the evaluations' files and the wall times.

The format, in one place (unknown keys fail in one line before anything runs)::

    evaluations:
      test: {split: test, seeds: [0, 1, 2, 3, 4], num_corrections: 5, greedy_actions: false, max_tasks: 0}
    entries:
      multiroom-gpl:
        base: ../multiroom.yaml          # relative to the suite file
        set: {model.variant: gpl}        # dotted config keys; no eval.* and no seed keys
        seeds: [0, 1, 2]
        evaluations: [test]
    reference: multiroom-gpl             # optional: the entry the report tests every other against
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from gpl_dist.app.suite.rl.plan import parse_rl_plan
from gpl_dist.atomic import write_atomic
from gpl_dist.config import (
    ConfigError,
    EvalConfig,
    RunConfig,
    bounded_repr,
    eval_config_from_dict,
    load_config,
    load_yaml_text,
)

#: Evaluation settings a suite file must give: fixed for every entry that names the evaluation.
_EVAL_REQUIRED = {"split", "seeds", "num_corrections", "greedy_actions"}


@dataclass(frozen=True)
class Evaluation:
    """One named set of meta-test settings (an ``EvalConfig``), identical for every entry that names it."""

    name: str
    config: EvalConfig

    def overrides(self) -> dict[str, str]:
        """This evaluation as ``eval.*`` config overrides."""
        return {f"eval.{k}": json.dumps(list(v)) if isinstance(v, tuple) else json.dumps(v) if isinstance(v, bool)
                else str(v) for k, v in dataclasses.asdict(self.config).items()}

    def settings(self) -> dict[str, Any]:
        """What a run's record keeps of it (``suite-run.json``), as JSON gives it back."""
        return json.loads(json.dumps({"name": self.name, **dataclasses.asdict(self.config)}))


#: Settings that older records lack, with the values they were made with.
EVAL_DEFAULTS = {"max_tasks": 0, "phrasings": "canonical"}


@dataclass(frozen=True)
class Entry:
    """One experiment: a base config with a method's overrides, its training seeds and evaluations."""

    name: str
    base: Path
    """The base config file."""
    overrides: tuple[tuple[str, str], ...]
    """Dotted config keys and YAML values applied over the base (the method)."""
    seeds: tuple[int, ...]
    """Training seeds (``seed`` of the run config): one run each."""
    evaluations: tuple[str, ...]
    """Names of the suite's evaluations; the first is each run's own ``eval`` section."""


@dataclass(frozen=True)
class Suite:
    """A parsed suite file."""

    path: Path
    evaluations: Mapping[str, Evaluation]
    entries: tuple[Entry, ...]
    rl: Any = None
    """The ``rl`` section (``gpl_dist.app.suite.rl.plan.RLPlan``): RL per test task against GPL and GPR; None when absent."""
    plugins: str = "own"
    """Whether its configs' domain modules are imported (``gpl_dist.config.PLUGIN_POLICIES``): ``none`` to read only."""
    reference: str | None = None
    """The entry the report holds every other against (Welch's test); None: the report names none."""

    def entry(self, name: str) -> Entry:
        for e in self.entries:
            if e.name == name:
                return e
        raise ConfigError(f"{self.path}: no entry '{name}' (entries: {', '.join(e.name for e in self.entries)})")


@dataclass(frozen=True)
class SuiteRun:
    """One (entry, training seed) of a suite, and where it lives."""

    entry: Entry
    seed: int
    run_dir: Path

    def config(self, suite: Suite, evaluation: str | None = None) -> RunConfig:
        """The run's resolved config: base, the entry's overrides, the seed, and an evaluation's
        settings as its ``eval`` section (its first evaluation unless ``evaluation`` is named).
        The suite's base configs are the user's own: their domain module is imported unless the
        suite was loaded to be read only (``Suite.plugins``)."""
        overrides = dict(self.entry.overrides)
        overrides["seed"] = str(self.seed)
        overrides.update(suite.evaluations[evaluation or self.entry.evaluations[0]].overrides())
        return load_config(self.entry.base, overrides, plugins=suite.plugins)


def _expect(ok: bool, where: str, message: str) -> None:
    if not ok:
        raise ConfigError(f"{where}: {message}")


def _keys(where: str, mapping: Any, allowed: set[str], required: set[str]) -> None:
    _expect(isinstance(mapping, dict), where, f"expected a mapping, got {type(mapping).__name__}")
    unknown = sorted(set(mapping) - allowed)
    _expect(not unknown, where, f"unknown key '{unknown[0] if unknown else ''}' (known: {', '.join(sorted(allowed))})")
    missing = sorted(required - set(mapping))
    _expect(not missing, where, f"missing key '{missing[0] if missing else ''}'")


def check_seeds(where: str, value: Any) -> tuple[int, ...]:
    """A list of distinct training or evaluation seeds >= 0; anything else fails in one line naming ``where``."""
    ok = isinstance(value, list) and value and all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in value)
    _expect(bool(ok), where, f"expected a non-empty list of seeds >= 0, got {bounded_repr(value)}")
    _expect(len(set(value)) == len(value), where, f"seeds repeat: {bounded_repr(value)}")
    return tuple(value)


def _evaluation(where: str, name: str, raw: Any) -> Evaluation:
    names = {f.name for f in dataclasses.fields(EvalConfig)}
    _keys(where, raw, names, _EVAL_REQUIRED)
    config = eval_config_from_dict(raw, where)
    check_seeds(f"{where}.seeds", list(config.seeds))
    return Evaluation(name, config)


def _entry(where: str, name: str, raw: Any, folder: Path, evaluations: Mapping[str, Evaluation]) -> Entry:
    _keys(where, raw, {"base", "set", "seeds", "evaluations"}, {"base", "seeds", "evaluations"})
    _expect(isinstance(raw["base"], str), f"{where}.base", "expected a config path")
    sets = raw.get("set") or {}
    _expect(isinstance(sets, dict), f"{where}.set", "expected a mapping of dotted config keys")
    for key in sets:
        _expect(isinstance(key, str) and key != "seed" and not key.startswith("eval."), f"{where}.set",
                f"'{key}' is the suite's to set (training seeds: seeds; evaluation: evaluations)")
    names = raw["evaluations"]
    _expect(isinstance(names, list) and bool(names) and all(isinstance(n, str) for n in names), f"{where}.evaluations",
            "expected a non-empty list of names")
    for n in names:
        _expect(n in evaluations, f"{where}.evaluations", f"unknown evaluation '{n}' (known: {', '.join(evaluations)})")
    overrides = tuple((k, v if isinstance(v, str) else json.dumps(v)) for k, v in sets.items())
    return Entry(name, (folder / raw["base"]).resolve(), overrides, check_seeds(f"{where}.seeds", raw["seeds"]), tuple(names))


#: Folders of a suite's output (and of its archive) that are not entries: an entry may not take their name.
RESERVED_NAMES = {"rl": "the RL comparison's results, OUT/rl/", "runs": "a report's archive of runs, REPORT/runs/"}


def load_suite(path: str | Path, plugins: str = "own") -> Suite:
    """Parse and check a suite file; every entry's config is built once, so a bad key or choice
    fails here, in one line, before anything runs. ``plugins="none"``: to read only (``suite
    status``), importing no domain module its configs name."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"suite file not found: {path}")
    try:
        raw = load_yaml_text(path.read_text(), path)
    except UnicodeDecodeError:
        raise ConfigError(f"{path} is not a text file") from None
    _keys(str(path), raw, {"evaluations", "entries", "rl", "reference"}, {"evaluations", "entries"})
    for section in ("evaluations", "entries"):
        _expect(isinstance(raw[section], dict) and bool(raw[section]), f"{path}: {section}",
                f"expected a mapping of names, got {type(raw[section]).__name__}")
    evaluations = {n: _evaluation(f"{path}: evaluations.{n}", n, v) for n, v in raw["evaluations"].items()}
    entries = []
    for name, spec in raw["entries"].items():
        _expect(isinstance(name, str) and name.replace("-", "").replace("_", "").isalnum(), f"{path}: entries",
                f"an entry's name is letters, digits, '-' and '_' (it names a folder), got {bounded_repr(name)}")
        _expect(name not in RESERVED_NAMES, f"{path}: entries.{name}",
                f"'{name}' is the name of the suite's own folder ({RESERVED_NAMES.get(name)}): rename the entry")
        entries.append(_entry(f"{path}: entries.{name}", name, spec, path.parent, evaluations))
    rl = None
    if "rl" in raw:

        rl = parse_rl_plan(f"{path}: rl", raw["rl"], tuple(e.name for e in entries))
    reference = raw.get("reference")
    names = [e.name for e in entries]
    _expect(reference is None or (isinstance(reference, str) and reference in names), f"{path}: reference",
            f"expected the name of one of its entries ({', '.join(names)[:200]}), got {bounded_repr(reference)}")
    suite = Suite(path, evaluations, tuple(entries), rl, plugins, reference)
    for e in suite.entries:
        for name in e.evaluations:  # every evaluation's split too, not only the run's own
            cfg = SuiteRun(e, e.seeds[0], Path(".")).config(suite, name)  # fails in one line on a bad key or choice
            _expect(not cfg.buffer.location, f"{path}: entries.{e.name}",
                    "buffer.location would put every run of the suite in one buffer: leave it unset (each run "
                    "keeps its buffer in its run dir)")
    return suite


def plan(suite: Suite, out: str | Path, only: tuple[str, ...] = (), seeds: tuple[int, ...] = ()) -> list[SuiteRun]:
    """The runs of ``suite`` under ``out``, in file order; ``only`` entries, ``seeds`` training seeds."""
    for name in only:
        suite.entry(name)
    runs = []
    for e in suite.entries:
        if only and e.name not in only:
            continue
        runs += [SuiteRun(e, s, Path(out).resolve() / e.name / f"seed{s}") for s in e.seeds if not seeds or s in seeds]
    return runs


def keep_copy(suite: Suite, out: str | Path) -> None:
    """Copy the suite file to ``OUT/suite.yaml``: the plan the report reads (its rows' seeds not
    run yet, the RL results that are jobs of its ``rl`` section), archived with the report."""
    Path(out).mkdir(parents=True, exist_ok=True)
    write_atomic(Path(out) / "suite.yaml", suite.path.read_text())

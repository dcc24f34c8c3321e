"""What the rest of a suite costs: the predicted wall time of every run and RL job not done yet.

Each prediction comes from what the suite's own finished work measured on this machine, never
from constants: a run's training from the ``train_seconds`` that finished runs recorded in their
``suite-run.json`` (per DAgger round, so a resumed run pays only its rounds left), each evaluation
from the seconds recorded for it, an RL job from the ``seconds`` in finished results. The source is
the same entry's finished runs when it has some, else its domain's (the same evaluation name, the
same RL method). A run whose training has neither has no estimate; an evaluation that no finished
run has made yet is left out of its run's estimate and named (``RunCost.unmeasured``); either way
the total says "at least".

The figures are as fast as the code that measured them: after a speed change, the first finished
runs of the new code are the ones to trust (``CostSource.commits`` names the commits behind each
figure).
"""

from __future__ import annotations

import json
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from statistics import fmean

from gpl_dist.app.suite.one_run import read_record
from gpl_dist.app.suite.spec import Suite, SuiteRun, plan
from learner.checkpoint import rounds_trained


@dataclass(frozen=True)
class RunCost:
    """The predicted cost of one suite run not done yet.

    Attributes:
        run: the run.
        train_seconds: its training left (0 when trained), or None without a source.
        eval_seconds: its evaluations left that have a source.
        source: where the figures come from: ``entry``, ``domain`` or ``none``.
        unmeasured: its evaluations left without a source (not in ``eval_seconds``).
    """

    run: SuiteRun
    train_seconds: float | None
    eval_seconds: float
    source: str
    unmeasured: tuple[str, ...] = ()

    @property
    def seconds(self) -> float | None:
        """Training and evaluations left; None without a training estimate (a lower bound when
        ``unmeasured``)."""
        return None if self.train_seconds is None else self.train_seconds + self.eval_seconds


@dataclass(frozen=True)
class SuiteCost:
    """Every run and RL job not done yet, with their predictions.

    Attributes:
        runs: one per (entry, seed) not done.
        rl_seconds: predicted seconds of the RL jobs not done (those with a source).
        rl_jobs: RL jobs not done; ``rl_unknown`` of them without a source.
        commits: the code commits whose measurements the predictions use.
    """

    runs: tuple[RunCost, ...]
    rl_seconds: float
    rl_jobs: int
    rl_unknown: int
    commits: tuple[str, ...]

    @property
    def total_seconds(self) -> float:
        """The sum of every prediction there is (a lower bound when some have none)."""
        return sum(r.seconds or 0.0 for r in self.runs) + self.rl_seconds

    def at_once_seconds(self, slots: int) -> float:
        """The wall time of the runs left when ``slots`` of them run at once (``suite run`` on this
        machine: ``gpl_dist.app.suite.cluster.local_plan``), longest first into the slot free first,
        each at the pace its prediction was measured at, then the RL jobs (a lower bound when some
        have no prediction)."""
        loads = [0.0] * max(1, slots)
        for seconds in sorted((r.seconds or 0.0 for r in self.runs), reverse=True):
            loads[loads.index(min(loads))] += seconds
        return max(loads) + self.rl_seconds

    @property
    def complete(self) -> bool:
        """Whether every run and job left has a prediction."""
        return all(r.seconds is not None and not r.unmeasured for r in self.runs) and self.rl_unknown == 0


def _domain(run: SuiteRun, suite: Suite) -> str:
    return run.config(suite).env.domain


def measured(suite: Suite, out: str | Path) -> tuple[dict, dict, set[str]]:
    """What the suite's trained runs under ``out`` measured: ``(per_round, per_eval, commits)`` with
    ``per_round[(key)]`` seconds of training per DAgger round and ``per_eval[(key, evaluation)]``
    seconds of an evaluation, each a list of observations under key ``("entry", name)`` and
    ``("domain", name)``."""

    per_round: dict[tuple[str, str], list[float]] = defaultdict(list)
    per_eval: dict[tuple[tuple[str, str], str], list[float]] = defaultdict(list)
    commits: set[str] = set()
    for run in plan(suite, out):
        record = read_record(run.run_dir) if run.run_dir.is_dir() else None
        if not record:
            continue
        keys = (("entry", run.entry.name), ("domain", _domain(run, suite)))
        rounds = run.config(suite).training.num_rounds
        if record.get("train_seconds") and rounds_trained(run.run_dir) >= rounds:
            commits.update(record.get("commits", []))
            for key in keys:
                per_round[key].append(float(record["train_seconds"]) / rounds)
        for name, ev in (record.get("evaluations") or {}).items():
            if isinstance(ev, dict) and ev.get("seconds"):
                if ev.get("commit"):
                    commits.add(str(ev["commit"]))
                for key in keys:
                    per_eval[(key, name)].append(float(ev["seconds"]))
    return per_round, per_eval, commits


def _lookup(table: dict, keys: tuple) -> tuple[float | None, str]:
    """The mean of the first key of ``keys`` that ``table`` has observations for, and that key's
    kind (``entry`` or ``domain``); ``(None, "none")`` without any."""
    for key in keys:
        if table.get(key):
            return fmean(table[key]), key[0] if isinstance(key[0], str) else key[0][0]
    return None, "none"


def predict(suite: Suite, out: str | Path, states: dict[Path, str], rl_left: tuple = (),
            measured_in: str | Path | None = None) -> SuiteCost:
    """The cost of every run of ``suite`` under ``out`` whose state (``states[run_dir]``, as
    ``gpl_dist.app.suite.one_run.run_state`` or ``running`` gives it) is not ``done``, and of the RL jobs
    ``rl_left`` (``gpl_dist.app.suite.rl.per_task.RLJob``s not done), from the work finished under ``measured_in``
    (``out`` itself by default; another suite's output predicts a new one from its costs)."""

    source_dir = out if measured_in is None else measured_in
    per_round, per_eval, commits = measured(suite, source_dir)
    order = {"entry": 0, "domain": 1, "none": 2}
    costs = []
    for run in plan(suite, out):
        state = states.get(run.run_dir, "new")
        if state == "done":
            continue
        keys = (("entry", run.entry.name), ("domain", _domain(run, suite)))
        train: float | None = 0.0
        sources = ["entry"]
        if state != "evaluate":
            rounds_left = run.config(suite).training.num_rounds - (rounds_trained(run.run_dir) if run.run_dir.is_dir() else 0)
            per, source = _lookup(per_round, keys)
            train = None if per is None else rounds_left * per
            sources.append(source)
        done = (read_record(run.run_dir) or {}).get("evaluations", {}) if run.run_dir.is_dir() else {}
        evals, unmeasured = 0.0, []
        for name in run.entry.evaluations:
            if name not in done:
                seconds, source = _lookup(per_eval, tuple((k, name) for k in keys))
                if seconds is None:
                    unmeasured.append(name)
                else:
                    evals += seconds
                    sources.append(source)
        costs.append(RunCost(run, train, evals, max(sources, key=order.__getitem__), tuple(unmeasured)))
    rl_seconds, rl_unknown = _rl_cost(source_dir, rl_left, commits)
    return SuiteCost(tuple(costs), rl_seconds, len(rl_left), rl_unknown, tuple(sorted(commits)))


def _rl_cost(out: str | Path, left: tuple, commits: set[str]) -> tuple[float, int]:
    """``(seconds, jobs without a source)`` of the RL jobs ``left``: each costs the mean ``seconds``
    of the finished results under ``out/rl`` of its method and domain (else of its domain)."""
    seconds: dict[tuple[str, ...], list[float]] = defaultdict(list)
    for path in sorted((Path(out) / "rl").glob("**/*.json")):
        try:
            data = json.loads(path.read_text())
            job, took = data["job"], float(data["seconds"])
        except (OSError, ValueError, KeyError, TypeError):
            continue  # not a job's result (or a damaged one): no measurement
        seconds[(str(job.get("method")), str(job.get("domain")))].append(took)
        seconds[(str(job.get("domain")),)].append(took)
        if data.get("commit"):
            commits.add(str(data["commit"]))
    total, unknown = 0.0, 0
    for job in left:
        found = seconds.get((job.method, job.domain)) or seconds.get((job.domain,))
        if found:
            total += fmean(found)
        else:
            unknown += 1
    return total, unknown


def hours(seconds: float | None) -> str:
    """``1.25 h``, ``12 min`` or ``45 s``; ``?`` for no estimate."""
    if seconds is None:
        return "?"
    if seconds >= 3600:
        return f"{seconds / 3600:.2f} h"
    if seconds >= 60:
        return f"{seconds / 60:.0f} min"
    return f"{seconds:.0f} s"

"""``gpl-dist suite status``: each run's state read from its files, and the wall time left.

The lines the command prints are built here (``suite_status``); the CLI prints them. Reading a
suite's runs imports no plug-in (the suite is loaded with ``plugins="none"``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from gpl_dist.app.suite.cost import hours, predict
from gpl_dist.app.suite.evidence import EvidenceError
from gpl_dist.app.suite.one_run import machine_numerics, run_state, trained_as_here
from gpl_dist.app.suite.schedule import local_plan
from gpl_dist.app.suite.spec import Suite, plan
from learner.cpu import machine_summary
from storage.lease import lease_holder


@dataclass(frozen=True)
class SuiteStatus:
    """What ``suite status`` found: the lines to print, and how many runs were refused (their
    evidence fails its checksums or its own consistency)."""

    lines: tuple[str, ...]
    refused: int

    @property
    def error(self) -> str | None:
        """The one error line when runs were refused; None when none was."""
        if not self.refused:
            return None
        return (f"{self.refused} run(s) refused: their evidence fails its checksums or its own consistency (named "
                "above); restore them again from the archive, or remove them to train them anew")


def suite_status(suite: Suite, suite_file: str, out: str, only: tuple[str, ...] = (), seeds: tuple[int, ...] = (),
                 costs_from: str | None = None) -> SuiteStatus:
    """Each run's state (done, evaluate, resume, new, or running with its driver), read from its
    files, and the predicted wall time of what is left (``gpl_dist.app.suite.cost``), as the lines
    ``gpl-dist suite status`` prints. ``suite_file`` names the suite in the lines."""
    runs = plan(suite, out, only, seeds)
    printed: list[str] = []
    states, lines = {}, []
    refused = 0
    numerics = {True: 0, False: 0, None: 0}  # trained runs: under this machine's fingerprint, another, none recorded
    here: set[str] = set()  # this machine's fingerprint for each run (its thread count), once per run
    for run in runs:
        holder = lease_holder(run.run_dir) if run.run_dir.is_dir() else None
        try:
            states[run.run_dir] = state = "running" if holder else run_state(run, suite)
        except EvidenceError as err:  # not counted: named in its line, and the status exits 2
            states[run.run_dir], state, refused = "refused", "refused", refused + 1
            lines.append((run, f"{state:8s} {run.entry.name} seed {run.seed}  ({' '.join(str(err).split())[:400]})"))
            continue
        held = f"; {holder.describe()}" if holder else ""
        mine = machine_numerics(run, suite)
        here.add(mine)
        if state in ("done", "evaluate"):
            same = trained_as_here(run, mine)
            numerics[same] += 1
            held += "; numerics as here" if same else ""
        lines.append((run, f"{state:8s} {run.entry.name} seed {run.seed}  ({run.run_dir}{held})"))
    rl_left: list = []
    if suite.rl is not None:
        from gpl_dist.app.suite.rl.jobs import NotTrainedYet, attempts_current, is_current, trained_fingerprint
        from gpl_dist.app.suite.rl.plan import attempts_jobs, rl_jobs

        rl_plan, jobs, points = suite.rl, rl_jobs(suite.rl), attempts_jobs(suite.rl)

        fingerprints: dict[str, str] = {}  # one checkpoint read per pretrained entry, not per job

        def start(job) -> str | None:  # the fingerprint of the policy rl-finetune starts from, as trained now
            if job.method != "rl-finetune":
                return None
            if job.pretrained not in fingerprints:
                try:
                    fingerprints[job.pretrained] = trained_fingerprint(out, job.pretrained)
                except NotTrainedYet:
                    fingerprints[job.pretrained] = "not trained"
            return fingerprints[job.pretrained]
        rl_left = [j for j in jobs if not is_current(out, j, rl_plan.settings(j.domain), start(j))]
    cost = predict(suite, out, states, tuple(rl_left), measured_in=costs_from)
    predicted = {c.run.run_dir: c for c in cost.runs}
    for run, line in lines:
        c = predicted.get(run.run_dir)
        unmeasured = f" + {', '.join(c.unmeasured)} (no evaluation of that name finished yet)" if c and c.unmeasured else ""
        printed.append(line if c is None else f"{line}  ~{hours(c.seconds)}{'' if c.source == 'entry' else f' ({c.source})'}"
                                               f"{unmeasured}")
    if suite.rl is not None:
        counts = (("RL jobs", len(jobs) - len(rl_left), len(jobs)),
                  ("GPL/GPR attempt sets", sum(attempts_current(out, j, rl_plan) for j in points), len(points)))
        for what, done, total in counts:  # made with other PPO settings or from another policy: not done
            printed.append(f"rl: {done} of {total} {what} done (gpl-dist suite rl {suite_file} --out {out})")
    todo = len(cost.runs)
    bound = "" if cost.complete else "at least "
    printed.append(f"predicted: {todo} run(s) and {cost.rl_jobs} RL job(s) left, {bound}{hours(cost.total_seconds)} "
          f"on this machine (RL {hours(cost.rl_seconds)}), from this suite's finished work"
          + (f" under {costs_from}" if costs_from else "")
          + (f" at commit(s) {', '.join(cost.commits)}" if cost.commits else " (none finished yet: no estimate)")
          + "".join(f"; {n} {what}" for n, what in (
              (sum(c.seconds is None for c in cost.runs) + cost.rl_unknown, "without an estimate"),
              (sum(bool(c.unmeasured) for c in cost.runs), "with evaluations not measured yet")) if n))
    if len(cost.runs) > 1:
        plan_here = local_plan(len(cost.runs), os.cpu_count() or 1)
        printed.append(f"at once ('suite run' here: {plan_here.runs_at_once} runs at a time, each with "
                       f"{plan_here.workers} rollout actor(s)): {bound}{hours(cost.at_once_seconds(plan_here.runs_at_once))}, "
                       "each run at the pace its figures were measured at (a figure from a run trained alone is faster "
                       "than the same run at once)")
    if here:
        printed.append(f"numerics: this machine's {', '.join(sorted(here))} ({machine_summary()}); of the "
                       f"{sum(numerics.values())} trained runs, {numerics[True]} were trained under it ('numerics as "
                       f"here': trained again here they give the same files, bit for bit), {numerics[False]} under "
                       f"another (trained again here they land elsewhere in their entry's seed spread), "
                       f"{numerics[None]} before fingerprints were recorded")
    return SuiteStatus(tuple(printed), refused)

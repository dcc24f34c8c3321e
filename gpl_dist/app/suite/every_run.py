"""``gpl-dist suite run``: every unfinished (entry, training seed) of a suite, one after another on
this machine or as Ray tasks on a cluster (``gpl_dist.app.suite.cluster``).
"""

from __future__ import annotations

from pathlib import Path

from gpl_dist.app.suite.one_run import execute, run_state
from gpl_dist.app.suite.provenance import code_commit
from gpl_dist.app.suite.spec import Suite, SuiteRun, keep_copy, plan
from gpl_dist.config import ConfigError


def run_suite(suite: Suite, out: str | Path, *, only: tuple[str, ...] = (), seeds: tuple[int, ...] = (),
              address: str | None = None, serial: bool = False, progress: bool = True, at_once: bool = False,
              log=print) -> list[tuple[SuiteRun, str]]:
    """Bring every run of the plan to ``done``; returns each run's state before.

    Without ``address``: one after another in this process, each with all of its config's
    workers (``serial``: one worker in this process, without Ray); with ``at_once``, as many at
    once as keep this machine's cores busy, on a local Ray cluster, through the cluster's path
    (``gpl_dist.app.suite.cluster.local_plan``; each run's files as if it ran alone). With ``address`` (a Ray
    cluster): every unfinished run at once, each a Ray task that drives its own rollout actors on
    the cluster (``OUT`` must then be on storage every node sees); Ray queues what does not fit.
    One after another, the first run that fails stops the suite (its error names it); on a
    cluster the other runs go on and the failures are reported together. Either way, running
    the suite again resumes.
    """
    commit = code_commit()  # this process's code, before anything can change the checkout
    runs = plan(suite, out, only, seeds)
    if not runs:
        raise ConfigError(f"{suite.path}: --only/--seeds select no run (entries: {', '.join(e.name for e in suite.entries)})")
    before = [(r, run_state(r, suite)) for r in runs]  # refuses a changed entry before anything runs
    keep_copy(suite, out)
    todo = [r for r, state in before if state != "done"]
    for run, state in before:
        if state == "done":
            log(f"[{run.entry.name} seed {run.seed}] done: skipped")
    if address is None and at_once and len(todo) > 1:
        from gpl_dist.app.suite.cluster import execute_on_cluster
        execute_on_cluster(todo, suite, None, commit, log=log)
    elif address is None:
        for run in todo:
            execute(run, suite, serial=serial, progress=progress, log=log, commit=commit)
    elif todo:
        from gpl_dist.app.suite.cluster import execute_on_cluster
        execute_on_cluster(todo, suite, address, commit, log=log)
    return before

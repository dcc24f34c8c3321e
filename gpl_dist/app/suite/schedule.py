"""How many runs at once keep one machine's cores busy, and how each is sized (no Ray here: ``suite
status`` predicts from it, ``gpl_dist.app.suite.cluster`` runs by it)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class LocalPlan:
    """Runs at once on one machine: ``runs_at_once`` of them, each with ``workers`` rollout actors
    (1 CPU each) and its driver and learner in its task (0 CPUs: a run's learner trains while its
    actors wait, so two runs' learners and actors take turns on the cores)."""

    runs_at_once: int
    workers: int


def local_plan(num_runs: int, cores: int) -> LocalPlan:
    """As many runs at once as cores (one learner thread each keeps a core busy while it trains),
    each with the cores left to it as rollout actors: every core busy in every phase."""
    at_once = max(1, min(num_runs, cores))
    return LocalPlan(at_once, max(1, cores // at_once))

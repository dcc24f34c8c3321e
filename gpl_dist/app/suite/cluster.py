"""A suite's runs as Ray tasks on a cluster: one of the two places the suite touches Ray (the other: ``rl.cluster``).

Each unfinished (entry, seed) becomes one task (1 CPU: its driver, with the learner unless that
is a GPU actor) that runs ``gpl_dist.app.suite.one_run.execute``; inside it the run's ``RayCollector`` finds
Ray already connected and starts its rollout actors (1 CPU each) on the same cluster. The records
name the commit the suite's driver runs, not what a worker node's checkout says. Runs are started only while the
cluster's CPUs hold every started run's task and actors: a run's task waiting for CPUs that other
runs' tasks hold, while those wait for their actors, would never finish. A task that fails is
reported and the others go on; running the suite again resumes it from its files.

On one machine (no ``--address``) the same path runs a local Ray cluster of the machine's cores:
``local_plan`` puts as many runs at once as there are cores, each with the cores left to it as
rollout actors, so that every core is busy whether a run collects or trains.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import ray

from gpl_dist.app.suite.one_run import execute
from gpl_dist.app.suite.schedule import LocalPlan, local_plan
from gpl_dist.app.suite.spec import Suite, SuiteRun
from gpl_dist.config import RunConfig, load_config
from gpl_dist.errors import SuiteError
from learner.driver import resume_config
from workers.ray_collector import init_ray


@ray.remote(num_cpus=1, max_retries=0)
def _execute_task(run: SuiteRun, suite: Suite, commit: str, workers: int | None = None) -> dict:
    # workers given: a local plan, on this machine's cores (its numerics are this machine's)
    return execute(run, suite, address="auto", progress=False, log=lambda line: print(line, flush=True), commit=commit,
                   workers=workers, on_this_machine=workers is not None)


def cpus_per_run(run: SuiteRun, suite: Suite, plan: LocalPlan | None = None) -> int:
    """CPUs one run holds on the cluster: its task (its driver and first learner), its further
    data-parallel learner processes, or its Ray Train learners beside the task, and its rollout
    actors; with a ``LocalPlan``, its actors only."""
    from learner.ray_train import group_cpus

    cfg = run.config(suite)
    if plan is not None:
        return plan.workers
    if cfg.training.engine == "ray-train":
        return 1 + group_cpus(cfg.training) + cfg.collection.num_workers
    return max(1, cfg.training.num_learners) + cfg.collection.num_workers


def execute_on_cluster(runs: list[SuiteRun], suite: Suite, address: str | None, commit: str, log=print,
                       cores: int | None = None) -> None:
    """Run ``runs`` on the Ray cluster at ``address``, as many at once as its CPUs hold; raise
    after all ended if any failed. Without ``address``: on a local Ray cluster of this machine's
    ``cores``, as ``local_plan`` sizes them (each run bit for bit what it is alone: its number of
    rollout actors changes how fast it collects, never what)."""
    plan, started = None, False
    if address is None:
        cores = cores or os.cpu_count() or 1
        plan = local_plan(len(runs), cores)
        started = init_ray(None, num_workers=cores)
        log(f"{len(runs)} run(s) on this machine's {cores} cores: {plan.runs_at_once} at once, each with "
            f"{plan.workers} rollout actor(s) and one learner thread")
    else:
        init_ray(address, num_workers=1)
    try:
        _run_all(runs, suite, commit, plan, log)
    finally:
        if started:
            ray.shutdown()


def _run_all(runs: list[SuiteRun], suite: Suite, commit: str, plan: LocalPlan | None, log) -> None:
    cluster_cpus = int(ray.cluster_resources().get("CPU", 0))
    too_big = [r for r in runs if cpus_per_run(r, suite, plan) > cluster_cpus]
    if too_big:
        r = too_big[0]
        raise SuiteError(f"{r.entry.name} seed {r.seed} needs {cpus_per_run(r, suite)} CPUs (a task, its learners and "
                         f"its rollout actors) and the cluster has {cluster_cpus}: lower collection.num_workers in the entry")
    queue, failed, free = list(runs), [], cluster_cpus
    pending: dict[ray.ObjectRef, SuiteRun] = {}
    task = _execute_task if plan is None else _execute_task.options(num_cpus=0)
    while queue or pending:
        while queue and cpus_per_run(queue[0], suite, plan) <= free:
            run = queue.pop(0)
            free -= cpus_per_run(run, suite, plan)
            pending[task.remote(run, suite, commit, None if plan is None else plan.workers)] = run
            log(f"[{run.entry.name} seed {run.seed}] started" + (" on the cluster" if plan is None else ""))
        done, _ = ray.wait(list(pending), num_returns=1)
        run = pending.pop(done[0])
        free += cpus_per_run(run, suite, plan)
        try:
            ray.get(done[0])
            log(f"[{run.entry.name} seed {run.seed}] done on the cluster")
        except ray.exceptions.RayError as err:
            failed.append(run)
            log(f"[{run.entry.name} seed {run.seed}] FAILED on the cluster: {str(err).strip().splitlines()[-1][:300]}")
    if failed:
        names = ", ".join(f"{r.entry.name}/seed{r.seed}" for r in failed)
        raise SuiteError(f"{len(failed)} suite run(s) failed on the cluster ({names}); run the suite again to resume them")


@ray.remote(num_cpus=0, max_retries=0)
def _train_task(cfg: RunConfig, run_dir: str, resume: bool) -> int:
    from learner.driver import run_training

    return len(run_training(cfg, run_dir, address="auto", resume=resume, progress=False).history)


def train_seeds(config: str | None, run_dir: str, seeds: tuple[int, ...], overrides: dict[str, str],
                resume: bool = False, log=print) -> None:
    """``gpl-dist train --seeds``: one run per training seed in ``run_dir/seed<k>``, from ``config``
    (the user's own file: its domain module is imported as asked) with ``overrides`` and the seed,
    or with ``resume`` each run's own latest checkpoint's config; trained by ``train_at_once``, then
    logs how to evaluate them."""
    runs = []
    for seed in seeds:
        seed_dir = str(Path(run_dir) / f"seed{seed}")
        runs.append((load_config(config, {**overrides, "seed": str(seed)}, plugins="own") if config
                     else resume_config(seed_dir, overrides), seed_dir))
    train_at_once(runs, resume=resume, log=log)
    log(f"trained {len(runs)} run(s) under {run_dir} (seed{seeds[0]} .. seed{seeds[-1]}); evaluate each with: "
        f"gpl-dist eval --run-dir {run_dir}/seed<k>")


def train_at_once(runs: list[tuple[RunConfig, str]], resume: bool = False, cores: int | None = None, log=print) -> None:
    """Train ``runs`` (config, run dir) on this machine as ``local_plan`` sizes them: as many at
    once as cores, each with the cores left to it as rollout actors (``gpl-dist train --seeds``).
    Each run is bit for bit what it is alone, resumes as one, and fails alone: the others go on,
    then the failures are raised together."""
    cores = cores or os.cpu_count() or 1
    plan = local_plan(len(runs), cores)
    started = init_ray(None, num_workers=cores)
    log(f"{len(runs)} run(s) on this machine's {cores} cores: {plan.runs_at_once} at once, each with {plan.workers} "
        "rollout actor(s) and one learner thread")
    try:
        queue = [(dataclasses.replace(cfg, collection=dataclasses.replace(cfg.collection, num_workers=plan.workers)), d)
                 for cfg, d in runs]
        pending: dict[ray.ObjectRef, str] = {}
        failed: list[str] = []
        while queue or pending:
            while queue and len(pending) < plan.runs_at_once:
                cfg, run_dir = queue.pop(0)
                pending[_train_task.remote(cfg, run_dir, resume)] = run_dir
                log(f"[{run_dir}] started")
            done, _ = ray.wait(list(pending), num_returns=1)
            run_dir = pending.pop(done[0])
            try:
                log(f"[{run_dir}] done: {ray.get(done[0])} round(s) trained")
            except ray.exceptions.RayError as err:
                failed.append(run_dir)
                log(f"[{run_dir}] FAILED: {str(err).strip().splitlines()[-1][:300]}")
        if failed:
            raise SuiteError(f"{len(failed)} run(s) failed ({', '.join(failed)}); "
                             "train them again with --resume to go on")
    finally:
        if started:
            ray.shutdown()

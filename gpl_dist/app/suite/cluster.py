"""A suite's runs as Ray tasks on a cluster: one of the two places the suite touches Ray (the other: ``rl_cluster``).

Each unfinished (entry, seed) becomes one task (1 CPU: its driver, with the learner unless that
is a GPU actor) that runs ``gpl_dist.app.suite.runs.execute``; inside it the run's ``RayCollector`` finds
Ray already connected and starts its rollout actors (1 CPU each) on the same cluster. The records
name the commit the suite's driver runs, not what a worker node's checkout says. Runs are started only while the
cluster's CPUs hold every started run's task and actors: a run's task waiting for CPUs that other
runs' tasks hold, while those wait for their actors, would never finish. A task that fails is
reported and the others go on; running the suite again resumes it from its files.
"""

from __future__ import annotations

import ray

from gpl_dist.app.suite.runs import execute
from gpl_dist.app.suite.spec import Suite, SuiteRun
from gpl_dist.errors import SuiteError
from workers.ray_collector import init_ray


@ray.remote(num_cpus=1, max_retries=0)
def _execute_task(run: SuiteRun, suite: Suite, commit: str) -> dict:
    return execute(run, suite, address="auto", progress=False, log=lambda line: print(line, flush=True), commit=commit)


def cpus_per_run(run: SuiteRun, suite: Suite) -> int:
    """CPUs one run holds on the cluster: its task (its driver and first learner), its further
    data-parallel learner processes, or its Ray Train learners beside the task, and its rollout actors."""
    from learner.ray_train import group_cpus

    cfg = run.config(suite)
    if cfg.training.engine == "ray-train":
        return 1 + group_cpus(cfg.training) + cfg.collection.num_workers
    return max(1, cfg.training.num_learners) + cfg.collection.num_workers


def execute_on_cluster(runs: list[SuiteRun], suite: Suite, address: str, commit: str, log=print) -> None:
    """Run ``runs`` on the Ray cluster at ``address``, as many at once as its CPUs hold; raise
    after all ended if any failed."""
    init_ray(address, num_workers=1)
    cluster_cpus = int(ray.cluster_resources().get("CPU", 0))
    too_big = [r for r in runs if cpus_per_run(r, suite) > cluster_cpus]
    if too_big:
        r = too_big[0]
        raise SuiteError(f"{r.entry.name} seed {r.seed} needs {cpus_per_run(r, suite)} CPUs (a task, its learners and "
                         f"its rollout actors) and the cluster has {cluster_cpus}: lower collection.num_workers in the entry")
    queue, failed, free = list(runs), [], cluster_cpus
    pending: dict[ray.ObjectRef, SuiteRun] = {}
    while queue or pending:
        while queue and cpus_per_run(queue[0], suite) <= free:
            run = queue.pop(0)
            free -= cpus_per_run(run, suite)
            pending[_execute_task.remote(run, suite, commit)] = run
            log(f"[{run.entry.name} seed {run.seed}] started on the cluster")
        done, _ = ray.wait(list(pending), num_returns=1)
        run = pending.pop(done[0])
        free += cpus_per_run(run, suite)
        try:
            ray.get(done[0])
            log(f"[{run.entry.name} seed {run.seed}] done on the cluster")
        except ray.exceptions.RayError as err:
            failed.append(run)
            log(f"[{run.entry.name} seed {run.seed}] FAILED on the cluster: {str(err).strip().splitlines()[-1][:300]}")
    if failed:
        names = ", ".join(f"{r.entry.name}/seed{r.seed}" for r in failed)
        raise SuiteError(f"{len(failed)} suite run(s) failed on the cluster ({names}); run the suite again to resume them")

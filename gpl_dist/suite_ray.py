"""A suite's runs as Ray tasks on a cluster: the one place the suite runner touches Ray.

Each unfinished (entry, seed) becomes one task (1 CPU: its driver and learner) that runs
``gpl_dist.suite.execute``; inside it the run's ``RayCollector`` finds Ray already connected and
starts its rollout actors on the same cluster. A task that fails is reported and the others go
on; running the suite again resumes it from its files.
"""

from __future__ import annotations

import ray

from gpl_dist.errors import SuiteError
from gpl_dist.suite import Suite, SuiteRun, execute
from workers.ray_pool import init_ray


@ray.remote(num_cpus=1, max_retries=0)
def _execute_task(run: SuiteRun, suite: Suite) -> dict:
    return execute(run, suite, address="auto", progress=False, log=lambda line: print(line, flush=True))


def execute_on_cluster(runs: list[SuiteRun], suite: Suite, address: str, log=print) -> None:
    """Run ``runs`` at once on the Ray cluster at ``address``; raise after all ended if any failed."""
    init_ray(address, num_workers=1)
    pending = {_execute_task.remote(r, suite): r for r in runs}
    failed = []
    while pending:
        done, _ = ray.wait(list(pending), num_returns=1)
        run = pending.pop(done[0])
        try:
            ray.get(done[0])
            log(f"[{run.entry.name} seed {run.seed}] done on the cluster")
        except ray.exceptions.RayError as err:
            failed.append(run)
            log(f"[{run.entry.name} seed {run.seed}] FAILED on the cluster: {str(err).splitlines()[-1][:300]}")
    if failed:
        names = ", ".join(f"{r.entry.name}/seed{r.seed}" for r in failed)
        raise SuiteError(f"{len(failed)} suite run(s) failed on the cluster ({names}); run the suite again to resume them")

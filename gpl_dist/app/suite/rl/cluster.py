"""The suite's RL jobs as Ray tasks (``gpl-dist suite rl --address``): the other place the suite
touches Ray. Each job is one task; a trained policy's weights go to the object store once.
"""

from __future__ import annotations

import ray

from gpl_dist.app.suite.rl.per_task import run_rl_job
from gpl_dist.errors import SuiteError
from workers.ray_collector import init_ray


@ray.remote(num_cpus=1, max_retries=0)
def _rl_task(job, settings, weights, model):

    return run_rl_job(job, settings, weights, model)


def run_rl_on_ray(jobs: list, settings: dict, pretrained: dict, address: str | None, on_done, log=print) -> None:
    """Every RL job as a Ray task of 1 CPU (local Ray unless ``address``); ``on_done(job, curve)``
    as each finishes. ``settings``: domain -> ``learner.ppo.PPOSettings``. ``pretrained``: domain ->
    ``gpl_dist.app.suite.rl.jobs.Pretrained`` for ``rl-finetune`` (its weights put in the object store
    once). Raises after all ended if any failed."""
    owned = init_ray(address, num_workers=1)
    try:
        shared = {d: (ray.put(dict(p.weights)), p.model) for d, p in pretrained.items()}
        pending = {}
        for job in jobs:
            w, arch = shared[job.domain] if job.method == "rl-finetune" else (None, None)
            pending[_rl_task.remote(job, settings[job.domain], w, arch)] = job
        failed = []
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            job = pending.pop(done[0])
            try:
                on_done(job, ray.get(done[0]))
            except ray.exceptions.RayError as err:
                failed.append(job.key)
                log(f"[rl] {job.key} FAILED: {str(err).strip().splitlines()[-1][:300]}")
        if failed:
            raise SuiteError(f"{len(failed)} RL job(s) failed ({', '.join(failed[:5])}); run again to resume them")
    finally:
        if owned:
            ray.shutdown()

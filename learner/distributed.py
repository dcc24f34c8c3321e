"""Ray wiring: rollout actors, dynamic hand-out of work units, weight broadcast.

This is the only module that imports Ray. Per round the driver puts the weights into the object
store once (``ray.put``, with a version number); actors fetch them only when the version changes.
Units are handed out one at a time to whichever actor is idle (``ray.wait``), so a slow actor does
not stall the round. An actor that dies is restarted by Ray (``max_restarts=-1``) and its unit is
handed out again; because a shard's name is a function of (round, unit) the retry replaces any
partial try, and only the driver commits the round's manifest.
"""

from __future__ import annotations

import logging
import os
from collections import deque
from typing import Callable, Sequence

import ray
from ray.exceptions import RayActorError, RayTaskError

from gpl_dist.records import WorkUnit
from learner.collectors import UnitResult, make_worker, run_unit
from workers.rollout import RolloutSettings

log = logging.getLogger(__name__)


class RoundFailed(RuntimeError):
    """A work unit failed more often than ``max_unit_retries``."""


@ray.remote(num_cpus=1, max_restarts=-1, max_task_retries=0)
class RolloutActor:
    """A ``RolloutWorker`` inside a Ray actor."""

    def __init__(self, domain_name: str, settings: RolloutSettings, buffer_root: str, run_id: str, worker_id: str):
        # One torch thread per actor: actors already use one core each.
        self.worker = make_worker(domain_name, settings, buffer_root, run_id, worker_id, num_threads=1)

    def run_unit(self, unit: WorkUnit, weights_box: list) -> UnitResult:
        if self.worker.policy_version != unit.policy_version:
            # The ref sits inside a list so Ray does not resolve it for every call.
            self.worker.set_weights(ray.get(weights_box[0]), unit.policy_version)
        return run_unit(self.worker, unit)

    def node_id(self) -> str:
        return ray.get_runtime_context().get_node_id()

    def pid(self) -> int:
        return os.getpid()


def init_ray(address: str | None, num_workers: int, temp_dir: str | None = None) -> bool:
    """Start or join Ray; returns True when this call started a local cluster (and owns it)."""
    if ray.is_initialized():
        return False
    if address:
        ray.init(address=address, log_to_driver=True)
        return False
    ray.init(
        num_cpus=max(num_workers, os.cpu_count() or 1),
        include_dashboard=False,
        # Local clusters listen on loopback only.
        _node_ip_address="127.0.0.1",
        _temp_dir=temp_dir,
        log_to_driver=True,
    )
    return True


class RayCollector:
    """Runs ``num_workers`` rollout actors and hands each round's units out dynamically."""

    def __init__(self, domain_name: str, settings: RolloutSettings, buffer_root: str, run_id: str,
                 num_workers: int, address: str | None = None, max_unit_retries: int = 3):
        self._owns_ray = init_ray(address, num_workers)
        self.max_unit_retries = max_unit_retries
        self.actors = [
            RolloutActor.options(name=None).remote(domain_name, settings, buffer_root, run_id, f"actor-{i}")
            for i in range(num_workers)
        ]
        self.unit_tries: dict[tuple[int, int], int] = {}

    def collect_round(self, units: Sequence[WorkUnit], weights: dict, policy_version: int,
                      on_result: Callable[[UnitResult], None] | None = None) -> list[UnitResult]:
        weights_ref = ray.put(weights)
        queue = deque(units)
        idle = list(self.actors)
        inflight: dict = {}
        results: dict[tuple[int, int], UnitResult] = {}
        while queue or inflight:
            while queue and idle:
                actor, unit = idle.pop(), queue.popleft()
                inflight[actor.run_unit.remote(unit, [weights_ref])] = (actor, unit)
            done, _ = ray.wait(list(inflight), num_returns=1)
            for ref in done:
                actor, unit = inflight.pop(ref)
                key = (unit.round_index, unit.unit_index)
                try:
                    result = ray.get(ref)
                except (RayActorError, RayTaskError) as err:
                    self.unit_tries[key] = self.unit_tries.get(key, 0) + 1
                    if self.unit_tries[key] > self.max_unit_retries:
                        raise RoundFailed(f"unit {key} failed {self.unit_tries[key]} times; last error: {err}") from err
                    log.warning("unit %s failed (%s); handing it out again", key, type(err).__name__)
                    queue.appendleft(unit)
                    idle.append(actor)  # a dead actor is restarted by Ray behind the same handle
                    continue
                results[key] = result
                idle.append(actor)
                if on_result is not None:
                    on_result(result)
        return [results[(u.round_index, u.unit_index)] for u in units]

    def close(self) -> None:
        for actor in self.actors:
            ray.kill(actor, no_restart=True)
        self.actors = []
        if self._owns_ray:
            ray.shutdown()

"""Collectors hand a round's work units to rollout workers and gather the shard records.

``SerialCollector`` runs one ``RolloutWorker`` in this process (``--serial``, tests, debugging);
``workers.ray_collector.RayCollector`` runs the same worker class as Ray actors. Both return shard
records only; the data itself is in the buffer.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Sequence

from gpl_dist.domains import get_domain, load_domain_module
from gpl_dist.records import WorkUnit
from workers.worker import RolloutSettings, RolloutWorker


@dataclass(frozen=True)
class UnitResult:
    """What a worker sends back for a unit: the shard record and the tasks that failed.

    Attributes:
        shard: the buffer's record of the written shard (paths, row counts, checksums).
        failed_tasks: ``(task_id, message)`` of tasks dropped because their env, expert or
            correction oracle raised.
        worker_id: who collected it.
        num_tasks: tasks in the unit.
    """

    shard: Any
    failed_tasks: tuple[tuple[int, str], ...]
    worker_id: str
    num_tasks: int


def run_unit(worker: RolloutWorker, unit: WorkUnit) -> UnitResult:
    """Collect ``unit`` with ``worker``; the shard record and the tasks that failed."""
    shard = worker.run_unit(unit)
    return UnitResult(shard, tuple((f.task_id, str(f)) for f in worker.failures), worker.worker_id, len(unit.task_ids))


def make_worker(domain_name: str, settings: RolloutSettings, buffer_root: str, run_id: str,
                worker_id: str, num_threads: int = 0) -> RolloutWorker:
    """A rollout worker that writes its shards into the buffer at ``buffer_root``; a plug-in domain's
    module (``env.domain_module``) is imported here first, in whichever process the worker runs."""
    from storage import ShardWriter

    if settings.env.domain_module:
        load_domain_module(settings.env.domain_module)
    return RolloutWorker(get_domain(domain_name), settings, ShardWriter(buffer_root, run_id), worker_id, num_threads)


class SerialCollector:
    """Collects every unit in this process, one after the other. It has no unit timeout (the
    ``collection.unit_timeout_*`` settings are the Ray actors'): a unit that hangs here hangs the
    driver itself, which Ctrl-C or SIGTERM ends (``train --resume`` goes on)."""

    def __init__(self, domain_name: str, settings: RolloutSettings, buffer_root: str, run_id: str):
        self.worker = make_worker(domain_name, settings, buffer_root, run_id, "serial-0")

    def collect_round(self, units: Sequence[WorkUnit], weights: dict, policy_version: int,
                      on_result: Callable[[UnitResult], None] | None = None) -> list[UnitResult]:
        self.worker.set_weights(weights, policy_version)
        results = []
        for unit in units:
            result = run_unit(self.worker, unit)
            if on_result is not None:
                on_result(result)
            results.append(result)
        return results

    def close(self) -> None:
        pass

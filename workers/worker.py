"""Rollout worker: steps many tasks in lockstep, labels every state, writes one shard per unit.

For each task of a unit (Algorithm 1's inner loops): attempt 0 is conditioned on the instruction
alone; after each attempt the correction oracle (beside the env, in this process) gives a
correction, and the next attempt is conditioned on every earlier (trajectory, correction) pair,
up to ``num_corrections`` corrections. A task stops once an attempt solves it. All tasks of the unit
advance together, so each environment step costs one batched policy forward for the whole unit;
the expert labels each visited state in-process. The unit's attempts go to the worker's own shard
through the buffer writer, and only the shard's record is returned: bulk data never travels back
through the caller.

The attempts themselves are stepped by the one rollout loop, ``workers.rollout.Rollout``. The same
class runs in one process (``--serial``, tests; ``workers.collector``) and inside a Ray actor
(``workers.ray_collector``); nothing here imports Ray.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from threadpoolctl import threadpool_limits

from gpl_dist.allocator import keep_freed_memory
from gpl_dist.config import CollectionConfig, EnvConfig, ModelConfig
from gpl_dist.corrections import make_corrector
from gpl_dist.faults import fault_point
from gpl_dist.models.build import PolicyNetwork, build_model_from_config, load_numpy_state
from gpl_dist.models.gpl import FULL_INFORMATION_VARIANTS
from gpl_dist.records import Attempt, WorkUnit
from gpl_dist.roles import DomainSpec
from workers.rollout import Rollout, TaskFailure


@dataclass(frozen=True)
class RolloutSettings:
    """A worker's own config sections, as the run's config holds them, and its mode.

    Attributes:
        env: the domain, the correction oracle's kind and the expert's (``EnvConfig``).
        collection: corrections per task and how actions are chosen (``CollectionConfig``).
        model: the architecture, built with ``build_model_from_config`` as the learner builds it,
            and how earlier attempts are subsampled (``ModelConfig``).
        label_states: query the expert for every state (False at meta-test time).
    """

    env: EnvConfig = field(default_factory=EnvConfig)
    collection: CollectionConfig = field(default_factory=CollectionConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    label_states: bool = True

    @classmethod
    def of_run(cls, cfg: Any) -> "RolloutSettings":
        """The worker's three sections of a ``RunConfig`` (the worker never holds the whole config)."""
        return cls(env=cfg.env, collection=cfg.collection, model=cfg.model)


class RolloutWorker:
    """Collects work units with the current weights; implements ``gpl_dist.roles.RolloutWorker``.

    Args:
        domain: the domain's spec.
        settings: the worker's config sections.
        writer: a ``storage.ShardWriter`` (anything with ``write_unit``); None for ``collect`` only.
        worker_id: name recorded with every shard.
        num_threads: torch intra-op threads for policy inference (0 leaves torch's default).

    While it collects, the process's BLAS (numpy's OpenBLAS: the learned relocation expert's
    batched forward) runs on one thread, as in a 1-CPU Ray actor, whose ``OMP_NUM_THREADS`` Ray sets to 1: in the serial
    collector, which runs the worker in the driver, a second BLAS thread of a forward this small
    stalls beside any other busy process. ``benchmarks/serial_blas.py`` (32 tasks): one thread
    collects 2.33x as fast as two beside one busy process, 0.91x as fast on an idle machine; the
    labels are the same bits either way.
    """

    def __init__(self, domain: DomainSpec, settings: RolloutSettings, writer: Any = None,
                 worker_id: str = "worker-0", num_threads: int = 0):
        if num_threads:
            torch.set_num_threads(num_threads)
        keep_freed_memory()  # the batched forward's temporaries would page-fault afresh every step
        self.domain = domain
        self.settings = settings
        self.writer = writer
        self.worker_id = worker_id
        self.model: PolicyNetwork = build_model_from_config(domain, settings.model)
        self.model.eval()
        self.policy_version = -1
        expert = domain.experts[settings.env.expert or next(iter(domain.experts))]() if settings.label_states else None
        self.rollout = Rollout(domain, self.model, make_corrector(domain.name, settings.env.correction_kind), expert,
                               greedy=settings.collection.greedy_actions,
                               end_aligned=settings.model.trajectory_ends_at_last_state,
                               full_information=settings.model.variant in FULL_INFORMATION_VARIANTS,
                               phrasings="train" if settings.model.paraphrases else "canonical")
        self.failures: list[TaskFailure] = []

    def set_weights(self, weights: dict[str, np.ndarray], policy_version: int) -> None:
        load_numpy_state(self.model, weights)
        self.model.eval()
        self.policy_version = policy_version

    def run_unit(self, unit: WorkUnit) -> Any:
        """Collect ``unit`` and write its shard; returns the shard record."""
        if unit.policy_version != self.policy_version:
            raise RuntimeError(f"worker {self.worker_id} holds weights v{self.policy_version}, unit wants v{unit.policy_version}")
        attempts = self.collect(unit.task_ids, unit.split, unit.seed, unit.round_index)
        fault_point("worker.unit_collected", round=unit.round_index, unit=unit.unit_index)
        return self.writer.write_unit(unit, attempts, self.worker_id)

    def collect(self, task_ids: Sequence[int], split: str, seed: int, round_index: int = 0) -> list[Attempt]:
        """All attempts of ``task_ids``, in (task order, attempt index) order."""
        with threadpool_limits(limits=1, user_api="blas"):  # as Ray's actor has it (class doc); restored after
            result = self.rollout.run(task_ids, self.settings.collection.num_corrections, seed, round_index=round_index,
                                      split=split, policy_version=self.policy_version)
        self.failures = list(result.failures)
        return list(result.attempts)

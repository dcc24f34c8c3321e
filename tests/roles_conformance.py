"""Each implementation, returned as the role it claims to be: type-checked by mypy in ``.ci/run``.

An implementation that drifts from its Protocol in ``gpl_dist/roles.py`` (a renamed method, a
changed signature) fails the type check here; ``tests/test_roles.py`` calls these functions with
real objects, so the runtime view (``isinstance``) is checked too. Nothing here runs in production.
"""

from __future__ import annotations

from gpl_dist import roles
from gpl_dist.corrections.multiroom import MultiRoomCorrector
from gpl_dist.corrections.relocation import RelocationCorrector
from gpl_dist.envs.multiroom import MultiRoomEnv
from gpl_dist.envs.relocation import RelocationEnv
from gpl_dist.experts.multiroom import MultiRoomExpert
from gpl_dist.experts.relocation import RelocationExpert
from gpl_dist.experts.relocation_learned import LearnedRelocationExpert
from gpl_dist.models.gpl import GPLPolicy
from gpl_dist.models.mivoa import MIVOAPolicy
from learner.parallel import DataParallelLearner
from learner.ray_train import RayTrainLearner
from learner.remote import RemoteLearner
from learner.trainer import Learner
from storage.reader import BufferReader
from storage.writer import ShardWriter
from workers.collector import SerialCollector
from workers.ray_collector import RayCollector
from workers.worker import RolloutWorker


def task_envs(a: MultiRoomEnv, b: RelocationEnv) -> tuple[roles.TaskEnv, roles.TaskEnv]:
    return a, b


def experts(a: MultiRoomExpert, b: RelocationExpert, c: LearnedRelocationExpert) -> tuple[roles.Expert, ...]:
    return a, b, c


def batch_experts(c: LearnedRelocationExpert) -> tuple[roles.BatchExpert, ...]:
    return (c,)


def oracles(a: MultiRoomCorrector, b: RelocationCorrector) -> tuple[roles.CorrectionOracle, ...]:
    return a, b


def policy(p: GPLPolicy) -> roles.Policy:
    return p


def mivoa_policy(p: MIVOAPolicy) -> roles.Policy:
    return p


def rollout_worker(w: RolloutWorker) -> roles.RolloutWorker:
    return w


def collectors(a: SerialCollector, b: RayCollector) -> tuple[roles.Collector, roles.Collector]:
    return a, b


def buffer(w: ShardWriter, r: BufferReader) -> tuple[roles.BufferWriter, roles.BufferReader]:
    return w, r


def learner(x: Learner) -> roles.Learner:
    return x


def other_learners(a: DataParallelLearner, b: RemoteLearner, c: RayTrainLearner) -> tuple[roles.Learner, ...]:
    return a, b, c

"""The roles of ``gpl_dist/roles.py`` are what the code implements (mypy checks the signatures
through ``tests/roles_conformance.py``; this checks real objects at run time)."""

from __future__ import annotations

import roles_conformance as rc

from gpl_dist import roles
from gpl_dist.corrections import make_corrector
from gpl_dist.domains import get_domain
from gpl_dist.experts import make_expert
from gpl_dist.experts.relocation_learned import LearnedRelocationExpert
from gpl_dist.models.build import build_model
from learner.trainer import Learner
from storage import BufferReader, ShardWriter
from workers.collector import SerialCollector
from workers.worker import RolloutSettings, RolloutWorker


def test_every_implementation_is_its_role(tmp_path):
    from gpl_dist.config import TrainingConfig

    mr, rl = get_domain("multiroom"), get_domain("relocation")
    envs = rc.task_envs(mr.make_env(0), rl.make_env(0))
    assert all(isinstance(e, roles.TaskEnv) for e in envs)
    experts = rc.experts(make_expert(envs[0]), make_expert(envs[1]), make_expert(envs[1], "learned"))
    assert all(isinstance(x, roles.Expert) for x in experts)
    assert all(isinstance(x, roles.BatchExpert) for x in rc.batch_experts(LearnedRelocationExpert()))
    assert not any(isinstance(x, roles.BatchExpert) for x in experts[:2])  # the planners label one env at a time
    oracles = rc.oracles(make_corrector("multiroom"), make_corrector("relocation"))
    assert all(isinstance(o, roles.CorrectionOracle) for o in oracles)
    model = build_model(mr, seed=0)
    assert isinstance(rc.policy(model), roles.Policy)
    mivoa = build_model(mr, "mivoa", seed=0)
    assert isinstance(rc.mivoa_policy(mivoa), roles.Policy)  # type: ignore[arg-type]
    assert isinstance(rc.rollout_worker(RolloutWorker(mr, RolloutSettings(), worker_id="t")), roles.RolloutWorker)
    serial = SerialCollector("multiroom", RolloutSettings(), str(tmp_path / "b"), "r")
    assert isinstance(serial, roles.Collector)
    writer, reader = rc.buffer(ShardWriter(tmp_path / "b", "r"), BufferReader(tmp_path / "b"))
    assert isinstance(writer, roles.BufferWriter) and isinstance(reader, roles.BufferReader)
    assert isinstance(rc.learner(Learner(model, TrainingConfig(), seed=0)), roles.Learner)

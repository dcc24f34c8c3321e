"""Rollout worker: steps many tasks in lockstep, labels every state, writes one shard per unit.

For each task of a unit (Algorithm 1's inner loops): attempt 0 is conditioned on the instruction
alone; after each attempt the correction oracle (beside the env, in this process) gives a
correction, and the next attempt is conditioned on every earlier (trajectory, correction) pair,
up to ``num_corrections`` corrections. A task stops once an attempt solves it. All tasks of the unit
advance together, so each environment step costs one batched policy forward for the whole unit;
the expert labels each visited state in-process. The unit's attempts go to the worker's own shard
through the buffer writer, and only the shard's record is returned: bulk data never travels back
through the caller.

The same class runs in one process (``--serial``, tests) and inside a Ray actor
(``learner.distributed``); nothing here imports Ray.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from gpl_dist.allocator import keep_freed_memory
from gpl_dist.corrections import make_corrector
from gpl_dist.experts import make_expert
from gpl_dist.metrics import completion_by_corrections
from gpl_dist.models.gpl import Conditioning, GPLPolicy, build_model, load_numpy_state
from gpl_dist.records import Attempt, WorkUnit
from gpl_dist.roles import DomainSpec, trajectory_times
from gpl_dist.seeding import derive_rng, derive_seed

log = logging.getLogger(__name__)

#: Test hook, inert unless set: ``pause-mid-unit:ROUND:UNIT:DIR`` makes the first try of that unit
#: (in any process: driver, actor) stop after collecting and before writing its shard, publish its
#: pid as ``DIR/round-ROUND-unit-UNIT.pid`` and sleep until killed. The file is created atomically
#: and only once, so a retry of the unit (a restarted actor, a resumed run) goes through. Used by
#: ``tests/test_fault_tolerance.py`` to SIGKILL an actor or a driver in the middle of a round.
TEST_HOOK_ENV = "GPL_DIST_WORKER_TEST_HOOK"


def _test_hook(unit: WorkUnit) -> None:
    hook = os.environ.get(TEST_HOOK_ENV, "")
    if not hook:
        return
    name, r, u, signal_dir = hook.split(":", 3)
    if name != "pause-mid-unit" or (int(r), int(u)) != (unit.round_index, unit.unit_index):
        return
    path = os.path.join(signal_dir, f"round-{r}-unit-{u}.pid")
    tmp = f"{path}.tmp-{os.getpid()}"
    with open(tmp, "w") as fh:
        fh.write(str(os.getpid()))
    try:
        os.link(tmp, path)  # atomic, and fails when a first try already paused here
    except FileExistsError:
        return
    finally:
        os.unlink(tmp)
    while True:  # wait to be killed
        time.sleep(0.05)


@dataclass(frozen=True)
class RolloutSettings:
    """What a worker needs to know, resolved from the run config's sections.

    Attributes:
        num_corrections: corrections per task; at most ``num_corrections + 1`` attempts.
        greedy_actions: act with the most likely action instead of sampling.
        correction_kind: correction oracle variant.
        variant: model variant (decides the instruction text and whether corrections are used).
        embedding_dim: word-embedding size of the model.
        policy_batchnorm: whether the model's policy MLP has BatchNorm layers.
        label_states: query the expert for every state (False at meta-test time).
        expert: which of the domain's experts labels the states (``scripted`` or ``learned``).
        trajectory_ends_at_last_state: how earlier attempts are subsampled for the correction
            module (``gpl_dist.roles.trajectory_times``).
    """

    num_corrections: int = 5
    greedy_actions: bool = False
    correction_kind: str = "default"
    variant: str = "gpl"
    embedding_dim: int = 16
    policy_batchnorm: bool = False
    label_states: bool = True
    expert: str = "scripted"
    trajectory_ends_at_last_state: bool = False

    @classmethod
    def from_config(cls, cfg: Any, **overrides: Any) -> "RolloutSettings":
        """The worker's slice of a ``RunConfig``; ``overrides`` replace fields (meta-test, analyses).

        The one place that maps config fields to worker settings, so collection, evaluation and
        analyses of a run cannot disagree on how its policy was conditioned.
        """
        settings = cls(num_corrections=cfg.collection.num_corrections, greedy_actions=cfg.collection.greedy_actions,
                       correction_kind=cfg.env.correction_kind, variant=cfg.model.variant,
                       embedding_dim=cfg.model.embedding_dim, policy_batchnorm=cfg.model.policy_batchnorm,
                       expert=cfg.env.expert,
                       trajectory_ends_at_last_state=cfg.model.trajectory_ends_at_last_state)
        return replace(settings, **overrides)


class TaskFailure(RuntimeError):
    """An env, expert or correction oracle raised for one task; carries the task id.

    The worker drops the task from the unit (its attempts so far are kept only if complete) and
    goes on with the others; ``RolloutWorker.failures`` lists what failed in the last unit.
    """

    def __init__(self, task_id: int, stage: str, cause: BaseException):
        super().__init__(f"task {task_id}: {stage} failed: {type(cause).__name__}: {cause}")
        self.task_id = task_id
        self.stage = stage


def sample_actions(logits: torch.Tensor, rng: np.random.Generator, greedy: bool) -> np.ndarray:
    """int64 ``(B,)`` actions: argmax, or one draw per row from softmax(logits) with ``rng``.

    Sampling is Gumbel-max (argmax of logits plus Gumbel noise), which draws exactly from the
    softmax without computing it: three numpy calls per step for the whole batch.
    """
    scores = logits.numpy().astype(np.float64)
    if not greedy:
        scores += rng.gumbel(size=scores.shape)
    return scores.argmax(axis=1).astype(np.int64)


class RolloutWorker:
    """Collects work units with the current weights; implements ``gpl_dist.roles.RolloutWorker``.

    Args:
        domain: the domain's spec.
        settings: rollout settings.
        writer: a ``storage.ShardWriter`` (anything with ``write_unit``); None for ``collect`` only.
        worker_id: name recorded with every shard.
        num_threads: torch intra-op threads for policy inference (0 leaves torch's default).
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
        self.model: GPLPolicy = build_model(domain, settings.variant, settings.embedding_dim,
                                            policy_batchnorm=settings.policy_batchnorm)
        self.model.eval()
        self.policy_version = -1
        self._corrector = make_corrector(domain.name, settings.correction_kind)
        self._expert = None
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
        _test_hook(unit)
        return self.writer.write_unit(unit, attempts, self.worker_id)

    # -- collection ---------------------------------------------------------------------------

    def _fail(self, task_id: int, stage: str, err: BaseException, failed: np.ndarray, i: int) -> None:
        """Drop one task from the unit, keeping the others going; the failure is reported."""
        failure = TaskFailure(int(task_id), stage, err)
        log.error("%s", failure)
        self.failures.append(failure)
        failed[i] = True

    def collect(self, task_ids: Sequence[int], split: str, seed: int, round_index: int = 0) -> list[Attempt]:
        """All attempts of ``task_ids``, in (task order, attempt index) order."""
        d, s = self.domain, self.settings
        vocab = d.vocabulary
        n = len(task_ids)
        self.failures = []
        failed = np.zeros(n, dtype=bool)
        envs: list[Any] = [None] * n
        for i, t in enumerate(task_ids):
            try:
                envs[i] = d.make_env(int(t))
            except Exception as err:  # noqa: BLE001
                self._fail(t, "env construction", err, failed, i)
        expert = None
        if s.label_states and not failed.all():
            if self._expert is None:
                self._expert = make_expert(next(e for e in envs if e is not None), s.expert)
            expert = self._expert
        max_attempts = s.num_corrections + 1 if self.model.uses_corrections else 1
        steps = d.steps_per_attempt
        traj_times = trajectory_times(steps, d.trajectory_stride, s.trajectory_ends_at_last_state)
        # histories[i]: (trajectory (S, *O), correction ids (L,)) of each finished attempt of task i
        histories: list[list[tuple[np.ndarray, np.ndarray]]] = [[] for _ in range(n)]
        instructions: list[str] = [""] * n
        solved = np.zeros(n, dtype=bool)
        attempts_out: list[list[Attempt]] = [[] for _ in range(n)]
        # one sampling stream per unit, named by its tasks: independent of which actor runs it
        action_rng = derive_rng(seed, round_index, *task_ids[:1], n, 0xAC7)

        for k in range(max_attempts):
            active = np.flatnonzero(~solved & ~failed)
            if active.size == 0:
                break
            m = active.size
            obs_buf = np.zeros((m, steps) + d.obs_shape, dtype=d.obs_dtype)
            act_buf = np.zeros((m, steps), dtype=np.int64)
            label_buf = np.full((m, steps), -1, dtype=np.int64)
            soft = expert is not None and expert.soft_labels
            probs_buf = np.zeros((m, steps, d.num_actions), dtype=np.float32) if soft else None
            reset_seeds = [derive_seed(seed, task_ids[i], k) for i in active]
            for j, i in enumerate(active):
                try:
                    obs_buf[j, 0] = envs[i].reset(seed=reset_seeds[j])[0]
                    if k == 0:
                        instructions[i] = (self._corrector.full_information(envs[i]) if s.variant == "full_information"
                                           else envs[i].instruction)
                except Exception as err:  # noqa: BLE001
                    self._fail(task_ids[i], "reset", err, failed, i)
            with torch.inference_mode():
                z = self.model.encode_conditioning(self._conditioning([instructions[i] for i in active],
                                                                      [histories[i] for i in active], k))
            infos = self._run_attempt(task_ids, active, envs, expert, z, obs_buf, act_buf, label_buf,
                                      probs_buf, action_rng, failed)
            for j, i in enumerate(active):
                if failed[i]:
                    continue
                info = infos[j]
                success = bool(info.get("success", False))
                give_correction = (not success) and k < max_attempts - 1
                if give_correction:
                    try:
                        corr = self._corrector.correct(envs[i], derive_rng(seed, task_ids[i], k, 0xC0))
                    except Exception as err:  # noqa: BLE001
                        self._fail(task_ids[i], "correction", err, failed, i)
                        continue
                    corr_text, corr_kind = corr.text, corr.kind
                else:
                    corr_text, corr_kind = "", ""
                corr_ids = vocab.encode(corr_text) if corr_text else np.zeros(vocab.max_tokens, dtype=np.int64)
                attempts_out[i].append(Attempt(
                    task_id=int(task_ids[i]), split=split, attempt_index=k,
                    instruction=instructions[i], instruction_ids=vocab.encode(instructions[i]),
                    observations=obs_buf[j], actions=act_buf[j], expert_actions=label_buf[j],
                    completion=float(info.get("completion", 0.0)), success=success,
                    correction=corr_text, correction_kind=corr_kind, correction_ids=corr_ids,
                    seed=reset_seeds[j], policy_version=self.policy_version,
                    expert_probs=None if probs_buf is None else probs_buf[j],
                ))
                histories[i].append((obs_buf[j, traj_times], corr_ids))
                solved[i] = success
        return [a for per_task in attempts_out for a in per_task]

    def _run_attempt(self, task_ids, active, envs, expert, z, obs_buf, act_buf, label_buf, probs_buf,
                     action_rng, failed) -> list[dict]:
        """Step the ``active`` tasks' envs in lockstep for one attempt; fills the buffers in place.

        The hot loop of collection: one batched policy forward per step, then per env one expert
        label and one env step. Per-env work stays in plain Python lists (numpy scalar indexing
        costs more than the env step's own bookkeeping); each step's observations are stacked
        once into the attempt's buffer, which the next forward reads as a view.
        """
        s = self.settings
        m, steps = len(active), self.domain.steps_per_attempt
        active_envs = [envs[i] for i in active]
        alive = [not failed[i] for i in active]
        label = s.label_states
        soft = probs_buf is not None
        last_obs = list(obs_buf[:, 0])  # the reset observations, written there by the caller
        infos: list[dict] = [{}] * m
        labels = [-1] * m
        zero_probs = np.zeros(self.domain.num_actions, dtype=np.float32)
        probs = [zero_probs] * m
        for t in range(steps):
            with torch.inference_mode():
                logits = self.model.action_logits(torch.from_numpy(obs_buf[:, t]), z)
            actions = sample_actions(logits, action_rng, s.greedy_actions)
            act_buf[:, t] = actions
            for j, a in enumerate(actions.tolist()):
                if not alive[j]:
                    continue
                env = active_envs[j]
                try:
                    if soft:
                        labels[j], probs[j] = expert.label(env)
                    elif label:
                        labels[j] = expert.act(env)
                    last_obs[j], _, _, _, infos[j] = env.step(a)
                except Exception as err:  # noqa: BLE001 - one broken task must not end the unit
                    alive[j] = False
                    labels[j], probs[j] = -1, zero_probs
                    self._fail(task_ids[active[j]], "step/expert", err, failed, active[j])
            if label:
                label_buf[:, t] = labels
                if soft:
                    np.stack(probs, out=probs_buf[:, t])
            if t + 1 < steps:
                np.stack(last_obs, out=obs_buf[:, t + 1])
        return infos

    def _conditioning(self, instructions: list[str], histories: list[list[tuple[np.ndarray, np.ndarray]]], k: int) -> Conditioning:
        vocab = self.domain.vocabulary
        m = len(instructions)
        pairs = [pair for hist in histories for pair in hist[:k]]
        s = self.domain.trajectory_samples
        traj = np.zeros((len(pairs), s) + self.domain.obs_shape, dtype=self.domain.obs_dtype)
        corr = np.zeros((len(pairs), vocab.max_tokens), dtype=np.int64)
        for u, (tr, c) in enumerate(pairs):
            traj[u, : tr.shape[0]] = tr
            corr[u] = c
        return Conditioning(
            instruction_ids=torch.from_numpy(vocab.encode_batch(instructions)),
            trajectories=torch.from_numpy(traj),
            correction_ids=torch.from_numpy(corr),
            slots=torch.arange(m * k, dtype=torch.long).reshape(m, k),
        )


def completion_by_attempt(attempts: Sequence[Attempt], max_attempts: int) -> np.ndarray:
    """Mean completion after 0..max_attempts-1 corrections over the tasks in ``attempts``."""
    return completion_by_corrections(np.array([a.task_id for a in attempts]), np.array([a.attempt_index for a in attempts]),
                                     np.array([a.completion for a in attempts]), max_attempts)

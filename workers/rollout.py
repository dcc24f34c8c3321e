"""The rollout loop: a batch of tasks through their attempts, with a policy, an optional expert and
a correction source. Collection, evaluation and interactive use all step envs through ``Rollout``.

For each task (Algorithm 1's inner loops, Algorithm 2 at meta-test): attempt 0 is conditioned on
the instruction alone (or on the full-information text); after each attempt that did not solve the
task, the correction source gives a correction, and the next attempt is conditioned on every
earlier (trajectory, correction) pair, up to ``num_corrections`` corrections. All tasks of the batch
advance together, so each environment step costs one batched policy forward for the batch; an
expert, when given, labels every visited state in-process (with one call a step for an expert
that has ``label_batch``, ``gpl_dist.roles.BatchExpert``: the same labels, bit for bit, as one
env at a time). A task whose env, expert or correction source raises is dropped
(``TaskFailure``) and the others go on.

Everything is a function of the seed: reset seeds ``seeding.reset_seed(seed, task, k)``, one action
sampling stream per batch named by its tasks (independent of which process runs it), correction
choices ``seeding.correction_rng(seed, task, k)``.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Union, cast

import numpy as np
import torch

from gpl_dist.errors import ContractError
from gpl_dist.models.build import PolicyNetwork
from gpl_dist.models.layers import Conditioning
from gpl_dist.models.mivoa import PreviousStep
from gpl_dist.records import Attempt, Correction
from gpl_dist.roles import BatchExpert, CorrectionOracle, DomainSpec, Expert, trajectory_times
from gpl_dist.seeding import actions_rng, correction_phrasing_rng, correction_rng, instruction_phrasing_rng, reset_seed

log = logging.getLogger(__name__)

#: What gives corrections: an oracle, or any callable ``(env, rng) -> Correction`` (a person
#: typing, a recorded list); a plain callable cannot give the full-information text.
CorrectionSource = Union[CorrectionOracle, Callable[[Any, np.random.Generator], Correction]]



def _completion(info: dict, task_id: int, attempt: int) -> float:
    """``info["completion"]`` at the end of an attempt; ``ContractError`` naming the task and the
    value when it is not a finite fraction in [0, 1] (the run stops: its numbers would be wrong)."""
    value = info.get("completion", 0.0)
    try:
        completion = float(value)
    except (TypeError, ValueError):
        completion = math.nan
    if not (math.isfinite(completion) and 0.0 <= completion <= 1.0):
        raise ContractError(f"task {task_id}, attempt {attempt}: the env's completion is {str(value)[:40]}, not a finite "
                            "fraction in [0, 1] (gpl-dist check-domain names every such problem)")
    return completion

def batch_stepper(envs: Sequence[Any]) -> Callable[..., tuple[np.ndarray, list[dict] | None]] | None:
    """The ``step_batch`` of ``envs``' class (``gpl_dist.roles.BatchStepEnv``) when they are all
    of one class that has it (a wrapped env is not: its wrappers would be skipped); else None."""
    kinds = {type(env) for env in envs}
    if len(kinds) != 1:
        return None
    return getattr(kinds.pop(), "step_batch", None)


class TaskFailure(RuntimeError):
    """An env, expert or correction source raised for one task; carries the task id and stage."""

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


@dataclass(frozen=True)
class RolloutResult:
    """What ``Rollout.run`` returns.

    Attributes:
        attempts: every finished attempt, in (task order, attempt index) order.
        failures: tasks dropped because their env, expert or correction source raised.
    """

    attempts: tuple[Attempt, ...]
    failures: tuple[TaskFailure, ...]


@dataclass
class _Batch:
    """Per-task state of one ``run`` (index ``i`` is the task's position in ``task_ids``)."""

    task_ids: tuple[int, ...]
    envs: list[Any]
    failed: np.ndarray
    solved: np.ndarray
    instructions: list[str]
    # (trajectory (S, *O), correction ids (L,), summed reward) of each finished attempt of each task
    histories: list[list[tuple[np.ndarray, np.ndarray, float]]]
    attempts: list[list[Attempt]]
    failures: list[TaskFailure] = field(default_factory=list)

    def fail(self, i: int, stage: str, err: BaseException) -> None:
        failure = TaskFailure(int(self.task_ids[i]), stage, err)
        log.error("%s", failure)
        self.failures.append(failure)
        self.failed[i] = True


@dataclass
class _AttemptBuffers:
    """One attempt of the ``m`` active tasks: observations, actions, labels (filled in place)."""

    obs: np.ndarray  # (m, T, *O)
    actions: np.ndarray  # int64 (m, T)
    labels: np.ndarray  # int64 (m, T), -1 where unlabelled
    probs: np.ndarray | None  # float32 (m, T, A), the expert's distributions (soft-label experts)


class Rollout:
    """Steps batches of tasks through their attempts (see the module docstring).

    Args:
        domain: the domain's spec.
        policy: the GPL network (its weights may change between runs; it is only read).
        corrections: an oracle or a callable ``(env, rng) -> Correction``.
        expert: labels every visited state when given (collection); None at meta-test time.
        greedy: act with the most likely action instead of sampling.
        end_aligned: subsample earlier attempts ending at their last state
            (``ModelConfig.trajectory_ends_at_last_state``).
        full_information: condition on the oracle's full-information text instead of the instruction.
        phrasings: say the instruction and the oracle's corrections as they are (``canonical``),
            or as the domain's ``train`` or ``heldout`` paraphrases (``language.Paraphrases``;
            drawn with ``seeding.instruction_phrasing_rng`` and ``seeding.correction_phrasing_rng``).
            A person's corrections are paraphrased too unless ``canonical``.
        told_instructions: the instruction each listed task is told in place of its own (the
            instruction-swap control, ``learner.evaluate.swapped_instructions``), said in
            ``phrasings`` as its own would be; tasks not listed are told their own.

    Text is encoded with the policy's own vocabulary (``policy.vocabulary``): words it lacks read
    as ``<unk>``.
    """

    def __init__(self, domain: DomainSpec, policy: PolicyNetwork, corrections: CorrectionSource,
                 expert: Expert | None = None, *, greedy: bool = False, end_aligned: bool = False,
                 full_information: bool = False, phrasings: str = "canonical",
                 told_instructions: Mapping[int, str] | None = None):
        self.domain = domain
        self.vocab = policy.vocabulary
        self.phrasings = phrasings
        if phrasings != "canonical" and domain.paraphrases is None:
            raise ValueError(f"phrasings {phrasings!r}: domain '{domain.name}' declares no paraphrases")
        if domain.paraphrases is not None:
            domain.paraphrases.pool(phrasings)  # an unknown name fails here
        self.policy = policy
        self.corrections = corrections
        self.expert = expert
        self.greedy = greedy
        self.full_information = full_information
        if told_instructions and full_information:
            raise ValueError("told_instructions replaces the instruction; the full-information variant reads none")
        self.told_instructions = dict(told_instructions or {})
        self.traj_times = trajectory_times(domain.steps_per_attempt, domain.trajectory_stride, end_aligned)
        if full_information and not hasattr(corrections, "full_information"):
            raise TypeError("the full-information variant needs an oracle with full_information(env)")

    def run(self, task_ids: Sequence[int], num_corrections: int, seed: int, *, round_index: int = 0,
            split: str = "", policy_version: int = -1) -> RolloutResult:
        """Every attempt of ``task_ids``: at most ``num_corrections + 1`` each (1 for a policy that
        takes no corrections), stopping at the first that solves the task."""
        task_ids = tuple(int(t) for t in task_ids)
        batch = self._start(task_ids)
        max_attempts = num_corrections + 1 if self.policy.uses_corrections else 1
        action_rng = actions_rng(seed, round_index, task_ids)
        for k in range(max_attempts):
            active = np.flatnonzero(~batch.solved & ~batch.failed)
            if active.size == 0:
                break
            reset_seeds = [reset_seed(seed, task_ids[i], k) for i in active]
            buffers = self._reset(batch, active, k, reset_seeds, seed)
            infos, returns = self._step_attempt(batch, active, buffers, action_rng, k)
            self._finish_attempt(batch, active, buffers, infos, returns, k, reset_seeds,
                                 seed=seed, split=split, last=k == max_attempts - 1, policy_version=policy_version)
        return RolloutResult(tuple(a for per_task in batch.attempts for a in per_task), tuple(batch.failures))

    # -- steps of run ----------------------------------------------------------------------------

    def _start(self, task_ids: tuple[int, ...]) -> _Batch:
        n = len(task_ids)
        batch = _Batch(task_ids, [None] * n, np.zeros(n, bool), np.zeros(n, bool), [""] * n,
                       [[] for _ in range(n)], [[] for _ in range(n)])
        for i, t in enumerate(task_ids):
            try:
                batch.envs[i] = self.domain.make_env(t)
            except Exception as err:  # noqa: BLE001 - one broken task must not end the batch
                batch.fail(i, "env construction", err)
        return batch

    def _reset(self, batch: _Batch, active: np.ndarray, k: int, reset_seeds: list[int], seed: int) -> _AttemptBuffers:
        d = self.domain
        m, steps = active.size, d.steps_per_attempt
        soft = self.expert is not None and self.expert.soft_labels
        buffers = _AttemptBuffers(obs=np.zeros((m, steps) + d.obs_shape, dtype=d.obs_dtype),
                                  actions=np.zeros((m, steps), dtype=np.int64),
                                  labels=np.full((m, steps), -1, dtype=np.int64),
                                  probs=np.zeros((m, steps, d.num_actions), dtype=np.float32) if soft else None)
        for j, i in enumerate(active):
            try:
                buffers.obs[j, 0] = batch.envs[i].reset(seed=reset_seeds[j])[0]
                if k == 0 and self.full_information:
                    batch.instructions[i] = self.corrections.full_information(batch.envs[i])  # type: ignore[union-attr]
                elif k == 0:
                    rng = instruction_phrasing_rng(seed, batch.task_ids[i]) if self.phrasings != "canonical" else None
                    own = batch.envs[i].instruction
                    batch.instructions[i] = self._say(self.told_instructions.get(batch.task_ids[i], own), rng)
            except Exception as err:  # noqa: BLE001
                batch.fail(i, "reset", err)
        return buffers

    def _step_attempt(self, batch: _Batch, active: np.ndarray, buffers: _AttemptBuffers,
                      action_rng: np.random.Generator, k: int) -> tuple[list[dict], list[float]]:
        """Step the active tasks' envs in lockstep for one attempt; fills ``buffers`` in place and
        returns each env's last info and its summed reward.

        The hot loop: one batched policy forward per step; then, for an expert that labels many
        envs at once (``BatchExpert``), one ``label_batch`` call over the live envs, written into
        the attempt's buffers as a block (otherwise one ``label``/``act`` per env); then one env
        step per env. Per-env work stays in plain Python lists (numpy scalar indexing costs more
        than the env step's own bookkeeping); each step's observations are stacked once into the
        attempt's buffer, which the next forward reads as a view.
        """
        with torch.inference_mode():
            z = self.policy.encode_conditioning(self._conditioning([batch.instructions[i] for i in active],
                                                                   [batch.histories[i] for i in active], k,
                                                                   [batch.task_ids[i] for i in active]))
        m, steps = active.size, self.domain.steps_per_attempt
        envs = [batch.envs[i] for i in active]
        alive = [not batch.failed[i] for i in active]
        expert, soft = self.expert, buffers.probs is not None
        batched = soft and isinstance(expert, BatchExpert)
        per_env_labels = expert is not None and not batched
        live = [j for j in range(m) if alive[j]]  # rebuilt when a task fails
        last_obs = list(buffers.obs[:, 0])  # the reset observations
        infos: list[dict] = [{}] * m
        returns = [0.0] * m  # each attempt's summed reward (GPR's feedback)
        labels = [-1] * m
        zero_probs = np.zeros(self.domain.num_actions, dtype=np.float32)
        probs = [zero_probs] * m
        stepper = None if per_env_labels else batch_stepper(envs)
        for t in range(steps):
            with torch.inference_mode():
                logits = self.policy.action_logits(torch.from_numpy(buffers.obs[:, t]), z, self._previous(buffers, t))
            actions = sample_actions(logits, action_rng, self.greedy)
            buffers.actions[:, t] = actions
            if batched and self._label_block(batch, active, envs, live, buffers, t):
                alive = [not batch.failed[i] for i in active]
                live = [j for j in range(m) if alive[j]]
            if stepper is not None:
                if self._step_block(stepper, batch, active, envs, live, actions, buffers, t, infos, returns):
                    alive = [not batch.failed[i] for i in active]
                    live = [j for j in range(m) if alive[j]]
                continue
            step_failed = False
            for j, a in enumerate(actions.tolist()):
                if not alive[j]:
                    continue
                env = envs[j]
                try:
                    if soft and not batched:
                        labels[j], probs[j] = expert.label(env)  # type: ignore[union-attr]
                    elif per_env_labels:
                        labels[j] = expert.act(env)  # type: ignore[union-attr]
                    last_obs[j], reward, _, _, infos[j] = env.step(a)
                    returns[j] += float(reward)
                except Exception as err:  # noqa: BLE001 - one broken task must not end the batch
                    alive[j] = False
                    step_failed = True
                    labels[j], probs[j] = -1, zero_probs
                    if batched:  # labelled before the step raised: unlabel, as the per-env path does
                        buffers.labels[j, t] = -1
                        buffers.probs[j, t] = 0.0  # type: ignore[index]
                    batch.fail(int(active[j]), "step/expert", err)
            if step_failed:
                live = [j for j in range(m) if alive[j]]
            if per_env_labels:
                buffers.labels[:, t] = labels
                if soft:
                    np.stack(probs, out=buffers.probs[:, t])  # type: ignore[index]
            if t + 1 < steps:
                np.stack(last_obs, out=buffers.obs[:, t + 1])
        return infos, returns

    def _step_block(self, stepper: Callable[..., tuple[np.ndarray, list[dict] | None]], batch: _Batch,
                    active: np.ndarray, envs: list[Any], live: list[int], actions: np.ndarray,
                    buffers: _AttemptBuffers, t: int, infos: list[dict], returns: list[float]) -> bool:
        """Step the ``live`` envs with one ``step_batch`` call (``gpl_dist.roles.BatchStepEnv``),
        their observations written into the attempt's buffer at ``t + 1``; rows of dead envs keep
        their last observation, as the per-env path leaves them. When the call raises, every live
        task fails (its label at ``t`` undone, as the per-env path does); returns whether any did."""
        steps = buffers.obs.shape[1]
        everyone = len(live) == len(envs)
        if t + 1 < steps and everyone:
            out = buffers.obs[:, t + 1]
        else:
            out = np.empty((len(live),) + buffers.obs.shape[2:], dtype=buffers.obs.dtype)
        if not live:
            return False
        try:
            rewards, step_infos = stepper(envs if everyone else [envs[j] for j in live],
                                          actions if everyone else actions[live], out, t + 1 == steps)
        except Exception as err:  # noqa: BLE001 - a batch step that raised is every live task's failure
            for j in live:
                buffers.labels[j, t] = -1
                if buffers.probs is not None:
                    buffers.probs[j, t] = 0.0
                batch.fail(int(active[j]), "step/expert", err)
            return True
        if t + 1 < steps and not everyone:
            buffers.obs[:, t + 1] = buffers.obs[:, t]
            buffers.obs[live, t + 1] = out
        for j, r in zip(live, rewards.tolist()):
            returns[j] += r
        if step_infos is not None:
            for j, info in zip(live, step_infos):
                infos[j] = info
        return False

    def _label_block(self, batch: _Batch, active: np.ndarray, envs: list[Any], live: list[int],
                     buffers: _AttemptBuffers, t: int) -> bool:
        """Label step ``t`` of the ``live`` envs with one ``label_batch`` call into the buffers
        (rows of dead envs stay unlabelled: -1, zero probabilities). When the call raises, each
        env is labelled alone to find the tasks at fault, which fail; returns whether any did."""
        expert = cast(BatchExpert, self.expert)  # checked once per attempt by the caller
        if not live:
            return False
        everyone = len(live) == len(envs)
        try:
            actions, probs = expert.label_batch(envs if everyone else [envs[j] for j in live])
        except Exception:  # noqa: BLE001 - find the task(s) at fault, one env at a time
            failed = False
            for j in live:
                try:
                    a, p = expert.label_batch([envs[j]])
                except Exception as err:  # noqa: BLE001
                    batch.fail(int(active[j]), "step/expert", err)
                    failed = True
                    continue
                buffers.labels[j, t], buffers.probs[j, t] = a[0], p[0]  # type: ignore[index]
            return failed
        if everyone:
            buffers.labels[:, t], buffers.probs[:, t] = actions, probs  # type: ignore[index]
        else:
            buffers.labels[live, t], buffers.probs[live, t] = actions, probs  # type: ignore[index]
        return False

    def _previous(self, buffers: _AttemptBuffers, t: int) -> PreviousStep | None:
        """The step before ``t`` for a policy that reads it (``PreviousStep``), else None."""
        if not self.policy.uses_previous_step:
            return None
        if t == 0:
            return PreviousStep(torch.from_numpy(buffers.obs[:, 0]), torch.full((buffers.obs.shape[0],), -1, dtype=torch.long))
        return PreviousStep(torch.from_numpy(buffers.obs[:, t - 1]), torch.from_numpy(buffers.actions[:, t - 1]))

    def _finish_attempt(self, batch: _Batch, active: np.ndarray, buffers: _AttemptBuffers, infos: list[dict],
                        returns: list[float], k: int, reset_seeds: list[int], *, seed: int, split: str, last: bool,
                        policy_version: int) -> None:
        """Record each active task's attempt, with the correction that follows it unless it
        solved the task or was the last."""
        vocab = self.vocab
        for j, i in enumerate(active):
            if batch.failed[i]:
                continue
            info, task_id = infos[j], batch.task_ids[i]
            success = bool(info.get("success", False))
            completion = _completion(info, task_id, k)
            text, kind = "", ""
            if not success and not last:
                try:
                    corr = self._correct(batch.envs[i], correction_rng(seed, task_id, k))
                except Exception as err:  # noqa: BLE001
                    batch.fail(int(i), "correction", err)
                    continue
                text, kind = corr.text, corr.kind
                if self.phrasings != "canonical":
                    text = self._say(text, correction_phrasing_rng(seed, task_id, k))
            corr_ids = vocab.encode(text) if text else np.zeros(vocab.max_tokens, dtype=np.int64)
            batch.attempts[i].append(Attempt(
                task_id=task_id, split=split, attempt_index=k,
                instruction=batch.instructions[i], instruction_ids=vocab.encode(batch.instructions[i]),
                observations=buffers.obs[j], actions=buffers.actions[j], expert_actions=buffers.labels[j],
                completion=completion, success=success,
                correction=text, correction_kind=kind, correction_ids=corr_ids,
                seed=reset_seeds[j], policy_version=policy_version,
                expert_probs=None if buffers.probs is None else buffers.probs[j],
                reward_sum=returns[j],
            ))
            batch.histories[i].append((buffers.obs[j, self.traj_times], corr_ids, returns[j]))
            batch.solved[i] = success

    def _say(self, text: str, rng: np.random.Generator | None) -> str:
        """``text`` in this rollout's phrasings (as it is for ``canonical``)."""
        if rng is None or self.domain.paraphrases is None:
            return text
        return self.domain.paraphrases.rewrite(text, self.phrasings, rng)

    def _correct(self, env: Any, rng: np.random.Generator) -> Correction:
        source = self.corrections
        return source.correct(env, rng) if hasattr(source, "correct") else source(env, rng)  # type: ignore[operator,union-attr]

    def _conditioning(self, instructions: list[str], histories: list[list[tuple[np.ndarray, np.ndarray, float]]],
                      k: int, task_ids: list[int]) -> Conditioning:
        vocab, d = self.vocab, self.domain
        m = len(instructions)
        pairs = [pair for hist in histories for pair in hist[:k]]
        traj = np.zeros((len(pairs), d.trajectory_samples) + d.obs_shape, dtype=d.obs_dtype)
        corr = np.zeros((len(pairs), vocab.max_tokens), dtype=np.int64)
        rewards = np.zeros(len(pairs), dtype=np.float32)
        for u, (tr, c, r) in enumerate(pairs):
            traj[u, : tr.shape[0]] = tr
            corr[u] = c
            rewards[u] = r
        return Conditioning(
            instruction_ids=torch.from_numpy(vocab.encode_batch(instructions)),
            trajectories=torch.from_numpy(traj),
            correction_ids=torch.from_numpy(corr),
            slots=torch.arange(m * k, dtype=torch.long).reshape(m, k),
            instruction_values=self._full_information_values(task_ids),
            correction_values=torch.from_numpy(rewards),
        )

    def _full_information_values(self, task_ids: list[int]) -> torch.Tensor | None:
        """float32 ``(m, F)``: the tasks' numeric full information, for a model that reads it."""
        values_of_task = self.domain.full_information_values
        if not self.policy.numeric_full_information or values_of_task is None:
            return None
        return torch.from_numpy(np.stack([values_of_task(t) for t in task_ids]))

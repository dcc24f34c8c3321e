"""Frozen, typed records that cross module boundaries.

Every array's shape and dtype is part of the record's contract; ``T`` is the number of labelled
states in an attempt, ``L`` the vocabulary's ``max_tokens``, ``O`` the domain's observation shape
(``(7, 7, 6)`` uint8 for multi-room, ``(28,)`` float32 for relocation).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np


@dataclass(frozen=True)
class Correction:
    """A correction given after an attempt.

    Attributes:
        text: the English sentence, e.g. ``"enter the blue room"``.
        kind: which rule produced it: ``subgoal``, ``directional``, ``binary``, ``relational``,
            ``touch``, ``full_information``, ``reward`` or ``retry``.
    """

    text: str
    kind: str


@dataclass(frozen=True)
class Attempt:
    """One rollout of one task by the current policy, labelled by the expert.

    Attempt ``k`` was conditioned on the instruction and on attempts ``0..k-1`` of the same
    (round, task) together with the corrections given after each of them.

    Attributes:
        task_id: index of the task in its domain's task set.
        split: the split the task belongs to (``train``, ``test``, ...).
        attempt_index: ``k``; 0 is the instruction-only attempt.
        instruction: the task's instruction sentence.
        instruction_ids: int64 ``(L,)`` token ids of ``instruction``.
        observations: ``(T, *O)`` every state the policy acted in, in order.
        actions: int64 ``(T,)`` the action the policy executed in each state.
        expert_actions: int64 ``(T,)`` the expert's label for each state.
        expert_probs: float32 ``(T, num_actions)`` the expert's action distribution in each state
            (the learner's target), or None: one-hot of ``expert_actions`` (also when unlabelled).
        completion: the domain's completion metric at the end of the attempt, in [0, 1].
        success: whether the task was solved during the attempt.
        correction: text of the correction given after this attempt; ``""`` when none was given
            (the task was solved or the correction budget is spent).
        correction_kind: the ``Correction.kind`` of ``correction``; ``""`` when none.
        correction_ids: int64 ``(L,)`` token ids of ``correction`` (all padding when none).
        seed: the seed the env was reset with.
        policy_version: version of the weights that acted.
        reward_sum: the env's reward summed over the attempt (its dense reward: the paper's
            GPR feeds it in place of the correction); NaN when not recorded (older shards).
    """

    task_id: int
    split: str
    attempt_index: int
    instruction: str
    instruction_ids: np.ndarray
    observations: np.ndarray
    actions: np.ndarray
    expert_actions: np.ndarray
    completion: float
    success: bool
    correction: str
    correction_kind: str
    correction_ids: np.ndarray
    seed: int
    policy_version: int
    expert_probs: np.ndarray | None = None
    reward_sum: float = float("nan")

    @property
    def length(self) -> int:
        """Number of labelled states ``T``."""
        return int(self.actions.shape[0])

    def __post_init__(self) -> None:
        n = self.observations.shape[0]
        if self.actions.shape != (n,) or self.expert_actions.shape != (n,):
            raise ValueError(
                f"attempt of task {self.task_id}: observations, actions and expert_actions disagree "
                f"on length ({n}, {self.actions.shape}, {self.expert_actions.shape})"
            )
        if self.expert_probs is not None and (self.expert_probs.ndim != 2 or self.expert_probs.shape[0] != n):
            raise ValueError(f"attempt of task {self.task_id}: expert_probs {self.expert_probs.shape} for {n} states")


@dataclass(frozen=True)
class WorkUnit:
    """A chunk of tasks one rollout worker collects in one round.

    The shard a unit writes is named by ``(round_index, unit_index)`` alone, so a retried unit
    replaces its own shard instead of adding a second one.

    Attributes:
        round_index: DAgger round, from 0.
        unit_index: position of the chunk in the round's task list.
        task_ids: the tasks to roll out, in order.
        split: split the tasks belong to.
        seed: base seed; each task's rollouts derive their seeds from it and the task id.
        policy_version: version of the weights the worker must act with.
    """

    round_index: int
    unit_index: int
    task_ids: tuple[int, ...]
    split: str
    seed: int
    policy_version: int


@dataclass(frozen=True)
class LearnerState:
    """Everything a learner's future training depends on, as ``gpl_dist.roles.Learner.state``
    gives it and ``load_state`` takes it (checkpoints, resume, a learner that trains elsewhere).

    Attributes:
        model: the model's state dict (tensors).
        optimizer: the Adam state dict, or None before the first step.
        generator: the batch-order generator's state (``torch.Generator.get_state``).
    """

    model: Mapping[str, Any]
    optimizer: Mapping[str, Any] | None
    generator: Any

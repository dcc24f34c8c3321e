"""The roles of gpl-dist, named once.

Data flows one way: env -> rollout worker (policy, expert, correction oracle beside the env) ->
buffer writer (one shard per work unit) -> driver commits the round's manifest -> buffer reader ->
learner -> weights -> rollout workers. Everything else in the code base implements one of these
interfaces; nothing here imports Ray, torch or a storage library.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Mapping, Protocol, Sequence, runtime_checkable

import numpy as np

from gpl_dist.language import Vocabulary
from gpl_dist.records import Attempt, Correction, WorkUnit

if TYPE_CHECKING:
    import gymnasium


@dataclass(frozen=True)
class DomainSpec:
    """What the domain-agnostic parts (worker, model, learner, evaluation) know of a domain.

    Attributes:
        name: short name used in configs and the CLI (``multiroom``, ``relocation``).
        env_id: gymnasium id, e.g. ``gpl/MultiRoom-v0``.
        num_tasks: size of the task set.
        obs_shape: shape of one observation.
        obs_dtype: numpy dtype name of observations (``uint8`` or ``float32``).
        num_actions: size of the discrete action space.
        steps_per_attempt: actions per attempt (the episode length).
        trajectory_stride: the correction module reads every ``trajectory_stride``-th state of an
            earlier attempt (25 for multi-room, 70 for relocation, as in the paper).
        vocabulary: words of instructions and corrections.
        make_env: builds the (unwrapped) env of a task: ``make_env(task_id, **kwargs)``.
        split_names: names of the versioned splits.
        obs_categories: for categorical grid observations, the number of codes each channel can
            hold (the model one-hot encodes them); None for continuous observations.
    """

    name: str
    env_id: str
    num_tasks: int
    obs_shape: tuple[int, ...]
    obs_dtype: str
    num_actions: int
    steps_per_attempt: int
    trajectory_stride: int
    vocabulary: Vocabulary
    make_env: Callable[..., "gymnasium.Env"]
    split_names: tuple[str, ...]
    obs_categories: tuple[int, ...] | None = None

    @property
    def trajectory_samples(self) -> int:
        """Number of states the correction module reads from one earlier attempt."""
        return len(trajectory_times(self.steps_per_attempt, self.trajectory_stride, end_aligned=False))


def trajectory_times(length: int, stride: int, end_aligned: bool) -> np.ndarray:
    """The time steps of an attempt of ``length`` states that the correction module reads.

    Every ``stride``-th step from 0, or (``end_aligned``, ``ModelConfig.trajectory_ends_at_last_state``)
    every ``stride``-th step ending at ``length - 1``: the state the attempt's correction was
    computed from. int64 ``(ceil(length / stride),)`` either way, so the anchoring changes no shape.
    The rollout worker and the buffer reader both sample with this, so that training sees what
    collection acted on.
    """
    first = (length - 1) % stride if end_aligned and length > 0 else 0
    return np.arange(first, length, stride, dtype=np.int64)


@runtime_checkable
class TaskEnv(Protocol):
    """A gymnasium env bound to one task of a domain (``env.unwrapped`` satisfies this).

    ``info`` from ``reset`` and ``step`` carries ``completion`` (float in [0, 1], best so far in
    the episode where the domain says so) and ``success`` (bool).
    """

    task_id: int
    instruction: str

    def reset(self, *, seed: int | None = None, options: Mapping[str, Any] | None = None) -> tuple[Any, dict]: ...

    def step(self, action: int) -> tuple[Any, float, bool, bool, dict]: ...


@runtime_checkable
class Expert(Protocol):
    """Near-optimal policy with privileged access to the env's full state.

    ``soft_labels``: whether ``label`` can return anything but the one-hot of ``act`` (when
    False, workers call ``act`` alone and store no distributions: they read back as one-hot).
    """

    soft_labels: bool

    def act(self, env: Any) -> int:
        """Optimal next action for the env's current state (``env`` wrapped or unwrapped)."""
        ...

    def label(self, env: Any) -> tuple[int, np.ndarray]:
        """``(act(env), probs)``: the action and a float32 ``(num_actions,)`` distribution over the
        actions the expert holds equally good (one-hot for an expert without ties). The learner
        fits ``probs`` (KL, as the paper's code fit its experts' action distributions)."""
        ...


@runtime_checkable
class CorrectionOracle(Protocol):
    """Generates the correction for the attempt that just ended in ``env``."""

    def correct(self, env: Any, rng: np.random.Generator) -> Correction:
        """Correction for the episode ``env`` has just run; ``rng`` drives any random choice."""
        ...

    def full_information(self, env: Any) -> str:
        """Everything needed to solve the task, as text (the full-information baseline's input)."""
        ...


@runtime_checkable
class Policy(Protocol):
    """Acts in many envs at once: one batched forward per step."""

    def act(self, observations: np.ndarray, conditioning: Any, greedy: bool = False) -> np.ndarray:
        """Actions int64 ``(B,)`` for observations ``(B, *obs_shape)`` under ``conditioning``."""
        ...


@runtime_checkable
class BufferWriter(Protocol):
    """Writes one work unit's attempts as one shard, visible only after the driver commits."""

    def write_unit(self, unit: WorkUnit, attempts: Sequence[Attempt], worker_id: str) -> Any:
        """Write the shard of ``unit`` (replacing a previous try) and return its shard record."""
        ...


@runtime_checkable
class BufferReader(Protocol):
    """Reads the committed rounds of a run."""

    def committed_rounds(self) -> list[int]: ...

    def load_training_view(self, capacity_tuples: int) -> Any:
        """Newest ``capacity_tuples`` labelled states over committed rounds, as in-memory arrays."""
        ...


@runtime_checkable
class RolloutWorker(Protocol):
    """Rolls the current policy out over a unit of tasks and writes the shard."""

    def set_weights(self, weights: Any, policy_version: int) -> None: ...

    def run_unit(self, unit: WorkUnit) -> Any:
        """Collect ``unit`` and return its shard record (never the data itself)."""
        ...


@runtime_checkable
class Learner(Protocol):
    """Trains the policy over the committed buffer view."""

    def train_round(self, view: Any) -> Mapping[str, float]:
        """Train ``num_epochs_per_round`` epochs over ``view``; return scalar statistics."""
        ...

    def weights(self) -> Any: ...

"""The roles of gpl-dist, named once.

Data flows one way: env -> rollout worker (policy, expert, correction oracle beside the env) ->
buffer writer (one shard per work unit) -> driver commits the round's manifest -> buffer reader ->
learner -> weights -> rollout workers. Everything else in the code base implements one of these
interfaces; nothing here imports Ray, torch or a storage library.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Mapping, Protocol, Sequence, runtime_checkable

import numpy as np

from gpl_dist.language import Paraphrases, Vocabulary
from gpl_dist.records import Attempt, Correction, LearnerState, WorkUnit

if TYPE_CHECKING:
    import gymnasium

    from gpl_dist.models.sizes import Sizes


def lazy(target: str) -> Callable[..., Any]:
    """A factory that imports ``"package.module:name"`` on first call and calls it: lets a domain
    declare its experts and correction oracle without importing them (or their dependencies)."""
    def make(*args: Any, **kwargs: Any) -> Any:
        module, name = target.split(":")
        return getattr(importlib.import_module(module), name)(*args, **kwargs)

    make.__qualname__ = make.__name__ = f"lazy({target})"
    return make


@dataclass(frozen=True)
class DomainSpec:
    """A domain, declared once: everything the domain-agnostic parts (config validation, CLI,
    worker, model, learner, evaluation) know of it. ``gpl_dist.domains`` is the registry;
    ``docs/adding-a-domain.md`` shows how to add one.

    Attributes:
        name: short name used in configs and the CLI (``multiroom``, ``relocation``).
        env_id: gymnasium id, e.g. ``gpl/MultiRoom-v0`` (registered with the domain).
        num_tasks: size of the task set; task ids are ``0..num_tasks-1``.
        obs_shape: shape of one observation.
        obs_dtype: numpy dtype name of observations (``uint8`` or ``float32``).
        num_actions: size of the discrete action space.
        steps_per_attempt: actions per attempt (the episode length).
        trajectory_stride: the correction module reads every ``trajectory_stride``-th state of an
            earlier attempt (25 for multi-room, 70 for relocation, as in the paper).
        vocabulary: words of instructions and corrections.
        make_env: builds the (unwrapped) env of a task: ``make_env(task_id, **kwargs)``; with
            ``render_mode="rgb_array"`` its ``render()`` draws the scene (``gpl-dist render``).
        split_names: names of the task splits.
        train_split: the split a run collects on unless ``env.train_split`` names another.
        eval_split: the split a meta-test reads unless ``eval.split`` names another.
        valid_splits: training split -> the split its runs are chosen on (the learning curve and
            the instruction-swap control): tasks of neither that training split nor any test split.
            A run on a training split not listed has no valid split.
        experts: expert kind -> factory of an ``Expert`` (the first kind is the default).
        correction_kinds: kinds ``make_corrector`` accepts; ``default`` is the paper's oracle.
        make_corrector: ``make_corrector(kind)`` -> ``CorrectionOracle``.
        model_sizes: layer sizes of the GPL network (``gpl_dist.models.sizes.Sizes``).
        paper_completion: the paper's GPL completion on test tasks after k corrections (Tables 1, 3).
        obs_categories: for categorical grid observations, the number of codes each channel can
            hold (the model one-hot encodes them); None for continuous observations.
        splits: task ids of each split, given inline; None reads the versioned file
            ``gpl_dist/splits/<name>.json`` (``gpl_dist.splits``).
        full_information_values: for a domain whose full information is numbers (relocation: the
            goal block and the target's coordinates), ``f(task_id)`` -> float32 ``(F,)``; the
            ``full_information`` variant then reads them through an MLP in place of the
            full-information text. None: the full information is the oracle's text.
        correction_phrasings: ``f()`` -> every sentence the oracle's text kinds can say, and
            optionally ``f(kind)`` -> those of one kind (``phrasings_of``); a person's correction is
            checked against the run's kind (``gpl_dist.app.teaching``: the closest known phrasing,
            and a warning for a sentence of a kind the policy never trained on). None: the
            vocabulary alone is known.
        paraphrases: other phrasings of the instructions and corrections (``language.Paraphrases``),
            for training with paraphrases (``model.paraphrases``) and meta-testing with held-out
            ones (``eval.phrasings``); None: the domain has only its canonical phrasings.
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
    experts: Mapping[str, Callable[[], "Expert"]]
    correction_kinds: tuple[str, ...]
    make_corrector: Callable[[str], "CorrectionOracle"]
    model_sizes: "Sizes"
    paper_completion: Mapping[int, float] = field(default_factory=dict)
    obs_categories: tuple[int, ...] | None = None
    splits: Mapping[str, tuple[int, ...]] | None = None
    full_information_values: Callable[[int], np.ndarray] | None = None
    correction_phrasings: Callable[..., tuple[str, ...]] | None = None
    paraphrases: Paraphrases | None = None
    train_split: str = "train"
    eval_split: str = "test"
    valid_splits: Mapping[str, str] = field(default_factory=dict)

    def vocabulary_for(self, paraphrases: bool) -> Vocabulary:
        """The vocabulary of a model trained with (``paraphrases``) or without paraphrases: the
        domain's, with the training paraphrases' words appended (ids of the others unchanged)."""
        if not paraphrases:
            return self.vocabulary
        if self.paraphrases is None:
            raise ValueError(f"domain '{self.name}' declares no paraphrases")
        return self.vocabulary.extended(self.paraphrases.words("train"))

    def phrasings_of(self, kind: str | None = None, paraphrases: bool = False) -> tuple[str, ...]:
        """The sentences the oracle of correction ``kind`` says (``correction_phrasings(kind)``);
        every text kind's with ``kind`` None or when ``correction_phrasings`` takes no kind; ()
        without ``correction_phrasings``. With ``paraphrases`` (a model trained with them,
        ``model.paraphrases``), each sentence is followed by its training paraphrases
        (``paraphrased``)."""
        f = self.correction_phrasings
        if f is None:
            return ()
        said: tuple[str, ...] | None = None
        if kind is not None:
            try:
                said = tuple(f(kind))
            except TypeError:  # a domain's phrasings that take no kind: every kind's
                pass
        if said is None:
            said = tuple(f())
        return self.paraphrased(said, ("train",)) if paraphrases else said

    def paraphrased(self, texts: Sequence[str], pools: Sequence[str] = ("train",)) -> tuple[str, ...]:
        """``texts``, each followed by its paraphrases of ``pools`` (``language.PHRASINGS``): every
        template of those pools of the first rule that matches it (whole, case-insensitive), as
        ``Paraphrases.rewrite`` would say it; each sentence once (by its lower-case words, the first
        spelling kept). ``texts`` alone when the domain declares no paraphrases."""
        import re

        out: dict[str, str] = {}
        p = self.paraphrases
        for text in texts:
            said = [text]
            for rule in p.rules if p is not None else ():
                m = re.fullmatch(rule.pattern, text.strip(), re.IGNORECASE)
                if m and p is not None:
                    said += [rule.templates[i].format(**m.groupdict()) for pool in pools for i in p.pool(pool)]
                    break
            for sentence in said:
                out.setdefault(" ".join(sentence.lower().split()), sentence)
        return tuple(out.values())

    def instruction_of(self, task_id: int) -> str:
        """The instruction of ``task_id`` (its env's ``TaskEnv.instruction``)."""
        env: Any = self.make_env(task_id)
        return str(env.instruction)

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

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]: ...

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
class BatchExpert(Expert, Protocol):
    """An ``Expert`` that also labels many envs with one call (one batched forward of a learned
    expert); the rollout loop labels every step's envs with it when the expert has it."""

    def label_batch(self, envs: Sequence[Any]) -> tuple[np.ndarray, np.ndarray]:
        """``(actions, probs)``: int64 ``(n,)`` and float32 ``(n, num_actions)``, row ``i`` the
        same bits as ``label(envs[i])`` (a label may not depend on the batch it is computed in)."""
        ...


class BatchStepEnv(Protocol):
    """An env class whose ``step_batch`` steps many of its instances at once; the rollout loop
    steps a batch's envs with it when they are all of that class (unwrapped) and their labels need
    no per-env call (no expert, or a ``BatchExpert``)."""

    @classmethod
    def step_batch(cls, envs: Sequence[Any], actions: np.ndarray, out: np.ndarray,
                   with_info: bool) -> tuple[np.ndarray, list[dict] | None]:
        """``envs[i].step(actions[i])`` for every ``i``, with the same results bit for bit: the
        observations written into ``out`` ``(n, *obs_shape)``, the rewards returned as float64
        ``(n,)``, and each env's info when ``with_info`` (else None). Raises before stepping any
        env on a bad action; a failure after that is the whole batch's."""
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
    """Acts in many envs at once: the conditioning is encoded once per attempt, then one batched
    forward per step (``workers.rollout.Rollout`` drives it; ``GPLPolicy`` and ``MIVOAPolicy`` implement it)."""

    vocabulary: Vocabulary
    """The words the network reads (``DomainSpec.vocabulary_for``); text is encoded with it."""

    @property
    def uses_corrections(self) -> bool:
        """Whether later attempts are conditioned on earlier (trajectory, correction) pairs."""
        ...

    @property
    def uses_previous_step(self) -> bool:
        """Whether ``action_logits`` reads the step before each state (MIVOA does, GPL does not)."""
        ...

    @property
    def numeric_full_information(self) -> bool:
        """Whether the conditioning carries the task's full information as numbers
        (``DomainSpec.full_information_values``) in place of the instruction."""
        ...

    def encode_conditioning(self, cond: Any) -> Any:
        """``(A, D)`` tensor: the instruction and correction history of each attempt row of ``cond``."""
        ...

    def action_logits(self, obs: Any, z: Any, previous: Any = None) -> Any:
        """``(B, num_actions)`` logits for observations ``(B, *obs_shape)`` under per-state conditioning
        ``z``; ``previous`` (``gpl_dist.models.mivoa.PreviousStep``) when ``uses_previous_step``."""
        ...

    def encode_states(self, obs: Any, previous: Any = None) -> Any:
        """The part of ``action_logits`` that does not read ``z``: ``(B, S)`` state encodings."""
        ...

    def head_logits(self, states: Any, z: Any, previous: Any = None) -> Any:
        """``action_logits`` from ``encode_states``'s output: ``head_logits(encode_states(obs, p), z, p)``."""
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

    def load_training_view(self, capacity_tuples: int = 1_000_000, trajectory_stride: int = 25,
                           trajectory_end_aligned: bool = False) -> Any:
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
class Collector(Protocol):
    """Hands a round's work units to rollout workers (in this process, or Ray actors)."""

    def collect_round(self, units: Sequence[WorkUnit], weights: dict, policy_version: int,
                      on_result: Callable[[Any], None] | None = None) -> list[Any]:
        """Every unit's result, in unit order; ``on_result`` sees each as it arrives."""
        ...

    def close(self) -> None: ...


@runtime_checkable
class Learner(Protocol):
    """Trains the policy over the committed buffer view."""

    def train_round(self, view: Any, on_epoch: Callable[[int, float, float], None] | None = None) -> Any:
        """Train ``num_epochs_per_round`` epochs over ``view``; return the round's statistics."""
        ...

    def weights(self) -> dict[str, np.ndarray]:
        """The current weights as numpy arrays (what workers load)."""
        ...

    def state(self) -> LearnerState:
        """Model, optimiser and batch-generator state (what a checkpoint keeps)."""
        ...

    def load_state(self, state: LearnerState) -> None:
        """Continue from ``state`` (as ``state`` gave it); raises on weights of another architecture."""
        ...

    def close(self) -> None:
        """Release what the learner holds (processes, a Ray actor); a no-op for one in-process learner."""
        ...

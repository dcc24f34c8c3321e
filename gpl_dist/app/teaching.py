"""Teaching a trained policy: a person corrects it in words and it tries again (``gpl-dist teach``
in the terminal, ``gpl-dist serve`` in a browser).

A teaching episode is meta-test (Algorithm 2) with a person in the oracle's place: attempt 0
follows the instruction alone; after each attempt the person types a correction, and the next
attempt is conditioned on every earlier (attempt, correction) pair. It runs through the one
rollout loop (``workers.loop.Rollout``) with the person's corrections as the correction source.

**Seeded replay.** An episode is a function of (run, checkpoint, task, seed, corrections): attempt
``k`` is made by rolling attempts ``0..k`` out again with the recorded corrections, so the same
seeds draw the same actions (the rollout loop's seeding) and the earlier attempts come out as they
were (checked: a difference fails loudly). Nothing but the corrections is kept between attempts,
and any logged episode can be replayed exactly.

**What a person types** is checked before it is used (``check_correction``): at most
``MAX_TEXT_CHARS`` characters, no control characters, at least one word the policy knows. Words it
does not know are pointed out with the closest known phrasing (the domain's
``correction_phrasings``) and reach the policy as ``<unk>``, as any unknown word would; a text of
mostly unknown words (another language, noise) is refused.

**The log.** Every attempt of every episode is a row of ``<log dir>/<episode>.parquet`` (rewritten
atomically after each attempt; ``pyarrow.dataset.dataset(log_dir)`` reads them all): see
``LOG_SCHEMA``.
"""

from __future__ import annotations

import difflib
import io
import threading
import time
import unicodedata
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from gpl_dist.app.rendering import captioned_attempt_frames, gif_bytes
from gpl_dist.corrections import make_corrector
from gpl_dist.domains import get_domain
from gpl_dist.errors import UsageError
from gpl_dist.language import Vocabulary, split_words
from gpl_dist.records import Correction
from gpl_dist.roles import DomainSpec
from gpl_dist.seeding import correction_rng
from gpl_dist.splits import split_of, split_tasks
from gpl_dist.variants import TEACHABLE
from learner.checkpoint import LATEST
from learner.evaluate import load_trained_policy
from storage.fs import resolve
from workers.loop import Rollout

#: Longest correction or instruction a person may type, in characters.
MAX_TEXT_CHARS = 200
#: Corrections an episode may take (the runs train with 5; meta-test reaches 10).
DEFAULT_MAX_CORRECTIONS = 10
#: Kind recorded for a person's correction in ``Attempt.correction_kind``.
PERSON_KIND = "person"
#: Policy variants that read the words of a correction (GPR reads a reward; the others none).
TEACHABLE_VARIANTS = TEACHABLE


class TeachingError(UsageError):
    """What a person asked for cannot be done; the message says why and what to do instead."""


@dataclass(frozen=True)
class CorrectionCheck:
    """A typed correction (or instruction), checked against the policy's language.

    Attributes:
        text: what was typed, without surrounding white space (cut at ``MAX_TEXT_CHARS`` + 1).
        words: its words as the tokenizer splits them (lower-case letters only).
        token_ids: the ids the policy reads (``Vocabulary.encode``, padding dropped).
        unknown_words: words the policy does not know (read as ``<unk>``), in order, each once.
        suggestion: the closest phrasing the policy was trained on, when a word is unknown or the
            text is not one of them; None when it is one.
        problem: why the text cannot be used (empty, too long, control characters, no known
            word); None when it can.
    """

    text: str
    words: tuple[str, ...]
    token_ids: tuple[int, ...]
    unknown_words: tuple[str, ...]
    suggestion: str | None
    problem: str | None

    @property
    def usable(self) -> bool:
        return self.problem is None


def check_correction(domain: DomainSpec, text: str, what: str = "correction",
                     vocabulary: Vocabulary | None = None, phrasings: tuple[str, ...] | None = None) -> CorrectionCheck:
    """``CorrectionCheck`` of ``text`` for a policy of ``domain`` that reads ``vocabulary`` (default
    the domain's; a model trained with paraphrases reads more); ``what`` names it in messages,
    ``phrasings`` are the known sentences it is compared with (default the oracle's corrections)."""
    text = (text if isinstance(text, str) else "").strip()
    vocab = vocabulary or domain.vocabulary
    if phrasings is None:
        phrasings = domain.correction_phrasings() if domain.correction_phrasings else ()
    if len(text) > MAX_TEXT_CHARS:  # before any other work: a pasted book costs nothing
        return CorrectionCheck(text[: MAX_TEXT_CHARS + 1], (), (), (), None,
                               f"the {what} is {len(text)} characters long; at most {MAX_TEXT_CHARS} are read")
    words = tuple(split_words(text))
    ids = tuple(int(i) for i in vocab.encode(text) if i != vocab.pad_id)
    unknown = tuple(dict.fromkeys(w for w in words if vocab.token_id(w) == vocab.unk_id))
    suggestion = closest_phrasing(words, phrasings) if words else None
    if suggestion is not None and split_words(suggestion) == list(words):
        suggestion = None
    problem = None
    if not text:
        problem = f"the {what} is empty: type a sentence" + (f", for example '{phrasings[0]}'" if phrasings else "")
    elif len(words) > vocab.max_tokens:
        problem = f"the {what} has {len(words)} words; this policy reads at most {vocab.max_tokens}"
    elif any(unicodedata.category(ch) in ("Cc", "Cf") for ch in text):
        problem = f"the {what} holds control characters: type plain words"
    elif not words:
        problem = f"the {what} has no English words (letters a-z): this policy reads English"
    elif 2 * sum(w in unknown for w in words) > len(words):  # mostly <unk>: another language, or noise
        problem = (f"this policy knows too few of the words of the {what} (unknown: {', '.join(w[:40] for w in unknown[:8])}); "
                   "it reads English" + (f", for example '{suggestion}'" if suggestion else ""))
    return CorrectionCheck(text[: MAX_TEXT_CHARS + 1], words, ids, unknown, suggestion, problem)


def closest_phrasing(words: tuple[str, ...] | list[str], phrasings: tuple[str, ...]) -> str | None:
    """The phrasing most like ``words`` (difflib's ratio over the lower-case letters and spaces, so
    a misspelt word still counts for most of itself: "gry" is closest to "grey")."""
    typed = " ".join(words)
    best, best_score = None, -1.0
    for p in phrasings:
        score = difflib.SequenceMatcher(None, typed, " ".join(split_words(p)), autojunk=False).ratio()
        if score > best_score:
            best, best_score = p, score
    return best


@dataclass(frozen=True)
class TaughtAttempt:
    """One attempt of a teaching episode.

    Attributes:
        index: ``k``, from 0 (the instruction-only attempt).
        said_before: the instruction (``k = 0``) or the correction that led to this attempt.
        check: the ``CorrectionCheck`` of that correction; None for attempt 0.
        completion: the domain's completion at the end of the attempt, in [0, 1].
        success: whether the attempt solved the task.
        actions: int64 ``(T,)`` the actions taken.
        reset_seed: the seed the env was reset with (replaying ``actions`` from it redraws the attempt).
        picture: the attempt as text (the env's ``ansi`` rendering: the path and the final state).
        hint_shown: whether the oracle's hint was asked for before this attempt's correction.
        started_at: Unix time the attempt was asked for.
        seconds: wall time to make it.
    """

    index: int
    said_before: str
    check: CorrectionCheck | None
    completion: float
    success: bool
    actions: np.ndarray
    reset_seed: int
    picture: str
    hint_shown: bool
    started_at: float
    seconds: float


class Teacher:
    """A run's trained policy, loaded once and shared by every teaching episode (thread-safe).

    Raises ``TeachingError`` for a policy a person cannot correct in words (one that takes no
    corrections, or GPR, which reads rewards).
    """

    def __init__(self, run_dir: str | Path, checkpoint: str | None = None,
                 max_corrections: int = DEFAULT_MAX_CORRECTIONS, greedy: bool = False, allow_foreign: bool = False):

        self.run_dir = str(Path(run_dir).resolve())
        #: the checkpoint file taught (absolute), as the log records it
        self.checkpoint = str(Path(checkpoint).resolve() if checkpoint else Path(self.run_dir) / "checkpoints" / LATEST)
        #: a checkpoint of another run, domain or model, taught as asked (``--foreign-checkpoint``)
        self.foreign = allow_foreign
        self.cfg, self.model, self.round_index = load_trained_policy(run_dir, checkpoint, allow_foreign=allow_foreign)
        variant = self.cfg.model.variant
        if variant not in TEACHABLE_VARIANTS:
            raise TeachingError(f"the policy of {run_dir} (model.variant {variant}) does not read corrections in words: "
                                f"teach a run of {', '.join(TEACHABLE_VARIANTS)}")
        if max_corrections < 1:
            raise TeachingError(f"max corrections must be at least 1, got {max_corrections}")
        self.model.eval()
        self.domain = _domain(self.cfg.env.domain)
        self.max_corrections = max_corrections
        self.greedy = greedy
        self.lock = threading.Lock()  # one rollout at a time: they share the model and the cores

    def resolve_task(self, task_id: int | None = None, instruction: str | None = None, seed: int = 0,
                     split: str = "test") -> int:
        """The task to teach: ``task_id``; else one of ``split``'s tasks whose instruction is
        ``instruction``; else one of ``split``'s tasks, drawn with ``seed``."""

        d = self.domain
        _check_seed(seed)
        if task_id is not None:
            if isinstance(task_id, bool) or not isinstance(task_id, (int, np.integer)) or not 0 <= task_id < d.num_tasks:
                shown = str(task_id) if len(str(task_id)) <= 12 else f"{str(task_id)[:6]}... ({len(str(task_id))} digits)"
                raise TeachingError(f"task {shown} is outside 0..{d.num_tasks - 1} of {d.name}")
            return int(task_id)
        tasks = split_tasks(d.name, split)
        rng = np.random.default_rng([seed, 0x7EAC])
        if instruction is None:
            return int(tasks[int(rng.integers(len(tasks)))])
        by_instruction: dict[str, list[int]] = {}
        for t in tasks:
            by_instruction.setdefault(instruction_of(d, t), []).append(int(t))
        check = check_correction(d, instruction, "instruction", self.model.vocabulary, tuple(by_instruction))
        if check.problem:
            raise TeachingError(check.problem)
        matching = [ts for text, ts in by_instruction.items() if tuple(split_words(text)) == check.words]
        if not matching:
            raise TeachingError(f"no {split} task has the instruction '{check.text}' (instructions are matched word for "
                                f"word); the closest is '{check.suggestion}'")
        return matching[0][int(rng.integers(len(matching[0])))]

    def episode(self, task_id: int, seed: int = 0, source: str = "terminal") -> "TeachingEpisode":
        """A new teaching episode of ``task_id`` (``resolve_task``) with action sampling seeded by ``seed``."""
        _check_seed(seed)
        return TeachingEpisode(self, int(task_id), int(seed), source)

    def replay(self, task_id: int, seed: int, corrections: list[str]) -> tuple:
        """Attempts ``0..len(corrections)`` of ``task_id``, the ``k``-th after ``corrections[k-1]``."""

        given = iter(corrections)

        def person(env, rng) -> Correction:
            return Correction(next(given), PERSON_KIND)

        rollout = Rollout(self.domain, self.model, person, greedy=self.greedy,
                          end_aligned=self.cfg.model.trajectory_ends_at_last_state)
        with self.lock:
            result = rollout.run([task_id], len(corrections), seed, split="teach")
        if result.failures:
            raise TeachingError(str(result.failures[0]))
        return result.attempts

    def oracle_hint(self, task_id: int, seed: int, attempt_index: int, reset_seed: int, actions: np.ndarray) -> str:
        """What the run's oracle would say after the attempt (``actions`` replayed from ``reset_seed``)."""

        env = self.domain.make_env(task_id)
        env.reset(seed=reset_seed)
        for a in actions.tolist():
            env.step(a)
        oracle = make_corrector(self.domain.name, self.cfg.env.correction_kind)
        return oracle.correct(env, correction_rng(seed, task_id, attempt_index)).text


#: Splits named in the log, the first holding the task (``gpl_dist.splits.split_of``).
SPLIT_ORDER = ("test", "train", "valid", "heldout_test", "heldout_train")
#: Seeds are mixed as 32-bit words (``gpl_dist.seeding``): larger ones would repeat smaller ones.
MAX_SEED = 2**32 - 1


def _check_seed(seed: int) -> None:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed <= MAX_SEED:
        raise TeachingError(f"the seed must be a whole number in 0..{MAX_SEED}, got {str(seed)[:24]}")


def instruction_of(domain: DomainSpec, task_id: int) -> str:
    """The instruction of ``task_id`` (``TaskEnv.instruction``)."""
    env: Any = domain.make_env(task_id)
    return str(env.instruction)


def _domain(name: str) -> DomainSpec:

    return get_domain(name)


@dataclass
class TeachingEpisode:
    """One person teaching one task: the attempts so far and the corrections between them.

    Nothing of one episode is shared with another but the ``Teacher``'s read-only policy.
    """

    teacher: Teacher
    task_id: int
    seed: int
    source: str
    episode_id: str = field(default_factory=lambda: uuid.uuid4().hex[:16])
    attempts: list[TaughtAttempt] = field(default_factory=list)
    _hint_asked: bool = False
    _gifs: dict[int, bytes] = field(default_factory=dict)  # drawn once, on first request

    @property
    def instruction(self) -> str:
        return instruction_of(self.teacher.domain, self.task_id)

    @property
    def split(self) -> str:
        """The split holding the task (``test``: held out from training)."""
        return split_of(self.teacher.domain.name, self.task_id, SPLIT_ORDER)

    @property
    def solved(self) -> bool:
        return bool(self.attempts) and self.attempts[-1].success

    @property
    def corrections_left(self) -> int:
        return self.teacher.max_corrections - max(0, len(self.attempts) - 1)

    def check(self, text: str) -> CorrectionCheck:
        """``check_correction`` against this episode's policy (for highlighting as one types)."""
        return check_correction(self.teacher.domain, text, vocabulary=self.teacher.model.vocabulary)

    def attempt(self, correction: str | None = None) -> TaughtAttempt:
        """The next attempt: the first one without ``correction``, each later one after it.

        ``TeachingError`` (and no change to the episode) when the correction is missing, given
        before the first attempt, unusable, or after the task is solved or the budget spent.
        """
        given = correction is not None and correction.strip() != ""
        if not self.attempts:
            if given:
                raise TeachingError("make the first attempt before correcting: it follows the instruction alone")
            check = None
        else:
            if self.solved:
                raise TeachingError("the task is solved: start a new episode to teach another")
            if self.corrections_left <= 0:
                raise TeachingError(f"this episode has used its {self.teacher.max_corrections} corrections: start a new one")
            check = self.check(correction or "")
            if check.problem:
                raise TeachingError(check.problem)
        started = time.time()
        texts = [a.check.text for a in self.attempts[1:] if a.check] + ([check.text] if check else [])
        replayed = self.teacher.replay(self.task_id, self.seed, texts)
        self._check_replay(replayed)
        new = replayed[-1]
        taught = TaughtAttempt(
            index=new.attempt_index, said_before=check.text if check else new.instruction, check=check,
            completion=float(new.completion), success=bool(new.success), actions=new.actions.copy(),
            reset_seed=int(new.seed), picture=self._picture(new.seed, new.actions), hint_shown=self._hint_asked,
            started_at=started, seconds=time.time() - started)
        self.attempts.append(taught)
        self._hint_asked = False
        return taught

    def hint(self) -> str:
        """What the run's oracle would say about the latest attempt (``--hint``; the page's button)."""
        if not self.attempts:
            raise TeachingError("there is no attempt to correct yet: make the first attempt")
        last = self.attempts[-1]
        self._hint_asked = True
        return self.teacher.oracle_hint(self.task_id, self.seed, last.index, last.reset_seed, last.actions)

    def _check_replay(self, replayed: tuple) -> None:
        if len(replayed) != len(self.attempts) + 1:
            raise RuntimeError(f"replaying episode {self.episode_id} gave {len(replayed)} attempts, not {len(self.attempts) + 1}")
        for old, again in zip(self.attempts, replayed):
            if not np.array_equal(old.actions, again.actions):
                raise RuntimeError(f"replaying episode {self.episode_id}: attempt {old.index} came out differently")

    def _picture(self, reset_seed: int, actions: np.ndarray) -> str:
        env = self.teacher.domain.make_env(self.task_id, render_mode="ansi")
        env.reset(seed=reset_seed)
        for a in actions.tolist():
            env.step(a)
        return str(env.render())

    def gif(self, index: int) -> bytes:
        """Attempt ``index`` as an animated GIF, captioned with what led to it and its completion."""

        if not 0 <= index < len(self.attempts):
            raise TeachingError(f"attempt {index} does not exist (this episode has {len(self.attempts)})")
        if index in self._gifs:
            return self._gifs[index]
        a = self.attempts[index]
        top = f"attempt {index + 1}: {'instruction' if index == 0 else 'correction'}: {a.said_before}"
        bottom = f"completion {a.completion:.2f}" + (" - solved" if a.success else "")
        frames = captioned_attempt_frames(self.teacher.domain.name, self.task_id, a.actions, a.reset_seed, top, bottom)
        self._gifs[index] = gif_bytes(frames)
        return self._gifs[index]

    def log_rows(self) -> list[dict]:
        """One row per attempt (``LOG_SCHEMA``)."""
        rows = []
        for a in self.attempts:
            rows.append({
                "episode": self.episode_id, "source": self.source, "run_dir": self.teacher.run_dir,
                "checkpoint": self.teacher.checkpoint, "checkpoint_round": self.teacher.round_index,
                "greedy": self.teacher.greedy, "split": self.split,
                "domain": self.teacher.domain.name,
                "task_id": self.task_id, "seed": self.seed, "attempt": a.index, "instruction": self.instruction,
                "correction": a.check.text if a.check else "",
                "correction_tokens": list(a.check.token_ids) if a.check else [],
                "unknown_words": list(a.check.unknown_words) if a.check else [],
                "hint_shown": a.hint_shown, "completion": a.completion, "success": a.success,
                "started_at": int(a.started_at * 1e6), "seconds": a.seconds,
            })
        return rows


#: The teaching log, one row per attempt: the run dir and checkpoint file (absolute), greedy or
#: sampled actions, the task's split; ``correction`` is the correction that led to the attempt
#: (empty for attempt 0), with its token ids and unknown words; ``hint_shown`` whether the
#: oracle's hint was asked for before it; ``started_at`` when the attempt was asked for. With the
#: seed and the corrections, what an episode needs to be replayed.
LOG_SCHEMA = pa.schema([
    ("episode", pa.string()), ("source", pa.string()), ("run_dir", pa.string()), ("checkpoint", pa.string()),
    ("checkpoint_round", pa.int64()), ("greedy", pa.bool_()), ("split", pa.string()),
    ("domain", pa.string()), ("task_id", pa.int64()), ("seed", pa.int64()), ("attempt", pa.int64()),
    ("instruction", pa.string()), ("correction", pa.string()), ("correction_tokens", pa.list_(pa.int64())),
    ("unknown_words", pa.list_(pa.string())), ("hint_shown", pa.bool_()), ("completion", pa.float64()),
    ("success", pa.bool_()), ("started_at", pa.timestamp("us", tz="UTC")), ("seconds", pa.float64()),
])


def write_episode_log(episode: TeachingEpisode, log_dir: str | Path) -> str:
    """Write (replace) ``<log_dir>/<episode>.parquet`` atomically; returns its path."""
    import pyarrow.parquet as pq


    table = pa.Table.from_pylist(episode.log_rows(), schema=LOG_SCHEMA)
    sink = io.BytesIO()
    pq.write_table(table, sink)
    loc = resolve(str(log_dir))
    loc.makedirs("")
    name = f"{episode.episode_id}.parquet"
    loc.write_bytes_atomic(name, sink.getvalue())
    return loc.full_url(name)

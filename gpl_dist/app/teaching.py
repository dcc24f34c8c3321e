"""Teaching a trained policy: a person corrects it in words and it tries again (``gpl-dist teach``
in the terminal, ``gpl-dist serve`` in a browser).

A teaching episode is meta-test (Algorithm 2) with a person in the oracle's place: attempt 0
follows the instruction alone; after each attempt the person types a correction, and the next
attempt is conditioned on every earlier (attempt, correction) pair. It runs through the one
rollout loop (``workers.rollout.Rollout``) with the person's corrections as the correction source.

**Seeded replay.** An episode is a function of (run, checkpoint, task, seed, corrections): attempt
``k`` is made by rolling attempts ``0..k`` out again with the recorded corrections, so the same
seeds draw the same actions (the rollout loop's seeding) and the earlier attempts come out as they
were (checked: a difference fails loudly). Nothing but the corrections is kept between attempts,
and any logged episode can be replayed exactly.

**What a person types** is checked before it is used (``check_correction``): at most
``MAX_TEXT_CHARS`` characters, no control characters, at least one word the policy knows. Words it
does not know are pointed out with the closest phrasing the policy was trained on (the domain's
``correction_phrasings`` of the run's correction kind, with their training paraphrases when the
run was trained with them: ``Teacher.phrasings``) and reach the policy as ``<unk>``, as any
unknown word would; a text of mostly unknown words (another language, noise) is refused.

**The log.** Every attempt of every episode is a row of ``<log dir>/<episode>.parquet`` (rewritten
atomically after each attempt; ``pyarrow.dataset.dataset(log_dir)`` reads them all): see
``LOG_SCHEMA``.

**Files on disk.** Every file a reader may see (a log, a GIF) is written under a temporary name,
``_tmp-<hex>-<name>``, then renamed into place (``write_atomic``, through
``gpl_dist.atomic.write_atomic``); a write that fails removes its
temporary and raises ``TeachingWriteError`` (one line: the file and the cause). Readers skip the
names pyarrow skips, those starting with ``_`` or ``.`` (``gpl_dist.app.export.is_temporary``). A
process writing into a teaching folder (``serve``, ``teach``) holds its ``.writers.lock`` shared
(``teaching_writer``); ``teaching_leftovers`` removes the temporaries no live writer can own (a
``kill -9`` leaves them), never following a symbolic link.
"""

from __future__ import annotations

import contextlib
import difflib
import errno
import io
import os
import threading
import time
import unicodedata
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Collection, Iterator, TypeVar

import numpy as np
import pyarrow as pa

from gpl_dist import atomic
from gpl_dist.app import rendering
from gpl_dist.app.policy import load_policy
from gpl_dist.app.rendering import (
    Replay,
    _captioned,
    caption_lines,
    frame_steps,
    step_caption,
    still_frame,
)
from gpl_dist.app.replay import step_through
from gpl_dist.domains import get_domain
from gpl_dist.errors import UsageError
from gpl_dist.language import Vocabulary, split_words
from gpl_dist.records import Attempt
from gpl_dist.roles import DomainSpec
from gpl_dist.splits import split_of, split_tasks
from gpl_dist.variants import TEACHABLE

#: Longest correction or instruction a person may type, in characters.
MAX_TEXT_CHARS = 200
#: Corrections an episode may take (the runs train with 5; meta-test reaches 10).
DEFAULT_MAX_CORRECTIONS = 10
#: Frames of an attempt in its film strip (``TeachingEpisode.film_strip``), and their width in pixels.
STRIP_FRAMES = 34
STRIP_FRAME_PX = 220
#: Policy variants that read the words of a correction (GPR reads a reward; the others none).
TEACHABLE_VARIANTS = TEACHABLE


class TeachingError(UsageError):
    """What a person asked for cannot be done; the message says why and what to do instead."""


#: ``errno`` values of a write failure that means no space (a full disk, a spent quota).
NO_SPACE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT})


class TeachingWriteError(TeachingError):
    """A file of a teaching folder could not be written: the message (one line) names the file and
    the cause; ``errno`` is the cause's (None when it is not the system's), ``no_space`` whether it
    is a full disk or a spent quota."""

    def __init__(self, message: str, errno_: int | None = None):
        super().__init__(" ".join(message.split()))
        self.errno = errno_

    @property
    def no_space(self) -> bool:
        return self.errno in NO_SPACE_ERRNOS


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
        warning: the text is a sentence the domain's oracle says, but of another correction kind
            than the policy was trained on (it may not follow it); None otherwise.
    """

    text: str
    words: tuple[str, ...]
    token_ids: tuple[int, ...]
    unknown_words: tuple[str, ...]
    suggestion: str | None
    problem: str | None
    warning: str | None = None

    @property
    def usable(self) -> bool:
        return self.problem is None


def check_correction(domain: DomainSpec, text: str, what: str = "correction",
                     vocabulary: Vocabulary | None = None, phrasings: tuple[str, ...] | None = None,
                     kind: str | None = None, paraphrases: bool = False) -> CorrectionCheck:
    """``CorrectionCheck`` of ``text`` for a policy of ``domain`` that reads ``vocabulary`` (default
    the domain's; a model trained with paraphrases reads more); ``what`` names it in messages,
    ``phrasings`` are the known sentences it is compared with (default: those the policy trained
    on, ``DomainSpec.phrasings_of(kind, paraphrases)``: correction ``kind``'s, the run's, with their
    training paraphrases when it was trained with them; every kind's without a kind). A sentence the
    policy never trained on but the domain knows (another kind's, or a paraphrase it was not
    trained with) is usable, with a warning saying so."""
    text = (text if isinstance(text, str) else "").strip()
    vocab = vocabulary or domain.vocabulary
    if phrasings is None:
        phrasings = domain.phrasings_of(kind, paraphrases)
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
    warning = None
    if kind is not None and not problem and suggestion is not None:
        said = " ".join(words)
        if said in _said(domain.phrasings_of(None, paraphrases)):
            warning = (f"this policy was trained on '{kind}' corrections and never on this sentence (another kind's): "
                       "it may not follow it")
        elif said in _said(domain.paraphrased(domain.phrasings_of(None), ("train", "heldout"))):
            trained = "with the training paraphrases only" if paraphrases else "without paraphrases"
            warning = (f"this policy was trained on '{kind}' corrections {trained} and never on this phrasing "
                       "(a paraphrase): it may not follow it")
    return CorrectionCheck(text[: MAX_TEXT_CHARS + 1], words, ids, unknown, suggestion, problem, warning)


def _said(phrasings: tuple[str, ...]) -> set[str]:
    """``phrasings`` as their lower-case words joined by spaces (how a typed text is compared)."""
    return {" ".join(split_words(p)) for p in phrasings}


def example_phrasings(phrasings: tuple[str, ...], count: int = 6) -> list[str]:
    """``count`` of ``phrasings`` spread over them (every n-th), the examples a person is shown."""
    return list(phrasings[:: max(1, len(phrasings) // count)][:count])


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
        record: the rollout's ``Attempt`` (the trajectory; its ``correction`` is the one after it).
        typed: what the person typed, when the policy was sent the closest known phrasing instead
            (``:use`` in the terminal, "use it" in the page); else ``said_before``.
        solved_at: the step at which the attempt first solved the task (None: never); it runs on after.
        key: this attempt's identity (an undone attempt and the one made in its place differ).
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
    record: Attempt
    typed: str
    solved_at: int | None
    key: str = field(default_factory=lambda: uuid.uuid4().hex[:12])


class Teacher:
    """A run's trained policy, loaded once and shared by every teaching episode (thread-safe).

    Raises ``TeachingError`` for a policy a person cannot correct in words (one that takes no
    corrections, or GPR, which reads rewards).
    """

    def __init__(self, run_dir: str | Path, checkpoint: str | None = None,
                 max_corrections: int = DEFAULT_MAX_CORRECTIONS, greedy: bool = False, allow_foreign: bool = False):

        self.policy = load_policy(run_dir, checkpoint, greedy=greedy, allow_foreign=allow_foreign)
        self.run_dir = self.policy.run_dir
        #: the checkpoint file taught (absolute), as the log records it
        self.checkpoint = self.policy.checkpoint
        #: a checkpoint of another run, domain or model, taught as asked (``--foreign-checkpoint``)
        self.foreign = allow_foreign
        self.cfg, self.model, self.round_index = self.policy.cfg, self.policy.model, self.policy.round_index
        variant = self.cfg.model.variant
        if variant not in TEACHABLE_VARIANTS:
            raise TeachingError(f"the policy of {run_dir} (model.variant {variant}) does not read corrections in words: "
                                f"teach a run of {', '.join(TEACHABLE_VARIANTS)}")
        if max_corrections < 1:
            raise TeachingError(f"max corrections must be at least 1, got {max_corrections}")
        self.domain = self.policy.domain
        #: the correction kind the policy was trained on, and whether with the training paraphrases
        self.kind: str = self.cfg.env.correction_kind
        self.paraphrases = bool(self.cfg.model.paraphrases)
        #: the corrections the policy was trained on (the closest of them is suggested)
        self.phrasings = self.domain.phrasings_of(self.kind, self.paraphrases)
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
            by_instruction.setdefault(d.instruction_of(t), []).append(int(t))
        check = check_correction(d, instruction, "instruction", self.model.vocabulary, tuple(by_instruction))
        if check.problem:
            raise TeachingError(check.problem)
        matching = [ts for text, ts in by_instruction.items() if tuple(split_words(text)) == check.words]
        if not matching:
            raise TeachingError(f"no {split} task has the instruction '{check.text}' (instructions are matched word for "
                                f"word); the closest is '{check.suggestion}'")
        return matching[0][int(rng.integers(len(matching[0])))]

    def check(self, text: str) -> CorrectionCheck:
        """``check_correction`` of a correction against what this policy reads and was trained on
        (its vocabulary, correction kind and paraphrases)."""
        return check_correction(self.domain, text, vocabulary=self.model.vocabulary, phrasings=self.phrasings,
                                kind=self.kind, paraphrases=self.paraphrases)

    def examples(self, count: int = 6) -> list[str]:
        """``count`` corrections this policy was trained on, to show a person: its kind's sentences,
        spread over them, every second one said as a training paraphrase when it was trained with them."""
        canonical = example_phrasings(self.domain.phrasings_of(self.kind), count)
        if not self.paraphrases:
            return canonical
        shown = []
        for i, text in enumerate(canonical):
            others = self.domain.paraphrased([text], ("train",))[1:]
            shown.append(others[0] if i % 2 and others else text)
        return shown

    def episode(self, task_id: int, seed: int = 0, source: str = "terminal") -> "TeachingEpisode":
        """A new teaching episode of ``task_id`` (``resolve_task``) with action sampling seeded by ``seed``."""
        _check_seed(seed)
        return TeachingEpisode(self, int(task_id), int(seed), source)

    def replay(self, task_id: int, seed: int, corrections: list[str]) -> tuple[Attempt, ...]:
        """Attempts ``0..len(corrections)`` of ``task_id``, the ``k``-th after ``corrections[k-1]``."""
        with self.lock:
            try:
                return self.policy.attempts(task_id, corrections, seed=seed)
            except UsageError as err:
                raise TeachingError(str(err)) from None

    def oracle_hint(self, attempt: Attempt, seed: int) -> str:
        """What the run's oracle would say after ``attempt`` (of an episode made with ``seed``): a
        sentence of the run's correction kind, said canonically (one of ``phrasings``, with or
        without paraphrases)."""
        return self.policy.oracle_correction(attempt, seed)


#: Splits named in the log first, the first holding the task (``gpl_dist.splits.split_of``); a
#: domain's other splits follow in its declared order.
SPLIT_ORDER = ("test", "train", "valid", "heldout_test", "heldout_train")
#: Seeds are mixed as 32-bit words (``gpl_dist.seeding``): larger ones would repeat smaller ones.
MAX_SEED = 2**32 - 1


def _check_seed(seed: int) -> None:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed <= MAX_SEED:
        raise TeachingError(f"the seed must be a whole number in 0..{MAX_SEED}, got {str(seed)[:24]}")


@dataclass
class TeachingEpisode:
    """One person teaching one task: the attempts so far and the corrections between them.

    Nothing of one episode is shared with another but the ``Teacher``'s read-only policy. ``undo``
    takes the last correction back (the attempt it led to is kept in ``undone`` and logged as
    such); ``oracle_attempt`` makes the next attempt with the oracle's correction instead, beside
    the episode (``oracle_branch``), without adding it.
    """

    teacher: Teacher
    task_id: int
    seed: int
    source: str
    episode_id: str = field(default_factory=lambda: uuid.uuid4().hex[:16])
    attempts: list[TaughtAttempt] = field(default_factory=list)
    undone: list[TaughtAttempt] = field(default_factory=list)
    oracle_branch: dict[int, TaughtAttempt] = field(default_factory=dict)
    _hint_asked: bool = False

    @property
    def instruction(self) -> str:
        return self.teacher.domain.instruction_of(self.task_id)

    @property
    def split(self) -> str:
        """The split holding the task (``test``: held out from training): the first of
        ``SPLIT_ORDER``, then of the domain's other splits in its declared order, that holds it."""
        domain = self.teacher.domain
        return split_of(domain.name, self.task_id, SPLIT_ORDER + tuple(n for n in domain.split_names if n not in SPLIT_ORDER))

    @property
    def solved(self) -> bool:
        return bool(self.attempts) and self.attempts[-1].success

    @property
    def corrections_left(self) -> int:
        return self.teacher.max_corrections - max(0, len(self.attempts) - 1)

    def check(self, text: str) -> CorrectionCheck:
        """``Teacher.check``: against this episode's policy (for highlighting as one types)."""
        return self.teacher.check(text)

    def attempt(self, correction: str | None = None, typed: str | None = None) -> TaughtAttempt:
        """The next attempt: the first one without ``correction``, each later one after it.
        ``typed`` is what the person typed when ``correction`` is the closest phrasing put in its place.

        ``TeachingError`` (and no change to the episode) when the correction is missing, given
        before the first attempt, unusable, or after the task is solved or the budget spent.
        """
        check = self._checked(correction)
        started = time.time()
        taught = self._make([*self._sent(), check], started, typed)
        self.attempts.append(taught)
        self._hint_asked = False
        return taught

    def undo(self) -> TaughtAttempt:
        """Take the last correction back: its attempt leaves the episode (kept in ``undone``, and
        logged with ``undone`` true); returns it. The episode replays from its seed, so the next
        attempt after another correction is exactly what it would have been without the undone one."""
        if len(self.attempts) < 2:
            raise TeachingError("there is no correction to undo: the first attempt follows the instruction alone")
        last = self.attempts.pop()
        self.undone.append(last)
        # an oracle's attempt after the undone one followed it: gone too (one at the undone index stays valid)
        self.oracle_branch = {k: v for k, v in self.oracle_branch.items() if k <= len(self.attempts)}
        return last

    def oracle_attempt(self) -> TaughtAttempt:
        """The next attempt as the run's oracle would have it corrected, made beside the episode."""
        index = len(self.attempts)
        if index in self.oracle_branch:
            return self.oracle_branch[index]
        check = self._checked(self.hint())
        self.oracle_branch[index] = self._make([*self._sent(), check], time.time(), None)
        return self.oracle_branch[index]

    def hint(self) -> str:
        """What the run's oracle would say about the latest attempt (``--hint``; the page's button)."""
        if not self.attempts:
            raise TeachingError("there is no attempt to correct yet: make the first attempt")
        self._hint_asked = True
        return self.teacher.oracle_hint(self.attempts[-1].record, self.seed)

    def _checked(self, correction: str | None) -> CorrectionCheck | None:
        given = correction is not None and correction.strip() != ""
        if not self.attempts:
            if given:
                raise TeachingError("make the first attempt before correcting: it follows the instruction alone")
            return None
        if self.solved:
            raise TeachingError("the task is solved: start a new episode to teach another")
        if self.corrections_left <= 0:
            raise TeachingError(f"this episode has used its {self.teacher.max_corrections} corrections: start a new one")
        check = self.check(correction or "")
        if check.problem:
            raise TeachingError(check.problem)
        return check

    def _sent(self) -> list[CorrectionCheck | None]:
        return [a.check for a in self.attempts[1:]]

    def _make(self, checks: list[CorrectionCheck | None], started: float, typed: str | None) -> TaughtAttempt:
        texts = [c.text for c in checks if c is not None]
        replayed = self.teacher.replay(self.task_id, self.seed, texts)
        self._check_replay(replayed, len(texts) + 1)
        new, check = replayed[-1], checks[-1] if checks else None
        said = check.text if check else new.instruction
        solved_at = step_through(self.teacher.domain, self.task_id, new.actions, new.seed).solved_at
        return TaughtAttempt(
            index=new.attempt_index, said_before=said, check=check,
            completion=float(new.completion), success=bool(new.success), actions=new.actions.copy(),
            reset_seed=int(new.seed), picture=self._picture(new.seed, new.actions, solved_at), hint_shown=self._hint_asked,
            started_at=started, seconds=time.time() - started, record=new, solved_at=solved_at,
            typed=said if typed is None else _plain(typed)[:MAX_TEXT_CHARS])

    def _check_replay(self, replayed: tuple, expected: int) -> None:
        if len(replayed) != expected:
            raise RuntimeError(f"replaying episode {self.episode_id} gave {len(replayed)} attempts, not {expected}")
        for old, again in zip(self.attempts, replayed):
            if not np.array_equal(old.actions, again.actions):
                raise RuntimeError(f"replaying episode {self.episode_id}: attempt {old.index} came out differently")

    def _picture(self, reset_seed: int, actions: np.ndarray, solved_at: int | None) -> str:
        env = step_through(self.teacher.domain, self.task_id, actions, reset_seed, render_mode="ansi").env
        ran = len(actions)
        note = (f"solved at step {solved_at} of {ran}" + (f" (the attempt ran on to step {ran})" if solved_at < ran else "")
                if solved_at is not None else f"not solved in {ran} steps")
        return f"{env.render()}\n{note}"

    def logged(self, change: Callable[["TeachingEpisode"], object], log_dir: str | Path) -> None:
        """``change`` the episode (``attempt``, ``undo``, ``oracle_attempt``), then write its log
        (``write_episode_log``). When the log cannot be written (``TeachingWriteError``), the episode
        is put back as it was before ``change``: what a person is shown is what is logged."""
        saved = (list(self.attempts), list(self.undone), dict(self.oracle_branch), self._hint_asked)
        change(self)
        try:
            write_episode_log(self, log_dir)
        except BaseException:
            self.attempts[:], self.undone[:] = saved[0], saved[1]
            self.oracle_branch, self._hint_asked = saved[2], saved[3]
            raise

    def find(self, index: int, oracle: bool = False) -> TaughtAttempt:
        """Attempt ``index`` of the episode (or of the oracle's branch)."""
        found = self.oracle_branch.get(index) if oracle else (self.attempts[index] if 0 <= index < len(self.attempts) else None)
        if found is None:
            raise TeachingError(f"attempt {index} does not exist (this episode has {len(self.attempts)})")
        return found

    def gif(self, index: int, oracle: bool = False) -> bytes:
        """Attempt ``index`` as an animated GIF, captioned with what led to it (wrapped, whole), the
        step, its completion and the step it solved the task at (``rendering.captioned_attempt_frames``,
        drawn from the frames it shows only)."""
        from PIL import Image

        a = self.find(index, oracle)
        name = self.teacher.domain.name
        top = f"attempt {index + 1}: {'instruction' if index == 0 else 'correction'}: {a.said_before}"
        course = step_through(name, self.task_id, a.actions, a.reset_seed)  # the captions' numbers
        last = len(course.completion) - 1
        lines = caption_lines(top)

        def captioned(t: int, frame: np.ndarray) -> Any:
            return Image.fromarray(_captioned(frame, [*lines, step_caption(t, last, course)]))

        shown = frame_steps(name, last)
        drawn, replay = drawn_at(name, self.task_id, a.actions, a.reset_seed, shown[:-1], captioned)
        images = [drawn[t] for t in shown[:-1]] + [captioned(last, still_frame(replay))]
        out = io.BytesIO()  # as rendering.gif_bytes: the last frame, path drawn, held for a moment
        images[0].save(out, format="GIF", save_all=True, append_images=images[1:] + [images[-1]] * 6,
                       duration=int(1000 / 8), loop=0)
        return out.getvalue()

    def strip_steps(self, index: int, oracle: bool = False) -> list[int]:
        """The steps ``film_strip`` draws attempt ``index`` at, in order."""
        a = self.find(index, oracle)
        return frame_steps(self.teacher.domain.name, len(a.actions), -(-len(a.actions) // (STRIP_FRAMES - 1)))

    def film_strip(self, index: int, oracle: bool = False) -> bytes:
        """Attempt ``index`` as one PNG: its frames at ``strip_steps``, ``STRIP_FRAME_PX`` wide, side by side."""
        from PIL import Image

        a = self.find(index, oracle)
        steps = self.strip_steps(index, oracle)

        def small(t: int, frame: np.ndarray) -> Any:
            image = Image.fromarray(frame)
            return image.resize((STRIP_FRAME_PX, round(image.height * STRIP_FRAME_PX / image.width)))

        drawn, replay = drawn_at(self.teacher.domain.name, self.task_id, a.actions, a.reset_seed, steps, small)
        frames = [drawn[t] for t in steps]
        strip = Image.new("RGB", (STRIP_FRAME_PX * len(frames), frames[0].height), "white")
        for i, f in enumerate(frames):
            strip.paste(f, (i * STRIP_FRAME_PX, 0))
        return _png(strip)

    def still(self, index: int, oracle: bool = False) -> bytes:
        """Attempt ``index``'s final state as a PNG, its path drawn and the step it solved the task ringed."""
        from PIL import Image

        a = self.find(index, oracle)
        _, replay = drawn_at(self.teacher.domain.name, self.task_id, a.actions, a.reset_seed, (), lambda t, f: f)
        return _png(Image.fromarray(still_frame(replay)))

    def log_rows(self) -> list[dict]:
        """One row per attempt made, undone ones included (``LOG_SCHEMA``), in the order they were made."""
        rows = []
        for a, undone in sorted([(a, False) for a in self.attempts] + [(a, True) for a in self.undone],
                                key=lambda x: x[0].started_at):
            rows.append({
                "episode": self.episode_id, "source": self.source, "run_dir": self.teacher.run_dir,
                "checkpoint": self.teacher.checkpoint, "checkpoint_round": self.teacher.round_index,
                "greedy": self.teacher.greedy, "split": self.split,
                "domain": self.teacher.domain.name,
                "task_id": self.task_id, "seed": self.seed, "attempt": a.index, "instruction": self.instruction,
                "correction_before": a.check.text if a.check else "",
                "typed": a.typed if a.check else "",
                "correction_tokens": list(a.check.token_ids) if a.check else [],
                "unknown_words": list(a.check.unknown_words) if a.check else [],
                "hint_shown": a.hint_shown, "completion": a.completion, "success": a.success,
                "solved_at": a.solved_at, "undone": undone,
                "started_at": int(a.started_at * 1e6), "seconds": a.seconds,
            })
        return rows


T = TypeVar("T")


def drawn_at(domain_name: str, task_id: int, actions: np.ndarray, reset_seed: int, steps: Collection[int],
             draw: Callable[[int, np.ndarray], T]) -> tuple[dict[int, T], Replay]:
    """An attempt stepped again from ``reset_seed`` through ``actions`` (``gpl_dist.app.replay.step_through``),
    drawn only at ``steps``: each frame is handed to ``draw`` (step, RGB frame) as it is drawn and not
    kept, so one full-size frame is held at a time, not one a step (101 frames of 1.1 MB a
    multi-room attempt). Returns what ``draw`` made, by step, and the replay: every step's
    completion, success and picture points, and the final frame alone (what ``still_frame`` draws)."""
    mode = rendering.picture_mode(domain_name)  # as replay_attempt draws: rgb_array, else text, else a card
    last = min(len(actions), get_domain(domain_name).steps_per_attempt)
    wanted = set(steps)
    drawn: dict[int, T] = {}
    points: list[tuple] = []
    final: list[np.ndarray] = []

    def visit(t: int, env: Any, info: dict) -> None:
        points.append(rendering._points(env))
        if t in wanted or t == last:
            frame = rendering.draw(env, mode, info)
            if t in wanted:
                drawn[t] = draw(t, frame)
            if t == last:
                final.append(frame)

    course = step_through(domain_name, task_id, actions, reset_seed, render_mode=mode, visit=visit)
    return drawn, Replay(final, points, course.completion, course.success)


def _png(image: Any) -> bytes:
    out = io.BytesIO()
    image.save(out, format="PNG")
    return out.getvalue()


def _plain(text: str) -> str:
    """``text`` as valid UTF-8 (a lone surrogate from a JSON body cannot be written to Parquet)."""
    return str(text).encode("utf-8", "replace").decode("utf-8")


#: The teaching log, one row per attempt made: the run dir and checkpoint file (absolute), greedy
#: or sampled actions, the task's split. ``correction_before`` is the correction that led to the
#: attempt, as the policy read it (empty for attempt 0), with its token ids and unknown words;
#: ``typed`` what the person typed (different when the closest known phrasing was sent in its
#: place). Note the buffer's attempts table names the other side: its ``correction`` is the one
#: given *after* that attempt (``docs/buffer.md``). ``hint_shown``: the oracle's hint was asked for
#: before the correction; ``solved_at``: the step at which the attempt first solved the task (null:
#: never); ``undone``: the person took this attempt's correction back (the episode went on without
#: it); ``started_at``: when the attempt was asked for. With the seed and the corrections of the rows
#: not undone, what an episode needs to be replayed.
LOG_SCHEMA = pa.schema([
    ("episode", pa.string()), ("source", pa.string()), ("run_dir", pa.string()), ("checkpoint", pa.string()),
    ("checkpoint_round", pa.int64()), ("greedy", pa.bool_()), ("split", pa.string()),
    ("domain", pa.string()), ("task_id", pa.int64()), ("seed", pa.int64()), ("attempt", pa.int64()),
    ("instruction", pa.string()), ("correction_before", pa.string()), ("typed", pa.string()),
    ("correction_tokens", pa.list_(pa.int64())),
    ("unknown_words", pa.list_(pa.string())), ("hint_shown", pa.bool_()), ("completion", pa.float64()),
    ("success", pa.bool_()), ("solved_at", pa.int64()), ("undone", pa.bool_()),
    ("started_at", pa.timestamp("us", tz="UTC")), ("seconds", pa.float64()),
])


#: The columns a log read by ``read_teaching_log`` lacks when it names the correction that led to
#: an attempt ``correction``: what the policy was sent, of which the current log says more.
_SAID_BEFORE = ("correction_before", "typed", "solved_at", "undone")


def read_teaching_log(files: Collection[str | Path]) -> list[dict]:
    """The rows of the teaching logs ``files`` (``*.parquet``; ``gpl_dist.app.export.teaching_log_files``
    lists a folder's), in the current shape (``LOG_SCHEMA``), file after file: the one place a log
    of an older shape is read. The shapes, oldest first:

    - the correction that led to an attempt as ``correction``, and no ``checkpoint``, ``greedy``
      or ``split``: refused (``UsageError``), as nothing records which weights acted, nor how;
    - ``correction`` (what the policy was sent; there was no undo), with ``checkpoint``,
      ``greedy`` and ``split``: ``correction_before`` is it, ``typed`` is it too (what was typed
      instead was not recorded), ``undone`` false, ``solved_at`` null (not recorded; a replay of
      the attempt tells it, as the export's does);
    - the current: every column of ``LOG_SCHEMA``.

    A file that cannot be read, or holds no teaching log, fails in one line naming it (``UsageError``)."""
    import pyarrow.parquet as pq

    tables = []
    for path in files:
        try:
            table = pq.read_table(str(path))
        except (OSError, ValueError) as err:
            raise UsageError(f"cannot read the teaching log {path} ({type(err).__name__}: {str(err)[:200]})") from None
        names = set(table.column_names)
        if "correction" in names and not {"checkpoint", "greedy", "split"} <= names:
            raise UsageError(f"{path} records no checkpoint file and no greedy or sampled actions: a log written "
                             "before they were recorded cannot be replayed")
        if "correction" in names and not names & set(_SAID_BEFORE):
            sent = table.column("correction")
            table = (table.append_column("correction_before", sent).append_column("typed", sent)
                     .append_column("solved_at", pa.nulls(table.num_rows, pa.int64()))
                     .append_column("undone", pa.array([False] * table.num_rows, pa.bool_())))
        missing = [n for n in LOG_SCHEMA.names if n not in table.column_names]
        if missing:
            raise UsageError(f"{path}: not a teaching log (no column {', '.join(missing[:3])})")
        try:
            tables.append(table.select(LOG_SCHEMA.names).cast(LOG_SCHEMA))
        except (pa.ArrowInvalid, pa.ArrowNotImplementedError) as err:
            raise UsageError(f"{path}: not a teaching log ({str(err)[:200]})") from None
    return pa.concat_tables(tables).to_pylist() if tables else []


def episode_log_bytes(episode: TeachingEpisode) -> bytes:
    """The episode's log as the bytes of a Parquet file (``LOG_SCHEMA``; the page's download)."""
    import pyarrow.parquet as pq

    sink = io.BytesIO()
    pq.write_table(pa.Table.from_pylist(episode.log_rows(), schema=LOG_SCHEMA), sink)
    return sink.getvalue()


def write_episode_log(episode: TeachingEpisode, log_dir: str | Path) -> str:
    """Write (replace) ``<log_dir>/<episode>.parquet`` atomically (``write_atomic``); returns its
    path. ``TeachingWriteError`` (and no file changed, no temporary left) when it cannot be written."""
    log_dir = Path(os.path.abspath(log_dir))
    ensure_folder(log_dir)
    path = log_dir / f"{episode.episode_id}.parquet"
    write_atomic(path, episode_log_bytes(episode))
    return str(path)


# -- files on disk -------------------------------------------------------------------------------

#: Prefix of a file being written (renamed into place once whole): as ``storage.layout.TMP_PREFIX``.
TMP_PREFIX = "_tmp-"
#: The lock every writer into a teaching folder holds shared while it runs (``teaching_writer``).
WRITERS_LOCK = ".writers.lock"
#: Sub-folders of a teaching folder that writers write into (besides the folder itself).
TEACHING_SUBFOLDERS = ("log", "gifs")
#: Age (seconds since last written) past which a temporary is dead even while a writer holds the
#: folder: a log or a GIF is written in well under a second, so an hour-old one is a dead writer's.
LEFTOVER_AGE_S = 3600.0

def _write_error(path: Path, err: OSError, what: str = "cannot write") -> TeachingWriteError:
    reason = err.strerror or type(err).__name__
    advice = "; free some space, then try again" if err.errno in NO_SPACE_ERRNOS else ""
    return TeachingWriteError(f"{what} {path}: {reason}{advice}", err.errno)


def ensure_folder(path: str | Path) -> Path:
    """``path`` as a folder, made with its parents when missing; ``TeachingWriteError`` (one line)
    when it is a file or cannot be made."""
    path = Path(path)
    if path.is_symlink() or path.parent.is_symlink():  # the teaching folder and its log/ and gifs/: never followed
        linked = path if path.is_symlink() else path.parent
        raise TeachingWriteError(f"{linked} is a symbolic link: gpl-dist never writes through one (give a real folder)",
                                 errno.ELOOP)
    if path.exists() and not path.is_dir():
        raise TeachingWriteError(f"{path} is not a folder (a file has its name)", errno.ENOTDIR)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        if err.errno in (errno.ENOTDIR, errno.EEXIST):
            raise TeachingWriteError(f"{path} is not a folder (a file is in its way)", err.errno) from None
        raise _write_error(path, err, "cannot make the folder") from None
    return path


def write_atomic(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` with ``gpl_dist.atomic.write_atomic`` through a temporary named
    ``_tmp-<hex>-<name>`` (``TMP_PREFIX``: what ``teaching_leftovers`` removes when its writer died),
    so a reader sees the old file or the new one, never half of one. A failure removes the
    temporary and raises ``TeachingWriteError`` (one line, the ``errno`` kept)."""
    try:
        return atomic.write_atomic(path, data, prefix=TMP_PREFIX)
    except OSError as err:
        advice = "; free some space, then try again" if err.errno in NO_SPACE_ERRNOS else ""
        raise TeachingWriteError(f"{err.strerror}{advice}", err.errno) from None


def check_out_folder(out: str | Path) -> Path:
    """The teaching folder ``out`` (``--out``), checked before anything is served or taught: a folder
    (made when missing, with ``log``) in which a file can be made. ``TeachingError`` (one line)
    otherwise: a file in its place, no permission, a read-only disk."""
    out = Path(out)
    for folder in (out, out / "log", out / "gifs"):
        if folder.is_symlink():
            raise TeachingError(f"{folder} is a symbolic link: gpl-dist never writes through one (give a real folder)")
    if out.exists() and not out.is_dir():
        raise TeachingError(f"--out {out} is not a folder: give a folder for the teaching log (OUT/log)")
    try:
        ensure_folder(out / "log")
        probe = out / "log" / f"{TMP_PREFIX}{uuid.uuid4().hex[:12]}-probe"
        os.close(os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o666))
        os.unlink(probe)
    except TeachingWriteError as err:
        raise TeachingError(f"--out {out} cannot hold the teaching log: {err}") from None
    except OSError as err:
        raise TeachingError(f"--out {out} cannot hold the teaching log: {err.strerror or err}") from None
    return out


@contextlib.contextmanager
def teaching_writer(out: str | Path) -> Iterator[Path]:
    """Write into the teaching folder ``out`` (``check_out_folder``) while inside: its
    ``.writers.lock`` is held shared (``flock``), so ``teaching_leftovers`` knows a writer is live
    (the lock goes with the process, however it ends). Waits only while a cleaner holds it."""
    import fcntl

    out = check_out_folder(out)
    try:
        fd = os.open(out / WRITERS_LOCK, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o666)
    except OSError as err:
        raise TeachingError(f"--out {out}: cannot open {WRITERS_LOCK} ({err.strerror or err}); "
                            "a symbolic link there is not followed") from None
    try:
        with contextlib.suppress(OSError):  # a filesystem without locks: leftovers go by age alone
            fcntl.flock(fd, fcntl.LOCK_SH)
        yield out
    finally:
        os.close(fd)


def teaching_leftovers(folder: str | Path, dry_run: bool, min_age_s: float = LEFTOVER_AGE_S) -> list[str]:
    """The dead temporaries of the teaching folder ``folder`` (``RUN_DIR/teaching``, or a ``--out``),
    sorted; removed unless ``dry_run``.

    Looked at: the files named ``_tmp-*`` directly in ``folder``, ``folder/log`` and
    ``folder/gifs`` (nothing deeper, nothing else: a reader skips every ``_``/``.`` name, and other
    files are not ours to remove). A temporary is dead when no writer holds ``folder``'s
    ``.writers.lock`` (``teaching_writer``: a ``serve`` or ``teach`` running now; the lock is
    taken exclusive for the look, so none starts meanwhile), or, while one does, when it was last
    written ``min_age_s`` or more ago. A symbolic link is never followed nor removed: ``folder``,
    ``log``, ``gifs`` or a ``_tmp-`` entry being one raises ``TeachingError`` (one line) before
    anything is removed. A missing ``folder`` has none.
    """
    import fcntl
    import stat

    folder = Path(folder)
    if folder.is_symlink():
        raise TeachingError(f"{folder} is a symbolic link: not followed; clean the folder it points to by its own path")
    if not folder.exists():
        return []
    top = _open_folder(folder, None, folder)
    if top is None:
        raise TeachingError(f"{folder} is not a folder")
    try:
        try:
            lock = os.open(WRITERS_LOCK, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC, dir_fd=top)
        except FileNotFoundError:
            lock = None  # no writer ever ran here (or one of before the lock): none is live
        except OSError as err:
            if err.errno == errno.ELOOP:
                raise TeachingError(f"{folder / WRITERS_LOCK} is a symbolic link: not followed; remove it") from None
            raise
        try:
            live = False
            if lock is not None:
                try:
                    fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except OSError:  # held by a writer (or no locks here): only old temporaries are dead
                    live = True
            now = time.time()
            found: list[tuple[int, str, Path]] = []  # (folder fd, name, path)
            subs = [(top, folder)]
            try:
                for name in TEACHING_SUBFOLDERS:
                    fd = _open_folder(folder / name, top, folder, name)
                    if fd is not None:
                        subs.append((fd, folder / name))
                for fd, path in subs:
                    with os.scandir(fd) as entries:
                        for e in entries:
                            if not e.name.startswith(TMP_PREFIX):
                                continue
                            info = e.stat(follow_symlinks=False)
                            if stat.S_ISLNK(info.st_mode):
                                raise TeachingError(f"{path / e.name} is a symbolic link, not a temporary this program "
                                                    "wrote: not followed nor removed; look at it yourself")
                            if stat.S_ISREG(info.st_mode) and (not live or now - info.st_mtime >= min_age_s):
                                found.append((fd, e.name, path / e.name))
                if not dry_run:
                    for fd, name, _ in found:
                        with contextlib.suppress(FileNotFoundError):  # gone meanwhile: fine
                            os.unlink(name, dir_fd=fd)
            finally:
                for fd, _ in subs[1:]:
                    os.close(fd)
        finally:
            if lock is not None:
                os.close(lock)
    finally:
        os.close(top)
    return sorted(str(p) for _, _, p in found)


def _open_folder(path: Path, parent_fd: int | None, top: Path, name: str | None = None) -> int | None:
    """A descriptor of the folder ``path`` (``name`` in ``parent_fd``), not following a symbolic
    link (``TeachingError``); None when it is missing or not a folder."""
    try:
        if name is None:
            return os.open(path, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC)
        return os.open(name, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC, dir_fd=parent_fd)
    except FileNotFoundError:
        return None
    except OSError as err:
        if err.errno == errno.ELOOP or (err.errno == errno.ENOTDIR and path.is_symlink()):
            raise TeachingError(f"{path} is a symbolic link: not followed; the temporaries of {top} are "
                                "looked for in its own folders only") from None
        if err.errno == errno.ENOTDIR:
            return None
        raise

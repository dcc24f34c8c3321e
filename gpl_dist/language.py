"""Language: one vocabulary and tokenizer per domain, shared by instructions and corrections.

Instructions and corrections are English sentences ("Move green triangle to green square",
"enter the blue room"). The model sees them as fixed-length arrays of token ids:

- id 0 is padding (``Vocabulary.pad_id``), id 1 is the unknown word (``Vocabulary.unk_id``);
- words are lower-cased and split on anything that is not a letter;
- sequences longer than ``max_tokens`` are cut, shorter ones are right-padded with 0.

The instruction and the correction modules share one word-embedding table, so both must be
encoded with the same ``Vocabulary``. A domain builds its vocabulary from its grammar's word list;
the word list is fixed and versioned with the code, so token ids are stable across runs.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Iterable, Sequence

import numpy as np

_WORD_RE = re.compile(r"[a-z]+")

PAD_TOKEN = "<pad>"
UNK_TOKEN = "<unk>"

#: Default length cap, in tokens, for instructions and corrections.
DEFAULT_MAX_TOKENS = 12


def split_words(text: str) -> list[str]:
    """Lower-case ``text`` and return its words (runs of letters)."""
    return _WORD_RE.findall(text.lower())


@dataclass(frozen=True)
class Vocabulary:
    """A fixed word list with padding and unknown-word ids.

    Attributes:
        words: the domain's words, in id order after ``<pad>`` (0) and ``<unk>`` (1).
        max_tokens: length of every encoded sequence.
    """

    words: tuple[str, ...]
    max_tokens: int = DEFAULT_MAX_TOKENS
    _index: dict[str, int] = field(init=False, repr=False, compare=False)

    pad_id = 0
    unk_id = 1

    def __post_init__(self) -> None:
        if self.max_tokens < 1:
            raise ValueError(f"max_tokens must be at least 1, got {self.max_tokens}")
        tokens = (PAD_TOKEN, UNK_TOKEN) + tuple(self.words)
        if len(set(tokens)) != len(tokens):
            raise ValueError("vocabulary words must be unique")
        object.__setattr__(self, "_index", {w: i for i, w in enumerate(tokens)})

    @classmethod
    def from_sentences(cls, sentences: Iterable[str], max_tokens: int = DEFAULT_MAX_TOKENS) -> "Vocabulary":
        """Vocabulary of every word in ``sentences``, sorted so ids do not depend on order."""
        words = sorted({w for s in sentences for w in split_words(s)})
        return cls(tuple(words), max_tokens)

    def __len__(self) -> int:
        return len(self.words) + 2

    @property
    def size(self) -> int:
        """Number of ids, padding and unknown included (the embedding table's rows)."""
        return len(self)

    def token_id(self, word: str) -> int:
        return self._index.get(word, self.unk_id)

    def encode(self, text: str) -> np.ndarray:
        """Token ids of ``text``: int64 array of shape ``(max_tokens,)``, right-padded with 0."""
        ids = np.zeros(self.max_tokens, dtype=np.int64)
        words = split_words(text)[: self.max_tokens]
        for i, w in enumerate(words):
            ids[i] = self._index.get(w, self.unk_id)
        return ids

    def encode_batch(self, texts: Sequence[str]) -> np.ndarray:
        """Token ids of several texts: int64 array ``(len(texts), max_tokens)``."""
        out = np.zeros((len(texts), self.max_tokens), dtype=np.int64)
        for row, text in enumerate(texts):
            out[row] = self.encode(text)
        return out

    def decode(self, ids: Sequence[int] | np.ndarray) -> str:
        """Words of ``ids`` joined by spaces; padding is dropped, unknown ids read ``<unk>``."""
        tokens = (PAD_TOKEN, UNK_TOKEN) + self.words
        return " ".join(tokens[int(i)] if 0 <= int(i) < len(tokens) else UNK_TOKEN for i in ids if int(i) != self.pad_id)

    def extended(self, words: Iterable[str]) -> "Vocabulary":
        """This vocabulary with ``words`` it lacks appended, in order: every id of this one keeps
        its meaning, so text without the new words encodes the same."""
        new = tuple(dict.fromkeys(w for w in words if w not in self._index))
        return Vocabulary(self.words + new, self.max_tokens)


#: Which phrasings a rollout says: the oracle's own sentences, or paraphrases drawn from the
#: training or the held-out templates (``Paraphrases``).
PHRASINGS = ("canonical", "train", "heldout")


@dataclass(frozen=True)
class ParaphraseRule:
    """The paraphrases of one form of sentence.

    Attributes:
        pattern: a regular expression with named groups that matches the canonical sentence
            (whole, case-insensitive), e.g. ``enter the (?P<c>\\w+) room``.
        templates: ``str.format`` templates over the groups; ``templates[0]`` is the canonical form.
    """

    pattern: str
    templates: tuple[str, ...]


@dataclass(frozen=True)
class Paraphrases:
    """A domain's paraphrases of its instructions and corrections.

    Every rule has the same number of templates; those at ``heldout`` indices are never said in
    training (``pool="train"`` draws from the others, the canonical one included), and are what
    ``pool="heldout"`` draws from. A sentence no rule matches (full information, reward texts) is
    said as it is.
    """

    rules: tuple[ParaphraseRule, ...]
    heldout: tuple[int, ...] = (3, 4)
    _compiled: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        sizes = {len(r.templates) for r in self.rules}
        if len(sizes) != 1 or max(self.heldout) >= sizes.pop() or 0 in self.heldout:
            raise ValueError("paraphrase rules need equally many templates, the canonical one (0) not held out")
        object.__setattr__(self, "_compiled", tuple(re.compile(r.pattern, re.IGNORECASE) for r in self.rules))

    def pool(self, name: str) -> tuple[int, ...]:
        """Template indices of ``name`` in ``PHRASINGS``."""
        n = len(self.rules[0].templates)
        if name == "train":
            return tuple(i for i in range(n) if i not in self.heldout)
        if name == "heldout":
            return self.heldout
        if name == "canonical":
            return (0,)
        raise ValueError(f"phrasings must be one of {', '.join(PHRASINGS)}, got {name!r}")

    def rewrite(self, text: str, pool: str, rng: "np.random.Generator") -> str:
        """``text`` said with a template of ``pool`` drawn with ``rng`` (``canonical``: as it is,
        and ``rng`` is not drawn from)."""
        indices = self.pool(pool)
        if pool == "canonical":
            return text
        for rule, compiled in zip(self.rules, self._compiled):
            m = compiled.fullmatch(text.strip())
            if m:
                return rule.templates[indices[int(rng.integers(len(indices)))]].format(**m.groupdict())
        return text

    def words(self, pool: str = "train") -> tuple[str, ...]:
        """Every literal word of the templates of ``pool`` (what a vocabulary must add to read them)."""
        found: dict[str, None] = {}
        for rule in self.rules:
            for i in self.pool(pool):
                found.update(dict.fromkeys(split_words(re.sub(r"\{\w+\}", " ", rule.templates[i]))))
        return tuple(found)

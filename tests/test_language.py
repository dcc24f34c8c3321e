import numpy as np
import pytest

from gpl_dist.language import Vocabulary, split_words


def test_sentences_encode_with_pad_and_unknown():
    vocab = Vocabulary(("move", "green", "triangle", "to", "square", "enter", "the", "blue", "room"), max_tokens=6)
    ids = vocab.encode("Move green triangle to green square")
    assert ids.dtype == np.int64 and ids.shape == (6,)
    assert vocab.decode(ids) == "move green triangle to green square"
    ids = vocab.encode("enter the purple room")
    assert ids[2] == vocab.unk_id and ids[4] == vocab.pad_id == 0
    decoded = vocab.decode(vocab.encode("enter the blue room now please and more words"))
    assert decoded.split()[:4] == ["enter", "the", "blue", "room"]
    assert (vocab.encode("a b c d e f g h") != 0).sum() == 6  # capped at max_tokens


def test_split_words_ignores_case_and_punctuation():
    assert split_words("Move a LOT, down-right!") == ["move", "a", "lot", "down", "right"]


def test_vocabulary_rejects_duplicates_and_is_order_independent():
    with pytest.raises(ValueError):
        Vocabulary(("a", "a"))
    a = Vocabulary.from_sentences(["b a", "c"])
    b = Vocabulary.from_sentences(["c", "a b"])
    assert a.words == b.words and a.size == 5


@pytest.mark.parametrize("domain", ["multiroom", "relocation"])
def test_domain_vocabularies_cover_their_sentences(domain):
    from gpl_dist.corrections import make_corrector
    from gpl_dist.domains import get_domain

    d = get_domain(domain)
    env = d.make_env(0)
    env.reset(seed=0)
    oracle = make_corrector(domain, "default")
    rng = np.random.default_rng(0)
    texts = [env.instruction, oracle.full_information(env), oracle.correct(env, rng).text]
    for text in texts:
        ids = d.vocabulary.encode(text)
        assert d.vocabulary.unk_id not in ids, f"unknown word in {text!r}"
        assert len(split_words(text)) <= d.vocabulary.max_tokens, f"{text!r} is longer than max_tokens"

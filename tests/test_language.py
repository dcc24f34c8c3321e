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


def test_an_extended_vocabulary_keeps_every_id():
    base = Vocabulary(("enter", "the", "room"), max_tokens=6)
    more = base.extended(["walk", "the", "into", "walk"])
    assert more.words == ("enter", "the", "room", "walk", "into") and more.max_tokens == 6
    assert np.array_equal(base.encode("enter the room"), more.encode("enter the room"))
    assert base.encode("walk into")[0] == base.unk_id and more.encode("walk into")[0] != more.unk_id


def test_paraphrases_draw_from_their_pool_and_canonical_draws_nothing():
    from gpl_dist.language import ParaphraseRule, Paraphrases

    p = Paraphrases((ParaphraseRule(r"enter the (?P<c>\w+) room", (
        "enter the {c} room", "go into the {c} room", "walk in {c}", "go in {c}", "walk into the {c} room")),))
    rng = np.random.default_rng(0)
    state = rng.bit_generator.state
    assert p.rewrite("enter the blue room", "canonical", rng) == "enter the blue room"
    assert rng.bit_generator.state == state  # canonical rollouts draw exactly as before paraphrases existed
    train = {p.rewrite("Enter the blue room", "train", rng) for _ in range(200)}
    heldout = {p.rewrite("enter the blue room", "heldout", rng) for _ in range(200)}
    assert train == {"enter the blue room", "go into the blue room", "walk in blue"}
    assert heldout == {"go in blue", "walk into the blue room"}
    assert p.rewrite("you are done", "train", rng) == "you are done"  # no rule: said as it is
    with pytest.raises(ValueError, match="phrasings must be one of"):
        p.rewrite("enter the blue room", "paraphrased", rng)
    with pytest.raises(ValueError, match="equally many templates"):
        Paraphrases((ParaphraseRule("a", ("a", "b")), ParaphraseRule("c", ("c", "d", "e"))), heldout=(1,))

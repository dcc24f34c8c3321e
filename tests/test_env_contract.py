"""Contract tests run over every registered gpl-dist env (Minigrid style)."""

import pickle
from pathlib import Path

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import gpl_dist  # noqa: F401  (registers the envs)
from gpl_dist.corrections import CONSTANT_KINDS
from gpl_dist.domains import domain_names, get_domain, load_domain_module
from gpl_dist.envs import ENV_IDS as BUILTIN_ENV_IDS
from gpl_dist.language import split_words
from gpl_dist.splits import load_splits

# a domain from outside the package, through the plug-in hook, is held to the same contract
load_domain_module(str(Path(__file__).parent / "domains" / "corridor.py"))
SPECS = {get_domain(name).env_id: get_domain(name) for name in domain_names()}
ENV_IDS = tuple(SPECS)
#: the paraphrase contract holds for the domains that declare paraphrases
PARAPHRASED = tuple(env_id for env_id, spec in SPECS.items() if spec.paraphrases is not None)


def test_every_domain_is_registered():
    assert set(BUILTIN_ENV_IDS) < set(SPECS) and "gpl-test/Corridor-v0" in SPECS
    assert set(PARAPHRASED) == set(BUILTIN_ENV_IDS)
    for env_id in SPECS:
        gymnasium.make(env_id, task_id=0)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_check_env_on_every_split(env_id):
    spec = SPECS[env_id]
    for split, tasks in load_splits(spec.name).items():
        env = gymnasium.make(env_id, task_id=int(tasks[len(tasks) // 2]))
        check_env(env.unwrapped, skip_render_check=True)
        env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_spec_matches_env(env_id):
    spec = SPECS[env_id]
    env = gymnasium.make(env_id, task_id=0)
    assert env.observation_space.shape == spec.obs_shape
    assert env.observation_space.dtype == np.dtype(spec.obs_dtype)
    assert env.action_space.n == spec.num_actions
    assert env.spec.max_episode_steps == spec.steps_per_attempt
    obs, info = env.reset(seed=0)
    assert {"completion", "success"} <= set(info)
    assert isinstance(env.unwrapped.instruction, str) and env.unwrapped.instruction
    assert env.unwrapped.domain_name == spec.name
    assert set(load_splits(spec.name)) == set(spec.split_names)  # the split file names what the spec lists


def _episode(env, seed, n):
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    out = [obs]
    for _ in range(n):
        obs, r, term, trunc, info = env.step(int(rng.integers(env.action_space.n)))
        out.append(obs)
        out.append(np.array([r, info["completion"]]))
    return out


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_same_seed_same_episode(env_id):
    a = _episode(gymnasium.make(env_id, task_id=7), 11, 60)
    b = _episode(gymnasium.make(env_id, task_id=7), 11, 60)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_pickled_env_continues_identically(env_id):
    env = gymnasium.make(env_id, task_id=3)
    _episode(env, 5, 20)
    clone = pickle.loads(pickle.dumps(env))
    for a in [0, 1, 2, 3] * 5:
        o1, r1, *_ = env.step(a)
        o2, r2, *_ = clone.step(a)
        assert np.array_equal(o1, o2) and r1 == r2


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_episode_is_truncated_at_the_paper_length(env_id):
    spec = SPECS[env_id]
    env = gymnasium.make(env_id, task_id=1)
    env.reset(seed=0)
    for t in range(spec.steps_per_attempt):
        _, _, terminated, truncated, _ = env.step(0)
        assert not terminated
        assert truncated == (t == spec.steps_per_attempt - 1)


@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize("bad", [-1, 10**6, "3", 2.5])
def test_bad_task_id_fails_clearly(env_id, bad):
    with pytest.raises(ValueError, match="task_id"):
        gymnasium.make(env_id, task_id=bad)


def _random_attempt_env(spec, task_id, seed, render_mode=None):
    env = spec.make_env(task_id, render_mode=render_mode)
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    for _ in range(spec.steps_per_attempt):
        env.step(int(rng.integers(spec.num_actions)))
    return env


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_text_picture_shows_the_path_and_is_deterministic(env_id):
    spec = SPECS[env_id]
    a = _random_attempt_env(spec, 3, 5, render_mode="ansi").render()
    b = _random_attempt_env(spec, 3, 5, render_mode="ansi").render()
    fresh = spec.make_env(3, render_mode="ansi")
    fresh.reset(seed=5)
    assert isinstance(a, str) and a == b
    assert f"{spec.steps_per_attempt} steps" in a and "0 steps" in fresh.render()
    assert a != fresh.render()  # the path and the final state are drawn


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_every_oracle_correction_is_a_listed_phrasing(env_id):
    """``correction_phrasings`` is what a person's correction is compared with: it must hold every
    sentence the text oracles say."""
    spec = SPECS[env_id]
    known = {" ".join(s.lower().split()) for s in spec.correction_phrasings()}
    text_kinds = [k for k in spec.correction_kinds if k not in ("reward",)]
    said = set()
    for task_id in range(0, spec.num_tasks, max(1, spec.num_tasks // 12)):
        env = _random_attempt_env(spec, task_id, task_id)
        for kind in text_kinds:
            said.add(spec.make_corrector(kind).correct(env, np.random.default_rng(task_id)).text)
    assert said and {" ".join(s.lower().split()) for s in said} <= known
    assert all(w in spec.vocabulary.words for s in known for w in s.split())


@pytest.mark.parametrize("env_id", PARAPHRASED)
def test_paraphrases_cover_every_sentence_and_hold_out_no_word(env_id):
    """Every instruction and oracle sentence has at least five phrasings, the first its own; the
    held-out phrasings are new sentences of words training phrasings use (a paraphrase test, not
    an unknown-word one); a model trained with paraphrases reads every phrasing without <unk>."""
    spec = SPECS[env_id]
    p = spec.paraphrases
    assert p is not None and len(p.rules[0].templates) >= 5
    instructions = {spec.make_env(t).instruction for t in range(0, spec.num_tasks, 7)}
    rng = np.random.default_rng(0)
    vocab = spec.vocabulary_for(True)
    seen_in_training = set(p.words("train")) | set(spec.vocabulary.words)
    assert set(p.words("heldout")) <= seen_in_training
    for text in sorted(instructions) + list(spec.correction_phrasings()):
        matching = [r for r, c in zip(p.rules, p._compiled) if c.fullmatch(text)]
        assert len(matching) == 1, text
        groups = p._compiled[p.rules.index(matching[0])].fullmatch(text).groupdict()
        assert matching[0].templates[0].format(**groups) == text
        for pool in ("train", "heldout"):
            said = p.rewrite(text, pool, rng)
            assert vocab.unk_id not in vocab.encode(said) and len(split_words(said)) <= vocab.max_tokens, said
    heldout_only = {p.rewrite(t, "heldout", rng) for t in instructions} - {p.rewrite(t, "train", rng) for t in instructions}
    assert heldout_only


@pytest.mark.parametrize("env_id,kind", [(e, k) for e in ENV_IDS for k in CONSTANT_KINDS if k in SPECS[e].correction_kinds])
def test_the_retry_control_says_one_sentence_whatever_the_attempt_did(env_id, kind):
    """The retry control's oracle carries no information: one sentence after every attempt (solved
    or not, any task, any draw), made of the domain's words, so no model's shapes change."""
    spec = SPECS[env_id]
    oracle = spec.make_corrector(kind)
    said = set()
    for task_id in range(0, spec.num_tasks, max(1, spec.num_tasks // 12)):
        env = _random_attempt_env(spec, task_id, task_id)
        said |= {oracle.correct(env, np.random.default_rng(s)).text for s in range(3)}
    default = {spec.make_corrector("default").correct(_random_attempt_env(spec, t, t), np.random.default_rng(0)).text
               for t in range(0, spec.num_tasks, max(1, spec.num_tasks // 12))}
    assert len(said) == 1 and len(default) > 1
    assert all(w in spec.vocabulary.words for w in next(iter(said)).lower().split())

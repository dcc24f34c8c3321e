"""Contract tests run over every registered gpl-dist env (Minigrid style)."""

import subprocess
from pathlib import Path

import gymnasium
import numpy as np
import pytest
from _cluster_tools import GPL_DIST, quiet_env

import gpl_dist  # noqa: F401  (registers the envs)
from gpl_dist.app.contract import check_domain
from gpl_dist.corrections import CONSTANT_KINDS
from gpl_dist.domains import domain_names, get_domain, load_domain_module
from gpl_dist.envs import ENV_IDS as BUILTIN_ENV_IDS
from gpl_dist.language import split_words

# a domain from outside the package, through the plug-in hook, is held to the same contract
CORRIDOR_FILE = Path(__file__).parent / "domains" / "corridor.py"
load_domain_module(str(CORRIDOR_FILE))
SPECS = {get_domain(name).env_id: get_domain(name) for name in domain_names()}
ENV_IDS = tuple(SPECS)
#: the paraphrase contract holds for the domains that declare paraphrases
PARAPHRASED = tuple(env_id for env_id, spec in SPECS.items() if spec.paraphrases is not None)


def test_every_domain_is_registered():
    assert set(BUILTIN_ENV_IDS) < set(SPECS) and "gpl-test/Corridor-v0" in SPECS
    assert set(BUILTIN_ENV_IDS) <= set(PARAPHRASED)  # a plug-in may declare paraphrases too
    for env_id in SPECS:
        gymnasium.make(env_id, task_id=0)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_every_registered_domain_meets_the_contract(env_id):
    """``gpl-dist check-domain``'s checks (``gpl_dist.app.contract``) over every registered domain:
    the built-ins, the test corridor and any installed plug-in."""
    findings = check_domain(SPECS[env_id])
    assert [f.line() for f in findings if not f.ok] == []
    assert {f.check for f in findings} >= {"completion in [0, 1]", "task_id bounds", "seeded determinism", "expert",
                                          "corrections", "splits", "vocabulary"}


#: Broken variants of the corridor (source edits), each with the check that must name it.
BROKEN = {
    "completion below 0": (('"completion": float(self.reached)', '"completion": float(self.reached) - 0.1'),
                           "FAIL completion in [0, 1]: task 0 seed 0 step 0: completion -0.1"),
    "completion NaN": (('"completion": float(self.reached)', '"completion": float("nan") if self.t == 3 else 0.0'),
                       "FAIL completion in [0, 1]"),
    "a lax task_id check": (("not 0 <= task_id < len(GOALS)", "not 0 <= task_id <= len(GOALS)"),
                            "FAIL task_id bounds: task_id 8 raised IndexError"),
    # an observation drawn from numpy's global generator, not from the reset seed
    "unseeded": (("np.array([self.pos / 6, self.t / STEPS, float(self.reached)], np.float32)",
                  "np.array([self.pos / 6, self.t / STEPS * (1 - 0.5 * np.random.random()), float(self.reached)], "
                  "np.float32)"), "FAIL seeded determinism"),
    "an instruction word outside the vocabulary": (
        ('f"go to the {COLOURS[task_id]} cell"', 'f"walk to the {COLOURS[task_id]} cell"'),
        "FAIL vocabulary: task 0: instruction 'walk to the red cell'"),
}


@pytest.mark.parametrize("name", sorted(BROKEN))
def test_check_domain_names_what_a_broken_domain_does_wrong(tmp_path, name):
    (old, new), needle = BROKEN[name]
    source = CORRIDOR_FILE.read_text()
    assert source.count(old) == 1, old
    broken = tmp_path / "broken_corridor.py"
    broken.write_text(source.replace(old, new))
    done = subprocess.run([GPL_DIST, "check-domain", str(broken)], capture_output=True, text=True, env=quiet_env(),
                          timeout=300)
    assert done.returncode == 2, done.stdout + done.stderr
    assert needle in done.stdout, done.stdout
    assert done.stderr.count("\n") == 1 and "check(s) of the env contract failed" in done.stderr
    ok = subprocess.run([GPL_DIST, "check-domain", str(CORRIDOR_FILE)], capture_output=True, text=True, env=quiet_env(),
                        timeout=300) if name == "completion below 0" else None
    assert ok is None or (ok.returncode == 0 and "FAIL" not in ok.stdout), ok


def test_a_completion_outside_0_1_stops_a_run_in_one_line(tmp_path):
    source = CORRIDOR_FILE.read_text().replace('"completion": float(self.reached)', '"completion": 1.5 * float(self.reached)')
    broken = tmp_path / "broken_corridor.py"
    broken.write_text(source)
    config = tmp_path / "c.yaml"
    config.write_text(f"env: {{domain: corridor, domain_module: {broken}}}\n"
                      "collection: {num_workers: 1, num_corrections: 1, tasks_per_unit: 4}\n"
                      "training: {num_rounds: 1, num_epochs_per_round: 1, batch_size: 16}\n")
    done = subprocess.run([GPL_DIST, "train", "--config", str(config), "--serial", "--run-dir", str(tmp_path / "run"),
                           "--no-progress"], capture_output=True, text=True, env=quiet_env(), timeout=300)
    assert done.returncode == 2, done.stderr[-2000:]
    err = done.stderr.strip().splitlines()[-1]
    assert err.startswith("gpl-dist: error:") and "the env's completion is 1.5, not a finite fraction in [0, 1]" in err
    assert "task " in err


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

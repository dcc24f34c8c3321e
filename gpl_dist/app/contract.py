"""The env contract a domain must meet (``docs/adding-a-domain.md``), checked on any ``DomainSpec``.

``check_domain`` runs every check and returns one ``Finding`` per check: gymnasium's env checker on
a task of each split, the spec against the env (spaces, attempt length, ``info``, instruction,
name), completion a finite fraction in [0, 1] at every step and success only where completion is
1 (a task done is a task whole), ``task_id`` bounds (anything but an int in ``0..num_tasks-1`` is a
``ValueError`` naming ``task_id``), seeded determinism, attempts that are never cut short, the
expert (valid actions and label distributions, and it solves the tasks), every correction kind
(seeded, its text in the vocabulary) and the full-information text, the splits (named as the spec
says, inside the task range, no test task trained on), vocabulary coverage of every instruction
and every correction said, and what the env offers optionally (ANSI and RGB pictures, path points,
phrasings, paraphrases), each checked where offered.

``gpl-dist check-domain FILE_OR_MODULE`` prints the findings, one line each; the repository's own
contract tests (``tests/test_env_contract.py``) run it over every registered domain.
"""

from __future__ import annotations

import math
import pickle
from dataclasses import dataclass
from typing import Callable

import gymnasium
import numpy as np

from gpl_dist.corrections import CONSTANT_KINDS
from gpl_dist.language import split_words
from gpl_dist.roles import DomainSpec
from gpl_dist.splits import load_splits

#: Correction kinds whose sentence carries a number, not a phrasing a person would say (GPR's reward).
NUMERIC_KINDS = ("reward",)


@dataclass(frozen=True)
class Finding:
    """One check of the contract: its name, whether it held, and a line saying what was seen."""

    check: str
    ok: bool
    message: str

    def line(self) -> str:
        return f"{'ok  ' if self.ok else 'FAIL'} {self.check}: {self.message}"


class _Failed(Exception):
    pass


def _expect(ok: bool, message: str) -> None:
    if not ok:
        raise _Failed(message)


def _sample_tasks(spec: DomainSpec, per_split: int) -> list[int]:
    """A few tasks of every split (first, middle, last), and task 0."""
    tasks = {0}
    for split in load_splits(spec.name).values():
        ids = list(split)
        if ids:
            picks = np.linspace(0, len(ids) - 1, num=min(per_split, len(ids))).round().astype(int)
            tasks.update(int(ids[i]) for i in picks)
    return sorted(tasks)


def _random_attempt(spec: DomainSpec, task_id: int, seed: int, render_mode: str | None = None):
    """The env of ``task_id`` after one attempt of seeded random actions, and each step's ``info``."""
    env = spec.make_env(task_id, render_mode=render_mode) if render_mode else spec.make_env(task_id)
    rng = np.random.default_rng(seed)
    _, info = env.reset(seed=seed)
    infos = [info]
    for _ in range(spec.steps_per_attempt):
        infos.append(env.step(int(rng.integers(spec.num_actions)))[-1])
    return env, infos


def check_domain(spec: DomainSpec, per_split: int = 3) -> list[Finding]:
    """Every check of the contract on ``spec`` (see the module docstring), ``per_split`` tasks of
    each split where a check samples tasks; never raises for what the domain does wrong."""
    tasks = _sample_tasks(spec, per_split)
    checks: list[tuple[str, Callable[[], str]]] = [
        ("gymnasium env checker", lambda: _gymnasium_checker(spec)),
        ("spec matches env", lambda: _spec_matches_env(spec)),
        ("completion in [0, 1]", lambda: _completion(spec, tasks)),
        ("task_id bounds", lambda: _task_id_bounds(spec)),
        ("seeded determinism", lambda: _determinism(spec, tasks)),
        ("attempt length", lambda: _attempt_length(spec)),
        ("expert", lambda: _expert(spec, tasks)),
        ("corrections", lambda: _corrections(spec, tasks)),
        ("splits", lambda: _splits(spec)),
        ("vocabulary", lambda: _vocabulary(spec, tasks)),
        ("optional: pictures", lambda: _pictures(spec)),
        ("optional: correction phrasings", lambda: _phrasings(spec, tasks)),
        ("optional: paraphrases", lambda: _paraphrases(spec)),
    ]
    out = []
    for name, run in checks:
        try:
            out.append(Finding(name, True, run()))
        except _Failed as err:
            out.append(Finding(name, False, str(err)))
        except Exception as err:  # noqa: BLE001 - the domain's own code failed: that is the finding
            first = " ".join(str(err).split())[:300]
            out.append(Finding(name, False, f"raised {type(err).__name__}: {first}"))
    return out


def _gymnasium_checker(spec: DomainSpec) -> str:
    from gymnasium.utils.env_checker import check_env

    done = []
    for split, ids in load_splits(spec.name).items():
        if ids:
            task = int(list(ids)[len(ids) // 2])
            check_env(spec.make_env(task), skip_render_check=True)
            done.append(f"{split} task {task}")
    return f"passed on {', '.join(done)}"


def _spec_matches_env(spec: DomainSpec) -> str:
    env = gymnasium.make(spec.env_id, task_id=0)
    _expect(env.observation_space.shape == tuple(spec.obs_shape),
            f"observation shape {env.observation_space.shape}, the spec says {tuple(spec.obs_shape)}")
    _expect(env.observation_space.dtype == np.dtype(spec.obs_dtype),
            f"observation dtype {env.observation_space.dtype}, the spec says {spec.obs_dtype}")
    _expect(getattr(env.action_space, "n", None) == spec.num_actions,
            f"action space {env.action_space}, the spec says Discrete({spec.num_actions})")
    _, info = env.reset(seed=0)
    _expect({"completion", "success"} <= set(info), f"reset's info lacks {sorted({'completion', 'success'} - set(info))}")
    instruction = getattr(env.unwrapped, "instruction", None)
    _expect(isinstance(instruction, str) and bool(instruction.strip()), f"instruction is {instruction!r}, not a sentence")
    _expect(getattr(env.unwrapped, "domain_name", None) == spec.name,
            f"env.domain_name is {getattr(env.unwrapped, 'domain_name', None)!r}, the spec's name is {spec.name!r}")
    _expect(getattr(env.unwrapped, "task_id", None) == 0, "env.task_id is not the task it was made for")
    return f"obs {spec.obs_dtype}{tuple(spec.obs_shape)}, {spec.num_actions} actions, instruction {instruction!r}"


def _completion(spec: DomainSpec, tasks: list[int]) -> str:
    steps = 0
    for task in tasks:
        for seed in (0, 1):
            _, infos = _random_attempt(spec, task, seed)
            for t, info in enumerate(infos):
                c, s = info.get("completion"), info.get("success")
                _expect(isinstance(c, (int, float, np.floating)) and not isinstance(c, bool) and math.isfinite(float(c))
                        and 0.0 <= float(c) <= 1.0,
                        f"task {task} seed {seed} step {t}: completion {c!r} is not a finite fraction in [0, 1]")
                _expect(isinstance(s, (bool, np.bool_)), f"task {task} seed {seed} step {t}: success {s!r} is not a bool")
                _expect(not s or float(c) > 0.0, f"task {task} seed {seed} step {t}: success with completion {c!r}")
                steps += 1
    return f"{steps} steps of random attempts on {len(tasks)} tasks"


def _task_id_bounds(spec: DomainSpec) -> str:
    for bad in (-1, spec.num_tasks, "3", 2.5, None, True):
        try:
            spec.make_env(bad)
        except ValueError as err:
            _expect("task_id" in str(err), f"task_id {bad!r} raised ValueError without naming task_id: {err}")
            continue
        except Exception as err:  # noqa: BLE001
            raise _Failed(f"task_id {bad!r} raised {type(err).__name__}, not ValueError naming task_id") from None
        raise _Failed(f"task_id {bad!r} was accepted (tasks are ints in 0..{spec.num_tasks - 1})")
    for good in (0, spec.num_tasks - 1, np.int64(spec.num_tasks - 1)):
        spec.make_env(good)
    return f"ints in 0..{spec.num_tasks - 1} only"


def _episode(spec: DomainSpec, task: int, seed: int) -> list[np.ndarray]:
    env = spec.make_env(task)
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    out = [np.asarray(obs)]
    for _ in range(spec.steps_per_attempt):
        obs, r, _, _, info = env.step(int(rng.integers(spec.num_actions)))
        out += [np.asarray(obs), np.array([r, info["completion"]], dtype=np.float64)]
    return out


def _determinism(spec: DomainSpec, tasks: list[int]) -> str:
    task = tasks[len(tasks) // 2]
    a, b = _episode(spec, task, 11), _episode(spec, task, 11)
    _expect(all(np.array_equal(x, y) for x, y in zip(a, b)), f"task {task}: the same seed gave another episode")
    env = spec.make_env(task)
    env.reset(seed=5)
    clone = pickle.loads(pickle.dumps(env))
    for action in [0, spec.num_actions - 1] * 4:
        o1, r1, *_ = env.step(action)
        o2, r2, *_ = clone.step(action)
        _expect(np.array_equal(o1, o2) and r1 == r2, f"task {task}: a pickled env went on differently")
    return f"task {task}: equal episodes from equal seeds; a pickled env goes on identically"


def _attempt_length(spec: DomainSpec) -> str:
    env = gymnasium.make(spec.env_id, task_id=0)
    _expect(env.spec is not None and env.spec.max_episode_steps == spec.steps_per_attempt,
            f"registered max_episode_steps {getattr(env.spec, 'max_episode_steps', None)}, the spec says "
            f"{spec.steps_per_attempt}")
    env.reset(seed=0)
    for t in range(spec.steps_per_attempt):
        _, _, terminated, truncated, _ = env.step(0)
        _expect(not terminated, f"terminated at step {t + 1}: an attempt runs its {spec.steps_per_attempt} steps")
        _expect(truncated == (t == spec.steps_per_attempt - 1), f"truncated at step {t + 1} of {spec.steps_per_attempt}")
    return f"{spec.steps_per_attempt} steps, never terminated early"


def _expert(spec: DomainSpec, tasks: list[int]) -> str:
    lines = []
    for kind in spec.experts:
        expert = spec.experts[kind]()
        solved, completion = 0, 0.0
        for task in tasks:
            env = spec.make_env(task)
            env.reset(seed=task)
            info: dict = {}
            for t in range(spec.steps_per_attempt):
                action, probs = expert.label(env)
                probs = np.asarray(probs)
                _expect(0 <= int(action) < spec.num_actions, f"{kind}: task {task} step {t}: action {action} out of range")
                _expect(probs.shape == (spec.num_actions,) and probs.dtype == np.float32,
                        f"{kind}: label probabilities of shape {probs.shape} and dtype {probs.dtype}, not float32 "
                        f"({spec.num_actions},)")
                _expect(abs(float(probs.sum()) - 1.0) < 1e-4 and probs[int(action)] > 0,
                        f"{kind}: task {task} step {t}: probabilities sum to {probs.sum():.4f} or exclude the action")
                _, _, _, _, info = env.step(int(action))
            solved += bool(info.get("success"))
            completion += float(info.get("completion", 0.0)) / len(tasks)
        _expect(completion >= 0.8, f"{kind}'s attempts completed {completion:.2f} of the sampled tasks on average "
                                   f"(solved {solved} of {len(tasks)}); an expert must reach at least 0.8")
        lines.append(f"{kind} completed {completion:.2f}, solved {solved}/{len(tasks)}")
    return "; ".join(lines)


def _corrections(spec: DomainSpec, tasks: list[int]) -> str:
    vocab = spec.vocabulary
    said: dict[str, set[str]] = {}
    for kind in spec.correction_kinds:
        oracle = spec.make_corrector(kind)
        for task in tasks:
            env, _ = _random_attempt(spec, task, task)
            a = oracle.correct(env, np.random.default_rng(task)).text
            b = oracle.correct(env, np.random.default_rng(task)).text
            _expect(a == b, f"{kind}: task {task}: the same rng seed gave {a!r} and {b!r}")
            _expect(isinstance(a, str), f"{kind}: task {task}: correction {a!r} is not text")
            unknown = [w for w in split_words(a) if vocab.token_id(w) == vocab.unk_id]
            _expect(not unknown, f"{kind}: task {task}: {a!r} has words outside the vocabulary: {unknown[:5]}")
            said.setdefault(kind, set()).add(a)
    for kind in CONSTANT_KINDS:
        if kind in said:
            _expect(len(said[kind]) == 1, f"{kind} (the retry control) said {len(said[kind])} different sentences")
    oracle = spec.make_corrector("default")
    for task in tasks[:3]:
        env, _ = _random_attempt(spec, task, task)
        text = oracle.full_information(env)
        _expect(isinstance(text, str) and text.strip() != "", f"task {task}: full information {text!r} is not a sentence")
    return ", ".join(f"{k}: {len(v)} sentence(s)" for k, v in said.items())


def _splits(spec: DomainSpec) -> str:
    splits = load_splits(spec.name)
    _expect(set(splits) == set(spec.split_names), f"splits {sorted(splits)}, the spec names {sorted(spec.split_names)}")
    for name, ids in splits.items():
        bad = [t for t in ids if not 0 <= int(t) < spec.num_tasks]
        _expect(not bad, f"split {name} holds task ids outside 0..{spec.num_tasks - 1}: {bad[:5]}")
        _expect(len(set(ids)) == len(ids), f"split {name} repeats a task")
    for train, valid in spec.valid_splits.items():
        chosen_on = {int(t) for t in splits.get(valid, ())}
        _expect(not chosen_on & {int(t) for t in splits.get(train, ())}, f"valid split {valid} shares tasks with {train}")
    default_valid = {int(t) for t in splits.get(spec.valid_splits.get(spec.train_split, ""), ())}
    _expect(not default_valid & {int(t) for t in splits.get(spec.eval_split, ())},
            f"the default valid split shares tasks with the evaluation split {spec.eval_split}")
    trained = {int(t) for t in splits.get(spec.train_split, ())}
    _expect(spec.train_split in splits and spec.eval_split in splits,
            f"the default splits {spec.train_split!r} and {spec.eval_split!r} must be split names")
    _expect(not trained & {int(t) for t in splits.get(spec.eval_split, ())},
            f"the default training split {spec.train_split} shares tasks with the evaluation split {spec.eval_split}")
    return ", ".join(f"{n} {len(ids)}" for n, ids in splits.items())


def _vocabulary(spec: DomainSpec, tasks: list[int]) -> str:
    vocab = spec.vocabulary
    step = max(1, spec.num_tasks // 500)
    for task in range(0, spec.num_tasks, step):
        text = spec.instruction_of(task)
        words = split_words(text)
        unknown = [w for w in words if vocab.token_id(w) == vocab.unk_id]
        _expect(not unknown, f"task {task}: instruction {text!r} has words outside the vocabulary: {unknown[:5]}")
        _expect(len(words) <= vocab.max_tokens, f"task {task}: instruction {text!r} has {len(words)} words, max_tokens "
                                                f"is {vocab.max_tokens}")
    return f"every instruction of {len(range(0, spec.num_tasks, step))} tasks in {vocab.size} words"


def _pictures(spec: DomainSpec) -> str:
    modes = list(getattr(spec.make_env(0), "metadata", {}).get("render_modes", []))
    said = []
    if "ansi" in modes:
        a = _random_attempt(spec, 0, 5, render_mode="ansi")[0].render()
        b = _random_attempt(spec, 0, 5, render_mode="ansi")[0].render()
        _expect(isinstance(a, str) and a == b, "render_mode='ansi' gives no string, or another one for the same seed")
        said.append("ansi")
    if "rgb_array" in modes:
        frame = np.asarray(_random_attempt(spec, 0, 5, render_mode="rgb_array")[0].render())
        _expect(frame.ndim == 3 and frame.shape[2] == 3 and frame.dtype == np.uint8,
                f"render_mode='rgb_array' gives an array of shape {frame.shape} and dtype {frame.dtype}, not (H, W, 3) uint8")
        said.append("rgb_array")
    env = _random_attempt(spec, 0, 5)[0]
    if hasattr(env, "picture_points"):
        points = env.picture_points()
        _expect(len(points) >= 1, "picture_points() is empty after an attempt")
        said.append("path points")
    return f"offers {', '.join(said) if said else 'no picture (teach shows the instruction and corrections only)'}"


def _phrasings(spec: DomainSpec, tasks: list[int]) -> str:
    if spec.correction_phrasings is None:
        return "none declared (a person's correction is checked against the vocabulary alone)"
    known = {" ".join(s.lower().split()) for s in spec.phrasings_of(None)}
    for kind in [k for k in spec.correction_kinds if k not in NUMERIC_KINDS]:
        own = {" ".join(s.lower().split()) for s in spec.phrasings_of(kind)}
        _expect(own <= known, f"correction_phrasings({kind!r}) holds sentences that correction_phrasings() lacks")
        oracle = spec.make_corrector(kind)
        for task in tasks:
            text = oracle.correct(_random_attempt(spec, task, task)[0], np.random.default_rng(task)).text
            _expect(" ".join(text.lower().split()) in own, f"{kind} said {text!r}, which its correction_phrasings lack")
    return f"{len(known)} phrasings cover every correction said, each kind's its own"


def _paraphrases(spec: DomainSpec) -> str:
    p = spec.paraphrases
    if p is None:
        return "none declared"
    vocab = spec.vocabulary_for(True)
    rng = np.random.default_rng(0)
    _expect(set(p.words("heldout")) <= set(p.words("train")) | set(spec.vocabulary.words),
            "held-out paraphrases use words no training phrasing uses")
    texts = sorted({spec.instruction_of(t) for t in range(0, spec.num_tasks, max(1, spec.num_tasks // 50))})
    texts += list(spec.correction_phrasings() if spec.correction_phrasings else ())
    for text in texts:
        for pool in ("train", "heldout"):
            said = p.rewrite(text, pool, rng)
            _expect(vocab.unk_id not in vocab.encode(said) and len(split_words(said)) <= vocab.max_tokens,
                    f"{pool} paraphrase {said!r} of {text!r} has an unknown word or too many")
    return f"{len(p.rules)} rules rewrite {len(texts)} sentences within the vocabulary"

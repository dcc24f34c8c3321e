"""``gpl-dist export PATH --format minari --out DIR``: a run's buffer, or a folder of teaching
logs, as a Minari dataset.

Minari (Farama's offline-RL dataset standard, ``pip install "gpl-dist[export]"``) stores episodes of
(observation, action, reward, termination, truncation, info). Each committed attempt of the buffer
becomes one episode, written in Minari's ``arrow`` format (no pickle; observations uncompressed, not
JPEG-encoded):

- ``observations``: a dict per state, ``observation`` (what the policy read, as the buffer holds
  it, plus the state after the last action, replayed from the attempt's reset seed and actions and
  checked against the stored states), ``instruction`` (the text) and ``instruction_ids`` (the
  token ids the policy read, int64 ``(L,)``): token ids beside the text, so a loader need not
  tokenise (torchrl cannot read a text mission from Minari), and ``correction`` /
  ``correction_ids``: the correction that led to this attempt ("" and zeros for a first attempt),
  at every step as the instruction is;
- ``actions``: the actions the policy executed;
- ``rewards``: the env's dense reward of each step (the paper's PPO reward), from the replay;
- ``terminations`` never, ``truncations`` at the attempt's last step (the time limit);
- ``infos``: ``expert_action`` (the expert's label of each state; -1 for the state after the last
  action, which is not labelled), ``completion`` and ``success`` after each step;
- the episode's metadata (``dataset.storage.get_episode_metadata``): ``task_id``, ``split``,
  ``attempt_index``, ``round``, ``unit``, ``attempt_key``, ``seed`` (the env's reset seed),
  ``policy_version``, ``worker_id``, ``completion``, ``success``, ``reward_sum``, and the language:
  ``corrections_before`` / ``corrections_before_ids`` (the corrections given after each earlier
  attempt of the same task and round, in order: what this attempt was conditioned on) and
  ``correction_after`` / ``correction_after_ids`` / ``correction_after_kind`` (the one given after
  this attempt: the buffer's ``correction`` column).

**Teaching logs** (``gpl-dist teach``/``serve``, ``gpl_dist.app.teaching.LOG_SCHEMA``, read by
``gpl_dist.app.teaching.read_teaching_log`` whichever shape they were written in) export the
same way (``export_teaching_minari``): each logged attempt, undone ones included, is replayed from
its episode's seed and the corrections it was conditioned on (exact: the rollout is seeded), checked
against the completion the log recorded, and written as an episode of the same spaces, labelled by
the expert. Its metadata: ``episode``, ``source``, ``run_dir``, ``checkpoint``, ``checkpoint_round``,
``greedy``, ``task_id``, ``split``, ``attempt_index``, ``seed``, ``completion``, ``success``,
``solved_at`` (of the replay: the step it first solved the task, -1 never), ``undone``,
``hint_shown``, ``started_at``, ``seconds``, the language as above
(``corrections_before`` as the policy read them, with ids) and what the person typed:
``typed_before`` (the text typed for the correction that led to this attempt: it differs from the
last of ``corrections_before`` when the closest known phrasing was sent) and ``unknown_words``.
A teaching log has no ``correction_after``: the correction after an attempt is the next attempt's.

The log files read are the ``*.parquet`` of the folder that ``pyarrow.dataset`` reads: names
starting with ``_`` or ``.`` (a temporary being written, a hidden file) are skipped, and a symbolic
link is refused, not followed (``teaching_log_files``).

``minari.load_dataset(DATASET_ID)`` with ``MINARI_DATASETS_PATH=DIR`` reads it back. The dataset
records an ``env_spec`` (``env_spec``): ``dataset.recover_environment(task_id=T)`` makes the env
of task ``T`` (an episode's metadata names its ``task_id``); the env's observation is the
``observation`` entry of the dataset's dict.

**Where it is written.** ``DATASET_ID`` must be Minari's ``namespace/name-vN`` form and resolve
inside ``DIR`` (``dataset_target``), or nothing is written. The dataset is written into a hidden
temporary folder beside its place (``.tmp-<hex>-<name-vN>``, which Minari's listing skips), read
back, and renamed into place at the end; a failure removes it (and the folders made for it), so a
failed export leaves nothing that blocks the next try.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import string
import uuid
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from gpl_dist.app.replay import step_through
from gpl_dist.config import load_config
from gpl_dist.domains import get_domain
from gpl_dist.errors import UsageError
from storage.fs import resolve
from storage.manifest import committed_rounds, load_manifest
from storage.reader import open_shard_obs, read_shard_table

#: Characters Minari's ``Text`` space of instructions allows (every printable ASCII one).
TEXT_CHARSET = string.printable
#: Longest instruction text the ``Text`` space admits.
MAX_INSTRUCTION_CHARS = 1000


#: Names a reader of a folder of logs skips: pyarrow.dataset's default ``ignore_prefixes``.
SKIPPED_PREFIXES = ("_", ".")
#: Minari's dataset id (minari 0.5.4, ``minari.dataset.minari_dataset.DATASET_ID_RE``: an optional
#: namespace of word characters, '-', '_' and '/', a name, a version), with the version required
#: (``minari.load_dataset`` needs one). Paths outside ``--out`` are excluded besides (``dataset_target``).
DATASET_ID_RE = re.compile(r"(?:(?P<namespace>[-_\w][-_\w/]*[-_\w]+)/)?(?P<dataset>[-_\w]+?)-v(?P<version>\d+)")


def is_temporary(name: str) -> bool:
    """Whether a reader skips the file ``name``: it starts with ``_`` or ``.``, as pyarrow.dataset
    skips (a temporary being written, ``_tmp-<hex>-<name>``, or a hidden file)."""
    return name.startswith(SKIPPED_PREFIXES)


def dataset_target(out: str | Path, dataset_id: str) -> Path:
    """The folder ``out/dataset_id`` of a dataset, checked before anything is written:
    ``UsageError`` (one line) for an id that is not Minari's ``namespace/name-vN`` form, or whose
    folder would not be inside ``out`` (a symbolic link on the way out of it)."""
    shown = repr(dataset_id)[:120]
    if not isinstance(dataset_id, str) or not DATASET_ID_RE.fullmatch(dataset_id) or "//" in dataset_id:
        raise UsageError(f"--dataset-id {shown} is not Minari's namespace/name-vN form (letters, digits, '-' and '_'; "
                         "namespace parts joined by '/'; e.g. gpl-dist/multiroom-run-v0)")
    target = Path(out) / dataset_id
    inside, real = os.path.realpath(out), os.path.realpath(target)
    if os.path.commonpath([inside, real]) != inside:
        raise UsageError(f"--dataset-id {shown} would be written at {real}, outside --out {out} "
                         "(a symbolic link on the way): give another id or --out")
    return target


@contextlib.contextmanager
def _dataset_folder(out: str | Path, dataset_id: str) -> Iterator[Path]:
    """A hidden temporary folder beside the dataset's place (``dataset_target``), to write it in:
    renamed into place when the body ends; removed, with the folders made for it, when it fails."""
    target = dataset_target(out, dataset_id)
    if target.exists() or target.is_symlink():
        raise UsageError(f"{target} exists: remove it or give another --dataset-id")
    made = []  # the folders from --out to the dataset's parent that are not there yet, deepest first
    for folder in (target.parent, *target.parent.parents):
        if folder.exists() or folder.is_symlink():
            break
        made.append(folder)
    tmp = target.parent / f".tmp-{uuid.uuid4().hex[:12]}-{target.name}"
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp.mkdir()
        yield tmp
        if target.exists() or target.is_symlink():
            raise UsageError(f"{target} was made while this export ran: remove it or give another --dataset-id")
        os.rename(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)  # never follows a symbolic link
        for folder in made:
            with contextlib.suppress(OSError):  # not empty: something else is there
                folder.rmdir()
        raise


def default_dataset_id(run_dir: str | Path, domain: str, kind: str = "") -> str:
    """``gpl-dist/<domain>-<run dir name>[-<kind>]-v0``: Minari's ``namespace/name-vN`` form."""
    name = re.sub(r"[^a-z0-9]+", "-", Path(run_dir).resolve().name.lower()).strip("-") or "run"
    return f"gpl-dist/{domain}-{name}{'-' + kind if kind else ''}-v0"


def _minari():
    """Minari's episode buffer, dataset and storage classes; a ``UsageError`` without minari."""
    try:
        from minari.data_collector import EpisodeBuffer
        from minari.dataset.minari_dataset import MinariDataset
        from minari.dataset.minari_storage import MinariStorage
    except ImportError:
        raise UsageError('the Minari export needs minari: pip install "gpl-dist[export]"') from None
    return EpisodeBuffer, MinariDataset, MinariStorage


def env_spec(domain, task_id: int = 0):
    """The gymnasium ``EnvSpec`` a dataset records: the domain's env of ``task_id``, made through
    an importable entry point (``gpl_dist.domains.make_task_env``), so that
    ``dataset.recover_environment(task_id=T)`` rebuilds the env of any episode's task."""
    from gymnasium.envs.registration import EnvSpec

    return EnvSpec(id=domain.env_id, entry_point="gpl_dist.domains:make_task_env",
                   kwargs={"domain": domain.name, "task_id": int(task_id)}, max_episode_steps=domain.steps_per_attempt)


def _new_storage(MinariStorage, domain, vocab, folder: Path) -> tuple[Any, Path]:
    """A new Minari storage of ``domain``'s spaces (the observation dict above) in ``folder/data``."""
    import gymnasium as gym

    env = domain.make_env(0)
    text = gym.spaces.Text(MAX_INSTRUCTION_CHARS, min_length=0, charset=TEXT_CHARSET)
    ids = gym.spaces.Box(0, len(vocab) - 1, (vocab.max_tokens,), np.int64)
    observation_space = gym.spaces.Dict({"observation": env.observation_space, "instruction": text,
                                         "instruction_ids": ids, "correction": text, "correction_ids": ids})
    data_path = folder / "data"
    data_path.mkdir()
    storage = MinariStorage.new(data_path, observation_space=observation_space, action_space=env.action_space,
                                env_spec=env_spec(domain), data_format="arrow", jpeg_encoding=False)
    return storage, data_path


def _finish(storage, MinariDataset, data_path: Path, dataset_id: str, metas: list[dict], algorithm: str,
            description: str) -> None:
    storage.update_episode_metadata(metas, range(len(metas)))
    storage.update_metadata({
        "dataset_id": dataset_id, "algorithm_name": algorithm, "description": description,
        "author": {"gpl-dist"}, "code_permalink": "gpl_dist/app/export.py", "minari_version": _minari_version(),
    })
    MinariDataset(data_path)  # reads back: fails here, not in a user's loader


def export_minari(run_dir: str | Path, buffer_root: str, out: str | Path, dataset_id: str | None = None) -> tuple[str, int]:
    """Write the committed buffer of ``run_dir`` (at ``buffer_root``) as a Minari dataset under the
    datasets folder ``out``; returns the dataset id and the number of episodes."""
    EpisodeBuffer, MinariDataset, MinariStorage = _minari()
    run_dir = Path(run_dir)
    cfg = load_config(run_dir / "config.yaml")
    domain = get_domain(cfg.env.domain)
    vocab = domain.vocabulary_for(cfg.model.paraphrases)
    dataset_id = dataset_id or default_dataset_id(run_dir, domain.name)
    dataset_target(out, dataset_id)  # a bad id fails before the buffer is read
    loc = resolve(buffer_root)
    rounds = committed_rounds(loc)
    if not rounds:
        raise UsageError(f"{buffer_root} has no committed round to export")
    with _dataset_folder(out, dataset_id) as folder:  # renamed into place at the end; removed on failure
        storage, data_path = _new_storage(MinariStorage, domain, vocab, folder)
        metas: list[dict[str, Any]] = []

        def episodes():
            for r in rounds:
                for shard in load_manifest(loc, r).shards:
                    attempts = read_shard_table(loc, shard, "attempts").to_pylist()
                    tuples = read_shard_table(loc, shard, "tuples", ["attempt_key", "t", "action", "expert_action"])
                    obs = open_shard_obs(loc, shard)
                    by_key = {a["attempt_key"]: a for a in attempts}
                    keys = tuples.column("attempt_key").to_numpy()
                    order = np.lexsort((tuples.column("t").to_numpy(), keys))
                    keys, actions = keys[order], tuples.column("action").to_numpy()[order]
                    labels = tuples.column("expert_action").to_numpy()[order]
                    for a in attempts:
                        rows = keys == a["attempt_key"]
                        stored = np.asarray(obs[a["obs_start"]:a["obs_start"] + a["length"]])
                        before = [by_key[k] for k in a["context_keys"]]
                        metas.append({
                            "task_id": a["task_id"], "split": a["split"], "attempt_index": a["attempt_index"],
                            "round": a["round"], "unit": a["unit"], "attempt_key": a["attempt_key"], "seed": a["seed"],
                            "policy_version": a["policy_version"], "worker_id": a["worker_id"],
                            "completion": a["completion"], "success": a["success"], "reward_sum": a["reward_sum"],
                            "instruction": a["instruction"], "instruction_ids": list(a["instruction_ids"]),
                            "corrections_before": [b["correction"] for b in before],
                            "corrections_before_ids": [list(b["correction_ids"]) for b in before],
                            "correction_after": a["correction"], "correction_after_ids": list(a["correction_ids"]),
                            "correction_after_kind": a["correction_kind"],
                        })
                        json.dumps(metas[-1])  # plain values only
                        led = before[-1] if before else None  # the correction this attempt followed
                        yield _episode(EpisodeBuffer, domain, len(metas) - 1, int(a["task_id"]), int(a["seed"]),
                                       a["instruction"], a["instruction_ids"], stored, actions[rows], labels[rows],
                                       f"attempt {a['attempt_key']} (task {a['task_id']}, round {a['round']})",
                                       led["correction"] if led else "",
                                       led["correction_ids"] if led else np.zeros(vocab.max_tokens, np.int64))

        storage.update_episodes(episodes())
        _finish(storage, MinariDataset, data_path, dataset_id, metas,
                "DAgger with language corrections (GPL, Co-Reyes et al. 2019)",
                f"gpl-dist buffer of {run_dir.resolve()} ({domain.name}, model.variant {cfg.model.variant}): "
                "each committed attempt an episode; see gpl_dist/app/export.py")
    return dataset_id, len(metas)


def _log_entries(folder: Path) -> list[os.DirEntry]:
    """The entries of ``folder`` named ``*.parquet`` that a reader does not skip (``is_temporary``)."""
    with os.scandir(folder) as entries:
        return [e for e in entries if e.name.endswith(".parquet") and not is_temporary(e.name)]


def teaching_log_files(log_dir: str | Path) -> list[Path]:
    """The teaching logs of ``log_dir``, sorted: the files ``pyarrow.dataset.dataset(log_dir)`` reads
    (``*.parquet`` not starting with ``_`` or ``.``: never a temporary being written). A symbolic
    link among them is refused (``UsageError``), not followed; a folder named ``*.parquet`` is not
    a log."""
    log_dir = Path(log_dir)
    files = []
    for e in _log_entries(log_dir):
        if e.is_symlink():
            raise UsageError(f"{log_dir / e.name} is a symbolic link: not followed; copy the log it points to "
                             f"into {log_dir} instead")
        if e.is_file(follow_symlinks=False):
            files.append(log_dir / e.name)
    return sorted(files)


def is_teaching_log(path: str | Path) -> bool:
    """Whether ``path`` is a folder of teaching logs (``*.parquet`` that a reader does not skip, no
    run's ``config.yaml``)."""
    p = Path(path)
    return p.is_dir() and not (p / "config.yaml").is_file() and bool(_log_entries(p))


def teaching_chains(rows: list[dict]) -> list[tuple[dict, list[dict]]]:
    """Each logged attempt with the attempts it was conditioned on (``rows`` of one episode, in any
    order): in the order they were made, an attempt of index ``k`` follows the first ``k`` attempts
    then standing (an undo takes the last one back, so the next attempt has its index)."""
    stack: list[dict] = []
    chains = []
    for row in sorted(rows, key=lambda r: (r["started_at"], r["attempt"])):
        k = int(row["attempt"])
        if k > len(stack):
            raise UsageError(f"teaching episode {str(row['episode'])[:40]}: attempt {k} follows {len(stack)} attempt(s) "
                             "(a row is missing from the log)")
        stack = stack[:k]
        chains.append((row, list(stack)))
        stack.append(row)
    return chains


def export_teaching_minari(log_dir: str | Path, out: str | Path, dataset_id: str | None = None,
                           run_dir: str | Path | None = None) -> tuple[str, int]:
    """Write every attempt of the teaching logs in ``log_dir`` as a Minari dataset under ``out``
    (see the module docstring); returns the dataset id and the number of episodes. ``run_dir``
    replaces the run dir the logs name (logs copied from another machine)."""
    from gpl_dist.app.policy import load_policy
    from gpl_dist.app.teaching import read_teaching_log

    EpisodeBuffer, MinariDataset, MinariStorage = _minari()
    if dataset_id:
        dataset_target(out, dataset_id)  # a bad id fails before the logs are read
    log_dir = Path(log_dir)
    files = teaching_log_files(log_dir) if log_dir.is_dir() else []
    if not files:
        raise UsageError(f"{log_dir} holds no teaching log (*.parquet not starting with '_' or '.')")
    rows = read_teaching_log(files)
    sources = {(r["run_dir"], r["checkpoint"], bool(r["greedy"]), r["domain"]) for r in rows}
    domains = {s[3] for s in sources}
    if len(domains) != 1:
        raise UsageError(f"{log_dir}: logs of several domains ({', '.join(sorted(domains))}); export one domain a folder")
    domain_name = domains.pop()
    policies: dict[tuple, Any] = {}
    for run, ckpt, greedy, _ in sources:
        run = str(run_dir) if run_dir else run
        if not Path(ckpt).is_file():
            raise UsageError(f"the checkpoint {ckpt} the logs name is not here: export on the machine that taught, "
                             "or restore the run and give --run-dir")
        policies[(run, ckpt, greedy)] = load_policy(run, ckpt, greedy=greedy, allow_foreign=True)
    domain = get_domain(domain_name)  # after the runs' configs: a plug-in domain is registered by them, as allowed
    first = next(iter(policies.values()))
    vocab = domain.vocabulary_for(first.cfg.model.paraphrases)
    if not dataset_id:  # RUN/teaching/log: named after the run, so two runs' logs do not share an id
        named = log_dir.resolve().parent.parent if log_dir.resolve().parent.name == "teaching" else log_dir
        dataset_id = default_dataset_id(named, domain.name, kind="teaching")
    with _dataset_folder(out, dataset_id) as folder:  # renamed into place at the end; removed on failure
        storage, data_path = _new_storage(MinariStorage, domain, vocab, folder)
        by_episode: dict[str, list[dict]] = {}
        for r in rows:
            by_episode.setdefault(r["episode"], []).append(r)
        metas: list[dict[str, Any]] = []

        def episodes():
            for episode in sorted(by_episode):
                for row, chain in teaching_chains(by_episode[episode]):
                    policy = policies[(str(run_dir) if run_dir else row["run_dir"], row["checkpoint"], bool(row["greedy"]))]
                    texts = [r["correction_before"] for r in chain[1:]] + ([row["correction_before"]] if chain else [])
                    replayed = policy.attempts(int(row["task_id"]), texts, seed=int(row["seed"]))
                    a = replayed[-1]
                    what = f"teaching episode {episode[:40]} attempt {row['attempt']} (task {row['task_id']})"
                    if a.completion != row["completion"]:
                        raise UsageError(f"{what} replays to completion {a.completion:.4f}, not the logged "
                                         f"{row['completion']:.4f}: another checkpoint or code than the one that taught")
                    ids = [[int(i) for i in r.correction_ids] for r in replayed[:-1]]  # what the policy read
                    solved_at = policy.solved_at(a)  # of the attempt replayed, which is the logged one (checked above)
                    metas.append({
                        "episode": episode, "source": row["source"], "run_dir": row["run_dir"], "checkpoint": row["checkpoint"],
                        "checkpoint_round": row["checkpoint_round"], "greedy": row["greedy"], "task_id": row["task_id"],
                        "split": row["split"], "attempt_index": row["attempt"], "seed": row["seed"],
                        "completion": row["completion"], "success": row["success"],
                        "solved_at": -1 if solved_at is None else solved_at, "undone": row["undone"],
                        "hint_shown": row["hint_shown"], "started_at": row["started_at"].isoformat(),
                        "seconds": row["seconds"], "instruction": a.instruction,
                        "instruction_ids": [int(i) for i in a.instruction_ids],
                        "corrections_before": texts, "corrections_before_ids": ids,
                        "typed_before": row["typed"], "unknown_words": list(row["unknown_words"]),
                    })
                    json.dumps(metas[-1])  # plain values only
                    yield _episode(EpisodeBuffer, domain, len(metas) - 1, int(a.task_id), int(a.seed), a.instruction,
                                   a.instruction_ids, np.asarray(a.observations), np.asarray(a.actions),
                                   np.asarray(a.expert_actions), what, texts[-1] if texts else "",
                                   ids[-1] if ids else np.zeros(vocab.max_tokens, np.int64))

        storage.update_episodes(episodes())
        _finish(storage, MinariDataset, data_path, dataset_id, metas,
                "a person's language corrections of a GPL policy (gpl-dist teach/serve)",
                f"gpl-dist teaching logs of {log_dir.resolve()} ({domain.name}): each attempt a person asked for an "
                "episode, replayed from its seed; see gpl_dist/app/export.py")
    return dataset_id, len(metas)


def _minari_version() -> str:
    import minari

    return str(minari.__version__)


def _episode(EpisodeBuffer, domain, index: int, task_id: int, seed: int, instruction: str, instruction_ids,
             stored: np.ndarray, actions: np.ndarray, labels: np.ndarray, what: str, correction: str = "",
             correction_ids=None) -> Any:
    """One attempt as a Minari episode: replayed from ``seed`` through ``actions`` (rewards, the final
    state), checked against the ``stored`` states it acted in; ``correction`` (and its ids) is the
    one that led to it ("" for a first attempt), repeated at every step."""
    course = step_through(domain, task_id, actions, seed, keep_observations=True)
    replayed = course.observations
    assert replayed is not None
    if len(actions) != len(stored) or not np.array_equal(replayed[:-1], stored):
        raise UsageError(f"{what} does not replay to its stored states: its final state cannot be recovered")
    rewards, completion, success = course.rewards.tolist(), course.completion.tolist(), course.success.tolist()
    n = len(replayed)
    return EpisodeBuffer(
        id=index, seed=seed,
        observations={"observation": replayed, "instruction": [instruction] * n,
                      "instruction_ids": np.tile(np.asarray(instruction_ids, np.int64), (n, 1)),
                      "correction": [correction] * n,
                      "correction_ids": np.tile(np.asarray(correction_ids, np.int64), (n, 1))},
        actions=actions.astype(np.int64), rewards=rewards, terminations=[False] * len(rewards),
        truncations=[False] * (len(rewards) - 1) + [True],
        # lists, not 1-D arrays: minari 0.5.4 cannot read back a 1-D array info (an empty shape)
        infos={"expert_action": [*labels.tolist(), -1], "completion": completion, "success": success})

"""``gpl-dist export RUN --format minari --out DIR``: a run's buffer as a Minari dataset.

Minari (Farama's offline-RL dataset standard, ``pip install "gpl-dist[export]"``) stores episodes of
(observation, action, reward, termination, truncation, info). Each committed attempt of the buffer
becomes one episode, written in Minari's ``arrow`` format (no pickle; observations uncompressed, not
JPEG-encoded):

- ``observations``: a dict per state, ``observation`` (what the policy read, as the buffer holds
  it, plus the state after the last action, replayed from the attempt's reset seed and actions and
  checked against the stored states), ``instruction`` (the text) and ``instruction_ids`` (the
  token ids the policy read, int64 ``(L,)``): token ids beside the text, so a loader need not
  tokenise (torchrl cannot read a text mission from Minari);
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

``minari.load_dataset(DATASET_ID)`` with ``MINARI_DATASETS_PATH=DIR`` reads it back.
"""

from __future__ import annotations

import json
import re
import string
from pathlib import Path
from typing import Any

import numpy as np

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


def default_dataset_id(run_dir: str | Path, domain: str) -> str:
    """``gpl-dist/<domain>-<run dir name>-v0``: Minari's ``namespace/name-vN`` form."""
    name = re.sub(r"[^a-z0-9]+", "-", Path(run_dir).resolve().name.lower()).strip("-") or "run"
    return f"gpl-dist/{domain}-{name}-v0"


def export_minari(run_dir: str | Path, buffer_root: str, out: str | Path, dataset_id: str | None = None) -> tuple[str, int]:
    """Write the committed buffer of ``run_dir`` (at ``buffer_root``) as a Minari dataset under the
    datasets folder ``out``; returns the dataset id and the number of episodes."""
    try:
        import gymnasium as gym
        from minari.data_collector import EpisodeBuffer
        from minari.dataset.minari_dataset import MinariDataset
        from minari.dataset.minari_storage import MinariStorage
    except ImportError:
        raise UsageError('the Minari export needs minari: pip install "gpl-dist[export]"') from None

    run_dir = Path(run_dir)
    cfg = load_config(run_dir / "config.yaml")
    domain = get_domain(cfg.env.domain)
    vocab = domain.vocabulary_for(cfg.model.paraphrases)
    dataset_id = dataset_id or default_dataset_id(run_dir, domain.name)
    target = Path(out) / dataset_id
    if target.exists():
        raise UsageError(f"{target} exists: remove it or give another --dataset-id")
    loc = resolve(buffer_root)
    rounds = committed_rounds(loc)
    if not rounds:
        raise UsageError(f"{buffer_root} has no committed round to export")
    env = domain.make_env(0)
    observation_space = gym.spaces.Dict({
        "observation": env.observation_space,
        "instruction": gym.spaces.Text(MAX_INSTRUCTION_CHARS, charset=TEXT_CHARSET),
        "instruction_ids": gym.spaces.Box(0, len(vocab) - 1, (vocab.max_tokens,), np.int64),
    })
    data_path = target / "data"
    data_path.mkdir(parents=True)
    storage = MinariStorage.new(data_path, observation_space=observation_space, action_space=env.action_space,
                                data_format="arrow", jpeg_encoding=False)
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
                    yield _episode(EpisodeBuffer, domain, a, stored, actions[rows], labels[rows], by_key, metas)

    storage.update_episodes(episodes())
    storage.update_episode_metadata(metas, range(len(metas)))
    storage.update_metadata({
        "dataset_id": dataset_id, "algorithm_name": "DAgger with language corrections (GPL, Co-Reyes et al. 2019)",
        "description": f"gpl-dist buffer of {run_dir.resolve()} ({domain.name}, model.variant {cfg.model.variant}): "
                       "each committed attempt an episode; see gpl_dist/app/export.py",
        "author": {"gpl-dist"}, "code_permalink": "gpl_dist/app/export.py",
        "minari_version": _minari_version(),
    })
    MinariDataset(data_path)  # reads back: fails here, not in a user's loader
    return dataset_id, len(metas)


def _minari_version() -> str:
    import minari

    return str(minari.__version__)


def _episode(EpisodeBuffer, domain, a: dict, stored: np.ndarray, actions: np.ndarray, labels: np.ndarray,
             by_key: dict, metas: list) -> Any:
    env = domain.make_env(int(a["task_id"]))
    first, info = env.reset(seed=int(a["seed"]))
    observations, rewards, completion, success = [np.asarray(first)], [], [info["completion"]], [info["success"]]
    for act in actions.tolist():
        o, reward, _, _, info = env.step(act)
        observations.append(np.asarray(o))
        rewards.append(float(reward))
        completion.append(float(info["completion"]))
        success.append(bool(info["success"]))
    replayed = np.stack(observations)
    if len(actions) != len(stored) or not np.array_equal(replayed[:-1], stored):
        raise UsageError(f"attempt {a['attempt_key']} (task {a['task_id']}, round {a['round']}) does not replay to its "
                         "stored states: its final state cannot be recovered")
    n = len(observations)
    before = [by_key[k] for k in a["context_keys"]]
    metas.append({
        "task_id": a["task_id"], "split": a["split"], "attempt_index": a["attempt_index"], "round": a["round"],
        "unit": a["unit"], "attempt_key": a["attempt_key"], "seed": a["seed"], "policy_version": a["policy_version"],
        "worker_id": a["worker_id"], "completion": a["completion"], "success": a["success"],
        "reward_sum": a.get("reward_sum"),
        "instruction": a["instruction"], "instruction_ids": list(a["instruction_ids"]),
        "corrections_before": [b["correction"] for b in before],
        "corrections_before_ids": [list(b["correction_ids"]) for b in before],
        "correction_after": a["correction"], "correction_after_ids": list(a["correction_ids"]),
        "correction_after_kind": a["correction_kind"],
    })
    json.dumps(metas[-1])  # plain values only
    return EpisodeBuffer(
        id=len(metas) - 1, seed=int(a["seed"]),
        observations={"observation": replayed, "instruction": [a["instruction"]] * n,
                      "instruction_ids": np.tile(np.asarray(a["instruction_ids"], np.int64), (n, 1))},
        actions=actions.astype(np.int64), rewards=rewards, terminations=[False] * len(rewards),
        truncations=[False] * (len(rewards) - 1) + [True],
        # lists, not 1-D arrays: minari 0.5.4 cannot read back a 1-D array info (an empty shape)
        infos={"expert_action": [*labels.tolist(), -1], "completion": completion, "success": success})

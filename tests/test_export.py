"""``gpl-dist export RUN --format minari``: the buffer as a Minari dataset, read back with minari
alone and compared field by field with the buffer's own tables and observations."""

import minari  # the test extra installs it (pip install -e ".[test]")
import numpy as np
import pyarrow.dataset as pads
import pytest

from gpl_dist.cli import main
from gpl_dist.domains import get_domain
from storage.fs import resolve
from storage.manifest import committed_rounds, load_manifest
from storage.reader import open_shard_obs


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    run = tmp_path_factory.mktemp("export") / "run"
    assert main(["train", "--config", "configs/multiroom-smoke.yaml", "--serial", "--no-progress", "--run-dir", str(run),
                 "--set", "training.num_rounds=2", "--set", "env.max_train_tasks=3",
                 "--set", "training.num_epochs_per_round=1"]) == 0
    return run


def test_every_field_of_every_attempt_round_trips_through_minari(run, tmp_path, monkeypatch, capsys):
    out = tmp_path / "datasets"
    assert main(["export", str(run), "--format", "minari", "--out", str(out), "--dataset-id", "gpl-dist/mr-smoke-v0"]) == 0
    assert [p.relative_to(out).as_posix() for p in out.glob("*/*")] == ["gpl-dist/mr-smoke-v0"]
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(out))
    dataset = minari.load_dataset("gpl-dist/mr-smoke-v0")

    root = run / "buffer"
    loc = resolve(str(root))
    attempts = pads.dataset(str(root / "data" / "attempts"), format="parquet").to_table().to_pylist()
    tuples = pads.dataset(str(root / "data" / "tuples"), format="parquet").to_table().to_pylist()
    attempts.sort(key=lambda a: a["attempt_key"])
    assert dataset.total_episodes == len(attempts) > 3
    assert dataset.total_steps == len(tuples)
    by_key = {a["attempt_key"]: a for a in attempts}
    obs_of = {}
    for r in committed_rounds(loc):
        for shard in load_manifest(loc, r).shards:
            obs_of[shard.files_of("obs")[0].path.split(".zarr/")[0] + ".zarr"] = np.asarray(open_shard_obs(loc, shard)[:])
    vocab = get_domain("multiroom").vocabulary
    metas = list(dataset.storage.get_episode_metadata(dataset.episode_indices))
    for episode, meta in zip(dataset.iterate_episodes(), metas):
        a = by_key[meta["attempt_key"]]
        steps = sorted((t for t in tuples if t["attempt_key"] == a["attempt_key"]), key=lambda t: t["t"])
        stored = obs_of[a["obs_path"]][a["obs_start"]:a["obs_start"] + a["length"]]
        assert np.array_equal(episode.observations["observation"][:-1], stored)  # what the policy read
        assert episode.observations["observation"].shape == (a["length"] + 1, 7, 7, 6)
        assert np.array_equal(episode.actions, [t["action"] for t in steps])
        assert np.array_equal(episode.infos["expert_action"][:-1], [t["expert_action"] for t in steps])
        assert episode.infos["expert_action"][-1] == -1
        assert set(episode.observations["instruction"]) == {a["instruction"]}
        assert np.array_equal(episode.observations["instruction_ids"], np.tile(a["instruction_ids"], (a["length"] + 1, 1)))
        assert np.array_equal(vocab.encode(a["instruction"]), a["instruction_ids"])
        assert abs(float(np.sum(episode.rewards)) - a["reward_sum"]) < 1e-6  # the replay's rewards: the env's own
        assert float(episode.infos["completion"][-1]) == a["completion"]
        assert bool(episode.truncations[-1]) and not episode.terminations.any()
        for field in ("task_id", "split", "attempt_index", "round", "unit", "seed", "policy_version", "worker_id",
                      "completion", "success", "instruction"):
            assert meta[field] == a[field], field
        assert meta["correction_after"] == a["correction"] and meta["correction_after_ids"] == list(a["correction_ids"])
        assert meta["corrections_before"] == [by_key[k]["correction"] for k in a["context_keys"]]
        assert meta["corrections_before_ids"] == [list(by_key[k]["correction_ids"]) for k in a["context_keys"]]
        # the correction that led to the attempt, at every step beside the instruction ("" for a first attempt)
        led = by_key[a["context_keys"][-1]] if a["context_keys"] else None
        assert set(episode.observations["correction"]) == {led["correction"] if led else ""}
        assert np.array_equal(episode.observations["correction_ids"][0],
                              led["correction_ids"] if led else np.zeros(vocab.max_tokens, np.int64))
    assert any(m["corrections_before"] for m in metas)  # later attempts carry the corrections they followed
    # the dataset rebuilds each episode's env: its task, stepping as the episode did
    for episode, meta in list(zip(dataset.iterate_episodes(), metas))[:3]:
        env = dataset.recover_environment(task_id=meta["task_id"])
        assert env.unwrapped.task_id == meta["task_id"] and env.spec.max_episode_steps == 100
        first, _ = env.reset(seed=meta["seed"])
        assert np.array_equal(first, episode.observations["observation"][0])
    assert main(["export", str(run), "--out", str(out), "--dataset-id", "gpl-dist/mr-smoke-v0"]) == 2  # never overwritten


def test_a_teaching_log_exports_every_attempt_replayed_undone_ones_included(run, tmp_path, monkeypatch, capsys):
    """Issue 40, item 4: teaching logs export the same way; each attempt is replayed from its seed
    and the corrections it followed (an undone one too), with what the person typed beside."""
    from gpl_dist.app.export import teaching_chains
    from gpl_dist.app.teaching import Teacher, write_episode_log

    teacher = Teacher(run)
    episode = teacher.episode(5, seed=2, source="test")
    episode.attempt()
    episode.attempt("enter the gry room")
    undone = episode.undo()
    episode.attempt("enter the grey room", typed="go into the grey rom")
    episode.attempt("go to the blue triangle")
    log = tmp_path / "log"
    write_episode_log(episode, log)
    rows = pads.dataset(str(log), format="parquet").to_table().to_pylist()
    assert len(rows) == 4 and sum(r["undone"] for r in rows) == 1
    out = tmp_path / "datasets"
    assert main(["export", str(log), "--out", str(out), "--dataset-id", "gpl-dist/taught-v0"]) == 0
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(out))
    dataset = minari.load_dataset("gpl-dist/taught-v0")
    assert dataset.total_episodes == 4
    metas = list(dataset.storage.get_episode_metadata(dataset.episode_indices))
    made = sorted(episode.attempts + [undone], key=lambda a: a.started_at)
    assert [(m["attempt_index"], m["undone"]) for m in metas] == [(0, False), (1, True), (1, False), (2, False)]
    by_key = {(m["attempt_index"], m["undone"], tuple(m["corrections_before"])): (e, m)
              for e, m in zip(dataset.iterate_episodes(), metas)}
    assert len(by_key) == 4
    for a in made:
        is_undone = a is undone
        texts = tuple(x.check.text for x in episode.attempts[1:a.index]) + ((a.check.text,) if a.check else ())
        e, m = by_key[(a.index, is_undone, texts)]
        assert np.array_equal(e.actions, a.actions) and np.array_equal(e.observations["observation"][:-1], a.record.observations)
        assert np.array_equal(e.infos["expert_action"][:-1], a.record.expert_actions)
        assert m["completion"] == a.completion == float(e.infos["completion"][-1])
        assert m["seed"] == 2 and m["task_id"] == 5 and m["episode"] == episode.episode_id
        assert m["typed_before"] == (a.typed if a.check else "")
        assert set(e.observations["correction"]) == {a.check.text if a.check else ""}
    assert by_key[(1, False, ("enter the grey room",))][1]["typed_before"] == "go into the grey rom"
    assert by_key[(1, True, ("enter the gry room",))][1]["unknown_words"] == ["gry"]
    # the chain rebuilt from the rows alone: attempt 2 followed the attempt made in the undone one's place
    chains = {(r["attempt"], r["undone"]): [c["correction_before"] for c in chain] for r, chain in teaching_chains(rows)}
    assert chains[(2, False)] == ["", "enter the grey room"] and chains[(1, True)] == [""]
    # RUN/teaching/log without --dataset-id: named after the run, not after the folder "log"
    import shutil

    taught = tmp_path / "myrun" / "teaching" / "log"
    shutil.copytree(log, taught)
    capsys.readouterr()
    assert main(["export", str(taught), "--out", str(out)]) == 0
    assert minari.load_dataset("gpl-dist/multiroom-myrun-teaching-v0").total_episodes == 4

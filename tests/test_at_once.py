"""Runs at once on one machine: ``train --seeds`` and ``suite run`` put as many runs at once as
keep the cores busy (``gpl_dist.app.suite.cluster.local_plan``), and each run's files are what it
gives alone, one after another: the same buffer, metrics and weights, bit for bit."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pyarrow.parquet as pq
import pytest
import torch
from _cluster_tools import TINY_YAML

from gpl_dist.app.suite.schedule import local_plan
from gpl_dist.cli import main

SMOKE = Path(__file__).resolve().parents[1] / "configs" / "multiroom-smoke.yaml"


def _content(path: Path) -> str:
    """A buffer file's content: a table's columns but who wrote it (the run's id, the worker's
    name: an actor's or the serial worker's), or the bytes of an observation chunk."""
    if path.suffix == ".parquet":
        table = pq.read_table(path)
        table = table.drop_columns([c for c in ("run_id", "worker_id") if c in table.column_names])
        return hashlib.sha256(json.dumps(table.to_pydict(), sort_keys=True, default=str).encode()).hexdigest()
    if path.name == "zarr.json":
        meta = json.loads(path.read_text())
        meta.get("attributes", {}).pop("run_id", None)
        meta.get("attributes", {}).pop("worker_id", None)
        return json.dumps(meta, sort_keys=True)
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _fingerprint(run_dir: Path) -> dict:
    """What a run computed: its committed buffer files, its metrics (timings aside) and its weights."""
    buffer = {str(p.relative_to(run_dir)): _content(p) for p in sorted((run_dir / "buffer" / "data").rglob("*"))
              if p.is_file()}
    metrics = [{k: v for k, v in json.loads(line).items() if "seconds" not in k}
               for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    state = torch.load(run_dir / "checkpoints" / "latest.pt", weights_only=True)["model_state"]
    return {"buffer": buffer, "metrics": metrics, "weights": {k: v.clone() for k, v in state.items()}}


def _same(a: dict, b: dict) -> bool:
    return (a["buffer"] == b["buffer"] and a["metrics"] == b["metrics"] and a["weights"].keys() == b["weights"].keys()
            and all(torch.equal(a["weights"][k], b["weights"][k]) for k in a["weights"]))


def test_the_plan_keeps_every_core_busy():
    assert local_plan(5, 2) == local_plan(2, 2) and local_plan(5, 2).runs_at_once == 2
    assert local_plan(5, 2).workers == 1 and local_plan(1, 2).workers == 2 and local_plan(3, 16).workers == 5
    assert local_plan(1, 1).runs_at_once == 1


@pytest.mark.ray
def test_seeds_at_once_are_bit_for_bit_the_runs_one_after_another(tmp_path, ray_cluster, capsys):
    config = tmp_path / "tiny.yaml"
    config.write_text(TINY_YAML)
    assert main(["train", "--config", str(config), "--run-dir", str(tmp_path / "at-once"), "--seeds", "0,1",
                 "--no-progress"]) == 0
    assert "2 run(s) on this machine's" in capsys.readouterr().out
    for seed in (0, 1):
        alone = tmp_path / f"alone{seed}"
        assert main(["train", "--config", str(config), "--run-dir", str(alone), "--serial", "--no-progress",
                     "--set", f"seed={seed}"]) == 0
        assert _same(_fingerprint(tmp_path / "at-once" / f"seed{seed}"), _fingerprint(alone)), seed
    assert not _same(_fingerprint(tmp_path / "alone0"), _fingerprint(tmp_path / "alone1"))
    # each is an ordinary run dir: it resumes alone
    assert main(["train", "--run-dir", str(tmp_path / "at-once" / "seed1"), "--resume", "--serial", "--no-progress",
                 "--set", "training.num_rounds=3"]) == 0
    assert len((tmp_path / "at-once" / "seed1" / "metrics.jsonl").read_text().splitlines()) == 3


@pytest.mark.ray
def test_a_suite_runs_its_seeds_at_once_with_the_files_of_one_after_another(tmp_path, ray_cluster):
    from gpl_dist.app.suite.every_run import run_suite
    from gpl_dist.app.suite.one_run import run_state
    from gpl_dist.app.suite.spec import load_suite, plan

    tiny = {"env.max_train_tasks": 4, "collection.num_corrections": 2, "training.num_epochs_per_round": 1,
            "training.num_rounds": 2}
    path = tmp_path / "suite.yaml"
    path.write_text(json.dumps({  # JSON is YAML
        "evaluations": {"test": {"split": "test", "seeds": [0], "num_corrections": 1, "greedy_actions": False,
                                 "max_tasks": 2}},
        "entries": {"gpl": {"base": str(SMOKE), "set": tiny, "seeds": [0, 1], "evaluations": ["test"]}}}))
    suite = load_suite(path)
    lines: list[str] = []
    run_suite(suite, tmp_path / "at-once", at_once=True, progress=False, log=lines.append)
    assert any("2 run(s) on this machine's" in line and "2 at once" in line for line in lines), lines
    run_suite(suite, tmp_path / "one-by-one", serial=True, progress=False, log=lambda _: None)
    for run in plan(suite, tmp_path / "at-once"):
        assert run_state(run, suite) == "done"
        alone = tmp_path / "one-by-one" / run.run_dir.relative_to(tmp_path / "at-once")
        assert _same(_fingerprint(run.run_dir), _fingerprint(alone)), run.run_dir
        record = json.loads((run.run_dir / "suite-run.json").read_text())
        assert record["numerics"] == json.loads((alone / "suite-run.json").read_text())["numerics"]  # this machine's


def test_status_predicts_the_runs_at_once_longest_first():
    from gpl_dist.app.suite.cost import RunCost, SuiteCost

    runs = tuple(RunCost(None, s, 0.0, "entry") for s in (100.0, 60.0, 50.0, 40.0, 30.0))  # type: ignore[arg-type]
    cost = SuiteCost(runs, rl_seconds=10.0, rl_jobs=1, rl_unknown=0, commits=())
    assert cost.total_seconds == 290.0
    assert cost.at_once_seconds(1) == 290.0
    assert cost.at_once_seconds(2) == 150.0  # 100 + 40 | 60 + 50 + 30: the longer slot, then the RL job
    assert cost.at_once_seconds(5) == 110.0

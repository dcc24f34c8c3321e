"""One DAgger round of BabyAI through the real CLI, serially, then a meta-test: the shipped smoke
config (plugins/gpl-babyai/configs/babyai-smoke.yaml), the domain found by its entry point."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

from gpl_babyai import tasks as task_table
from gpl_babyai.corrections import phrasings
from gpl_babyai.generate import TRAIN_LEVELS

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def _gpl_dist() -> str:
    return shutil.which("gpl-dist") or str(Path(sys.executable).with_name("gpl-dist"))


def test_smoke_config_trains_one_round_serially_and_evaluates(tmp_path):
    from storage import BufferReader

    env = {**os.environ, "OMP_NUM_THREADS": "1"}  # a batched forward on 2 busy cores: one thread
    run = tmp_path / "run"
    train = subprocess.run([_gpl_dist(), "train", "--config", str(CONFIGS / "babyai-smoke.yaml"), "--serial",
                            "--run-dir", str(run), "--no-progress"], capture_output=True, text=True, env=env, timeout=900)
    assert train.returncode == 0, train.stderr[-3000:]
    assert "round 0:" in train.stdout and "c5:" in train.stdout

    reader = BufferReader(run / "buffer")
    assert reader.committed_rounds() == [0]
    attempts = reader.read_table("attempts")
    trained = sorted(set(attempts.column("task_id").to_pylist()))
    assert trained == sorted(task_table.splits()["train"][:18])
    assert {task_table.task(t).level for t in trained} == set(TRAIN_LEVELS)
    said = set(attempts.column("correction").to_pylist()) - {""}
    assert said and said <= set(phrasings())

    done = subprocess.run([_gpl_dist(), "eval", "--run-dir", str(run)], capture_output=True, text=True, env=env,
                          timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    report = json.loads((run / "eval.json").read_text())
    assert report["domain"] == "babyai" and report["num_tasks"] == 18 and len(report["completion"]) == 6
    assert all(0.0 <= c <= 1.0 for c in report["completion"])

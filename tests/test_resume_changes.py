"""``--resume`` says what it changes (issue 65): a setting it can apply (``learner.driver.RESUMABLE``)
applies from the next round, is printed in one line and recorded with the rounds that used it; one
that would change what the rounds already trained mean (the seed, the domain's tasks, the
collection's method, ...) is refused in one line before anything is written; ``config.yaml`` stays
the run as it was created. Real serial runs of 4 multi-room tasks through the CLI."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import torch
import yaml

from gpl_dist.cli import main
from learner.checkpoint import load_checkpoint


def _train_argv(run: Path, *extra: str) -> list[str]:
    return ["train", "--serial", "--no-progress", "--run-dir", str(run), *extra]


@pytest.fixture(scope="module")
def one_round(tmp_path_factory) -> Path:
    """A finished 1-round run (made once; the tests work on copies)."""
    run = tmp_path_factory.mktemp("resume") / "run"
    assert main(_train_argv(run, "--config", "configs/multiroom-smoke.yaml", "--set", "training.num_rounds=1",
                            "--set", "env.max_train_tasks=4", "--set", "training.num_epochs_per_round=1")) == 0
    return run


def _copy(run: Path, dst: Path) -> Path:
    shutil.copytree(run, dst, ignore=shutil.ignore_patterns("_lease*", "tb"))
    return dst


def _snapshot(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and not p.name.startswith("_lease")}


def _lr(ckpt_path: Path) -> float:
    return load_checkpoint(ckpt_path).optimizer_state["param_groups"][0]["lr"]


def test_a_resume_applies_a_new_learning_rate_from_the_next_round_says_so_and_records_it(one_round, tmp_path, capsys):
    changed, plain = _copy(one_round, tmp_path / "changed"), _copy(one_round, tmp_path / "plain")
    created = (changed / "config.yaml").read_text()
    capsys.readouterr()
    assert main(_train_argv(changed, "--resume", "--set", "training.num_rounds=2",
                            "--set", "training.learning_rate=0.5")) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "--resume changes training.learning_rate 0.001 -> 0.5 from round 1" in lines, lines[:5]
    assert "--resume changes training.num_rounds 1 -> 2 from round 1" in lines, lines[:5]
    assert main(_train_argv(plain, "--resume", "--set", "training.num_rounds=2")) == 0
    assert [x for x in capsys.readouterr().out.splitlines() if x.startswith("--resume changes")] == \
        ["--resume changes training.num_rounds 1 -> 2 from round 1"]
    # applied: Adam stepped round 1 with 0.5, and the weights differ from a resume without it
    assert _lr(changed / "checkpoints" / "latest.pt") == 0.5 and _lr(plain / "checkpoints" / "latest.pt") == 0.001
    assert _lr(changed / "checkpoints" / "round-000000.pt") == 0.001
    a, b = load_checkpoint(changed / "checkpoints").model_state, load_checkpoint(plain / "checkpoints").model_state
    assert any(not torch.equal(a[k], b[k]) for k in a)
    # recorded per round: each round's checkpoint has the config it used, metrics.jsonl the change
    assert load_checkpoint(changed / "checkpoints" / "round-000000.pt").config["training"]["learning_rate"] == 0.001
    assert load_checkpoint(changed / "checkpoints" / "round-000001.pt").config["training"]["learning_rate"] == 0.5
    rows = [json.loads(x) for x in (changed / "metrics.jsonl").read_text().splitlines()]
    assert "config_changes" not in rows[0]
    assert rows[1]["config_changes"] == {"training.num_rounds": [1, 2], "training.learning_rate": [0.001, 0.5]}
    # config.yaml claims nothing for rounds that did not use it: it is the run as created
    assert (changed / "config.yaml").read_text() == created
    assert yaml.safe_load(created)["training"]["learning_rate"] == 0.001


@pytest.mark.parametrize("override, needle", [
    ("seed=7", "--resume cannot change seed (0 -> 7): round 0 was trained so, and a resume must not change "
     "what the rounds done mean"),
    ("env.max_train_tasks=3", "--resume cannot change env.max_train_tasks (4 -> 3)"),
    ("collection.num_corrections=2", "--resume cannot change collection.num_corrections (5 -> 2)"),
    ("buffer.location={tmp}/elsewhere", '--resume cannot change buffer.location ("" -> {tmp}/elsewhere)'),
])
def test_a_resume_refuses_what_it_cannot_apply_in_one_line_before_writing_anything(one_round, tmp_path, capsys,
                                                                                   override, needle):
    override, needle = override.format(tmp=tmp_path), needle.format(tmp=tmp_path)
    run = _copy(one_round, tmp_path / "run")
    before = _snapshot(run)
    capsys.readouterr()
    assert main(_train_argv(run, "--resume", "--set", "training.num_rounds=2", "--set", override)) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("gpl-dist: error: ") and "\n" not in err and needle in err, err
    assert _snapshot(run) == before
    assert not (tmp_path / "elsewhere").exists()  # nor outside it (a lease of the new buffer location)


def test_a_later_resume_continues_with_the_changed_setting(one_round, tmp_path, capsys):
    """The config a resume continues with is the latest checkpoint's (``resume_config``), not
    config.yaml's: a second resume keeps the new learning rate and says only what it changes."""
    from learner.driver import resume_config, run_training

    run = _copy(one_round, tmp_path / "run")
    run_training(resume_config(run, {"training.num_rounds": "2", "training.learning_rate": "0.5"}), run, serial=True,
                 resume=True, progress=False)
    capsys.readouterr()
    cfg = resume_config(run, {"training.num_rounds": "3"})
    assert cfg.training.learning_rate == 0.5
    result = run_training(cfg, run, serial=True, resume=True, progress=False)
    changes = [x for x in capsys.readouterr().out.splitlines() if x.startswith("--resume")]
    assert changes == ["--resume changes training.num_rounds 2 -> 3 from round 2"]
    assert _lr(run / "checkpoints" / "latest.pt") == 0.5
    assert [m.config_changes for m in result.history] == [(), (("training.num_rounds", 1, 2),
                                                               ("training.learning_rate", 0.001, 0.5)),
                                                          (("training.num_rounds", 2, 3),)]


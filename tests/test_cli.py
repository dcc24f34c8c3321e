"""The gpl-dist command line, run as a user would (in-process through main(), and as a console script)."""

import json
import subprocess
import sys

import numpy as np
from PIL import Image

from gpl_dist.cli import main
from gpl_dist.domains import get_domain
from learner.checkpoint import load_checkpoint
from learner.evaluate import EVAL_SCHEMA, EvalRecord, read_eval


def test_render_png_and_gif(tmp_path, capsys):
    assert main(["render", "--env", "multiroom", "--task", "17", "--out", str(tmp_path / "t.png")]) == 0
    img = np.asarray(Image.open(tmp_path / "t.png"))
    assert img.ndim == 3 and img.shape[2] == 3 and img.shape[0] >= 19 * 8
    assert main(["render", "--env", "multiroom", "--task", "17", "--expert", "--out", str(tmp_path / "t.gif")]) == 0
    gif = Image.open(tmp_path / "t.gif")
    assert gif.n_frames > 10
    assert main(["render", "--env", "relocation", "--task", "3", "--actions", "2,2,2,0,0", "--out", str(tmp_path / "r.gif")]) == 0
    assert Image.open(tmp_path / "r.gif").n_frames == 6


def test_render_errors_are_one_line(tmp_path, capsys):
    assert main(["render", "--env", "multiroom", "--task", "5000", "--out", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("gpl-dist: error:") and "task_id" in err and "\n" not in err
    assert main(["render", "--env", "multiroom", "--task", "1", "--actions", "0,9", "--out", str(tmp_path / "x.gif")]) == 2
    err = capsys.readouterr().err.strip()
    assert "action 9" in err and "\n" not in err
    assert not list(tmp_path.iterdir())  # neither picture was written


def test_render_draws_a_trained_policys_attempts_with_the_corrections_between(tmp_path, capsys, monkeypatch):
    run = tmp_path / "run"
    assert main(["train", "--config", "configs/multiroom-smoke.yaml", "--serial", "--no-progress", "--run-dir", str(run),
                 "--set", "training.num_rounds=1", "--set", "env.max_train_tasks=4",
                 "--set", "training.num_epochs_per_round=1"]) == 0
    captions = []
    import gpl_dist.app.rendering as rendering
    draw = rendering._captioned

    def recording(frame, lines, **kw):
        captions.append((" ".join(x for x in lines[:-1] if x), lines[-1]))
        return draw(frame, lines, **kw)

    monkeypatch.setattr(rendering, "_captioned", recording)
    assert main(["render", "--run-dir", str(run), "--task", "263", "--attempts", "3", "--out", str(tmp_path / "p.gif")]) == 0
    gif = Image.open(tmp_path / "p.gif")
    assert gif.n_frames > 3 and gif.size[0] == 400
    tops = list(dict.fromkeys(top for top, _ in captions))  # one caption per attempt, in order
    instruction = get_domain("multiroom").make_env(263).instruction
    assert tops[0].startswith("attempt 1/") and tops[0].endswith(f": instruction: {instruction}")  # whole, wrapped
    assert all(": correction: " in t for t in tops[1:]) and len(tops) <= 3
    assert all(b.startswith("step ") and ": completion " in b for _, b in captions)
    sizes = set()
    for i in range(gif.n_frames):  # wrapped captions of different lengths: every frame the same size
        gif.seek(i)
        sizes.add(gif.size)
    assert len(sizes) == 1
    capsys.readouterr()
    for args, needle in ((["--task", "99999"], "99999"), (["--task", "1", "--attempts", "0"], "--attempts"),
                         (["--task", "1", "--env", "multiroom"], "--env")):
        assert main(["render", "--run-dir", str(run), *args, "--out", str(tmp_path / "x.gif")]) == 2
        err = capsys.readouterr().err.strip()
        assert needle in err and "\n" not in err, err
    assert not (tmp_path / "x.gif").exists()


def test_train_rejects_bad_config_in_one_line(tmp_path, capsys):
    cfg = tmp_path / "bad.yaml"
    cfg.write_text("collection:\n  num_correction: 3\n")
    assert main(["train", "--config", str(cfg), "--run-dir", str(tmp_path / "run"), "--serial"]) == 2
    err = capsys.readouterr().err.strip()
    assert "collection.num_correction" in err and "\n" not in err
    assert not (tmp_path / "run").exists()
    assert main(["train", "--config", str(tmp_path / "missing.yaml"), "--run-dir", str(tmp_path / "run")]) == 2
    assert str(tmp_path / "missing.yaml") in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


def test_train_eval_inspect_clean(tmp_path, capsys):
    run = tmp_path / "run"
    args = ["train", "--config", "configs/multiroom-smoke.yaml", "--serial", "--run-dir", str(run), "--no-progress",
            "--set", "env.max_train_tasks=4", "--set", "collection.tasks_per_unit=2", "--set", "collection.num_corrections=2",
            "--set", "training.num_rounds=1", "--set", "training.num_epochs_per_round=1"]
    assert main(args) == 0
    (trained,) = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert trained["round"] == 0 and len(trained["completion_by_corrections"]) == 3  # c0..c2
    assert load_checkpoint(run / "checkpoints").round_index == 0

    assert main(["eval", "--run-dir", str(run), "--max-tasks", "3", "--seeds", "0,1", "--corrections", "2"]) == 0
    out = capsys.readouterr().out
    assert "c0" in out and "c2" in out and "paper" in out
    # settings other than the run's own eval section get their own report, named after the difference
    report = run / "eval-c2-first3.json"  # seeds 0,1 are the config's own
    assert sorted(run.glob("eval*.json")) == [report]
    result = read_eval(report)
    assert result.num_tasks == 3 and len(result.completion) == 3 and len(result.per_seed) == 2
    assert result.split == "test" and result.greedy_actions is False and result.max_tasks == 3
    assert result.schema_version == EVAL_SCHEMA and EvalRecord.from_json(report.read_text()) == result
    assert main(["eval", "--run-dir", str(run), "--max-tasks", "2", "--seeds", "0", "--corrections", "1", "--greedy"]) == 0
    greedy = run / "eval-greedy-c1-seeds0-first2.json"
    assert read_eval(greedy).greedy_actions is True
    assert read_eval(report) == result  # the first report is untouched
    assert greedy.with_suffix(".png").stat().st_size > 1000
    assert not (run / "eval.json").exists()
    from gpl_dist.config import RunConfig
    from learner.evaluate import report_stem
    own = dict(split="test", greedy=False, num_corrections=5, seeds=(0, 1, 2), max_tasks=0, checkpoint=None)
    assert report_stem(RunConfig(), **own) == "eval"
    assert report_stem(RunConfig(), **{**own, "split": "train", "checkpoint": "c/round-000003.pt"}) == \
        "eval-train-round-000003"

    assert main(["inspect", str(run), "--tasks"]) == 0
    out = capsys.readouterr().out
    assert "round" in out.lower() and "attempt" in out.lower()

    dead = run / "buffer" / "staging" / "round-000009" / "unit-00000" / "_tmp-dead-writer"
    dead.mkdir(parents=True)
    (dead / "tuples.parquet").write_text("partial")

    def committed():
        return {p: p.read_bytes() for p in (run / "buffer").rglob("*")
                if p.is_file() and "staging" not in p.parts and not p.name.startswith("_lease")}

    before = committed()
    assert main(["clean", str(run), "--dry-run"]) == 0
    assert "_tmp-dead-writer" in capsys.readouterr().out and (dead / "tuples.parquet").read_text() == "partial"
    assert main(["clean", str(run)]) == 0
    assert not dead.exists() and before and committed() == before
    # committed data is untouched
    assert main(["inspect", str(run)]) == 0


def test_console_script_help():
    out = subprocess.run([sys.executable, "-m", "gpl_dist.cli", "--help"], capture_output=True, text=True, check=True).stdout
    for command in ("train", "eval", "render", "inspect", "clean"):
        assert command in out

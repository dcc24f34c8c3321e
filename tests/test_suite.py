"""The suite runner and report: parse, run, skip, resume after a kill, refuse a changed entry,
report the paper's tables from the eval files, and run entries as Ray tasks on a cluster."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path

import pytest

from gpl_dist.app.suite.every_run import run_suite
from gpl_dist.app.suite.one_run import run_state
from gpl_dist.app.suite.report import collect_results
from gpl_dist.app.suite.spec import load_suite, plan
from gpl_dist.cli import main
from gpl_dist.config import ConfigError
from learner.evaluate import read_eval
from tests.test_safety import _one_line_error

REPO = Path(__file__).resolve().parent.parent
SMOKE = REPO / "configs" / "multiroom-smoke.yaml"
TINY = {"env.max_train_tasks": 4, "collection.num_corrections": 2, "training.num_epochs_per_round": 1,
        "training.num_rounds": 2, "collection.num_workers": 1}


def write_suite(path: Path, entries: dict, evaluations: dict | None = None) -> Path:
    evaluations = evaluations or {"test": {"split": "test", "seeds": [0, 1], "num_corrections": 2,
                                           "greedy_actions": False, "max_tasks": 4}}
    path.write_text(json.dumps({"evaluations": evaluations, "entries": entries}))  # JSON is YAML
    return path


def entry(seeds=(0,), evaluations=("test",), **overrides) -> dict:
    return {"base": str(SMOKE), "set": {**TINY, **overrides}, "seeds": list(seeds), "evaluations": list(evaluations)}


def rounds_in(run_dir: Path) -> list[int]:
    return [json.loads(line)["round"] for line in (run_dir / "metrics.jsonl").read_text().splitlines()]


@pytest.mark.parametrize("change, needle", [
    ({"entries": {"a": {**entry(), "colour": 1}}}, "unknown key 'colour'"),
    ({"entries": {"a": entry(evaluations=("nope",))}}, "unknown evaluation 'nope'"),
    ({"entries": {"a": entry(**{"eval.split": "valid"})}}, "is the suite's to set"),
    ({"entries": {"a": entry(seeds=(0, 0))}}, "seeds repeat"),
    ({"entries": {"a": entry(**{"model.variant": "mivoa-typo"})}}, "model.variant must be one of"),
    ({"entries": {"a/b": entry()}}, "names a folder"),
    ({"evaluations": {"test": {"split": "test", "seeds": [0], "num_corrections": "5", "greedy_actions": False}}},
     "expected int"),
    ({"evaluations": {"test": {"split": "test", "seeds": [0], "num_corrections": 2, "greedy_actions": False},
                      "later": {"split": "nope", "seeds": [0], "num_corrections": 2, "greedy_actions": False}},
      "entries": {"a": entry(evaluations=("test", "later"))}}, "eval.split"),  # a later evaluation is checked too
    ({"entries": {"a": entry(**{"buffer.location": "/tmp/one-buffer"})}}, "buffer.location would put"),
    ({"evaluations": [{"split": "test"}]}, "expected a mapping of names"),
])
def test_a_bad_suite_fails_in_one_line_before_anything_runs(tmp_path, capsys, change, needle):
    spec = {"evaluations": {"test": {"split": "test", "seeds": [0], "num_corrections": 2, "greedy_actions": False}},
            "entries": {"a": entry()}, **change}
    path = tmp_path / "suite.yaml"
    path.write_text(json.dumps(spec))
    assert main(["suite", "run", str(path), "--out", str(tmp_path / "out"), "--serial"]) == 2
    _one_line_error(capsys, needle)
    assert not (tmp_path / "out").exists()


def test_a_suite_runs_every_entry_once_and_a_rerun_skips_them(tmp_path):
    entries = {"gpl": entry(seeds=(0, 1)), "instr": entry(**{"model.variant": "instruction_only"})}
    path = write_suite(tmp_path / "suite.yaml", entries)
    suite = load_suite(path)
    out = tmp_path / "out"
    before = run_suite(suite, out, serial=True, progress=False)
    assert [s for _, s in before] == ["new", "new", "new"]
    for run in plan(suite, out):
        assert run_state(run, suite) == "done"
        assert rounds_in(run.run_dir) == [0, 1]
        record = json.loads((run.run_dir / "suite-run.json").read_text())
        assert record["entry"] == run.entry.name and record["seed"] == run.seed and record["commits"]
        evaluated = read_eval(run.run_dir / record["evaluations"]["test"]["file"])
        assert evaluated.seeds == (0, 1) and evaluated.num_corrections == 2 and evaluated.max_tasks == 4
    # the suite's settings went into each run's config: seed and evaluation
    assert "seed: 1" in (out / "gpl" / "seed1" / "config.yaml").read_text()
    stamp = (out / "gpl" / "seed0" / "metrics.jsonl").stat().st_mtime_ns
    assert [s for _, s in run_suite(suite, out, serial=True, progress=False)] == ["done"] * 3
    assert (out / "gpl" / "seed0" / "metrics.jsonl").stat().st_mtime_ns == stamp
    # --only and --seeds select
    assert [(r.entry.name, r.seed) for r in plan(suite, out, only=("gpl",), seeds=(1,))] == [("gpl", 1)]
    with pytest.raises(ConfigError, match="no entry 'nope'"):
        plan(suite, out, only=("nope",))


def test_a_killed_suite_resumes_without_repeating_a_round(tmp_path, capsys):
    path = write_suite(tmp_path / "suite.yaml", {"gpl": entry(**{"training.num_rounds": 4, "env.max_train_tasks": 24})})
    out = tmp_path / "out"
    run_dir = out / "gpl" / "seed0"
    proc = subprocess.Popen([sys.executable, "-m", "gpl_dist.cli", "suite", "run", str(path), "--out", str(out),
                             "--serial", "--no-progress"], cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + 300
        while not (run_dir / "metrics.jsonl").exists() or not rounds_in(run_dir):
            assert proc.poll() is None and time.monotonic() < deadline, "the suite ended before its first round"
            time.sleep(0.2)
        assert main(["suite", "status", str(path), "--out", str(out)]) == 0
        assert capsys.readouterr().out.startswith(f"running  gpl seed 0  ({run_dir}; gpl-dist train (pid ")
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # our own child's process group
        proc.wait()
    suite = load_suite(path)
    (run,) = plan(suite, out)
    killed_after = rounds_in(run_dir)
    assert run_state(run, suite) == "resume" and len(killed_after) < 4
    assert main(["suite", "status", str(path), "--out", str(out)]) == 0
    assert capsys.readouterr().out.startswith("resume   gpl seed 0")
    run_suite(suite, out, serial=True, progress=False)
    assert rounds_in(run_dir) == [0, 1, 2, 3]
    assert run_state(run, suite) == "done"


def test_a_run_made_by_another_version_of_its_entry_is_refused(tmp_path, capsys):
    out = tmp_path / "out"
    run_suite(load_suite(write_suite(tmp_path / "a.yaml", {"gpl": entry()})), out, serial=True, progress=False)
    changed = write_suite(tmp_path / "b.yaml", {"gpl": entry(**{"training.learning_rate": 0.01})})
    assert main(["suite", "run", str(changed), "--out", str(out), "--serial"]) == 2
    _one_line_error(capsys, "another config than entry 'gpl'")


def test_another_suite_evaluates_a_run_it_did_not_train_under_its_own_settings(tmp_path):
    """An entry trained the same way under another suite, whose first evaluation differs (the run's
    config.yaml holds that evaluation's eval section), is the same training: kept, and evaluated
    under this suite's evaluations only; its own evaluations stay as they were."""
    out = tmp_path / "out"
    first = load_suite(write_suite(tmp_path / "a.yaml", {"gpl": entry()}))
    run_suite(first, out, serial=True, progress=False)
    run_dir = out / "gpl" / "seed0"
    test_eval = (run_dir / "eval.json").read_bytes()
    curve = (run_dir / "curve-valid.json").read_bytes()  # capped at this suite's 4 tasks
    checkpoints = sorted(p.name for p in (run_dir / "checkpoints").iterdir())
    valid = {"valid": {"split": "valid", "seeds": [0], "num_corrections": 1, "greedy_actions": False, "max_tasks": 3}}
    second = load_suite(write_suite(tmp_path / "b.yaml", {"gpl": entry(evaluations=("valid",))}, valid))
    (run,) = plan(second, out)
    assert run_state(run, second) == "evaluate"
    run_suite(second, out, serial=True, progress=False)
    assert run_state(run, second) == "done"
    record = json.loads((run_dir / "suite-run.json").read_text())
    assert sorted(record["evaluations"]) == ["test", "valid"]
    assert record["evaluations"]["valid"]["settings"]["split"] == "valid"
    assert (run_dir / "eval.json").read_bytes() == test_eval
    assert (run_dir / "curve-valid.json").read_bytes() == curve  # the training suite's curve, not measured again
    assert sorted(p.name for p in (run_dir / "checkpoints").iterdir()) == checkpoints  # nothing trained again


def test_the_report_holds_every_paper_row_and_only_numbers_from_eval_files(tmp_path):
    """Tiny real runs of three of the paper's entries: under their own suite file (three entries)
    the report is that suite's, with its rows and none of the paper's; under the paper's suite file
    (its copy in OUT) it holds every row of the paper's tables, each cell from the eval files."""
    import shutil

    from gpl_dist.app.suite.report_paper import load_paper

    evaluations = {"test": {"split": "test", "seeds": [0, 1], "num_corrections": 5, "greedy_actions": False, "max_tasks": 3},
                   "test-c10": {"split": "test", "seeds": [0], "num_corrections": 10, "greedy_actions": False, "max_tasks": 2}}
    path = write_suite(tmp_path / "suite.yaml", {
        "multiroom-gpl": entry(seeds=(0, 1, 2), evaluations=("test", "test-c10"), **{"training.num_rounds": 1}),
        "multiroom-instruction": entry(**{"model.variant": "instruction_only", "training.num_rounds": 1}),
        "multiroom-no-trajectory": entry(**{"model.variant": "no_trajectory"})}, evaluations)
    out = tmp_path / "out"
    run_suite(load_suite(path), out, only=("multiroom-gpl", "multiroom-instruction"), seeds=(0, 1), serial=True,
              progress=False)
    # GPL's c1 cell is the mean over training seeds of each run's eval.json completion, ± its 95 % t
    # interval's half-width (t(0.975, 1) = 12.706)
    per_seed = [read_eval(out / "multiroom-gpl" / f"seed{s}" / "eval.json").completion[1] for s in (0, 1)]
    mean, half = statistics.fmean(per_seed), 12.7062047 * statistics.stdev(per_seed) / 2 ** 0.5
    assert main(["suite", "report", str(out), "--out", str(tmp_path / "own")]) == 0
    own = (tmp_path / "own" / "report.md").read_text()
    assert own.startswith("# The suite's experiments\n") and "## Table 1" not in own and "| GPL |" not in own
    test = own.split("## Evaluation 'test': every entry\n", 1)[1].split("\n## ", 1)[0]
    own_row = next(line for line in test.splitlines() if line.startswith("| multiroom-gpl |"))
    assert own_row.startswith("| multiroom-gpl | multiroom | 1 |") and f"| {mean:.3f} ± {half:.3f} |" in own_row
    assert own_row.endswith("| 2 training seed(s): 0, 1; not run yet: 2 |")  # the suite file's seed 2 is missing
    assert next(line for line in test.splitlines() if line.startswith("| multiroom-no-trajectory |")).endswith(
        "| not run yet |")
    assert "## Evaluation 'test-c10': every entry" in own
    # the same runs under the paper's suite file: the paper's tables
    shutil.copyfile(REPO / "configs" / "suites" / "paper.yaml", out / "suite.yaml")
    assert main(["suite", "report", str(out), "--out", str(tmp_path / "report")]) == 0
    md = (tmp_path / "report" / "report.md").read_text()
    assert md.startswith("# The paper's experiments, reproduced\n") and "## Evaluation 'test'" not in md
    paper = load_paper()
    assert paper is not None
    for table in paper.tables:
        for row in table.rows:
            assert f"| {row.label} |" in md
    # beside it, where the paper's 0.46 lies against its interval
    gpl_row = next(line for line in md.splitlines() if line.startswith("| GPL |"))
    where = "" if mean - half <= 0.46 <= mean + half else f"; ours {'above' if mean - half > 0.46 else 'below'}"
    assert f"{mean:.3f} ± {half:.3f} (0.46{where})" in gpl_row
    for section in ("## Comparisons", "## Budgets", "## Learning curves", "## Run health", "## Per training seed"):
        assert section in md
    health = md.split("## Run health", 1)[1].split("\n## ", 1)[0]
    assert "`runs/multiroom-gpl/seed0`" in health and "3 runs; 0 not valid" in health
    assert gpl_row.endswith("| 2 training seed(s): 0, 1; not run yet: 2, 3, 4 |")  # the paper's seeds 2-4 are missing
    assert "not in the paper either" in md and "| No trajectory |" in md
    no_trajectory_row = next(line for line in md.splitlines() if line.startswith("| No trajectory |"))
    assert no_trajectory_row.endswith("| not run yet |")
    not_run = md.split("## Not run yet", 1)[1].split("\n## ", 1)[0]  # every run of the suite file not reported, only those
    listed = [line for line in not_run.splitlines() if line.startswith("- ")]
    assert "- `multiroom-gpl`: training seed(s) 2, 3, 4" in listed and len(listed) == len(paper.entries)
    assert "- `multiroom-no-trajectory`: training seed(s) 0, 1, 2, 3, 4" in listed
    effort = read_eval(out / "multiroom-gpl" / "seed0" / "eval.json").correction_effort
    effort_md = md.split("## Correction effort", 1)[1].split("\n## ", 1)[0]
    effort_row = next(line for line in effort_md.splitlines() if line.startswith("| multiroom-gpl |"))
    auc = [read_eval(out / "multiroom-gpl" / f"seed{s}" / "eval.json").correction_effort.completion_auc for s in (0, 1)]
    assert effort is not None and f"{statistics.fmean(auc):.3f}" in effort_row and effort.unsolved_fraction >= 0
    results = collect_results(out)
    assert {(r.entry, r.evaluation) for r in results} == {("multiroom-gpl", "test"), ("multiroom-gpl", "test-c10"),
                                                          ("multiroom-instruction", "test")}
    html = (tmp_path / "report" / "report.html").read_text()
    assert html.count("data:image/png;base64,") >= 4 and "<table>" in html
    assert "<li>multiroom-no-trajectory: training seed(s) 0, 1, 2, 3, 4</li>" in html
    assert (tmp_path / "report" / "table2.png").stat().st_size > 1000


@pytest.mark.ray
def test_a_suite_on_a_ray_cluster_runs_its_entries_as_tasks(tmp_path, ray_cluster):
    path = write_suite(tmp_path / "suite.yaml", {"gpl": entry(seeds=(0, 1), **{"training.num_rounds": 1})})
    suite = load_suite(path)
    out = tmp_path / "out"
    address = ray_cluster.get_runtime_context().gcs_address
    run_suite(suite, out, address=address, progress=False)
    for run in plan(suite, out):
        assert run_state(run, suite) == "done" and rounds_in(run.run_dir) == [0]


def test_a_changed_evaluation_and_an_empty_selection_are_refused(tmp_path, capsys):
    out = tmp_path / "out"
    ev = {"split": "test", "seeds": [0], "num_corrections": 2, "greedy_actions": False, "max_tasks": 2}
    first = write_suite(tmp_path / "a.yaml", {"gpl": entry(evaluations=("test", "more"), **{"training.num_rounds": 1})},
                        {"test": ev, "more": {**ev, "num_corrections": 3}})
    run_suite(load_suite(first), out, serial=True, progress=False)
    changed = write_suite(tmp_path / "b.yaml", {"gpl": entry(evaluations=("test", "more"), **{"training.num_rounds": 1})},
                          {"test": ev, "more": {**ev, "num_corrections": 4}})
    assert main(["suite", "run", str(changed), "--out", str(out), "--serial"]) == 2
    _one_line_error(capsys, "evaluation 'more' was made with other settings")
    assert main(["suite", "run", str(first), "--out", str(out), "--serial", "--seeds", "7"]) == 2
    _one_line_error(capsys, "select no run")
    assert main(["suite", "run", str(first), "--out", str(out), "--serial", "--address", "auto"]) == 2
    _one_line_error(capsys, "give one of them")


def test_held_out_phrasings_are_an_evaluation_and_older_records_still_count(tmp_path):
    """An evaluation may name its phrasings; a record written before that setting existed reads
    as canonical, so adding the setting neither re-runs nor refuses finished runs."""
    out = tmp_path / "out"
    ev = {"split": "test", "seeds": [0], "num_corrections": 2, "greedy_actions": False, "max_tasks": 2}
    path = write_suite(tmp_path / "s.yaml", {"para": entry(**{"training.num_rounds": 1, "model.paraphrases": True},
                                                          evaluations=("test", "test-heldout-phrasings"))},
                       {"test": ev, "test-heldout-phrasings": {**ev, "phrasings": "heldout"}})
    suite = load_suite(path)
    run_suite(suite, out, serial=True, progress=False)
    run = plan(suite, out)[0]
    record = json.loads((run.run_dir / "suite-run.json").read_text())
    heldout = read_eval(run.run_dir / record["evaluations"]["test-heldout-phrasings"]["file"])
    assert heldout.phrasings == "heldout"
    assert record["evaluations"]["test"]["file"] != record["evaluations"]["test-heldout-phrasings"]["file"]
    for ev_record in record["evaluations"].values():  # as an older gpl-dist wrote them
        if ev_record["settings"]["phrasings"] == "canonical":
            del ev_record["settings"]["phrasings"]
    (run.run_dir / "suite-run.json").write_text(json.dumps(record))
    assert run_state(run, suite) == "done"
    assert {r.evaluation for r in collect_results(out)} == {"test", "test-heldout-phrasings"}
    with pytest.raises(ConfigError, match="phrasings"):
        load_suite(write_suite(tmp_path / "bad.yaml", {"a": entry()}, {"test": {**ev, "phrasings": "mumbled"}}))


def test_the_effort_table_says_when_a_run_was_evaluated_before_effort_was_recorded(tmp_path):
    from gpl_dist.app.suite.report import RunResult, effort_markdown
    from learner.evaluate import CorrectionEffort

    def result(entry, effort):
        return RunResult(entry, 0, tmp_path, "test", (0.1, 0.5), tmp_path / "eval.json", (), ("abc",), 1.0, 1.0, effort)

    md = effort_markdown([result("old", None), result("new", CorrectionEffort(corrections_to_solve=2.0, unsolved_fraction=0.5,
                                                                               words_per_solved_task=6.0, completion_auc=0.3))])
    assert "| new | 2.000 | 6.000 | 0.500 | 0.300 | 1 |" in md
    assert "| old | — | — | — | — | none: evaluated before the effort was recorded" in md


def test_the_report_archives_its_runs_so_a_lost_run_folder_loses_no_row_and_restores_as_done(tmp_path, capsys):
    """The report keeps each run's evidence (record, config, metrics, eval files, final weights;
    never the buffer) in REPORT/runs and reads its numbers from there; the run folder can then go:
    a later report into the same folder keeps the rows, and ``suite restore`` gives a new run
    folder in which the suite counts those runs done and trains nothing."""
    path = write_suite(tmp_path / "suite.yaml", {
        "multiroom-gpl": entry(seeds=(0, 1), **{"training.num_rounds": 1}),
        "multiroom-instruction": entry(**{"model.variant": "instruction_only", "training.num_rounds": 1})})
    suite = load_suite(path)
    first, report = tmp_path / "first", tmp_path / "report"
    run_suite(suite, first, serial=True, progress=False, only=("multiroom-gpl",))
    assert main(["suite", "report", str(first), "--out", str(report)]) == 0
    archived = report / "runs" / "multiroom-gpl" / "seed1"
    assert sorted(p.relative_to(archived).as_posix() for p in archived.rglob("*") if p.is_file()) == [
        "checkpoints/latest.pt", "config.yaml", "curve-valid.json", "eval.json", "metrics.jsonl", "run.json",
        "suite-run.json"]
    assert "multiroom-gpl/seed1/eval.json" in json.loads((report / "runs" / "checksums.json").read_text())["files"]
    # the suite's own table (its entries are not all the paper's): the row of multiroom-gpl
    gpl_row = next(line for line in (report / "report.md").read_text().splitlines()
                   if line.startswith("| multiroom-gpl | multiroom | 1 |"))
    assert gpl_row.endswith("| 2 training seed(s): 0, 1 |")
    assert "| `runs/multiroom-gpl/seed1` |" in (report / "report.md").read_text()

    # the first run folder is lost; another one trains only the instruction-only entry
    for run in plan(suite, first):
        for p in sorted(run.run_dir.rglob("*"), reverse=True):
            p.unlink() if p.is_file() else p.rmdir()
    second = tmp_path / "second"
    run_suite(suite, second, serial=True, progress=False, only=("multiroom-instruction",))
    assert main(["suite", "report", str(second), "--out", str(report)]) == 0
    md = (report / "report.md").read_text()
    assert next(line for line in md.splitlines() if line.startswith("| multiroom-gpl | multiroom | 1 |")) == gpl_row
    assert "| `runs/multiroom-instruction/seed0` |" in md

    # restore into the second folder: the archived runs are done there, nothing trains again
    capsys.readouterr()
    assert main(["suite", "restore", str(report / "runs"), "--out", str(second)]) == 0
    printed = capsys.readouterr().out
    assert f"kept {second / 'multiroom-instruction' / 'seed0'}: it exists" in printed
    assert "restored 2 run(s)" in printed
    stamp = (second / "multiroom-instruction" / "seed0" / "metrics.jsonl").stat().st_mtime_ns
    assert [s for _, s in run_suite(suite, second, serial=True, progress=False)] == ["done"] * 3
    assert (second / "multiroom-instruction" / "seed0" / "metrics.jsonl").stat().st_mtime_ns == stamp
    assert not (second / "multiroom-gpl" / "seed0" / "buffer").exists()
    capsys.readouterr()
    assert main(["suite", "restore", str(report / "runs"), "--out", str(second)]) == 0  # twice: nothing to do
    assert "restored 0 run(s)" in capsys.readouterr().out

    # a run evaluated again replaces its archived copy whole: a file it no longer has goes too
    stale = report / "runs" / "multiroom-instruction" / "seed0" / "eval-old.json"
    stale.write_text("{}")
    assert main(["suite", "report", str(second), "--out", str(report)]) == 0
    assert not stale.exists() and not list((report / "runs").rglob(".*"))


def test_the_committed_report_archive_is_not_ignored_by_git():
    """The archive exists to be committed: no ignore rule may catch it (``runs/`` once did)."""
    path = "docs/paper-report/runs/multiroom-gpl/seed0/checkpoints/latest.pt"
    check = subprocess.run(["git", "check-ignore", "-v", path], cwd=REPO, capture_output=True, text=True)
    assert check.returncode == 1, f"git ignores {path}: {check.stdout.strip()}"


def test_status_predicts_what_is_left_from_the_suites_own_finished_runs(tmp_path, capsys):
    """A finished seed predicts the same entry's seeds left (per round, so a half-trained run pays
    only its rounds left) and its evaluations; an entry of a domain with no finished run has no
    estimate and the total says "at least"; another suite's folder predicts a new one."""
    from gpl_dist.app.suite.cost import predict
    from gpl_dist.app.suite.one_run import read_record

    out = tmp_path / "out"
    done = write_suite(tmp_path / "a.yaml", {"gpl": entry()})
    run_suite(load_suite(done), out, serial=True, progress=False)
    record = read_record(out / "gpl" / "seed0")
    took = record["train_seconds"] + record["evaluations"]["test"]["seconds"]
    more = write_suite(tmp_path / "b.yaml", {"gpl": entry(seeds=(0, 1, 2))})
    suite = load_suite(more)
    states = {r.run_dir: run_state(r, suite) for r in plan(suite, out)}
    cost = predict(suite, out, states)
    assert [c.run.seed for c in cost.runs] == [1, 2] and cost.complete
    assert all(c.source == "entry" and c.seconds == pytest.approx(took) for c in cost.runs)
    assert cost.total_seconds == pytest.approx(2 * took)
    assert main(["suite", "status", str(more), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "predicted: 2 run(s) and 0 RL job(s) left" in printed and "at least" not in printed
    # a domain without a finished run: no estimate, and the total is a lower bound
    other = write_suite(tmp_path / "c.yaml", {"gpl": entry(seeds=(0, 1)),
                                             "reloc": {**entry(), "base": str(REPO / "configs" / "relocation.yaml")}})
    assert main(["suite", "status", str(other), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "new      reloc seed 0" in printed and "~?" in printed and "at least" in printed
    # a fresh folder, predicted from the finished one
    fresh = predict(suite, tmp_path / "fresh", {}, measured_in=out)
    assert len(fresh.runs) == 3 and fresh.total_seconds == pytest.approx(3 * took)
    # an evaluation added to the entry that no run has made yet: the trained run only evaluates,
    # its estimate leaves that evaluation out and names it, and the total is a lower bound
    test = {"split": "test", "seeds": [0, 1], "num_corrections": 2, "greedy_actions": False, "max_tasks": 4}
    added = load_suite(write_suite(tmp_path / "d.yaml", {"gpl": entry(evaluations=("test", "valid"))},
                                   {"test": test, "valid": {**test, "split": "valid"}}))
    states = {r.run_dir: run_state(r, added) for r in plan(added, out)}
    assert list(states.values()) == ["evaluate"]
    (only,) = predict(added, out, states).runs
    assert (only.train_seconds, only.eval_seconds, only.unmeasured) == (0.0, 0.0, ("valid",))
    assert not predict(added, out, states).complete
    assert main(["suite", "status", str(tmp_path / "d.yaml"), "--out", str(out)]) == 0
    assert "at least" in capsys.readouterr().out


def test_valid_curves_evaluate_every_rounds_weights_resume_and_reach_the_archive_and_report(tmp_path):
    from gpl_dist.app.suite.archive import archive_runs
    from gpl_dist.app.suite.curves import compute_curve, compute_curves, curve_tasks
    from gpl_dist.app.suite.records import CURVE_FILE, CurveSettings, read_curve
    from gpl_dist.app.suite.run_facts import learning_curve
    from gpl_dist.splits import split_tasks
    from learner.evaluate import evaluate_policy, load_trained_policy

    path = write_suite(tmp_path / "suite.yaml", {"multiroom-gpl": entry(**{"training.num_rounds": 2})})
    out = tmp_path / "out"
    run_suite(load_suite(path), out, serial=True, progress=False)
    run_dir = out / "multiroom-gpl" / "seed0"
    settings = CurveSettings(tasks=3, num_corrections=1)
    tasks = curve_tasks("multiroom", settings)
    valid = split_tasks("multiroom", "valid")
    assert len(tasks) == 3 and set(tasks) <= set(valid) and tasks[-1] > valid[len(valid) // 2]  # spread over the split
    logged: list[str] = []
    assert compute_curves(out, settings=settings, log=logged.append) == [run_dir / CURVE_FILE]
    written = read_curve(run_dir / CURVE_FILE)
    assert written.rounds == (0, 1) and len(logged) == 2 and written.settings.split == "valid"
    cfg, model, r = load_trained_policy(run_dir, str(run_dir / "checkpoints" / "round-000000.pt"))
    again = evaluate_policy(cfg, model, num_corrections=1, seeds=(0,), split="valid", tasks=tasks)
    assert r == 0 and list(written.completion[0]) == again.completion  # each point is that round's weights on valid
    compute_curve(run_dir, settings, log=logged.append)
    assert len(logged) == 2  # a finished curve is not computed again
    curve = learning_curve(run_dir)
    assert curve.valid_rounds == (0, 1) and len(curve.train) == 2
    archive_runs(out, tmp_path / "archive")
    assert (tmp_path / "archive" / "multiroom-gpl" / "seed0" / CURVE_FILE).is_file()
    # choose on valid, report on test: training rolled out train tasks only, the curve valid tasks only
    import pyarrow.dataset as ds

    trained = set(ds.dataset(run_dir / "buffer" / "data" / "attempts").to_table(columns=["task_id"])["task_id"].to_pylist())
    test = set(split_tasks("multiroom", "test"))
    assert trained and trained <= set(split_tasks("multiroom", "train")) and not trained & test
    assert not set(tasks) & test


def test_model_selection_reads_the_valid_split_only():
    """The recipe suite (every design choice) evaluates on the valid split, never on a test split."""
    from gpl_dist.app.suite.spec import plan
    from gpl_dist.splits import valid_split

    recipe = load_suite(Path(__file__).resolve().parents[1] / "configs" / "suites" / "recipe.yaml")
    assert recipe.evaluations and {ev.config.split for ev in recipe.evaluations.values()} == {"valid"}
    for run in plan(recipe, "unused"):
        cfg = run.config(recipe)
        assert cfg.eval.split == valid_split(cfg.env.domain, cfg.env.train_split), run.entry.name
        assert "test" not in cfg.env.train_split, run.entry.name


def test_every_paper_run_is_chosen_on_tasks_it_neither_trains_nor_is_tested_on(tmp_path):
    """The learning curve and the swap control of each entry of the paper suite read its own valid
    split: no task of its training split, none of any test split. A curve measured on another split
    (the held-out runs' curves read the main valid split before split file version 3, which holds
    tasks of their test splits) is left out."""
    import shutil

    from gpl_dist.app.suite.curves import curve_tasks
    from gpl_dist.app.suite.records import CURVE_FILE, CurveSettings, read_curve
    from gpl_dist.app.suite.report_controls import plateau_table
    from gpl_dist.app.suite.report_data import run_curves
    from gpl_dist.app.suite.run_facts import learning_curve
    from gpl_dist.splits import split_tasks

    suite = load_suite(REPO / "configs" / "suites" / "paper.yaml")
    chosen = set()
    for run in plan(suite, "unused"):
        cfg = run.config(suite)
        settings = CurveSettings().for_run(cfg)
        if settings is None:
            continue
        chosen.add((cfg.env.domain, cfg.env.train_split, settings.split))
        tasks = set(split_tasks(cfg.env.domain, settings.split))
        tested = {t for name in run.entry.evaluations for t in split_tasks(cfg.env.domain, suite.evaluations[name].config.split)}
        assert tested and all("test" in suite.evaluations[name].config.split for name in run.entry.evaluations)
        assert not tasks & set(split_tasks(cfg.env.domain, cfg.env.train_split)), run.entry.name
        assert not tasks & tested, run.entry.name
        assert set(curve_tasks(cfg.env.domain, settings)) <= tasks
    assert ("multiroom", "heldout4_train", "heldout4_valid") in chosen and ("relocation", "train", "valid") in chosen
    run = tmp_path / "multiroom-heldout-gpl" / "seed0"
    shutil.copytree(REPO / "docs" / "paper-report" / "runs" / "multiroom-heldout-gpl" / "seed0", run)
    curve = read_curve(run / CURVE_FILE)
    on = lambda split: dataclasses.replace(curve, settings=dataclasses.replace(curve.settings, split=split))  # noqa: E731
    (run / CURVE_FILE).write_text(on("heldout4_valid").to_json())
    assert learning_curve(run).valid and not learning_curve(run).off_split
    (run / CURVE_FILE).write_text(on("valid").to_json())
    assert learning_curve(run).valid == () and learning_curve(run).off_split == "valid"
    results = collect_results(tmp_path, log=lambda _: None)
    table = plateau_table(results, {}, run_curves(results), {})
    assert "| multiroom-heldout-gpl |" not in table and "left out: `multiroom-heldout-gpl` seed0 (`valid`)" in table
    # a training split without a valid split has no curve; reading a run imports no domain module: a
    # user's domain this process does not know keeps the split its curve measured, one it knows is checked
    from gpl_dist.config import load_config
    from gpl_dist.domains import domain_names, load_domain_module, unregister_domain

    cfg = load_config(REPO / "configs" / "multiroom.yaml", {"env.train_split": "heldout_train"})
    assert CurveSettings().for_run(cfg) is None
    corridor = tmp_path / "corridor" / "seed0"
    corridor.mkdir(parents=True)
    shutil.copy(run / "metrics.jsonl", corridor / "metrics.jsonl")
    module = REPO / "tests" / "domains" / "corridor.py"
    (corridor / "config.yaml").write_text(f"env: {{domain: corridor, domain_module: {module}}}\n")
    (corridor / CURVE_FILE).write_text(on("valid").to_json())
    unregister_domain("corridor")
    assert learning_curve(corridor).valid and learning_curve(corridor).off_split == ""
    assert "corridor" not in domain_names()  # reading it imported nothing
    load_domain_module(str(module))
    assert learning_curve(corridor).off_split == "valid"  # corridor declares no valid split


def test_a_run_left_out_as_not_valid_is_not_listed_as_not_run(tmp_path):
    """The archived all-corrections seed 0 failed the health gate: the report leaves it out of the
    means and says so in its row, but it was run, so 'Not run yet' names only seeds never run."""
    import shutil

    from gpl_dist.app.suite.report import write_report

    out = tmp_path / "out"
    for seed in (0, 1):
        shutil.copytree(REPO / "docs" / "paper-report" / "runs" / "multiroom-all-corrections" / f"seed{seed}",
                        out / "multiroom-all-corrections" / f"seed{seed}")
    shutil.copyfile(REPO / "configs" / "suites" / "paper.yaml", out / "suite.yaml")
    md = write_report(out, tmp_path / "report")[0].read_text()
    row = next(line for line in md.splitlines() if line.startswith("| All |"))
    assert "left out: 0" in row and "not run yet: 2, 3, 4, 5" in row
    not_run = md.split("## Not run yet", 1)[1].split("\n## ", 1)[0]
    assert "- `multiroom-all-corrections`: training seed(s) 2, 3, 4, 5" in not_run.splitlines()


def test_the_plateau_table_says_which_entry_was_still_rising_on_valid(tmp_path):
    """Deliverable 6: an entry whose valid completion rose over its last round, significantly over
    its training seeds, is 'still rising' and names its longer entry; a gain that ties with 0 is
    'flat'; a curve not computed to the run's last round is not read."""
    import shutil

    from gpl_dist.app.suite.records import CURVE_FILE, CurveRecord, CurveSettings
    from gpl_dist.app.suite.report import RunResult
    from gpl_dist.app.suite.report_controls import plateau_table
    from gpl_dist.app.suite.report_data import SuitePlan, run_curves, trained_longer

    metrics = REPO / "docs" / "paper-report" / "runs" / "multiroom-full-info" / "seed0" / "metrics.jsonl"
    rounds = len({json.loads(line)["round"] for line in metrics.read_text().splitlines() if line.strip()})
    gains = {"rising": (0.10, 0.12, 0.09, 0.11, 0.10), "flat": (0.02, -0.03, 0.01, -0.01, 0.0),
             "peaked": (0.0,) * 5}
    results = []
    for entry, by_seed in gains.items():
        for seed, gain in enumerate(by_seed):
            run_dir = tmp_path / entry / f"seed{seed}"
            run_dir.mkdir(parents=True)
            shutil.copy(metrics, run_dir / "metrics.jsonl")
            shutil.copy(metrics.with_name("config.yaml"), run_dir / "config.yaml")
            values = [[0.5]] * (rounds - 1) + [[0.5 + gain]]
            if entry == "peaked":  # best at round 1 (0.8 + 0.02 * seed), flat at 0.6 over its last round
                values = [[0.5], [0.8 + 0.02 * seed]] + [[0.6]] * (rounds - 2)
            (run_dir / CURVE_FILE).write_text(CurveRecord(CurveSettings(), tuple(range(rounds)), tuple(map(tuple, values)),
                                                          ((1.0,),) * rounds).to_json())
            results.append(RunResult(entry, seed, run_dir, "test", (0.5,), run_dir / "eval.json", (), (), 0.0, 0.0))
    short = tmp_path / "short" / "seed0"  # a curve stopped before the last round
    short.mkdir(parents=True)
    shutil.copy(metrics, short / "metrics.jsonl")
    shutil.copy(metrics.with_name("config.yaml"), short / "config.yaml")
    (short / CURVE_FILE).write_text(CurveRecord(CurveSettings(), (0, 1), ((0.1,), (0.9,)), ((0.0,), (1.0,))).to_json())
    results.append(RunResult("short", 0, short, "test", (0.5,), short / "eval.json", (), (), 0.0, 0.0))
    # the entry trained longer: the same definition but more rounds (the suite file's), whatever its name
    plan = SuitePlan({"rising": (0,), "rising-more": (0,)}, {}, {
        "rising": ("base.yaml", {"model.variant": "gpl"}),
        "rising-more": ("base.yaml", {"model.variant": "gpl", "training.num_rounds": rounds + 6}),
        "shorter": ("base.yaml", {"model.variant": "gpl", "training.num_rounds": rounds - 1}),
        "other": ("base.yaml", {"model.variant": "no_trajectory", "training.num_rounds": rounds + 6})})
    longer = trained_longer(plan, {"rising": rounds, "flat": rounds})
    assert longer == {"rising": ("rising-more",)}
    curves = run_curves(results)
    md = plateau_table(results, plan.seeds, curves, longer)
    table = {line.split(" | ")[0].strip("| "): line for line in md.splitlines()}
    assert "still rising" in table["rising"] and "`rising-more` (not run yet)" in table["rising"]
    assert "+0.104" in table["rising"]
    assert "| flat |" in table["flat"] and "| — |" in table["flat"]
    # a curve that peaked and fell shows its best rounds beside a 'flat' end
    assert "| flat |" in table["peaked"] and "| 1, 1, 1, 1, 1: 0.840 |" in table["peaked"]
    assert f"| {', '.join([str(rounds - 1)] * 5)}: 0.604 |" in table["rising"]
    assert "short" not in table
    # a run without a curve to its last round is named as not checked, never silently dropped
    assert md.splitlines()[-1].startswith("Runs without a valid curve") and "`short` 1 of 1" in md
    assert "`rising`" not in md.splitlines()[-1]


def test_a_run_trained_again_under_the_same_numerics_gives_the_same_files_and_status_says_which(tmp_path, capsys):
    """The record names the machine's numerics fingerprint; a second training of the same entry and
    seed under it writes the same losses and the same eval; status marks the run 'numerics as
    here', and not once its record names another machine's."""
    from gpl_dist.app.suite.one_run import machine_numerics, read_record

    path = write_suite(tmp_path / "suite.yaml", {"gpl": entry()})
    suite = load_suite(path)
    first, second = tmp_path / "one", tmp_path / "two"
    run_suite(suite, first, serial=True, progress=False)
    run_suite(suite, second, serial=True, progress=False)
    run = plan(suite, first)[0]
    record = read_record(run.run_dir)
    assert record["numerics"] == [machine_numerics(run, suite)]
    for name in ("metrics.jsonl", record["evaluations"]["test"]["file"]):
        a, b = (out / "gpl" / "seed0" / name for out in (first, second))
        if name == "metrics.jsonl":
            keep = ("loss", "accuracy", "collected_tuples", "completion_by_corrections", "encoder_health")
            rows = [[{k: json.loads(line).get(k) for k in keep} for line in p.read_text().splitlines()] for p in (a, b)]
            assert rows[0] == rows[1]
        else:
            assert read_eval(a).completion == read_eval(b).completion
    assert main(["suite", "status", str(path), "--out", str(first)]) == 0
    printed = capsys.readouterr().out
    assert "; numerics as here)" in printed and "of the 1 trained runs, 1 were trained under it" in printed
    record["numerics"] = ["0123456789ab"]  # as another machine would have recorded
    (run.run_dir / "suite-run.json").write_text(json.dumps(record))
    assert main(["suite", "status", str(path), "--out", str(first)]) == 0
    printed = capsys.readouterr().out
    assert "; numerics as here)" not in printed and "0 were trained under it" in printed
    assert "1 under another" in printed

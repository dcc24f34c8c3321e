"""The instruction-swap control (``gpl-dist eval --swap-instructions``): each task is told another
task's instruction, so completion with it against completion with its own says how much a policy
reads its instruction. Run on the report's archived multi-room policies, on the valid split."""

import dataclasses
import json
import shutil
from pathlib import Path

import pytest

from gpl_dist.app.policy import load_policy
from gpl_dist.app.suite.curves import curve_tasks
from gpl_dist.app.suite.records import CurveSettings, Measured, SwapRecord, read_swap
from gpl_dist.cli import main
from gpl_dist.domains import get_domain
from gpl_dist.errors import UsageError
from gpl_dist.splits import split_tasks
from learner.evaluate import evaluate_policy, meta_test_rollout, read_eval, swapped_instructions

ARCHIVE = Path(__file__).resolve().parents[1] / "docs" / "paper-report" / "runs"
TASKS = split_tasks("multiroom", "valid")[:24]


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("swap")
    for entry in ("multiroom-gpl", "multiroom-no-instruction"):
        shutil.copytree(ARCHIVE / entry / "seed0", root / entry)
    return root


def test_each_task_is_told_the_most_different_instruction_of_another_task():
    own = {t: get_domain("multiroom").make_env(t).instruction for t in TASKS}
    told = swapped_instructions("multiroom", TASKS)
    assert set(told) == set(TASKS)
    differing = lambda a, b: sum(x != y for x, y in zip(a.split(), b.split()))  # noqa: E731
    for t in TASKS:
        assert told[t] in own.values()
        assert differing(own[t], told[t]) == max(differing(own[t], o) for o in own.values())
    spread = curve_tasks("multiroom", CurveSettings())  # the suite's: every k-th valid task
    told_spread = swapped_instructions("multiroom", spread)
    for t in spread:  # "Move <colour> <shape> to <colour> square": another object and another goal
        assert differing(get_domain("multiroom").make_env(t).instruction, told_spread[t]) == 3
    assert swapped_instructions("multiroom", TASKS) == told  # a function of the task list
    same = tuple(t for t in TASKS if own[t] == own[TASKS[0]])[:3]
    with pytest.raises(UsageError, match="share one instruction"):
        swapped_instructions("multiroom", same)


def test_a_rollout_conditions_on_the_told_instruction(runs):
    policy = load_policy(runs / "multiroom-gpl")
    told = swapped_instructions("multiroom", TASKS)
    swapped = meta_test_rollout(policy.cfg, policy.model, told_instructions=told).run(TASKS[:8], 1, 0).attempts
    own = meta_test_rollout(policy.cfg, policy.model).run(TASKS[:8], 1, 0).attempts
    assert all(a.instruction == told[a.task_id] for a in swapped)
    assert all(a.instruction != told[a.task_id] for a in own)
    firsts = lambda attempts: {a.task_id: a.actions.tolist() for a in attempts if a.attempt_index == 0}  # noqa: E731
    assert firsts(swapped) != firsts(own)  # the policy acted on what it was told


def test_eval_swap_instructions_writes_its_own_file_and_refuses_a_policy_without_instruction(runs, tmp_path, capsys):
    args = ["eval", "--max-tasks", "8", "--seeds", "0", "--corrections", "1", "--swap-instructions"]
    assert main([*args, "--run-dir", str(runs / "multiroom-gpl"), "--out", str(tmp_path)]) == 0
    report = read_eval(tmp_path / "eval-valid-c1-seeds0-first8-swapped-instructions.json")
    assert report.swapped and report.instructions.startswith("swapped") and report.split == "valid" and report.num_tasks == 8
    policy = load_policy(runs / "multiroom-gpl")
    direct = evaluate_policy(policy.cfg, policy.model, num_corrections=1, seeds=(0,), split="valid", max_tasks=8,
                             swap_instructions=True)
    assert direct.completion == list(report.completion)
    assert main([*args, "--run-dir", str(runs / "multiroom-no-instruction"), "--out", str(tmp_path)]) == 2
    assert "reads no instruction" in capsys.readouterr().err


def test_suite_swap_measures_each_instruction_reading_run_once_and_the_report_tabulates_it(tmp_path):
    from gpl_dist.app.suite.records import SWAP_FILE
    from gpl_dist.app.suite.report import collect_results, health_of, swap_markdown
    from gpl_dist.app.suite.swap import compute_swaps

    out = tmp_path / "suite"
    for entry in ("multiroom-gpl", "multiroom-heldout-gpl", "multiroom-no-instruction", "multiroom-instruction"):
        shutil.copytree(ARCHIVE / entry / "seed0", out / entry / "seed0")
    training = out / "multiroom-gpl" / "seed1"  # a run still training: its record names no evaluation yet
    shutil.copytree(ARCHIVE / "multiroom-gpl" / "seed1", training)
    record = json.loads((training / "suite-run.json").read_text())
    (training / "suite-run.json").write_text(json.dumps({**record, "evaluations": {}}))
    settings = CurveSettings(tasks=8, num_corrections=1)
    written = compute_swaps(out, settings=CurveSettings(split="test", tasks=8, num_corrections=1), log=lambda _: None)
    assert written == [out / "multiroom-gpl" / "seed0" / SWAP_FILE, out / "multiroom-heldout-gpl" / "seed0" / SWAP_FILE,
                       out / "multiroom-instruction" / "seed0" / SWAP_FILE]
    # each run on its own valid split, whatever split the settings name: the held-out run's holds
    # no task it trained on and no test task
    assert [read_swap(w).settings.split for w in written] == ["valid", "heldout4_valid", "valid"]
    held = read_swap(written[1])
    assert held.num_tasks == 8 and not set(split_tasks("multiroom", "heldout4_valid")) & (
        set(split_tasks("multiroom", "heldout4_train")) | set(split_tasks("multiroom", "heldout4_test"))
        | set(split_tasks("multiroom", "heldout4_indist_test")))
    written[1].write_text(dataclasses.replace(held, settings=dataclasses.replace(held.settings, split="valid")).to_json())
    found = collect_results(out, log=lambda _: None)
    off = swap_markdown(found, health_of(found))  # measured before each run had its own valid split: left out
    assert "| multiroom-heldout-gpl |" not in off
    assert "`multiroom-heldout-gpl` seed 0: measured on `valid`, not the run's valid split (`heldout4_valid`)" in off
    shutil.rmtree(out / "multiroom-heldout-gpl")
    written = [written[0], written[2]]
    assert len(read_swap(written[1]).own.completion) == 1  # one attempt: the instruction alone
    record = read_swap(written[0])
    assert record.settings.split == "valid" and record.num_tasks == 8
    assert len(record.own.completion) == len(record.swapped.completion) == 2
    before = written[0].stat().st_mtime_ns
    assert compute_swaps(out, settings=settings, log=lambda _: None) == written
    assert written[0].stat().st_mtime_ns == before  # measured once
    results = collect_results(out, log=lambda _: None)
    table = swap_markdown(results, health_of(results))
    row = next(line for line in table.splitlines() if line.startswith("| multiroom-gpl |"))
    own_last, swapped_last = record.own.completion[-1], record.swapped.completion[-1]
    assert f"{own_last:.3f}, {swapped_last:.3f}" in row and f"{swapped_last - own_last:+.3f}" in row
    assert "multiroom-no-instruction" not in table
    assert "| multiroom-instruction | 1 |" in table and "(one attempt)" in table
    (out / "multiroom-gpl" / "seed0" / SWAP_FILE).write_text(dataclasses.replace(record, weights_sha256="0" * 64).to_json())
    stale = swap_markdown(results, health_of(results))
    assert "| multiroom-gpl |" not in stale and "`multiroom-gpl` seed 0: measured other weights" in stale
    from gpl_dist.app.suite.archive import archive_runs, restore_runs

    archive_runs(out, tmp_path / "archive", log=lambda _: None)  # the archive keeps it under its checksums
    kept = tmp_path / "archive" / "multiroom-instruction" / "seed0" / SWAP_FILE
    assert kept.read_bytes() == written[1].read_bytes()
    sums = json.loads((tmp_path / "archive" / "checksums.json").read_text())["files"]
    assert f"multiroom-instruction/seed0/{SWAP_FILE}" in sums
    restore_runs(tmp_path / "archive", tmp_path / "restored", log=lambda _: None)
    assert (tmp_path / "restored" / "multiroom-instruction" / "seed0" / SWAP_FILE).read_bytes() == kept.read_bytes()


def test_the_report_pairs_the_swap_by_training_seed_and_calls_a_significant_drop_reading(tmp_path):
    from gpl_dist.app.suite.evidence import sha256_file
    from gpl_dist.app.suite.records import SWAP_FILE
    from gpl_dist.app.suite.report import collect_results, health_of, swap_markdown
    from gpl_dist.app.suite.stats import mean_ci, t_two_sided_p
    from learner.evaluate import SWAP_RULE

    out = tmp_path / "suite"
    own, swapped = (0.90, 0.95, 0.80), (0.70, 0.74, 0.62)  # a drop of 0.20, 0.21, 0.18
    for seed, (o, s) in enumerate(zip(own, swapped)):
        run = out / "multiroom-gpl" / f"seed{seed}"
        shutil.copytree(ARCHIVE / "multiroom-gpl" / f"seed{seed}", run)
        weights = sha256_file(run / "checkpoints" / "latest.pt")
        measured = Measured((0.0, o), (0.0, 0.0)), Measured((0.0, s), (0.0, 0.0))
        (run / SWAP_FILE).write_text(SwapRecord(CurveSettings(), SWAP_RULE, 5, weights, "gpl", 250, *measured).to_json())
    results = collect_results(out, log=lambda _: None)
    row = next(line for line in swap_markdown(results, health_of(results)).splitlines()
               if line.startswith("| multiroom-gpl |"))
    diff = mean_ci([s - o for o, s in zip(own, swapped)])
    p = t_two_sided_p(diff.mean / (diff.sd / 3 ** 0.5), 2)
    assert f"| 3 | 0.000, 0.000 | +0.000 ± 0.000, p 1 | {sum(own) / 3:.3f}, {sum(swapped) / 3:.3f} | " in row
    assert f"| {diff.mean:+.3f} ± {diff.half_width:.3f}, p {p:.2g} | yes |" in row and p < 0.05
    # runs of the entry less than FLOOR_CHANGE lower told another task's instruction (one higher, one
    # a noise dip lower) are named, beside one that drops by READ_DROP or more: they do not read it
    for seed, (o, s) in enumerate(((0.90, 0.70), (0.80, 0.82), (0.95, 0.94))):
        path = out / "multiroom-gpl" / f"seed{seed}" / SWAP_FILE
        record = read_swap(path)
        path.write_text(dataclasses.replace(record, own=Measured((0.0, o), record.own.success),
                                            swapped=Measured((0.0, s), record.swapped.success)).to_json())
    md = swap_markdown(results, health_of(results))
    assert ("- `multiroom-gpl` seed(s) 1, 2: told another task's instruction, less than 0.02 lower after the last "
            "attempt (0.800 own, 0.820 told another's, 0.950 own, 0.940 told another's)") in md
    # at the floor, where no run drops by READ_DROP, nothing is named, though every run is within
    # FLOOR_CHANGE: the control cannot tell there
    for seed, (o, s) in enumerate(((0.030, 0.031), (0.020, 0.025), (0.025, 0.018))):
        path = out / "multiroom-gpl" / f"seed{seed}" / SWAP_FILE
        record = read_swap(path)
        path.write_text(dataclasses.replace(record, own=Measured((0.0, o), record.own.success),
                                            swapped=Measured((0.0, s), record.swapped.success)).to_json())
    assert "do not read their instruction" not in swap_markdown(results, health_of(results))

"""The instruction-swap control (``gpl-dist eval --swap-instructions``): each task is told another
task's instruction, so completion with it against completion with its own says how much a policy
reads its instruction. Run on the report's archived multi-room policies, on the valid split."""

import json
import shutil
from pathlib import Path

import pytest

from gpl_dist.app.policy import load_policy
from gpl_dist.cli import main
from gpl_dist.domains import get_domain
from gpl_dist.errors import UsageError
from gpl_dist.splits import split_tasks
from learner.evaluate import evaluate_policy, meta_test_rollout, swapped_instructions

ARCHIVE = Path(__file__).resolve().parents[1] / "docs" / "paper-report" / "runs"
TASKS = split_tasks("multiroom", "valid")[:24]


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("swap")
    for entry in ("multiroom-gpl", "multiroom-no-instruction"):
        shutil.copytree(ARCHIVE / entry / "seed0", root / entry)
    return root


def test_each_task_is_told_a_differing_instruction_of_another_task():
    own = {t: get_domain("multiroom").make_env(t).instruction for t in TASKS}
    told = swapped_instructions("multiroom", TASKS)
    assert set(told) == set(TASKS)
    assert all(told[t] != own[t] and told[t] in own.values() for t in TASKS)
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
    args = ["eval", "--split", "valid", "--max-tasks", "8", "--seeds", "0", "--corrections", "1", "--swap-instructions"]
    assert main([*args, "--run-dir", str(runs / "multiroom-gpl"), "--out", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "eval-valid-c1-seeds0-first8-swapped-instructions.json").read_text())
    assert report["instructions"] == "swapped" and report["split"] == "valid" and report["num_tasks"] == 8
    policy = load_policy(runs / "multiroom-gpl")
    direct = evaluate_policy(policy.cfg, policy.model, num_corrections=1, seeds=(0,), split="valid", max_tasks=8,
                             swap_instructions=True)
    assert direct.completion == report["completion"]
    assert main([*args, "--run-dir", str(runs / "multiroom-no-instruction"), "--out", str(tmp_path)]) == 2
    assert "reads no instruction" in capsys.readouterr().err

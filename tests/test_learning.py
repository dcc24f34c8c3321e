"""Learning, end to end: a policy meta-trained on tasks that need corrections uses them."""

import numpy as np
import pytest

from gpl_dist.config import config_from_dict
from learner.driver import run_training
from learner.evaluate import evaluate_policy


@pytest.mark.slow
def test_corrections_raise_completion_after_meta_training(tmp_path):
    # Two instructions, all 30 tasks of each: the same sentence, the object and the goal in every
    # pair of rooms. The instruction cannot tell the tasks apart; only corrections can.
    from gpl_dist.envs.multiroom import make_env

    tasks = [t for t in range(3240) if make_env(t).instruction in ("Move green triangle to blue square",
                                                                   "Move red ball to yellow square")]
    assert len(tasks) == 60
    cfg = config_from_dict({
        "seed": 0,
        "env": {"domain": "multiroom", "task_ids": tasks},
        "collection": {"num_corrections": 3, "tasks_per_unit": 24},
        "training": {"num_rounds": 5, "num_epochs_per_round": 4, "batch_size": 256},
        "buffer": {"capacity_tuples": 40000},
    })
    run_training(cfg, tmp_path / "run", serial=True, progress=False)
    from gpl_dist.domains import get_domain
    from gpl_dist.models.build import build_model
    from learner.checkpoint import load_checkpoint

    model = build_model(get_domain("multiroom"))
    model.load_state_dict(load_checkpoint(tmp_path / "run" / "checkpoints").model_state)
    result = evaluate_policy(cfg, model, num_corrections=3, seeds=(0,), tasks=tuple(tasks))
    with_corrections, without = result.completion[3], result.completion[0]
    print("completion after 0..3 corrections:", result.completion)
    assert with_corrections > without + 0.1, result.completion


def test_correction_effort_counts_corrections_words_and_the_area_under_the_curve():
    from gpl_dist.records import Attempt
    from learner.evaluate import correction_effort

    def att(task, k, success, correction=""):
        z = np.zeros(1, np.int64)
        return Attempt(task_id=task, split="test", attempt_index=k, instruction="", instruction_ids=z,
                       observations=np.zeros((1, 1)), actions=z, expert_actions=z, completion=0.0, success=success,
                       correction=correction, correction_kind="", correction_ids=z, seed=0, policy_version=0)

    seed0 = [att(1, 0, False, "go left now"), att(1, 1, True),                        # solved after 1 correction, 3 words
             att(2, 0, False, "up"), att(2, 1, False, "down there"), att(2, 2, True),  # after 2, 3 words
             att(3, 0, False, "left"), att(3, 1, False)]                             # never solved
    seed1 = [att(1, 0, True)]                                                          # solved at once
    effort = correction_effort([seed0, seed1], [0.2, 0.5, 0.8])
    assert effort.corrections_to_solve == pytest.approx((1 + 2 + 0) / 3)
    assert effort.words_per_solved_task == pytest.approx((3 + 3 + 0) / 3)
    assert effort.unsolved_fraction == pytest.approx(1 / 4)
    assert effort.completion_auc == pytest.approx((0.35 + 0.65) / 2)
    none_solved = correction_effort([[att(1, 0, False)]], [0.3])
    assert none_solved.corrections_to_solve is None and none_solved.unsolved_fraction == 1 and none_solved.completion_auc == 0.3

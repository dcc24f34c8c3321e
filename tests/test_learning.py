"""Learning, end to end: a policy meta-trained on tasks that need corrections uses them."""

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
    from gpl_dist.models.gpl import build_model
    from learner.checkpoint import load_checkpoint

    model = build_model(get_domain("multiroom"))
    model.load_state_dict(load_checkpoint(tmp_path / "run" / "checkpoints").model_state)
    result = evaluate_policy(cfg, model, num_corrections=3, seeds=(0,), tasks=tuple(tasks))
    with_corrections, without = result.completion[3], result.completion[0]
    print("completion after 0..3 corrections:", result.completion)
    assert with_corrections > without + 0.1, result.completion

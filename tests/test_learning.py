"""Learning, end to end: a policy meta-trained on tasks that need corrections uses them."""

import pytest

from gpl_dist.config import config_from_dict
from learner.driver import run_training
from learner.evaluate import evaluate_policy


@pytest.mark.slow
def test_corrections_raise_completion_after_meta_training(tmp_path):
    cfg = config_from_dict({
        "seed": 0,
        "env": {"domain": "multiroom", "max_train_tasks": 48},
        "collection": {"num_corrections": 3, "tasks_per_unit": 24},
        "training": {"num_rounds": 3, "num_epochs_per_round": 3, "batch_size": 512},
    })
    run_training(cfg, tmp_path / "run", serial=True, progress=False)
    from learner.checkpoint import load_checkpoint
    from gpl_dist.domains import get_domain
    from gpl_dist.models.gpl import build_model, state_dict_to_numpy

    model = build_model(get_domain("multiroom"))
    model.load_state_dict(load_checkpoint(tmp_path / "run" / "checkpoints").model_state)
    result = evaluate_policy(cfg, state_dict_to_numpy(model), num_corrections=3, seeds=(0,), split="train",
                             max_tasks=48, greedy=False)
    with_corrections, without = result.completion[3], result.completion[0]
    # The instruction names no room: without corrections the policy can only guess where to go.
    assert with_corrections > without + 0.1, result.completion

"""Training with paraphrased language and meta-testing with held-out phrasings."""

import json

import numpy as np
import pytest
from test_rollout import TASKS, worker_settings

from gpl_dist.cli import main
from gpl_dist.domains import get_domain
from gpl_dist.language import split_words
from gpl_dist.models.build import build_model, state_dict_to_numpy
from learner.evaluate import meta_test_rollout
from workers.worker import RolloutWorker


def _collect(domain_name: str, paraphrases: bool, seed: int = 3):
    d = get_domain(domain_name)
    w = RolloutWorker(d, worker_settings(domain_name, num_corrections=3, paraphrases=paraphrases), worker_id="t")
    w.set_weights(state_dict_to_numpy(build_model(d, seed=0, paraphrases=paraphrases)), 0)
    return w.collect(TASKS, "train", seed=seed)


@pytest.mark.parametrize("domain_name", ["multiroom", "relocation"])
def test_collection_with_paraphrases_says_training_phrasings_only(domain_name):
    d = get_domain(domain_name)
    plain, para = _collect(domain_name, False), _collect(domain_name, True)
    assert [a.instruction for a in plain] == [d.make_env(a.task_id).instruction for a in plain]
    assert any(a.instruction != d.make_env(a.task_id).instruction for a in para)
    vocab = d.vocabulary_for(True)
    train_words = set(d.paraphrases.words("train")) | set(d.vocabulary.words)
    for a in para:
        for text, ids in ((a.instruction, a.instruction_ids), (a.correction, a.correction_ids)):
            assert set(split_words(text)) <= train_words, text
            assert np.array_equal(ids, vocab.encode(text)) and vocab.unk_id not in ids
    again = _collect(domain_name, True)
    assert [(a.instruction, a.correction) for a in again] == [(a.instruction, a.correction) for a in para]


def test_a_model_trained_without_paraphrases_reads_new_words_as_unknown():
    from gpl_dist.config import RunConfig

    d = get_domain("multiroom")
    cfg = RunConfig()
    model = build_model(d, seed=0)
    model.eval()
    heldout = meta_test_rollout(cfg, model, phrasings="heldout").run(TASKS, 2, 0).attempts
    assert any(d.vocabulary.unk_id in a.instruction_ids for a in heldout)
    canonical = meta_test_rollout(cfg, model).run(TASKS, 2, 0).attempts
    assert all(a.instruction == d.make_env(a.task_id).instruction for a in canonical)


def test_train_with_paraphrases_then_meta_test_with_held_out_phrasings(tmp_path, capsys):
    run = tmp_path / "run"
    assert main(["train", "--config", "configs/multiroom-smoke.yaml", "--serial", "--no-progress", "--run-dir", str(run),
                 "--set", "training.num_rounds=1", "--set", "env.max_train_tasks=4",
                 "--set", "training.num_epochs_per_round=1", "--set", "model.paraphrases=true"]) == 0
    for phrasings, name in (("heldout", "eval-heldout-phrasings.json"), ("canonical", "eval.json")):
        assert main(["eval", "--run-dir", str(run), "--phrasings", phrasings]) == 0
        report = json.loads((run / name).read_text())
        assert report["phrasings"] == phrasings and report["trained_with_paraphrases"] is True
    capsys.readouterr()
    with pytest.raises(SystemExit):
        main(["eval", "--run-dir", str(run), "--phrasings", "spoken"])
    assert "invalid choice: 'spoken'" in capsys.readouterr().err
    assert main(["train", "--config", "configs/multiroom-smoke.yaml", "--serial", "--run-dir", str(tmp_path / "r2"),
                 "--set", "eval.phrasings=mumbled"]) == 2
    assert "eval.phrasings must be one of" in capsys.readouterr().err

import dataclasses
from pathlib import Path

import pytest

from gpl_dist.config import ConfigError, RunConfig, config_to_dict, field_docs, load_config, save_config

CONFIGS = sorted(Path(__file__).resolve().parents[1].joinpath("configs").glob("*.yaml"))
SECTION_TYPES = [f.type for f in dataclasses.fields(RunConfig)]


def _sections():
    cfg = RunConfig()
    return [type(cfg)] + [type(getattr(cfg, f.name)) for f in dataclasses.fields(cfg)
                          if dataclasses.is_dataclass(getattr(cfg, f.name))]


@pytest.mark.parametrize("cls", _sections(), ids=lambda c: c.__name__)
def test_every_field_has_a_one_line_docstring(cls):
    docs = field_docs(cls)
    for f in dataclasses.fields(cls):
        assert f.name in docs, f"{cls.__name__}.{f.name} has no docstring"
        assert "\n" not in docs[f.name], f"{cls.__name__}.{f.name} docstring is not one line"


@pytest.mark.parametrize("path", [p for p in CONFIGS if p.name != "cluster.yaml"], ids=lambda p: p.name)
def test_shipped_configs_load(path):
    cfg = load_config(path)
    assert cfg.training.num_epochs_per_round >= 1


def test_paper_settings_in_multiroom_config():
    cfg = load_config(Path(__file__).resolve().parents[1] / "configs" / "multiroom.yaml")
    assert cfg.collection.num_corrections == 5
    assert cfg.training.num_epochs_per_round == 5
    assert cfg.buffer.capacity_tuples == 1_000_000
    assert cfg.training.learning_rate == pytest.approx(1e-3)
    assert cfg.env.max_train_tasks == 0  # all 1700 training tasks
    # the shipped network: without these, 2 of 4 training seeds never learnt to use corrections
    assert cfg.model.linear_encodings and cfg.model.policy_batchnorm and cfg.model.conv_batchnorm
    assert not cfg.model.encoder_layernorm  # measured: it kept the hidden layers alive, not the 5-seed mean up


def test_unknown_key_fails_with_one_line(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("training:\n  num_epochs: 3\n")
    with pytest.raises(ConfigError) as err:
        load_config(p)
    msg = str(err.value)
    assert "training.num_epochs" in msg and str(p) in msg and "\n" not in msg


def test_wrong_type_fails_naming_key(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("training:\n  batch_size: big\n")
    with pytest.raises(ConfigError, match=r"training\.batch_size: expected int"):
        load_config(p)
    p.write_text("collection:\n  greedy_actions: 1\n")
    with pytest.raises(ConfigError, match=r"collection\.greedy_actions: expected bool"):
        load_config(p)


def test_missing_file_and_bad_yaml(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "nope.yaml")
    p = tmp_path / "bad.yaml"
    p.write_text("training: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(p)


def test_range_check_and_overrides(tmp_path):
    with pytest.raises(ConfigError, match="env.domain"):
        load_config(None, {"env.domain": "atari"})
    cfg = load_config(None, {"training.num_rounds": "7", "buffer.capacity_tuples": "1e5", "eval.seeds": "[4, 5]"})
    assert cfg.training.num_rounds == 7 and cfg.buffer.capacity_tuples == 100_000 and cfg.eval.seeds == (4, 5)


def test_resolved_config_round_trips(tmp_path):
    cfg = load_config(None, {"model.variant": "no_trajectory", "seed": "3"})
    save_config(cfg, tmp_path / "config.yaml")
    again = load_config(tmp_path / "config.yaml")
    assert again == cfg
    assert config_to_dict(again)["model"]["variant"] == "no_trajectory"


def test_a_run_saved_before_an_architecture_switch_keeps_its_architecture(tmp_path):
    """Switches that change the function a checkpoint computes default to the behaviour from before
    they existed, so an older run dir (its config.yaml lacks them) evaluates as it was trained."""
    saved = tmp_path / "config.yaml"
    saved.write_text("env:\n  domain: multiroom\nmodel:\n  variant: gpl\n")
    model = load_config(saved).model
    assert not model.linear_encodings and not model.policy_batchnorm and not model.trajectory_ends_at_last_state
    assert not model.conv_batchnorm

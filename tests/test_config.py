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


def _alias_bomb(levels: int, key: str = "training:\n  num_rounds") -> str:
    """A YAML alias bomb under a known key: 9**levels strings from a few hundred bytes."""
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x]"]
    for i in range(1, levels):
        lines.append(f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]")
    lines.append(f"{key}: [" + ", ".join([f"*a{levels - 1}"] * 9) + "]")
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("what", ["alias bomb", "deep nesting"])
def test_hostile_configs_fail_in_one_line_with_exit_2(tmp_path, capsys, what):
    """An alias bomb under a known key (before: gigabytes, a MemoryError traceback) and a value
    nested 500 deep (before: RecursionError), in a run config, a --set value and a suite file."""
    from gpl_dist.cli import main

    deep = "[" * 500 + "]" * 500
    body = _alias_bomb(8) if what == "alias bomb" else f"training:\n  num_rounds: {deep}\n"
    assert len(body) < 2000
    (tmp_path / "c.yaml").write_text(body)
    needle = "YAML aliases (*name) are not accepted" if what == "alias bomb" else "nested deeper than 32 levels"
    cases = [["train", "--config", str(tmp_path / "c.yaml"), "--run-dir", str(tmp_path / "r"), "--serial"],
             ["train", "--config", "configs/multiroom-smoke.yaml", "--run-dir", str(tmp_path / "r"), "--serial",
              "--set", "training.num_rounds=" + (deep if what == "deep nesting" else "[&a [x, x], *a]")]]
    suite = tmp_path / "s.yaml"
    suite.write_text(body.replace("training:\n  num_rounds", "evaluations") if what == "alias bomb"
                     else f"evaluations: {deep}\nentries: {{}}\n")
    cases.append(["suite", "status", str(suite), "--out", str(tmp_path / "o")])
    for argv in cases:
        capsys.readouterr()
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and needle in err and len(err) < 700, err
    assert not (tmp_path / "r").exists()


def test_a_wrong_type_names_a_bounded_value(tmp_path):
    """A huge value of the wrong type is shown cut, never formatted whole."""
    from gpl_dist.config import bounded_repr, config_from_dict

    huge = [list(range(1000))] * 1000
    with pytest.raises(ConfigError) as info:
        config_from_dict({"training": {"num_rounds": huge}})
    assert len(str(info.value)) < 200 and "expected int, got list [[0, 1, 2, 3, 4, 5, ...]" in str(info.value)
    assert len(bounded_repr("y" * 10**6)) <= 83
    with pytest.raises(ConfigError, match="characters long"):
        load_config(None, {"training.num_rounds": "1" * 20_000})

"""A study of one's own: the network's layer sizes from the config, and every config key listed
with its default and doc (``gpl-dist config``)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
import yaml

from gpl_dist.cli import main
from gpl_dist.config import ConfigError, load_config
from gpl_dist.domains import get_domain
from gpl_dist.models.build import build_model_from_config
from gpl_dist.models.sizes import SIZE_FIELDS

REPO = Path(__file__).resolve().parents[1]
CORRIDOR = REPO / "tests" / "domains" / "corridor.py"


def _params(model) -> int:
    return sum(p.numel() for p in model.parameters())


def test_every_layer_size_is_a_config_key_and_changes_the_network():
    base = load_config(REPO / "configs" / "multiroom-smoke.yaml", plugins="own")
    domain = get_domain("multiroom")
    reference = _params(build_model_from_config(domain, base.model, seed=0))
    for name in SIZE_FIELDS:
        value = getattr(domain.model_sizes, name)
        if isinstance(value, bool):
            new = "false" if value else "true"
        elif isinstance(value, int):
            new = str(value * 2)
        else:
            new = str([w * 2 for w in value])
        cfg = load_config(REPO / "configs" / "multiroom-smoke.yaml", {f"model.{name}": new}, plugins="own")
        assert getattr(cfg.model, name) == yaml.safe_load(new) if not isinstance(value, tuple) else tuple(yaml.safe_load(new))
        model = build_model_from_config(domain, cfg.model, seed=0)
        if isinstance(value, bool):  # a ReLU more or less: same parameters, other outputs
            continue
        assert _params(model) != reference, name


@pytest.mark.parametrize("override, needle", [
    ("model.policy_mlp=[0]", "model.policy_mlp must hold widths in 1..65536"),
    ("model.pair_mlp=[]", "model.pair_mlp needs at least one layer"),
    ("model.text_conv=wide", "model.text_conv: expected int, got str"),
    ("model.state_mlp=[8, -1]", "model.state_mlp must hold widths in 1..65536"),
])
def test_a_bad_layer_size_fails_in_one_line_before_anything_starts(tmp_path, capsys, override, needle):
    run = tmp_path / "run"
    assert main(["train", "--config", str(REPO / "configs" / "multiroom-smoke.yaml"), "--serial", "--run-dir", str(run),
                 "--set", override]) == 2
    err = capsys.readouterr().err
    assert needle in err and err.count("\n") == 1, err
    assert not run.exists()


def test_a_wider_network_trains_and_its_sizes_are_recorded(tmp_path):
    config = tmp_path / "corridor.yaml"
    config.write_text(f"env: {{domain: corridor, domain_module: {CORRIDOR}}}\n"
                      "collection: {num_workers: 1, num_corrections: 1, tasks_per_unit: 4}\n"
                      "training: {num_rounds: 1, num_epochs_per_round: 1, batch_size: 16}\neval: {seeds: [0]}\n")
    runs = {}
    for name, extra in (("default", []), ("wide", ["--set", "model.policy_mlp=[64, 64, 64]", "--set", "model.pair_mlp=[16]"])):
        run = tmp_path / name
        assert main(["train", "--config", str(config), "--serial", "--run-dir", str(run), "--no-progress", *extra]) == 0
        state = torch.load(run / "checkpoints" / "latest.pt", weights_only=True)["model_state"]
        runs[name] = (sum(v.numel() for v in state.values() if v.is_floating_point()),
                      yaml.safe_load((run / "config.yaml").read_text())["model"])
    assert runs["wide"][0] > runs["default"][0]
    assert runs["wide"][1]["policy_mlp"] == [64, 64, 64] and runs["wide"][1]["pair_mlp"] == [16]
    assert "policy_mlp" not in runs["default"][1]  # left to the domain: the config says nothing
    # read back, the run's config builds the network it trained
    cfg = load_config(tmp_path / "wide" / "config.yaml")
    assert cfg.model.policy_mlp == (64, 64, 64)
    with pytest.raises(ConfigError, match="model.traj_mlp needs at least one layer"):
        load_config(tmp_path / "wide" / "config.yaml", {"model.traj_mlp": "[]"})


def test_gpl_dist_config_lists_every_key_with_its_default_and_doc(capsys):
    assert main(["config"]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    i = next(i for i, line in enumerate(lines) if line.startswith("training.batch_size "))
    assert "int, default 512" in lines[i] and "Labelled states per gradient step." in lines[i + 1]
    j = next(i for i, line in enumerate(lines) if line.startswith("model.encoder_activation "))
    assert "default 'relu'" in lines[j] and "leaky_relu" in lines[j + 1]
    assert main(["config", "model", "--domain", "relocation"]) == 0
    out = capsys.readouterr().out
    assert "model.policy_mlp" in out and "[256, 256, 256]" in out and "training." not in out
    assert main(["config", "--domain", "corridor", "--domain-module", str(CORRIDOR), "env"]) == 0
    assert "env.expert" in (out := capsys.readouterr().out) and "'walker'" in out
    assert main(["config", "trainin"]) == 2
    assert "no config section 'trainin'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["train", "--help"])
    assert "gpl-dist config" in capsys.readouterr().out


def test_the_config_names_every_layer_size_of_the_network():
    from gpl_dist.config import LAYER_SIZE_KEYS

    assert LAYER_SIZE_KEYS == SIZE_FIELDS


def test_gym_make_without_a_task_says_how_to_name_one():
    import gymnasium

    with pytest.raises(TypeError, match=r"gpl/MultiRoom-v0 is one task of 3240: name it, e\.g\. gymnasium\.make"):
        gymnasium.make("gpl_dist:gpl/MultiRoom-v0")
    assert gymnasium.make("gpl_dist:gpl/MultiRoom-v0", task_id=5).unwrapped.task_id == 5


def test_piped_training_prints_no_progress_bars(tmp_path):
    import subprocess

    from _cluster_tools import GPL_DIST, quiet_env

    config = tmp_path / "corridor.yaml"
    config.write_text(f"env: {{domain: corridor, domain_module: {CORRIDOR}}}\n"
                      "collection: {num_workers: 1, num_corrections: 1, tasks_per_unit: 4}\n"
                      "training: {num_rounds: 2, num_epochs_per_round: 1, batch_size: 16}\n")
    done = subprocess.run([GPL_DIST, "train", "--config", str(config), "--serial", "--run-dir", str(tmp_path / "run")],
                          capture_output=True, text=True, env=quiet_env(), timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "round 1:" in done.stdout
    assert "\r" not in done.stderr + done.stdout and "it/s" not in done.stderr and "task/s" not in done.stderr


def test_render_draws_a_plug_in_domain_without_rgb_or_path_points(tmp_path, capsys):
    """The corridor offers only an ANSI picture and no picture_points: ``render`` draws its text
    picture, a trained policy's attempts included, and names an unknown domain in one line."""
    from PIL import Image

    assert main(["render", "--env", "corridor", "--domain-module", str(CORRIDOR), "--task", "1", "--expert",
                 "--out", str(tmp_path / "expert.gif")]) == 0
    gif = Image.open(tmp_path / "expert.gif")
    assert gif.n_frames >= 2 and gif.size[0] >= 160
    assert main(["render", "--env", "nowhere", "--task", "1", "--out", str(tmp_path / "x.png")]) == 2
    assert "unknown domain 'nowhere'" in capsys.readouterr().err
    config = tmp_path / "corridor.yaml"
    config.write_text(f"env: {{domain: corridor, domain_module: {CORRIDOR}}}\n"
                      "collection: {num_workers: 1, num_corrections: 1, tasks_per_unit: 4}\n"
                      "training: {num_rounds: 1, num_epochs_per_round: 1, batch_size: 16}\neval: {seeds: [0]}\n")
    run = tmp_path / "run"
    assert main(["train", "--config", str(config), "--serial", "--run-dir", str(run), "--no-progress"]) == 0
    assert main(["render", "--run-dir", str(run), "--task", "6", "--attempts", "2", "--out", str(tmp_path / "p.gif")]) == 0
    assert Image.open(tmp_path / "p.gif").n_frames >= 4


def test_teaching_offers_and_expects_the_corrections_the_policy_trained_on(tmp_path, capsys):
    """A multi-room run trained on subgoal corrections: the page's examples are subgoal sentences
    (no directional one), a directional sentence is accepted with a warning that the policy never
    trained on it, and a subgoal sentence without one; each kind's phrasings are its own."""
    from fastapi.testclient import TestClient

    from gpl_dist.app.teach_web import create_app
    from gpl_dist.app.teaching import Teacher

    domain = get_domain("multiroom")
    assert set(domain.phrasings_of("subgoal")) <= set(domain.phrasings_of(None))
    assert not set(domain.phrasings_of("subgoal")) & set(domain.phrasings_of("directional")) - {"you are done"}
    run = tmp_path / "run"
    assert main(["train", "--config", str(REPO / "configs" / "multiroom-smoke.yaml"), "--serial", "--no-progress",
                 "--run-dir", str(run), "--set", "training.num_rounds=1", "--set", "env.max_train_tasks=4",
                 "--set", "training.num_epochs_per_round=1"]) == 0
    client = TestClient(create_app(Teacher(run), tmp_path / "teaching"), base_url="http://127.0.0.1")
    examples = client.get("/api/info").json()["examples"]
    subgoal = set(domain.phrasings_of("subgoal"))
    assert examples and set(examples) <= subgoal
    assert not any(" is " in e for e in examples)  # "the object room is southeast": directional, never trained on
    directional = client.post("/api/check", json={"text": "the object room is southeast"}).json()
    assert directional["problem"] is None and "never on this sentence" in directional["warning"]
    assert "'subgoal' corrections" in directional["warning"] or "'default' corrections" in directional["warning"]
    own = client.post("/api/check", json={"text": "enter the blue room"}).json()
    assert own["warning"] is None and own["suggestion"] is None


def test_terminal_teaching_keeps_an_undone_attempts_gif(tmp_path):
    from gpl_dist.app.teach_terminal import teach_in_terminal
    from gpl_dist.app.teaching import Teacher

    run = tmp_path / "run"
    assert main(["train", "--config", str(REPO / "configs" / "multiroom-smoke.yaml"), "--serial", "--no-progress",
                 "--run-dir", str(run), "--set", "training.num_rounds=1", "--set", "env.max_train_tasks=4",
                 "--set", "training.num_epochs_per_round=1"]) == 0
    lines = iter(["enter the blue room", ":undo", "enter the red room", ":quit"])
    teacher = Teacher(run)
    teach_in_terminal(teacher.episode(263, 3, "terminal"), tmp_path / "out", read_line=lambda prompt: next(lines))
    gifs = sorted(p.name for p in (tmp_path / "out" / "gifs").iterdir())
    assert len(gifs) == 3 and sum("-attempt1" in g for g in gifs) == 2 and any("-take2" in g for g in gifs), gifs

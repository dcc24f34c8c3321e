"""The field's conventions and a new user's first steps: gymnasium ids in a fresh interpreter, the
instruction in ``info``, ``terminate_on_success``, ``--version``, help on every option, and the
notes that keep a first run from misleading (restored runs, held-out phrasings, Ray's warning)."""

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
from _cluster_tools import quiet_env

from gpl_dist.app.suite.archive import restore_runs
from gpl_dist.cli import build_parser, main
from gpl_dist.domains import get_domain
from gpl_dist.experts import make_expert

REPO = Path(__file__).resolve().parents[1]
ARCHIVE = REPO / "docs" / "paper-report" / "runs"


def _fresh_python(code: str, **env: str) -> subprocess.CompletedProcess:
    """``code`` in a new interpreter that has imported nothing of gpl-dist."""
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600,
                          cwd="/", env=quiet_env(PYTHONPATH=str(REPO), **env))


def test_gymnasium_makes_each_env_in_a_fresh_interpreter_from_its_module_prefixed_id():
    code = ("import sys, gymnasium as gym\n"
            "assert 'gpl_dist' not in sys.modules\n"
            "env = gym.make('gpl_dist:gpl/MultiRoom-v0', task_id=17)\n"
            "obs, info = env.reset(seed=0)\n"
            "print(obs.shape, env.spec.max_episode_steps, info['instruction'])\n"
            "env = gym.make('gpl/Relocation-v0', task_id=3)\n"  # registered now, by the first make
            "print(env.reset(seed=0)[0].shape, list(info['instruction_ids'][:3]))\n")
    done = _fresh_python(code)
    assert done.returncode == 0, done.stderr[-2000:]
    lines = done.stdout.splitlines()
    env = get_domain("multiroom").make_env(17)
    assert lines[0] == f"(7, 7, 6) 100 {env.instruction}"
    assert lines[1] == f"(28,) {list(env.instruction_ids[:3])}"


@pytest.mark.parametrize("domain_name, task_id", [("multiroom", 17), ("relocation", 3)])
def test_every_info_carries_the_instruction_as_text_and_token_ids(domain_name, task_id):
    domain = get_domain(domain_name)
    env = domain.make_env(task_id)
    _, info = env.reset(seed=1)
    ids = tuple(domain.vocabulary.encode(env.instruction).tolist())
    for step_info in (info, env.step(0)[4]):
        assert step_info["instruction"] == env.instruction and step_info["instruction_ids"] == ids
    assert len(ids) == domain.vocabulary.max_tokens and all(type(i) is int for i in ids)


def test_multiroom_terminates_on_success_only_when_asked():
    domain = get_domain("multiroom")
    for terminate in (False, True):
        env = domain.make_env(17, terminate_on_success=terminate)
        obs, _ = env.reset(seed=0)
        expert = make_expert(env)
        plain = domain.make_env(17)  # the default env, stepped alongside: the same observations
        plain.reset(seed=0)
        solved_at, terminated_at = None, None
        for t in range(100):
            a = expert.act(env)
            obs, _, terminated, _, info = env.step(a)
            assert np.array_equal(obs, plain.step(a)[0])
            if info["success"] and solved_at is None:
                solved_at = t
            if terminated:
                terminated_at = t
                break
        assert solved_at is not None
        assert terminated_at == (solved_at if terminate else None)


def test_relocation_terminates_when_the_block_reaches_the_target_only_when_asked():
    domain = get_domain("relocation")
    for terminate in (False, True):
        env = domain.make_env(3, terminate_on_success=terminate)
        env.reset(seed=0)
        assert not env.step(0)[2]
        qpos = np.array(env.data.qpos[:9])
        qpos[env._bq:env._bq + 2] = env._target  # the block on its target
        env.set_state(qpos)
        _, _, terminated, _, info = env.step(0)
        assert info["success"] and terminated == terminate


def test_version_and_help_on_every_option(capsys):
    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0
    from gpl_dist import __version__
    assert capsys.readouterr().out.strip() == f"gpl-dist {__version__}"

    def parsers(p: argparse.ArgumentParser):
        yield p
        for action in p._actions:
            if isinstance(action, argparse._SubParsersAction):
                for sub in action.choices.values():
                    yield from parsers(sub)

    missing = [f"{p.prog} {a.dest}" for p in parsers(build_parser()) for a in p._actions
               if not isinstance(a, argparse._SubParsersAction) and not a.help]
    assert missing == []
    train_help = next(p for p in parsers(build_parser()) if p.prog.endswith(" train")).format_help()
    assert "corr-spread" in train_help and "c0" in train_help


@pytest.fixture(scope="module")
def restored(tmp_path_factory) -> Path:
    """The archived multi-room GPL and instruction-only seed-0 runs, put back by ``suite restore``."""
    root = tmp_path_factory.mktemp("restored")
    for entry in ("multiroom-gpl",):
        shutil.copytree(ARCHIVE / entry / "seed0", root / "archive" / entry / "seed0")
    restore_runs(root / "archive", root / "out", log=lambda _: None)
    return root / "out"


def test_inspect_on_a_restored_run_says_restored_runs_carry_no_buffer(restored, capsys):
    run = restored / "multiroom-gpl" / "seed0"
    assert main(["inspect", str(run)]) == 0
    out = capsys.readouterr().out
    assert "runs restored by 'gpl-dist suite restore' carry no buffer" in out
    assert "committed rounds" not in out


def test_eval_with_heldout_phrasings_on_a_run_trained_without_paraphrases_says_so(restored, capsys):
    run = restored / "multiroom-gpl" / "seed0"
    assert "paraphrases: false" in (run / "config.yaml").read_text()
    assert main(["eval", "--run-dir", str(run), "--phrasings", "heldout", "--max-tasks", "1", "--seeds", "0",
                 "--corrections", "0"]) == 0
    out = capsys.readouterr().out
    assert "trained without paraphrases" in out
    report = json.loads(next(run.glob("eval-*heldout-phrasings.json")).read_text())
    assert report["phrasings"] == "heldout" and report["trained_with_paraphrases"] is False
    assert main(["eval", "--run-dir", str(run), "--max-tasks", "1", "--seeds", "0", "--corrections", "0"]) == 0
    assert "trained without paraphrases" not in capsys.readouterr().out


@pytest.mark.ray
def test_a_local_ray_cluster_starts_without_the_token_authentication_warning():
    tmp_path = Path(tempfile.mkdtemp(prefix="ray-", dir="/tmp"))  # Ray's socket paths must stay short
    code = ("import ray\nfrom workers.ray_collector import init_ray\n"
            f"assert init_ray(None, 1, temp_dir={str(tmp_path)!r}, object_store_memory=80 * 2**20)\n"
            "import os; print('mode', os.environ['RAY_AUTH_MODE'])\nray.shutdown()\n")
    env = quiet_env()
    env.pop("RAY_AUTH_MODE", None)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, cwd=str(tmp_path),
                          env={**env, "PYTHONPATH": str(REPO)})
    assert done.returncode == 0, done.stderr[-2000:]
    assert "mode token" in done.stdout  # authentication stays on, as Ray's default would have it
    assert "Token authentication" not in done.stderr + done.stdout
    shutil.rmtree(tmp_path, ignore_errors=True)

"""Code runs only when asked: a run's config names a plug-in file (``env.domain_module``), and
reading that run never imports it. Commands that only read (``verify``, ``inspect``, ``suite
status``, ``clean``) never do; commands that must build the domain (``eval``) do only for a file
this machine trained with (same path, same sha256), an installed entry point, or with
``--trust-domain-module``; an archive refuses to carry a plug-in file.

Each command runs as its own process (a fresh interpreter: nothing imported before), with its own
trust file, as another user of the machine would."""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
from pathlib import Path

import pytest
from _cluster_tools import GPL_DIST, REPO, quiet_env

CORRIDOR = REPO / "tests" / "domains" / "corridor.py"


def _gpl(args: list[str], trust: Path, mark: Path, cwd: Path) -> subprocess.CompletedProcess:
    env = quiet_env(GPL_DIST_TRUST_FILE=str(trust), GPL_TEST_PLUGIN_MARK=str(mark))
    return subprocess.run([GPL_DIST, *args], capture_output=True, text=True, env=env, cwd=cwd, timeout=300)


@pytest.fixture(scope="module")
def plugin_run(tmp_path_factory):
    """A one-round serial run of a plug-in file that records each import in a mark file."""
    base = tmp_path_factory.mktemp("plugin")
    plugin = base / "marked_corridor.py"
    plugin.write_text(CORRIDOR.read_text() + "\nimport os as _os\n"
                      "with open(_os.environ.get('GPL_TEST_PLUGIN_MARK', _os.devnull), 'a') as _f:\n"
                      "    _f.write('imported\\n')\n")
    config = base / "corridor.yaml"
    config.write_text(f"env: {{domain: corridor, domain_module: {plugin}}}\n"
                      "collection: {num_workers: 1, num_corrections: 1, tasks_per_unit: 4}\n"
                      "training: {num_rounds: 1, num_epochs_per_round: 1, batch_size: 16}\neval: {seeds: [0]}\n")
    trust, mark = base / "trust-trainer.json", base / "mark-trainer"
    run = base / "run"
    done = _gpl(["train", "--config", str(config), "--serial", "--run-dir", str(run), "--no-progress"], trust, mark, base)
    assert done.returncode == 0, done.stderr[-2000:]
    assert mark.read_text().count("imported") >= 1  # asked for: the user's own config
    digest = hashlib.sha256(plugin.read_bytes()).hexdigest()
    assert {"module": str(plugin), "sha256": digest} in json.loads(trust.read_text())
    return base, run, plugin, config, trust, digest


def test_reading_a_run_imports_nothing_and_building_its_domain_asks_first(plugin_run, tmp_path):
    base, run, plugin, _, trainer_trust, digest = plugin_run
    stranger = tmp_path / "trust-stranger.json"  # another user: this machine never trained from the file
    mark = tmp_path / "mark"
    for args in (["verify", str(run)], ["inspect", str(run)], ["clean", "--dry-run", str(run)]):
        done = _gpl(args, stranger, mark, tmp_path)
        assert done.returncode == 0, (args, done.stderr[-2000:])
        assert not mark.exists(), f"{args[0]} imported the run's plug-in"
    done = _gpl(["eval", "--run-dir", str(run), "--max-tasks", "2"], stranger, mark, tmp_path)
    assert done.returncode == 2 and not mark.exists()
    err = done.stderr.strip()
    assert err.count("\n") == 0 and str(plugin) in err and digest in err and "--trust-domain-module" in err, err
    # told to: imported, and evaluated
    done = _gpl(["eval", "--run-dir", str(run), "--max-tasks", "2", "--trust-domain-module"], stranger, mark, tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    assert mark.read_text().count("imported") >= 1
    # the machine that trained from the file goes on without asking
    mark.unlink()
    done = _gpl(["eval", "--run-dir", str(run), "--max-tasks", "2"], trainer_trust, mark, tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]


def test_a_changed_plug_in_file_is_asked_for_again(plugin_run, tmp_path):
    base, run, plugin, _, trainer_trust, digest = plugin_run
    copy = tmp_path / "run"
    shutil.copytree(run, copy)
    edited = tmp_path / "marked_corridor.py"
    edited.write_text(plugin.read_text() + "\n# edited after training\n")
    cfg = (copy / "config.yaml").read_text()
    (copy / "config.yaml").write_text(cfg.replace(str(plugin), str(edited)))
    trust = tmp_path / "trust.json"
    shutil.copyfile(trainer_trust, trust)
    mark = tmp_path / "mark"
    done = _gpl(["eval", "--run-dir", str(copy), "--max-tasks", "2"], trust, mark, tmp_path)
    assert done.returncode == 2 and not mark.exists(), done.stderr
    assert str(edited) in done.stderr and hashlib.sha256(edited.read_bytes()).hexdigest() in done.stderr
    # resuming a run dir is building its domain from data too: its latest checkpoint's config names the file
    import torch

    latest = copy / "checkpoints" / "latest.pt"
    ckpt = torch.load(latest, weights_only=True)
    ckpt["config"]["env"]["domain_module"] = str(edited)
    torch.save(ckpt, latest)
    done = _gpl(["train", "--run-dir", str(copy), "--resume", "--serial", "--no-progress",
                 "--set", "training.num_rounds=2"], trust, mark, tmp_path)
    assert done.returncode == 2 and not mark.exists() and "--trust-domain-module" in done.stderr


def test_suite_status_reads_a_plug_in_suite_without_importing_it(plugin_run, tmp_path):
    _, _, _, config, _, _ = plugin_run
    suite = tmp_path / "suite.yaml"
    suite.write_text("evaluations:\n  test: {split: test, seeds: [0], num_corrections: 1, greedy_actions: false}\n"
                     f"entries:\n  corridor-gpl:\n    base: {config}\n    seeds: [0, 1]\n    evaluations: [test]\n")
    mark = tmp_path / "mark"
    done = _gpl(["suite", "status", str(suite), "--out", str(tmp_path / "out")], tmp_path / "trust.json", mark, tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "new      corridor-gpl seed 0" in done.stdout and not mark.exists()


def test_an_archive_refuses_a_plug_in_file_and_a_link(tmp_path, capsys):
    from gpl_dist.app.suite.archive import check_archive
    from gpl_dist.app.suite.evidence import EvidenceError, write_checksums

    src = REPO / "docs" / "paper-report" / "runs" / "relocation-gpl" / "seed0"
    archive = tmp_path / "archive"
    run = archive / "relocation-gpl" / "seed0"
    shutil.copytree(src, run)
    files = sorted(p.relative_to(archive).as_posix() for p in archive.rglob("*") if p.is_file())
    (run / "corridor.py").write_text("print('pwned')\n")  # listed in the sums, as an attacker would
    write_checksums(archive, [*files, "relocation-gpl/seed0/corridor.py"])
    with pytest.raises(EvidenceError, match="corridor.py is not data an archive may carry"):
        check_archive(archive)
    from gpl_dist.cli import main

    assert main(["suite", "restore", str(archive), "--out", str(tmp_path / "out")]) == 2
    assert "not data an archive may carry" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
    (run / "corridor.py").unlink()
    secret = tmp_path / "secret.json"
    secret.write_text("{}")
    (run / "leak.json").symlink_to(secret)
    with pytest.raises(EvidenceError, match="leak.json is a symbolic link"):
        check_archive(archive)


def test_a_suite_entry_may_not_take_the_name_of_the_suites_own_folders(tmp_path, capsys):
    from gpl_dist.cli import main

    suite = tmp_path / "suite.yaml"
    suite.write_text("evaluations:\n  test: {split: test, seeds: [0], num_corrections: 1, greedy_actions: false}\n"
                     f"entries:\n  rl:\n    base: {REPO / 'configs' / 'multiroom-smoke.yaml'}\n    seeds: [0]\n"
                     "    evaluations: [test]\n")
    assert main(["suite", "run", str(suite), "--out", str(tmp_path / "out"), "--serial"]) == 2
    err = capsys.readouterr().err
    assert "entries.rl: 'rl' is the name of the suite's own folder" in err and err.count("\n") == 1
    assert not (tmp_path / "out").exists()


def test_verify_names_a_config_yaml_edited_after_the_run_wrote_it(plugin_run, tmp_path):
    _, run, plugin, _, trust, _ = plugin_run
    copy = tmp_path / "run"
    shutil.copytree(run, copy)
    mark = tmp_path / "mark"
    assert _gpl(["verify", str(copy)], trust, mark, tmp_path).returncode == 0
    evil = tmp_path / "evil.py"
    evil.write_text("raise SystemExit('pwned')\n")
    (copy / "config.yaml").write_text((copy / "config.yaml").read_text().replace(str(plugin), str(evil)))
    done = _gpl(["verify", str(copy)], trust, mark, tmp_path)
    assert done.returncode == 2 and not mark.exists()
    assert f"BAD  {copy / 'config.yaml'}: says env.domain_module: {evil}" in done.stdout, done.stdout
    assert "edited after the run wrote it" in done.stdout


def test_an_installed_plug_in_is_not_imported_to_read_a_run(tmp_path):
    """An installed package's entry point (a real dist-info on the path) builds its domain for
    train and eval, and is never imported by verify, inspect, clean or suite status."""
    site = tmp_path / "site"
    dist = site / "marked_plugin-0.1.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: marked-plugin\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[gpl_dist.domains]\ncorridor = marked_corridor_ep\n")
    (site / "marked_corridor_ep.py").write_text(CORRIDOR.read_text() + "\nimport os as _os\n"
                                                "with open(_os.environ.get('GPL_TEST_PLUGIN_MARK', _os.devnull), 'a') as _f:\n"
                                                "    _f.write('imported\\n')\n")
    config = tmp_path / "corridor.yaml"
    config.write_text("env: {domain: corridor}\ncollection: {num_workers: 1, num_corrections: 1, tasks_per_unit: 4}\n"
                      "training: {num_rounds: 1, num_epochs_per_round: 1, batch_size: 16}\neval: {seeds: [0]}\n")
    env = {"PYTHONPATH": str(site)}
    trust, mark, run = tmp_path / "trust.json", tmp_path / "mark", tmp_path / "run"

    def gpl(*args):
        done = subprocess.run([GPL_DIST, *args], capture_output=True, text=True, cwd=tmp_path, timeout=300,
                              env=quiet_env(GPL_DIST_TRUST_FILE=str(trust), GPL_TEST_PLUGIN_MARK=str(mark), **env))
        return done

    done = gpl("train", "--config", str(config), "--serial", "--run-dir", str(run), "--no-progress")
    assert done.returncode == 0, done.stderr[-2000:]
    mark.unlink()
    suite = tmp_path / "suite.yaml"
    suite.write_text("evaluations:\n  test: {split: test, seeds: [0], num_corrections: 1, greedy_actions: false}\n"
                     f"entries:\n  corridor-gpl:\n    base: {config}\n    seeds: [0]\n    evaluations: [test]\n")
    for args in (["verify", str(run)], ["inspect", str(run)], ["clean", "--dry-run", str(run)],
                 ["suite", "status", str(suite), "--out", str(tmp_path / "out")]):
        done = gpl(*args)
        assert done.returncode == 0, (args, done.stderr[-2000:])
        assert not mark.exists(), f"{args[0]} imported the installed plug-in"
    done = gpl("eval", "--run-dir", str(run), "--max-tasks", "2")
    assert done.returncode == 0 and mark.exists(), done.stderr[-2000:]  # building the domain: an entry point may


def test_a_cached_pyc_beside_the_plug_in_file_is_never_run(tmp_path):
    """The file's own bytes run, the ones whose sha256 was checked: never a ``__pycache__`` .pyc
    that Python's loader would take when its recorded mtime and size match."""
    import os
    import py_compile
    import sys

    from gpl_dist.domains import load_domain_module

    folder = tmp_path / "plug"
    folder.mkdir()
    benign = CORRIDOR.read_text().replace('name="corridor"', 'name="pyc_check"').replace("gpl-test/Corridor-v0",
                                                                                           "gpl-test/PycCheck-v0")
    hostile = benign + "\nraise SystemExit('the cached pyc ran')\n"
    benign += "\n#" + " " * (len(hostile) - len(benign) - 3) + "\n"  # the same size as the hostile source
    assert len(benign) == len(hostile)
    source = folder / "pyc_check.py"
    source.write_text(hostile)
    cached = folder / "__pycache__" / f"pyc_check.{sys.implementation.cache_tag}.pyc"
    py_compile.compile(str(source), cfile=str(cached))
    stat = source.stat()
    source.write_text(benign)
    os.utime(source, ns=(stat.st_atime_ns, stat.st_mtime_ns))  # what the pyc records: a loader would trust it
    assert load_domain_module(str(source)) == ("pyc_check",)

"""Nothing lost, nothing exposed: bad input and faults, probed through the CLI and real processes.

Every expected failure answers with one line on stderr and exit status 2 and leaves no file behind;
``clean`` acts only on a gpl-dist buffer that no run holds and never removes committed data; a
fresh ``train`` never reuses another run's buffer; corruption of any committed file is named by
``verify``, ``inspect`` and ``train --resume`` before any new work; a local Ray cluster listens on
loopback only.
"""

from __future__ import annotations

import ipaddress
import os
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import psutil
import pytest
import torch
from _cluster_tools import GPL_DIST, TINY_YAML, kill_session, pids_mentioning, quiet_env, short_temp_dir, wait_for

from gpl_dist.cli import main
from gpl_dist.config import ConfigError, config_from_dict, load_config
from gpl_dist.domains import get_domain
from storage.verify import MISSING_NOTE, verify_buffer

# ---------------------------------------------------------------------------------------------------------------
# helpers


def _one_line_error(capsys, *needles: str) -> str:
    err = capsys.readouterr().err.strip()
    assert err.startswith("gpl-dist: error:"), err
    assert "\n" not in err and "Traceback" not in err, err
    for needle in needles:
        assert needle in err, (needle, err)
    return err


def _snapshot(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` (lease files aside) and its bytes."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and not p.name.startswith("_lease")}


def _flip_byte(path: Path, offset: int | None = None) -> None:
    data = bytearray(path.read_bytes())
    i = len(data) // 2 if offset is None else offset
    data[i] ^= 0xFF
    path.write_bytes(bytes(data))


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory) -> Path:
    """A finished 2-round serial run of 6 multi-room tasks (made once; tests work on copies)."""
    base = tmp_path_factory.mktemp("tiny")
    cfg = base / "tiny.yaml"
    cfg.write_text(TINY_YAML)
    run = base / "run"
    assert main(["train", "--config", str(cfg), "--serial", "--run-dir", str(run), "--no-progress"]) == 0
    return run


@pytest.fixture
def run_copy(tiny_run, tmp_path) -> Path:
    dst = tmp_path / "run"
    shutil.copytree(tiny_run, dst)
    return dst


# ---------------------------------------------------------------------------------------------------------------
# clean


def test_clean_refuses_a_directory_that_is_not_a_buffer(tmp_path, capsys):
    thesis = tmp_path / "x" / "data" / "thesis.tex"
    thesis.parent.mkdir(parents=True)
    thesis.write_text("hi")
    (tmp_path / "x" / "staging").mkdir()
    (tmp_path / "x" / "staging" / "notes.txt").write_text("keep")
    for command in (["clean"], ["clean", "--dry-run"], ["inspect"], ["verify"]):
        assert main([*command, str(tmp_path / "x")]) == 2
        _one_line_error(capsys, "holds no gpl-dist run or buffer")
    assert thesis.read_text() == "hi" and (tmp_path / "x" / "staging" / "notes.txt").exists()
    assert main(["inspect", str(tmp_path / "nowhere")]) == 2
    _one_line_error(capsys, "no run directory or buffer")


def test_clean_never_removes_committed_data_even_without_its_manifest(run_copy, capsys):
    buffer = run_copy / "buffer"
    round0 = sorted(p for p in (buffer / "data").rglob("*") if p.is_file() and "round-000000" in str(p))
    assert round0
    (buffer / "manifests" / "round-000000.json").unlink()
    before = _snapshot(buffer)
    assert main(["clean", str(run_copy)]) == 0
    assert all(p.exists() for p in round0) and _snapshot(buffer) == before
    assert main(["verify", str(run_copy)]) == 2
    assert "data/attempts/round-000000" in capsys.readouterr().out
    problems = {(p.path, p.round_index, p.kind) for p in verify_buffer(buffer).problems}
    assert problems == {(f"data/{role}/round-000000", 0, "unlisted") for role in ("attempts", "obs", "tuples")}


# ---------------------------------------------------------------------------------------------------------------
# a fresh run never reuses a buffer


def test_fresh_train_refuses_a_run_dir_or_buffer_that_holds_a_run(run_copy, tmp_path, capsys):
    (run_copy / "checkpoints" / "latest.pt").unlink()
    before = _snapshot(run_copy)
    other = tmp_path / "other.yaml"
    other.write_text(TINY_YAML.replace("seed: 3", "seed: 4"))
    assert main(["train", "--config", str(other), "--serial", "--run-dir", str(run_copy), "--no-progress"]) == 2
    _one_line_error(capsys, str(run_copy), "--resume")
    assert _snapshot(run_copy) == before
    # a new run dir whose buffer.location points at another run's buffer
    fresh = tmp_path / "fresh"
    assert main(["train", "--config", str(other), "--serial", "--run-dir", str(fresh), "--no-progress",
                 "--set", f"buffer.location={run_copy / 'buffer'}"]) == 2
    _one_line_error(capsys, str(run_copy / "buffer"), "--resume")
    assert not fresh.exists() and _snapshot(run_copy) == before


# ---------------------------------------------------------------------------------------------------------------
# corruption is named before any work


def _tuples_file(run: Path, round_index: int) -> Path:
    return sorted((run / "buffer" / "data" / "tuples" / f"round-{round_index:06d}").glob("*.parquet"))[0]


def _zarr_chunk(run: Path, round_index: int) -> Path:
    obs = sorted((run / "buffer" / "data" / "obs" / f"round-{round_index:06d}").glob("*.zarr"))[0]
    return max((p for p in obs.rglob("*") if p.is_file() and "zarr.json" not in p.name), key=lambda p: p.stat().st_size)


def _truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


CORRUPTIONS = {
    "flipped byte in a tuples parquet": (lambda run: _flip_byte(_tuples_file(run, 0)), lambda run: _tuples_file(run, 0)),
    "flipped byte in a zarr chunk": (lambda run: _flip_byte(_zarr_chunk(run, 1), 40), lambda run: _zarr_chunk(run, 1)),
    "truncated tuples shard": (lambda run: _truncate(_tuples_file(run, 1)), lambda run: _tuples_file(run, 1)),
    "truncated manifest": (lambda run: _truncate(run / "buffer/manifests/round-000001.json"),
                           lambda run: run / "buffer/manifests/round-000001.json"),
    "deleted manifest": (lambda run: (run / "buffer/manifests/round-000000.json").unlink(),
                         lambda run: run / "buffer/data/attempts/round-000000"),
}


@pytest.mark.parametrize("corruption", list(CORRUPTIONS))
def test_corruption_is_named_by_verify_inspect_and_resume_before_any_work(run_copy, capsys, corruption):
    corrupt, bad_path = CORRUPTIONS[corruption]
    bad = str(bad_path(run_copy).relative_to(run_copy / "buffer"))
    corrupt(run_copy)
    before = _snapshot(run_copy)

    assert main(["verify", str(run_copy)]) == 2
    out = capsys.readouterr()
    assert f"BAD  {bad}" in out.out and "problem(s)" in out.err
    assert main(["inspect", str(run_copy)]) == 2
    _one_line_error(capsys, bad)
    assert main(["train", "--run-dir", str(run_copy), "--resume", "--serial", "--no-progress",
                 "--set", "training.num_rounds=3"]) == 2
    _one_line_error(capsys, bad, "gpl-dist verify")
    assert _snapshot(run_copy) == before, "resume wrote something before refusing"


def test_quarantined_round_after_the_last_checkpoint_is_collected_again(run_copy, capsys):
    # as if the driver died after committing round 1 and before its checkpoint, and round 1 then rotted
    ckpts = run_copy / "checkpoints"
    shutil.copyfile(ckpts / "round-000000.pt", ckpts / "latest.pt")
    _flip_byte(_tuples_file(run_copy, 1))
    assert main(["verify", str(run_copy), "--quarantine"]) == 0
    assert verify_buffer(run_copy / "buffer").quarantined == (1,)
    assert not (run_copy / "buffer/manifests/round-000001.json").exists()
    assert list((run_copy / "buffer/quarantine/round-000001").glob("*/manifests/round-000001.json"))
    assert main(["verify", str(run_copy)]) == 0
    assert main(["train", "--run-dir", str(run_copy), "--resume", "--serial", "--no-progress"]) == 0
    assert (run_copy / "buffer/manifests/round-000001.json").exists()
    assert main(["verify", str(run_copy)]) == 0
    report = verify_buffer(run_copy / "buffer")
    assert report.rounds == (0, 1) and report.quarantined == (1,) and report.ok


# ---------------------------------------------------------------------------------------------------------------
# one error path: one line, exit 2, nothing written


#: each probe's key at fault (a message naming another key fails), and the rejected value where the
#: message repeats it (the source, "... with --set KEY", names the key whatever the message says)
_PROBES = {
    "env.correction_kind=subgoals": (": env.correction_kind", "'subgoals'"),
    "env.expert=learnt": (": env.expert", "'learnt'"),
    "model.variant=transformer": (": model.variant", "'transformer'"),
    "training.num_rounds=[1": ("training.num_rounds='[1'",),
    "env.max_train_tasks=-1": (": env.max_train_tasks",),
    "env.task_ids=[0,99999]": (": env.task_ids", "[99999]"),
    "env.train_split=trian": (": env.train_split", "'trian'"),
    "model.embedding_dim=0": (": model.embedding_dim",),
    "model.correction_width=-4": (": model.correction_width",),
    "training.num_threads=-1": (": training.num_threads",),
    "collection.max_unit_retries=-1": (": collection.max_unit_retries",),
    "collection.unit_timeout_s=0": (": collection.unit_timeout_s",),
    "eval.max_tasks=-2": (": eval.max_tasks",),
}


@pytest.mark.parametrize("override", list(_PROBES))
def test_bad_config_values_fail_in_one_line_before_anything_is_written(tmp_path, capsys, override):
    run = tmp_path / "run"
    start = time.perf_counter()
    assert main(["train", "--config", "configs/multiroom-smoke.yaml", "--num-workers", "2", "--run-dir", str(run),
                 "--set", override]) == 2
    _one_line_error(capsys, *_PROBES[override])
    assert not run.exists()
    assert time.perf_counter() - start < 20, "the check came late (after Ray started?)"


def test_domain_foreign_correction_kind_fails_and_each_domain_has_a_default():
    with pytest.raises(ConfigError, match=r"env\.correction_kind.*'subgoal'"):
        config_from_dict({"env": {"domain": "relocation", "correction_kind": "subgoal"}})
    assert "subgoal" not in get_domain("relocation").correction_kinds
    assert config_from_dict({"env": {"domain": "relocation"}}).env.correction_kind == "default"


def test_cuda_on_a_machine_without_one_fails_before_anything_is_written(tmp_path, capsys):
    run = tmp_path / "run"
    code = main(["train", "--config", "configs/multiroom-smoke.yaml", "--serial", "--run-dir", str(run),
                 "--set", "training.device=cuda", "--set", "training.num_rounds=1", "--set", "env.max_train_tasks=2",
                 "--set", "training.num_epochs_per_round=0", "--no-progress"])
    if torch.cuda.is_available():  # a GPU machine: the same command trains
        assert code == 0
        return
    assert code == 2
    _one_line_error(capsys, ": training.device")
    assert not run.exists()


def test_eval_and_checkpoint_probes_answer_in_one_line(run_copy, tmp_path, capsys):
    before = _snapshot(run_copy)
    for args, needle in [(["--corrections", "-1"], "corrections"), (["--max-tasks", "-3"], "max_tasks"),
                         (["--seeds", "a,b"], "'a,b'"), (["--split", "tset"], "'tset'")]:
        assert main(["eval", "--run-dir", str(run_copy), *args]) == 2
        _one_line_error(capsys, needle)
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(np.random.default_rng(0).bytes(4096))
    assert main(["eval", "--run-dir", str(run_copy), "--checkpoint", str(garbage)]) == 2
    err = _one_line_error(capsys, str(garbage))
    assert "weights_only" not in err
    not_ours = tmp_path / "not_ours.pt"
    torch.save({"weights": torch.zeros(3)}, not_ours)
    assert main(["eval", "--run-dir", str(run_copy), "--checkpoint", str(not_ours)]) == 2
    _one_line_error(capsys, str(not_ours))
    assert _snapshot(run_copy) == before, "a refused eval wrote files"

    # --resume with a garbage checkpoint: refused before config.yaml is rewritten
    shutil.copyfile(garbage, run_copy / "checkpoints" / "latest.pt")
    before = _snapshot(run_copy)
    assert main(["train", "--run-dir", str(run_copy), "--resume", "--serial", "--no-progress",
                 "--set", "training.num_rounds=3"]) == 2
    _one_line_error(capsys, str(run_copy / "checkpoints" / "latest.pt"))
    assert _snapshot(run_copy) == before


def test_corrupt_attempts_file_at_inspect_and_verbose_traceback(run_copy, capsys):
    attempts = sorted((run_copy / "buffer/data/attempts/round-000001").glob("*.parquet"))[0]
    _flip_byte(attempts)
    assert main(["inspect", str(run_copy)]) == 2
    _one_line_error(capsys, "data/attempts/round-000001/", "checksum mismatch")
    assert main(["-v", "inspect", str(run_copy)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" in err and err.strip().splitlines()[-1].startswith("gpl-dist: error:")


# ---------------------------------------------------------------------------------------------------------------
# leases


def test_remote_lease_refuses_a_second_holder_and_takes_over_an_abandoned_one():
    from storage.lease import Lease, lease_holder

    url = f"memory://lease-{os.getpid()}-{time.time_ns()}"
    with Lease(url, "gpl-dist train") as first:
        assert lease_holder(url).pid == os.getpid()
        with pytest.raises(Exception, match=r"in use by gpl-dist train \(pid"):
            Lease(url, "gpl-dist clean").acquire()
        # a holder whose heartbeat stopped long ago (its driver was killed) is taken over
        first._stop.set()
        first._thread.join()
        import json

        raw = json.loads(first.location.read_bytes("_lease.json"))
        raw.update(heartbeat=time.time() - 10 * Lease.TTL_S, pid=raw["pid"] + 1, host="another-host")
        first.location.write_bytes("_lease.json", json.dumps(raw).encode())
        assert lease_holder(url) is None
        with Lease(url, "gpl-dist clean"):
            assert lease_holder(url).command == "gpl-dist clean"


# ---------------------------------------------------------------------------------------------------------------
# a running local run: loopback only, and nobody else may touch its run dir


def _is_loopback(ip: str) -> bool:
    addr = ipaddress.ip_address(ip.split("%")[0])
    mapped = getattr(addr, "ipv4_mapped", None)
    return (mapped or addr).is_loopback


def _listening(pids: list[int]) -> list[tuple[int, str, int]]:
    out = []
    for pid in pids:
        try:
            conns = psutil.Process(pid).net_connections(kind="inet")
        except psutil.Error:
            continue
        out += [(pid, c.laddr.ip, c.laddr.port) for c in conns if c.status == psutil.CONN_LISTEN]
    return out


@pytest.mark.ray
@pytest.mark.slow
def test_a_local_run_listens_on_loopback_only_and_holds_its_run_dir(tmp_path, capsys):
    cfg = tmp_path / "long.yaml"
    cfg.write_text(TINY_YAML.replace("num_rounds: 2", "num_rounds: 500"))
    run = tmp_path / "run"
    ray_tmp = short_temp_dir("gplsafe-")
    log = open(tmp_path / "driver.log", "w")
    proc = subprocess.Popen([GPL_DIST, "train", "--config", str(cfg), "--num-workers", "2", "--run-dir", str(run),
                             "--no-progress"], stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
                            env=quiet_env(RAY_TMPDIR=ray_tmp))
    try:
        wait_for(run / "buffer" / "manifests" / "round-000000.json", proc, timeout=180)
        ray_pids = [proc.pid] + [c.pid for c in psutil.Process(proc.pid).children(recursive=True)]
        listening = _listening(ray_pids)
        names = {psutil.Process(p).name() for p, _, _ in listening}
        assert len(listening) >= 4 and any("gcs" in n for n in names) and any("raylet" in n for n in names), listening
        exposed = [(psutil.Process(p).name(), ip, port) for p, ip, port in listening if not _is_loopback(ip)]
        assert not exposed, f"Ray listens beyond loopback: {exposed}"

        staged_before = _snapshot(run / "buffer")
        assert main(["clean", str(run)]) == 2
        _one_line_error(capsys, "is in use by gpl-dist train (pid", str(proc.pid))
        assert main(["clean", str(run), "--dry-run"]) == 2
        _one_line_error(capsys, "in use by gpl-dist train")
        assert main(["train", "--run-dir", str(run), "--resume", "--serial", "--no-progress"]) == 2
        _one_line_error(capsys, "in use by gpl-dist train")
        committed = {k: v for k, v in staged_before.items() if k.startswith(("data/", "manifests/round"))}
        assert all((run / "buffer" / k).read_bytes() == v for k, v in committed.items())
        assert proc.poll() is None, "the run died while others were refused"
    finally:
        kill_session(proc.pid)
        proc.wait(10)
        log.close()
        left = pids_mentioning(ray_tmp)
        shutil.rmtree(ray_tmp, ignore_errors=True)
        assert not left, f"Ray processes of the driver survived: {left}"
    # the kernel dropped the dead driver's lock: clean may act now, and keeps every committed file
    assert main(["clean", str(run)]) == 0
    assert all((run / "buffer" / k).read_bytes() == v for k, v in committed.items())


@pytest.mark.ray
def test_the_shared_test_cluster_listens_on_loopback_only(ray_cluster):
    @ray_cluster.remote
    class Probe:
        def pid(self) -> int:
            return os.getpid()

    probe = Probe.remote()
    actor_pid = ray_cluster.get(probe.pid.remote())
    pids = [os.getpid()] + [c.pid for c in psutil.Process().children(recursive=True)]
    assert actor_pid in pids
    listening = _listening(pids)
    assert any(p == actor_pid for p, _, _ in listening), "the actor's gRPC server was not seen"
    exposed = [(psutil.Process(p).name(), ip, port) for p, ip, port in listening if not _is_loopback(ip)]
    assert not exposed, f"Ray listens beyond loopback: {exposed}"
    ray_cluster.kill(probe)


# ---------------------------------------------------------------------------------------------------------------
# more probes of the same kind


def test_a_manifests_folder_alone_does_not_make_a_buffer(tmp_path, capsys):
    repo = tmp_path / "k8s"
    (repo / "manifests" / "base").mkdir(parents=True)
    deployment = repo / "staging" / "overlays" / "prod" / "app" / "deployment.yaml"
    deployment.parent.mkdir(parents=True)
    deployment.write_text("kind: Deployment\n")
    assert main(["clean", str(repo)]) == 2
    _one_line_error(capsys, "holds no gpl-dist run or buffer")
    assert deployment.read_text() == "kind: Deployment\n"
    assert not list(repo.rglob("_lease*")), "a refused clean left a lock file"


def test_resume_without_latest_checkpoint_never_starts_over(run_copy, capsys):
    (run_copy / "checkpoints" / "latest.pt").unlink()
    before = _snapshot(run_copy)
    assert main(["train", "--run-dir", str(run_copy), "--resume", "--serial", "--no-progress",
                 "--set", "training.num_rounds=3"]) == 2
    _one_line_error(capsys, str(run_copy / "checkpoints" / "latest.pt"), "round-000001.pt")
    assert _snapshot(run_copy) == before


def test_resume_refuses_another_model_or_domain_and_does_nothing_once_finished(run_copy, capsys):
    before = _snapshot(run_copy)
    for override, needle in [("model.variant=instruction_only", "model.variant"),
                             ("model.embedding_dim=8", "model.embedding_dim")]:
        load_config(run_copy / "config.yaml", dict([override.split("=")]))  # the override itself is valid
        assert main(["train", "--run-dir", str(run_copy), "--resume", "--serial", "--no-progress", "--set", override]) == 2
        _one_line_error(capsys, needle)  # so the refusal is resume's: the run's own value cannot change
    # a resubmitted job of a finished run: nothing to do, exit 0, nothing rewritten
    assert main(["train", "--run-dir", str(run_copy), "--resume", "--serial", "--no-progress"]) == 0
    assert _snapshot(run_copy) == before


def test_a_round_missing_whole_is_set_aside_and_training_goes_on(run_copy, capsys):
    root = run_copy / "buffer"
    (root / "manifests" / "round-000000.json").unlink()
    for role in ("attempts", "tuples", "obs"):
        shutil.rmtree(root / "data" / role / "round-000000")
    assert main(["verify", str(run_copy)]) == 2
    assert [(p.path, p.round_index, p.kind) for p in verify_buffer(root).problems] == [
        ("manifests/round-000000.json", 0, "gap")]
    assert main(["verify", str(run_copy), "--quarantine"]) == 0
    assert verify_buffer(root).quarantined == (0,)
    assert [p.name for p in (root / "quarantine" / "round-000000").rglob("*") if p.is_file()] == [MISSING_NOTE]
    assert main(["verify", str(run_copy)]) == 0
    assert main(["train", "--run-dir", str(run_copy), "--resume", "--serial", "--no-progress",
                 "--set", "training.num_rounds=3"]) == 0
    assert (root / "manifests" / "round-000002.json").exists()


def test_a_damaged_commit_journal_is_named_and_never_followed(run_copy, tmp_path, capsys):
    import json

    root = run_copy / "buffer"
    journal = root / "manifests" / "_pending-round-000002.json"
    journal.write_text('{"manifest": {"round_index": 2}, "mo')  # truncated
    before = _snapshot(run_copy)
    assert main(["verify", str(run_copy)]) == 2
    assert "manifests/_pending-round-000002.json" in capsys.readouterr().out
    assert [(p.path, p.kind) for p in verify_buffer(root).problems] == [("manifests/_pending-round-000002.json", "journal")]
    for command in (["clean", str(run_copy)], ["clean", "--dry-run", str(run_copy)],
                    ["train", "--run-dir", str(run_copy), "--resume", "--serial", "--no-progress",
                     "--set", "training.num_rounds=3"]):
        assert main(command) == 2
        _one_line_error(capsys, "_pending-round-000002.json")
    assert _snapshot(run_copy) == before
    # a journal whose move reaches outside the buffer is refused, and the outside file stays where it is
    victim = tmp_path / "victim.txt"
    victim.write_text("mine")
    journal.write_text(json.dumps({"manifest": {"round_index": 2}, "moves": [["../../../victim.txt", "data/x", 4]]}))
    assert main(["clean", str(run_copy)]) == 2
    _one_line_error(capsys, "_pending-round-000002.json", "victim.txt")
    assert victim.read_text() == "mine"


def test_environment_problems_answer_in_one_line(tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("x")
    start = time.perf_counter()
    probes = [(["train", "--config", "configs/multiroom-smoke.yaml", "--serial", "--run-dir", str(afile / "sub")], None),
              (["inspect", str(tmp_path / ("n" * 300))], "File name too long"),
              (["train", "--config", "configs/multiroom-smoke.yaml", "--run-dir", str(tmp_path / "r"),
                "--address", "127.0.0.1:1"], "127.0.0.1:1"),
              (["render", "--env", "multiroom", "--task", "1", "--out", str(tmp_path / "r.png"), "--seed", "-1"],
               "--seed"),
              (["render", "--env", "multiroom", "--task", "1", "--out", str(tmp_path / "r.gif"), "--actions",
                str(tmp_path / "missing.txt")], str(tmp_path / "missing.txt"))]
    for args, needle in probes:
        assert main(args) == 2, args
        _one_line_error(capsys, *([needle] if needle else []))
    assert not (tmp_path / "r").exists() and not list(tmp_path.glob("r.*"))
    assert time.perf_counter() - start < 60


def test_config_text_mistakes_are_named(tmp_path, capsys):
    twice = tmp_path / "twice.yaml"
    twice.write_text("seed: 1\ntraining:\n  num_rounds: 2\n  num_rounds: 3\n")
    binary = tmp_path / "binary.yaml"
    binary.write_bytes(bytes(range(256)))
    for args, needle in [(["--config", str(twice)], "'num_rounds'"),
                         (["--config", str(binary)], str(binary)),
                         (["--config", "configs/multiroom-smoke.yaml", "--set", "seed=" + "9" * 5000], "seed='999"),
                         (["--config", "configs/multiroom-smoke.yaml", "--set", "eval.seeds=[1,1]"], ": eval.seeds"),
                         (["--config", "configs/multiroom-smoke.yaml", "--set", "collection.num_corrections=1000"],
                          ": collection.num_corrections"),
                         (["--config", "configs/multiroom-smoke.yaml", "--set", "env.domain=" + "x" * 100_000],
                          "100000"),  # the value's length, not the value
                         (["--config", "configs/multiroom-smoke.yaml", "--set", "env.domain=" + "x" * 5000],
                          ": env.domain")]:
        assert main(["train", *args, "--serial", "--run-dir", str(tmp_path / "run")]) == 2
        err = _one_line_error(capsys, needle)
        assert len(err) < 1000
    assert not (tmp_path / "run").exists()


def test_a_commit_in_progress_is_not_corruption_and_is_finished_not_quarantined(run_copy, capsys):
    """A driver killed after the first move of a commit: data of the round is in data/, the manifest
    is not written yet, the journal is sound. verify says so and does not call it a problem."""
    import json

    root = run_copy / "buffer"
    manifest = root / "manifests" / "round-000001.json"
    entry = json.loads(manifest.read_text())
    moved = [f["path"] for s in entry["shards"] for f in s["files"]]
    moves = [[f"staging/round-000001/unit-00000/try-x/{i}", dst, (root / dst).stat().st_size] for i, dst in enumerate(moved)]
    (root / "manifests" / "_pending-round-000001.json").write_text(json.dumps(
        {"manifest": entry, "moves": moves, "staging_dirs": ["staging/round-000001/unit-00000/try-x"]}))
    manifest.unlink()
    assert main(["verify", str(run_copy)]) == 0
    report = verify_buffer(root)
    assert report.ok and report.in_progress == (1,) and report.rounds == (0,)
    assert main(["verify", str(run_copy), "--quarantine"]) == 0
    assert not (root / "quarantine").exists()
    assert main(["clean", str(run_copy)]) == 0  # rolls the commit forward
    assert manifest.exists() and not (root / "manifests" / "_pending-round-000001.json").exists()
    assert main(["verify", str(run_copy)]) == 0


def test_quarantining_a_round_twice_keeps_both_copies(run_copy, capsys):
    from storage.verify import quarantine_round

    root = run_copy / "buffer"
    first = quarantine_round(root, 1)
    (root / "manifests" / "round-000001.json").write_text("{}")  # something of round 1 again, then set aside again
    second = quarantine_round(root, 1)
    assert "manifests/round-000001.json" in first and second == ["manifests/round-000001.json"]
    copies = sorted((root / "quarantine" / "round-000001").iterdir())
    assert len(copies) == 2 and all((c / "manifests" / "round-000001.json").exists() for c in copies)


def test_paths_in_manifests_cannot_leave_the_buffer(run_copy, tmp_path, capsys):
    import json

    outside = tmp_path / "outside.bin"
    outside.write_bytes(b"secret")
    manifest = run_copy / "buffer" / "manifests" / "round-000001.json"
    entry = json.loads(manifest.read_text())
    entry["shards"][0]["files"][0]["path"] = "../../outside.bin"
    manifest.write_text(json.dumps(entry))
    assert main(["verify", str(run_copy)]) == 2
    assert "../../outside.bin" in capsys.readouterr().out
    problems = verify_buffer(run_copy / "buffer").problems
    assert ("../../outside.bin", 1, "file") in [(p.path, p.round_index, p.kind) for p in problems]
    assert main(["inspect", str(run_copy)]) == 2
    _one_line_error(capsys, "../../outside.bin")
    assert outside.read_bytes() == b"secret"

"""Fault tolerance with real processes: a SIGKILLed rollout actor, a SIGKILLed driver resumed with
``gpl-dist train --resume``, a node removed mid-round, and a broken task.

The first three run ``gpl-dist train`` / a multi-node driver in sessions the test starts
(``start_new_session=True``, own ``RAY_TMPDIR``), and pause a chosen unit at the worker's fault point
(``gpl_dist.faults``, given as ``GPL_DIST_FAULT``), so that each kill lands in the middle of a round
deterministically. Exactly-once is checked on the committed buffer:
one shard per unit in each manifest, no data file outside the manifests, every (round, task,
attempt) once in the attempts table.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pytest
import yaml
from _cluster_tools import (
    GPL_DIST,
    TINY_TASKS,
    TINY_UNITS,
    TINY_YAML,
    assert_buffer_exactly_once,
    kill_session,
    pids_mentioning,
    quiet_env,
    run_multinode,
    short_temp_dir,
    wait_for,
)

from gpl_dist.faults import FAULT_ENV, PauseAt


def _pause_unit(round_index: int, unit_index: int, signals: Path) -> str:
    """``GPL_DIST_FAULT`` pausing the first try of one unit after collection; its pid goes to
    ``signals/round-R-unit-U.pid``."""
    signal_file = signals / f"round-{round_index}-unit-{unit_index}.pid"
    return PauseAt("worker.unit_collected", str(signal_file), {"round": str(round_index), "unit": str(unit_index)}).spec()


class _Driver:
    """``gpl-dist train`` in its own session with its own Ray temp dir (local Ray, 2 actors)."""

    def __init__(self, args: list[str], log: Path, **env: str):
        self.ray_tmp = short_temp_dir("gplk-")
        self.log = open(log, "w")
        self.proc = subprocess.Popen([GPL_DIST, "train", *args, "--no-progress"], stdout=self.log,
                                     stderr=subprocess.STDOUT, start_new_session=True,
                                     env=quiet_env(RAY_TMPDIR=self.ray_tmp, **env))

    def finish(self, timeout: float = 240) -> int:
        try:
            return self.proc.wait(timeout)
        finally:
            self.cleanup()

    def cleanup(self) -> list[int]:
        """Kill the driver's whole session; returns processes that outlived the process group kill."""
        stragglers = kill_session(self.proc.pid)
        self.proc.wait(10)
        self.log.close()
        left = pids_mentioning(self.ray_tmp)
        shutil.rmtree(self.ray_tmp, ignore_errors=True)
        assert not left, f"Ray processes of the driver survived: {left}"
        return stragglers


@pytest.fixture
def tiny_config(tmp_path) -> Path:
    path = tmp_path / "tiny.yaml"
    path.write_text(TINY_YAML)
    return path


@pytest.mark.cluster
def test_actor_killed_mid_round_is_restarted_and_its_unit_retried(tmp_path, tiny_config):
    run_dir, signals = tmp_path / "run", tmp_path / "signals"
    signals.mkdir()
    driver = _Driver(["--config", str(tiny_config), "--run-dir", str(run_dir)], tmp_path / "driver.log",
                     **{FAULT_ENV: _pause_unit(0, 1, signals)})
    try:
        pid_file = signals / "round-0-unit-1.pid"
        wait_for(pid_file, driver.proc)
        actor_pid = int(pid_file.read_text())
        assert actor_pid != driver.proc.pid
        assert "RolloutActor" in Path(f"/proc/{actor_pid}/cmdline").read_bytes().decode(errors="replace")
        os.kill(actor_pid, signal.SIGKILL)  # the actor, in the middle of unit 1 of round 0
        assert driver.proc.wait(240) == 0
    finally:
        assert driver.cleanup() == []
    log = (tmp_path / "driver.log").read_text()
    assert "unit (0, 1) failed" in log and "handing it out again" in log, log[-3000:]
    assert "round 1:" in log
    assert_buffer_exactly_once(run_dir / "buffer", [0, 1])


@pytest.mark.cluster
def test_actor_that_hangs_mid_unit_is_replaced_after_the_unit_timeout(tmp_path, tiny_config):
    """An actor alive but silent (paused in unit 1 of round 0, as a hung env or a lost call would
    leave it): after ``collection.unit_timeout_s`` the unit is a failed try, the actor is killed and
    replaced, and the run finishes instead of waiting without end."""
    run_dir, signals = tmp_path / "run", tmp_path / "signals"
    signals.mkdir()
    timeout_s = 60  # above an actor's start on 2 loaded cores (its first unit's clock includes it)
    driver = _Driver(["--config", str(tiny_config), "--run-dir", str(run_dir), "--set",
                      f"collection.unit_timeout_s={timeout_s}"], tmp_path / "driver.log",
                     **{FAULT_ENV: _pause_unit(0, 1, signals)})
    try:
        wait_for(signals / "round-0-unit-1.pid", driver.proc)
        paused_pid = int((signals / "round-0-unit-1.pid").read_text())
        paused_at = time.monotonic()
        assert driver.proc.wait(240) == 0
        assert time.monotonic() - paused_at > timeout_s - 10, "the unit was handed out again before its timeout"
        assert not Path(f"/proc/{paused_pid}").exists() or b"RolloutActor" not in \
            Path(f"/proc/{paused_pid}/cmdline").read_bytes(), "the hung actor was left running"
    finally:
        assert driver.cleanup() == []
    log = (tmp_path / "driver.log").read_text()
    assert "unit (0, 1) got no result from actor-" in log and f"unit_timeout_s={timeout_s}s" in log, log[-3000:]
    assert "returned nothing in time" in log and "round 1:" in log, log[-3000:]
    assert_buffer_exactly_once(run_dir / "buffer", [0, 1])


@pytest.mark.cluster
def test_driver_killed_mid_round_resumes_from_last_committed_round(tmp_path, tiny_config):
    from learner.checkpoint import load_checkpoint
    from storage import clean_leftovers, committed_rounds, load_manifest

    run_dir, signals = tmp_path / "run", tmp_path / "signals"
    root = run_dir / "buffer"
    signals.mkdir()
    driver = _Driver(["--config", str(tiny_config), "--run-dir", str(run_dir)], tmp_path / "killed.log",
                     **{FAULT_ENV: _pause_unit(1, 0, signals)})
    try:
        wait_for(signals / "round-1-unit-0.pid", driver.proc)
        # the other actor stages units 1 and 2 of round 1 meanwhile: wait for them, then kill
        deadline = time.monotonic() + 60
        while len(list((root / "staging" / "round-000001").glob("unit-*/try-*"))) < TINY_UNITS - 1:
            assert time.monotonic() < deadline, "units 1 and 2 of round 1 were not staged"
            time.sleep(0.05)
        os.killpg(driver.proc.pid, signal.SIGKILL)  # the driver and every Ray process it started
        assert driver.proc.wait(10) == -signal.SIGKILL
    finally:
        # ray.init's processes share the driver's session and process group: nothing survives the group kill
        assert driver.cleanup() == []
    assert committed_rounds(root) == [0]
    assert load_checkpoint(run_dir / "checkpoints").round_index == 0
    stale = {p.name for p in (root / "staging" / "round-000001").glob("unit-*/try-*")}
    assert len(stale) == TINY_UNITS - 1

    resumed = _Driver(["--run-dir", str(run_dir), "--resume"], tmp_path / "resumed.log")
    assert resumed.finish() == 0, (tmp_path / "resumed.log").read_text()[-3000:]
    log = (tmp_path / "resumed.log").read_text()
    assert "round 1:" in log and "round 0:" not in log  # round 0 was not collected or trained again
    ckpt = load_checkpoint(run_dir / "checkpoints")
    assert ckpt.round_index == 1 and [m["round"] for m in ckpt.history] == [0, 1]
    lines = [json.loads(x) for x in (run_dir / "metrics.jsonl").read_text().splitlines()]
    assert [m["round"] for m in lines] == [0, 1]
    # round 1 was collected again: its manifest lists the new tries, not the killed run's
    assert not {f"try-{s.try_id}" for s in load_manifest(root, 1).shards} & stale
    assert_buffer_exactly_once(root, [0, 1])
    removed = clean_leftovers(root)
    assert removed and all(r.startswith("staging/round-000001/") for r in removed)
    assert {Path(r).name for r in removed} == stale
    assert clean_leftovers(root) == []
    assert_buffer_exactly_once(root, [0, 1])


@pytest.mark.cluster
def test_node_removed_mid_round_its_units_finish_elsewhere(tmp_path):
    signals = tmp_path / "signals"
    signals.mkdir()
    res = run_multinode("node-loss", tmp_path, **{FAULT_ENV: _pause_unit(0, 1, signals)})
    survivor = set(res["worker_nodes"]) - {res["removed_node"]}
    assert res["removed_node"] in res["worker_nodes"] and len(survivor) == 1
    assert res["rounds"] == [0, 1]
    assert res["unit_tries"] == {"0/1": 1}, res  # only the unit on the lost node was retried
    assert res["unit_nodes"]["0/1"] in survivor
    # the lost node's actor cannot restart (no free CPU): the survivor collects all of round 1
    assert {res["unit_nodes"][f"1/{u}"] for u in range(TINY_UNITS)} == survivor
    assert_buffer_exactly_once(tmp_path / "run" / "buffer", [0, 1])


def test_broken_tasks_are_reported_and_do_not_stop_the_run(tmp_path, monkeypatch, caplog):
    """A task whose env cannot be built and one whose env raises mid-attempt (serial mode, so an
    in-process monkeypatch of the domain registry reaches the worker)."""
    import workers.collector
    from gpl_dist.config import config_from_dict
    from learner.driver import run_training, training_tasks
    from storage import load_manifest

    cfg = config_from_dict(yaml.safe_load(TINY_YAML))
    tasks = training_tasks(cfg)
    bad_env, bad_step = tasks[1], tasks[4]
    real_get_domain = workers.collector.get_domain

    def broken_get_domain(name):
        domain = real_get_domain(name)

        def make_env(task_id, **kwargs):
            if task_id == bad_env:
                raise RuntimeError("cannot build this env")
            env = domain.make_env(task_id, **kwargs)
            if task_id == bad_step:
                calls = [0]
                real_step = env.step

                def step(action):
                    calls[0] += 1
                    if calls[0] == 5:
                        raise ValueError("env step exploded")
                    return real_step(action)

                env.step = step
            return env

        return dataclasses.replace(domain, make_env=make_env)

    monkeypatch.setattr(workers.collector, "get_domain", broken_get_domain)
    with caplog.at_level(logging.ERROR):
        result = run_training(cfg, tmp_path / "run", serial=True, progress=False)
    assert [m.round_index for m in result.history] == [0, 1]
    for m in result.history:
        assert sorted(m.failed_tasks) == sorted([bad_env, bad_step])
    root = tmp_path / "run" / "buffer"
    for r in (0, 1):
        assert sorted(load_manifest(root, r).extra["failed_tasks"]) == sorted([bad_env, bad_step])
    errors = [rec.getMessage() for rec in caplog.records if rec.name == "learner.driver"]
    assert any(f"task {bad_env}: env construction failed" in e for e in errors), errors
    assert any(f"task {bad_step}: step/expert failed" in e and "exploded" in e for e in errors), errors
    lines = [json.loads(x) for x in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert all(sorted(m["failed_tasks"]) == sorted([bad_env, bad_step]) for m in lines)
    # the broken tasks have no attempts; every other task is there exactly once per round
    assert_buffer_exactly_once(root, [0, 1], num_tasks=TINY_TASKS, missing_tasks=frozenset({bad_env, bad_step}))


@pytest.mark.cluster
def test_sigterm_ends_train_like_ctrl_c_in_one_line(tmp_path, tiny_config):
    """SIGTERM to a ``gpl-dist train`` on local Ray, mid-round (before: Ray's C++ '*** SIGTERM
    received ... PC: @' dump and exit 134): one line saying how to resume, exit 143, and the
    resumed run finishes."""
    run_dir, signals = tmp_path / "run", tmp_path / "signals"
    signals.mkdir()
    driver = _Driver(["--config", str(tiny_config), "--run-dir", str(run_dir)], tmp_path / "driver.log",
                     **{FAULT_ENV: _pause_unit(1, 0, signals)})
    try:
        wait_for(signals / "round-1-unit-0.pid", driver.proc)
        driver.proc.send_signal(signal.SIGTERM)
        assert driver.proc.wait(120) == 143
    finally:
        driver.cleanup()
    log = (tmp_path / "driver.log").read_text()
    assert "SIGTERM received" not in log and "PC: @" not in log, log[-3000:]
    assert f"gpl-dist: terminated (SIGTERM); resume with: gpl-dist train --run-dir {run_dir} --resume" in log
    assert "Traceback" not in log, log[-3000:]
    resumed = _Driver(["--run-dir", str(run_dir), "--resume"], tmp_path / "resume.log")
    assert resumed.finish() == 0, (tmp_path / "resume.log").read_text()[-3000:]
    assert_buffer_exactly_once(run_dir / "buffer", [0, 1])


def test_a_failed_unit_names_its_root_cause_without_ray_decoration(tmp_path, ray_cluster):
    """Every try of a unit fails writing its shard (here: ``staging`` is a file, so the writer's
    directories cannot be made, as a full disk would fail them): the round's error is the
    exception's type and message, with no ANSI colour codes and no Ray traceback."""
    from gpl_dist.config import config_from_dict
    from learner.driver import make_units, training_tasks
    from workers.ray_collector import RayCollector, RoundFailed
    from workers.worker import RolloutSettings

    cfg = config_from_dict(yaml.safe_load(TINY_YAML))
    root = tmp_path / "buffer"
    root.mkdir()
    (root / "staging").write_text("not a directory")
    collector = RayCollector("multiroom", RolloutSettings.of_run(cfg), str(root), "run-x", 1, max_unit_retries=1)
    try:
        from gpl_dist.domains import get_domain
        from gpl_dist.models.build import build_model_from_config, state_dict_to_numpy

        weights = state_dict_to_numpy(build_model_from_config(get_domain("multiroom"), cfg.model, seed=0))
        units = make_units(training_tasks(cfg)[:2], 0, cfg, cfg.env.train_split, 0)
        with pytest.raises(RoundFailed) as info:
            collector.collect_round(units, weights, 0)
    finally:
        collector.close()
    message = str(info.value)
    assert "failed 2 times; last error: " in message, message
    cause = message.split("last error: ", 1)[1]
    assert cause.startswith(("FileExistsError: [Errno 17]", "NotADirectoryError: [Errno 20]")), cause
    assert "\x1b[" not in message and "ray::" not in message and "Traceback" not in message and len(message) < 500

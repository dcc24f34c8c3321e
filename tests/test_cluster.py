"""Cluster paths with real processes: ``ray job submit`` to a token-authenticated head, and a
multi-node cluster whose rollout actors must spread over the nodes.

Each test runs its Ray processes in a session it started (``start_new_session=True``), on free
ports, in its own short temp dir; teardown SIGKILLs that session by id and checks no process of it
is left. The pytest process's shared ``ray_cluster`` session is never touched. Never ``ray stop``.
"""

from __future__ import annotations

import json
import secrets
import shutil
import subprocess
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest
from _cluster_tools import (
    GPL_DIST,
    RAY,
    REPO,
    TINY_TASKS,
    assert_buffer_exactly_once,
    free_ports,
    kill_session,
    pids_mentioning,
    quiet_env,
    run_multinode,
    short_temp_dir,
)

pytestmark = pytest.mark.cluster

#: What ``--working-dir .`` must not upload (see docs/cluster.md).
EXCLUDES = [".venv", "runs", ".git", "*.egg-info", "__pycache__", ".pytest_cache"]
#: The tiny run of tests/_cluster_tools.py, as overrides of a shipped config (what a user types).
TINY_SET = ["env.max_train_tasks=6", "collection.num_corrections=1", "collection.tasks_per_unit=2",
            "training.num_rounds=2", "training.num_epochs_per_round=1", "training.batch_size=256", "seed=3"]


def _wait_http(url: str, proc: subprocess.Popen, timeout: float = 120.0) -> None:
    """Until the dashboard answers at all (401 counts: it is up and enforcing the token)."""
    deadline = time.monotonic() + timeout
    while True:
        assert proc.poll() is None, f"ray start exited with {proc.returncode}"
        try:
            urllib.request.urlopen(url, timeout=2)
            return
        except urllib.error.HTTPError:
            return
        except (urllib.error.URLError, OSError):
            assert time.monotonic() < deadline, f"{url} not up within {timeout}s"
            time.sleep(0.5)


@pytest.fixture
def token_head(tmp_path):
    """``ray start --head --block`` on loopback and free ports, token authentication on.

    The token is generated for this cluster and handed to the head and to the client through
    ``RAY_AUTH_MODE=token`` + ``RAY_AUTH_TOKEN_PATH`` (a 0600 file), exactly as a user would; the
    user's ``~/.ray/auth_token`` is neither read nor written.
    """
    temp_dir = short_temp_dir("gplh-")
    token_file = tmp_path / "auth_token"
    token_file.write_text(secrets.token_hex(32))
    token_file.chmod(0o600)
    auth = {"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN_PATH": str(token_file)}
    (gcs, dash, client, agent_http, agent_grpc, env_agent, metrics, node_mgr, obj_mgr) = free_ports(9)
    cmd = [RAY, "start", "--head", "--block", "--node-ip-address=127.0.0.1", f"--port={gcs}",
           "--include-dashboard=true", "--dashboard-host=127.0.0.1", f"--dashboard-port={dash}",
           f"--ray-client-server-port={client}", f"--dashboard-agent-listen-port={agent_http}",
           f"--dashboard-agent-grpc-port={agent_grpc}", f"--runtime-env-agent-port={env_agent}",
           f"--metrics-export-port={metrics}", f"--node-manager-port={node_mgr}", f"--object-manager-port={obj_mgr}",
           "--num-cpus=2", "--object-store-memory=268435456", f"--temp-dir={temp_dir}", "--disable-usage-stats"]
    log = open(tmp_path / "head.log", "w")
    head = subprocess.Popen(cmd, env=quiet_env(**auth), stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        url = f"http://127.0.0.1:{dash}"
        _wait_http(f"{url}/api/version", head)
        yield {"url": url, "auth": auth, "temp_dir": temp_dir, "log": tmp_path / "head.log"}
    finally:
        stragglers = kill_session(head.pid)
        head.wait(10)
        log.close()
        left = pids_mentioning(temp_dir)
        shutil.rmtree(temp_dir, ignore_errors=True)
        assert not left, f"processes of the test's Ray head survived: {left}"
        assert not stragglers, f"processes outside the head's process group: {stragglers}"


def test_job_submit_trains_on_a_token_authenticated_head(token_head, tmp_path):
    run_dir = tmp_path / "run"
    client_env = quiet_env(**token_head["auth"])
    # a client without the cluster's token is refused
    denied = subprocess.run([RAY, "job", "list", "--address", token_head["url"]], capture_output=True, text=True, check=False,
                            env=quiet_env(RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=secrets.token_hex(32)), timeout=60)
    assert denied.returncode != 0 and "auth" in (denied.stdout + denied.stderr).lower()

    runtime_env = {"excludes": EXCLUDES, "env_vars": {"OMP_NUM_THREADS": "1"}}
    sets = [a for s in TINY_SET for a in ("--set", s)]
    submit = [RAY, "job", "submit", "--address", token_head["url"], "--submission-id", "gpl-dist-test",
              "--working-dir", str(REPO), "--runtime-env-json", json.dumps(runtime_env), "--",
              GPL_DIST, "train", "--config", "configs/multiroom-smoke.yaml", *sets,
              "--run-dir", str(run_dir), "--address", "auto", "--no-progress"]
    t0 = time.monotonic()
    job = subprocess.run(submit, capture_output=True, text=True, check=False, env=client_env, timeout=300)
    seconds = time.monotonic() - t0
    output = job.stdout + job.stderr
    assert job.returncode == 0, output[-4000:] + Path(token_head["log"]).read_text()[-2000:]
    status = subprocess.run([RAY, "job", "status", "--address", token_head["url"], "gpl-dist-test"],
                            capture_output=True, text=True, check=False, env=client_env, timeout=60)
    assert "succeeded" in (status.stdout + status.stderr).lower(), status.stdout + status.stderr + output[-3000:]
    assert "round 1:" in output  # the job's log came back to the client

    counts = assert_buffer_exactly_once(run_dir / "buffer", [0, 1])
    assert counts["tasks_per_round"] == TINY_TASKS
    from learner.checkpoint import load_checkpoint

    assert load_checkpoint(run_dir / "checkpoints").round_index == 1
    print(f"job submitted and finished in {seconds:.1f}s")


def test_multinode_actors_spread_over_nodes(tmp_path):
    res = run_multinode("spread", tmp_path)
    workers = set(res["worker_nodes"])
    # head has num_cpus=0: only the driver runs there; each worker node could hold both actors
    assert res["driver_node"] == res["head_node"]
    assert set(res["actor_nodes"]) == workers, res
    assert set(res["unit_nodes"].values()) == workers, res
    assert res["rounds"] == [0, 1] and not res["unit_tries"]
    assert_buffer_exactly_once(tmp_path / "run" / "buffer", [0, 1])


def test_ray_train_learners_train_from_two_nodes(tmp_path):
    """training.engine=ray-train: the learners are placed where the cluster has room (here one on
    each worker node, beside a rollout actor), train every round, and the run checkpoints as ever."""
    res = run_multinode("ray-train", tmp_path)
    workers = set(res["worker_nodes"])
    assert len(res["learner_nodes"]) == 2 and set(res["learner_nodes"]) == workers, res
    assert res["learners_stopped"], res  # the run's end stopped the group, within close()'s wait
    assert res["rounds"] == [0, 1]
    assert_buffer_exactly_once(tmp_path / "run" / "buffer", [0, 1])
    from learner.checkpoint import load_checkpoint

    ckpt = load_checkpoint(tmp_path / "run" / "checkpoints")
    assert ckpt.round_index == 1 and ckpt.optimizer_state["state"][0]["step"] > 0

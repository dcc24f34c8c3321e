"""Helpers of the cluster and fault-tolerance tests: free ports, owned process groups, buffer checks.

Every Ray process these tests start lives in a process group (and session) that the test started
with ``start_new_session=True``; teardown SIGKILLs that session by id and checks nothing is left.
No test calls ``ray stop`` (it would stop every Ray cluster on the machine).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
VENV_BIN = Path(sys.executable).parent
GPL_DIST = str(VENV_BIN / "gpl-dist")
RAY = str(VENV_BIN / "ray")

#: Small enough for CI on 2 cores: 6 tasks in 3 units, at most 2 attempts each, tiny training.
TINY_YAML = """\
seed: 3
env: {domain: multiroom, max_train_tasks: 6}
collection: {num_workers: 2, num_corrections: 1, tasks_per_unit: 2}
training: {num_rounds: 2, num_epochs_per_round: 1, batch_size: 256}
"""
TINY_TASKS = 6
TINY_UNITS = 3


def free_ports(n: int) -> list[int]:
    """``n`` distinct ports that were free a moment ago (bound to port 0 together, then released)."""
    socks = []
    try:
        for _ in range(n):
            s = socket.socket()
            s.bind(("127.0.0.1", 0))
            socks.append(s)
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def short_temp_dir(prefix: str) -> str:
    """A short directory under /tmp (Ray's Unix socket paths have a length limit)."""
    return tempfile.mkdtemp(prefix=prefix, dir="/tmp")


def quiet_env(**extra: str) -> dict[str, str]:
    """The test's environment for child processes: one torch/OMP thread (2 shared cores)."""
    env = dict(os.environ)
    env.update(OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", RAY_DEDUP_LOGS="0", RAY_USAGE_STATS_ENABLED="0")
    for k in ("RAY_ADDRESS", "GPL_DIST_FAULT"):
        env.pop(k, None)
    env.update(extra)
    return env


def session_pids(sid: int) -> list[int]:
    """Live processes whose session id is ``sid`` (zombies excluded)."""
    out = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()
        if fields[0] != "Z" and int(fields[3]) == sid:
            out.append(int(entry))
    return out


def pids_mentioning(text: str) -> list[int]:
    """Live processes whose command line contains ``text`` (e.g. a test's own Ray temp dir)."""
    out = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit() or int(entry) == os.getpid():
            continue
        try:
            cmd = Path(f"/proc/{entry}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            state = Path(f"/proc/{entry}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if text in cmd and state != "Z":
            out.append(int(entry))
    return out


def kill_session(sid: int, timeout: float = 20.0) -> list[int]:
    """SIGKILL the process group ``sid`` and then any straggler of that session; returns what was
    still alive after the group kill (should be empty). Only for sessions this test started."""
    try:
        os.killpg(sid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    deadline = time.monotonic() + timeout
    while session_pids(sid) and time.monotonic() < deadline:
        time.sleep(0.2)
    stragglers = session_pids(sid)
    for pid in stragglers:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    return stragglers


def wait_for_port(port: int, proc: subprocess.Popen, seconds: float = 60) -> None:
    """Return once something listens on loopback ``port``; fail if ``proc`` (the server) exits first
    or nothing listens within ``seconds``."""
    deadline = time.time() + seconds
    while time.time() < deadline:
        assert proc.poll() is None, f"the server exited with {proc.returncode}"
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.2)
    raise TimeoutError(f"nothing listened on port {port} within {seconds:.0f} s")


def wait_for(path: Path, proc=None, timeout: float = 120.0) -> None:
    deadline = time.monotonic() + timeout
    while not path.exists():
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f"process exited with {proc.returncode} before {path} appeared")
        assert time.monotonic() < deadline, f"{path} did not appear within {timeout}s"
        time.sleep(0.05)


def assert_buffer_exactly_once(root: Path, rounds: list[int], num_tasks: int = TINY_TASKS,
                               num_units: int = TINY_UNITS, missing_tasks: frozenset = frozenset()) -> dict:
    """The committed buffer holds ``rounds``, one shard per unit, no file outside the manifests and
    every (round, task, attempt) exactly once with attempts 0..k contiguous; returns the counts."""
    import pyarrow.dataset as ds

    from storage import committed_rounds, load_manifest

    root = Path(root)
    assert committed_rounds(root) == rounds
    listed: set[str] = set()
    attempts_in_manifests = 0
    for r in rounds:
        manifest = load_manifest(root, r)
        assert sorted(s.unit_index for s in manifest.shards) == list(range(num_units)), f"round {r}: shards per unit"
        attempts_in_manifests += manifest.num_attempts
        for shard in manifest.shards:
            for f in shard.files:
                assert f.path not in listed, f"{f.path} listed twice"
                listed.add(f.path)
    on_disk = {str(p.relative_to(root)) for p in (root / "data").rglob("*") if p.is_file()}
    assert on_disk == listed, f"data files not in a manifest: {sorted(on_disk - listed)}; missing: {sorted(listed - on_disk)}"
    table = ds.dataset(root / "data" / "attempts", format="parquet").to_table(
        columns=["round", "unit", "task_id", "attempt_index"]).to_pydict()
    keys = list(zip(table["round"], table["task_id"], table["attempt_index"]))
    assert len(keys) == len(set(keys)) == attempts_in_manifests, "an attempt appears more than once"
    per_task: dict[tuple[int, int], list[int]] = {}
    for r, t, k in keys:
        per_task.setdefault((r, t), []).append(k)
    assert {r for r, _ in per_task} == set(rounds)
    for r in rounds:
        tasks = {t for rr, t in per_task if rr == r}
        assert len(tasks) == num_tasks - len(missing_tasks) and not tasks & set(missing_tasks), \
            f"round {r}: tasks {sorted(tasks)}"
    for key, ks in per_task.items():
        assert sorted(ks) == list(range(len(ks))), f"{key}: attempts {sorted(ks)}"
    return {"attempts": len(keys), "tasks_per_round": len(per_task) // len(rounds)}


def run_multinode(mode: str, tmp_path: Path, **env) -> dict:
    """Run tests/multinode_run.py in a fresh session; returns its RESULT and cleans its processes."""
    ray_tmp = short_temp_dir("gplm-")
    proc = subprocess.Popen([sys.executable, str(REPO / "tests" / "multinode_run.py"), mode, str(tmp_path)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True,
                            env=quiet_env(RAY_TMPDIR=ray_tmp, **env))
    try:
        out, _ = proc.communicate(timeout=300)
    finally:
        stragglers = kill_session(proc.pid)
        left = pids_mentioning(ray_tmp)
        shutil.rmtree(ray_tmp, ignore_errors=True)
    assert proc.returncode == 0, out[-6000:]
    assert not left and not stragglers, f"leftover Ray processes: {left} {stragglers}"
    line = next(ln for ln in out.splitlines() if ln.startswith("RESULT "))
    return json.loads(line[len("RESULT "):])

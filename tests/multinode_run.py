"""Driver of the multi-node tests, run as a fresh process by ``tests/test_cluster.py`` and
``tests/test_fault_tolerance.py`` (so the pytest process's shared Ray session is never disturbed).

``python tests/multinode_run.py MODE WORK_DIR`` starts a ``ray.cluster_utils.Cluster`` on this
machine (head with ``num_cpus=0``: it runs only the driver; two worker nodes), trains the tiny config
of ``tests/_cluster_tools.py`` into ``WORK_DIR/run`` with ``run_training(..., address=cluster.address)``
and prints one JSON line ``RESULT {...}``. Modes:

* ``spread``: worker nodes of 2 CPUs each, so both rollout actors would fit on one node; the
  collector's ``SPREAD`` strategy must put them on two.
* ``node-loss``: worker nodes of 1 CPU each. ``GPL_DIST_FAULT`` (set by the test) pauses
  one unit of round 0 mid-unit; the node running it is then removed. Its actor cannot restart
  anywhere (no free CPU left), so the other node must finish round 0 and round 1 alone.
* ``ray-train``: worker nodes of 2 CPUs each and ``training.engine: ray-train`` with 2 learners:
  the rollout actors take one CPU of each node, so the two learners must train from two nodes.

The environment (set by the test) gives ``RAY_TMPDIR``: every Ray file of this cluster lives there.
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _cluster_tools import TINY_YAML, free_ports

from gpl_dist.faults import FAULT_ENV, PauseAt


def _raylet_pid(node) -> int:
    from ray._private import ray_constants

    return node.all_processes[ray_constants.PROCESS_TYPE_RAYLET][0].process.pid


def _node_of_pid(cluster, pid: int):
    """The worker node whose raylet is an ancestor of process ``pid``."""
    import psutil

    raylets = {_raylet_pid(n): n for n in cluster.worker_nodes}
    for parent in psutil.Process(pid).parents():
        if parent.pid in raylets:
            return raylets[parent.pid]
    raise RuntimeError(f"process {pid} is not under any worker node's raylet")


def _record_learner_nodes(out: dict) -> None:
    """Note in ``out`` the nodes of the Ray Train learners the run makes (observed, not changed)."""
    from learner import driver

    make = driver._make_learner

    def recording(*args, **kwargs):
        learner = make(*args, **kwargs)
        out["learner_nodes"] = list(learner.nodes)
        close = learner.close

        def closing():
            close()
            out["learners_stopped"] = not learner._fit.is_alive()

        learner.close = closing
        return learner

    driver._make_learner = recording


def main(mode: str, work: Path) -> None:
    import yaml
    from ray.cluster_utils import Cluster

    from gpl_dist.config import config_from_dict
    from gpl_dist.domains import get_domain
    from learner.driver import buffer_root, run_training
    from workers.ray_collector import RayCollector
    from workers.worker import RolloutSettings

    temp_dir = os.path.join(os.environ["RAY_TMPDIR"], "ray")  # where Ray itself looks (ray_current_cluster)
    os.makedirs(temp_dir, exist_ok=True)
    gcs_port, dash_port, agent_port = free_ports(3)
    # No loopback binding here: a driver joining by address resolves 127.0.0.1 to the machine's IP.
    common = dict(temp_dir=temp_dir, object_store_memory=128 << 20)
    cluster = Cluster(initialize_head=True, head_node_args=dict(
        num_cpus=0, gcs_server_port=gcs_port, include_dashboard=False, dashboard_port=dash_port,
        dashboard_agent_listen_port=agent_port, **common))
    node_cpus = 1 if mode == "node-loss" else 2
    workers = [cluster.add_node(num_cpus=node_cpus, **common) for _ in range(2)]
    out: dict = {"worker_nodes": [n.node_id for n in workers], "head_node": cluster.head_node.node_id}
    collector = None
    try:
        cluster.wait_for_nodes()
        raw = yaml.safe_load(TINY_YAML)
        if mode == "ray-train":
            raw["training"].update(engine="ray-train", num_learners=2)
            _record_learner_nodes(out)
        cfg = config_from_dict(raw)
        run_dir = work / "run"
        collector = RayCollector(get_domain(cfg.env.domain).name, RolloutSettings.of_run(cfg), buffer_root(cfg, run_dir),
                                 run_dir.name, cfg.collection.num_workers, cluster.address, cfg.collection.max_unit_retries,
                                 cfg.collection.unit_timeout_s)
        import ray

        out["driver_node"] = ray.get_runtime_context().get_node_id()
        out["actor_nodes"] = ray.get([a.node_id.remote() for a in collector.actors])
        watcher = None
        if mode == "node-loss":
            signal_file = Path(PauseAt.parse(os.environ[FAULT_ENV]).signal_file)

            def remove_paused_node() -> None:
                while not signal_file.exists():
                    time.sleep(0.05)
                node = _node_of_pid(cluster, int(signal_file.read_text()))
                out["removed_node"] = node.node_id
                out["removed_at"] = time.time()
                cluster.remove_node(node)

            watcher = threading.Thread(target=remove_paused_node, daemon=True)
            watcher.start()
        t0 = time.time()
        result = run_training(cfg, run_dir, address=cluster.address, progress=False, collector=collector)
        out["seconds"] = time.time() - t0
        if watcher is not None:
            watcher.join(5)
        out["rounds"] = [m.round_index for m in result.history]
        out["unit_nodes"] = {f"{r}/{u}": n for (r, u), n in collector.unit_nodes.items()}
        out["unit_tries"] = {f"{r}/{u}": n for (r, u), n in collector.unit_tries.items()}
        out["replaced_actors"] = collector.replaced_actors
    finally:
        if collector is not None:
            collector.close()
        import ray

        ray.shutdown()
        cluster.shutdown()
    print("RESULT " + json.dumps(out), flush=True)


if __name__ == "__main__":
    main(sys.argv[1], Path(sys.argv[2]))

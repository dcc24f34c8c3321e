"""Data-parallel learners anywhere on a Ray cluster, through Ray Train (``training.engine: ray-train``).

``learner.parallel`` runs its learner processes on the driver's machine only. Here the same
``learner.trainer.Learner`` runs in each worker of a ``ray.train.torch.TorchTrainer`` group of
``training.num_learners`` workers, which Ray places on any nodes with room (``training.num_threads``
CPUs each, or one GPU each when the learner trains on CUDA). Ray Train sets up the collective
(gloo between CPUs, NCCL between GPUs, rank 0's node address as the rendezvous); the learners'
``Group`` is torch.distributed's default group, so a step is the same one all-reduce of the flat
gradient as on one machine, and N Ray Train learners train as N local processes do.

The group starts once per run and lives for all rounds (starting it costs tens of seconds):
``TorchTrainer.fit`` runs in a thread of the driver, and the rounds go through a ``_RoundBoard``
actor. Every round the driver posts the state it holds (``learner.remote.ShippedStateLearner``:
model, Adam, batch generator) with a reference to the training view, put once in the object
store; every learner takes them, they train together, and rank 0 posts the new state back. Ray
Train retries nothing: a learner that dies fails the group, the round is lost, the driver raises
``LearnerFailed``, and ``--resume`` retrains it from the last checkpoint.

This module imports Ray and Ray Train: it is only loaded by a run that uses them.
"""

from __future__ import annotations

import asyncio
import dataclasses
import logging
import shutil
import tempfile
import threading
import time
from typing import Any

import ray
import torch
import torch.distributed as dist
from torch import nn

from gpl_dist.config import ConfigError, TrainingConfig
from learner.parallel import COLLECTIVE_TIMEOUT, LearnerFailed
from learner.remote import ShippedStateLearner, train_from_state

log = logging.getLogger(__name__)

#: how long the driver waits for the whole group to be placed and to join (torch imports included)
START_WAIT_S = 600.0
#: how often the driver, while waiting, checks that the group has not failed
POLL_S = 2.0


def learner_resources(cfg: TrainingConfig, use_gpu: bool) -> dict[str, float]:
    """What each Ray Train learner holds: ``num_threads`` CPUs (at least one), and one GPU when
    it trains on CUDA."""
    return {"CPU": float(max(1, cfg.num_threads)), **({"GPU": 1.0} if use_gpu else {})}


def group_cpus(cfg: TrainingConfig) -> int:
    """CPUs a run's Ray Train learners hold on the cluster for the whole run (0 with ``processes``)."""
    return cfg.num_learners * int(learner_resources(cfg, use_gpu=False)["CPU"]) if cfg.engine == "ray-train" else 0


def wants_gpu(device: str, cluster_gpus: float, num_learners: int) -> bool:
    """Whether the learners take a GPU each: ``cuda`` must find one per learner in the cluster
    (else a ``ConfigError``); ``auto`` takes them when there are enough; ``cpu`` never."""
    if device == "cpu":
        return False
    if cluster_gpus >= num_learners:
        return True
    if device == "cuda":
        raise ConfigError(f"training.device is cuda with {num_learners} Ray Train learner(s), but the Ray cluster "
                          f"has {cluster_gpus:g} GPU(s) (use training.device=auto or cpu, or fewer learners)")
    return False


@ray.remote(num_cpus=0)
class _RoundBoard:
    """Where the driver posts each round's job and rank 0 posts the round's result.

    A job is dropped once all ``size`` learners took it (its view then leaves the object store
    with the driver's reference); after ``stop`` every learner that asks for a job gets None.
    """

    def __init__(self, size: int) -> None:
        self.size = size
        self.jobs: dict[int, Any] = {}
        self.takers: dict[int, set[int]] = {}
        self.results: dict[int, Any] = {}
        self.stopped = False
        self.changed = asyncio.Condition()

    async def post_job(self, k: int, job: Any) -> None:
        async with self.changed:
            self.jobs[k], self.takers[k] = job, set()
            self.changed.notify_all()

    async def stop(self) -> None:
        async with self.changed:
            self.stopped, self.jobs = True, {}
            self.changed.notify_all()

    async def job(self, k: int, rank: int) -> Any:
        """Round ``k``'s job for learner ``rank``, once posted; None once stopped."""
        async with self.changed:
            await self.changed.wait_for(lambda: self.stopped or k in self.jobs)
            if self.stopped:
                return None
            job = self.jobs[k]
            self.takers[k].add(rank)
            if len(self.takers[k]) == self.size:
                del self.jobs[k], self.takers[k]
            return job

    async def post_result(self, k: int, result: Any) -> None:
        async with self.changed:
            self.results[k] = result
            self.changed.notify_all()

    async def result(self, k: int) -> Any:
        async with self.changed:
            await self.changed.wait_for(lambda: k in self.results)
            return self.results.pop(k)


class _DefaultGroup:
    """torch.distributed's default group (set up by Ray Train) as a ``learner.trainer.Group``.
    NCCL reduces only GPU tensors: a CPU tensor goes through a GPU copy."""

    def __init__(self) -> None:
        self.rank, self.size = dist.get_rank(), dist.get_world_size()
        self._device = torch.device("cuda", torch.cuda.current_device()) if dist.get_backend() == "nccl" \
            else torch.device("cpu")

    def _on_device(self, tensor: torch.Tensor, op) -> None:
        if tensor.device == self._device:
            op(tensor)
            return
        copy = tensor.to(self._device)
        op(copy)
        tensor.copy_(copy)

    def all_reduce_sum_(self, tensor: torch.Tensor) -> None:
        self._on_device(tensor, dist.all_reduce)

    def broadcast_(self, tensor: torch.Tensor) -> None:
        self._on_device(tensor, lambda t: dist.broadcast(t, 0))


def _learner_loop(config: dict) -> None:
    """What each Ray Train worker runs: build a learner in the group, then train every round the
    driver posts until the board is stopped."""
    from learner.trainer import Learner

    group = _DefaultGroup()
    board = config["board"]
    learner = Learner(config["model"], config["cfg"], config["seed"], group=group)
    nodes: list = [None] * group.size
    dist.all_gather_object(nodes, ray.get_runtime_context().get_node_id())
    if group.rank == 0:
        ray.get(board.post_result.remote(-1, nodes))
    k = 0
    while (job := ray.get(board.job.remote(k, group.rank))) is not None:
        state, (view_ref,) = job
        result = train_from_state(learner, state, ray.get(view_ref))
        if group.rank == 0:
            ray.get(board.post_result.remote(k, result))
        k += 1


def _last_line(error: BaseException | None) -> str:
    """The last line of an error's text: Ray Train's errors carry every learner's traceback."""
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    return lines[-1] if lines else (type(error).__name__ if error is not None else "no error given")


class RayTrainLearner(ShippedStateLearner):
    """``cfg.num_learners`` learners in a Ray Train group; implements ``gpl_dist.roles.Learner``
    (see the module doc). Needs a connected Ray cluster with room for the group."""

    def __init__(self, model: nn.Module, cfg: TrainingConfig, seed: int = 0, use_gpu: bool = False):
        from ray.train import FailureConfig, RunConfig, ScalingConfig
        from ray.train.torch import TorchConfig, TorchTrainer

        super().__init__(model, cfg, seed)
        need = learner_resources(cfg, use_gpu)
        self._check_room(cfg.num_learners, need)
        # what the learners resolve on their nodes: the device this group holds, the threads its CPUs allow
        worker_cfg = dataclasses.replace(cfg, device="cuda" if use_gpu else "cpu", num_threads=int(need["CPU"]))
        self._storage = tempfile.mkdtemp(prefix="gpl-ray-train-")
        self._board: Any = _RoundBoard.remote(cfg.num_learners)  # type: ignore[attr-defined]  # an ActorClass
        # no retries of any kind: a lost learner loses the round, and --resume retrains it from the
        # checkpoint (a group restarted behind the driver's back would wait for a round never posted)
        failures = FailureConfig(max_failures=0, max_preemption_failures=0,  # type: ignore[call-arg]  # V2 fields
                                 controller_failure_limit=0)
        trainer = TorchTrainer(
            _learner_loop, train_loop_config={"board": self._board, "model": model, "cfg": worker_cfg, "seed": seed},
            torch_config=TorchConfig(backend="nccl" if use_gpu else "gloo",
                                     timeout_s=int(COLLECTIVE_TIMEOUT.total_seconds())),
            scaling_config=ScalingConfig(num_workers=cfg.num_learners, use_gpu=use_gpu, resources_per_worker=need),
            run_config=RunConfig(name="gpl-learners", storage_path=self._storage, failure_config=failures))
        self._error: BaseException | None = None
        self._fit = threading.Thread(target=self._run, args=(trainer,), name="ray-train-fit", daemon=True)
        self._fit.start()
        self._round = 0
        try:
            #: the Ray node id of each learner, by rank
            self.nodes: list[str] = self._await(
                self._board.result.remote(-1), START_WAIT_S,
                f"the {cfg.num_learners} Ray Train learner(s) of {need} each were not all placed and started within "
                f"{START_WAIT_S:.0f} s (is there a node with room for each?)")
        except BaseException:
            self.close()
            raise
        log.info("%d Ray Train learner(s) started (%s each) on %d node(s)", cfg.num_learners, need, len(set(self.nodes)))

    @staticmethod
    def _check_room(num_learners: int, need: dict[str, float]) -> None:
        """A ``ConfigError`` in one line when the cluster cannot hold the group now (Ray Train
        would wait for room forever)."""
        free = ray.available_resources()
        short = {k: v * num_learners for k, v in need.items() if free.get(k, 0.0) < v * num_learners}
        if short:
            raise ConfigError(f"the Ray cluster has no room for {num_learners} learner(s) of {need}: "
                              f"free {({k: free.get(k, 0.0) for k in short})}; lower training.num_learners "
                              "or training.num_threads, or add nodes")

    def _run(self, trainer) -> None:
        try:
            trainer.fit()
        except BaseException as exc:  # noqa: BLE001 - reported to the driver's waits
            self._error = exc

    def _await(self, ref, timeout_s: float | None = None, what: str = ""):
        """``ray.get(ref)``, failing at once with the group's error when the group fails first (a
        stalled collective fails the group after ``COLLECTIVE_TIMEOUT``)."""
        deadline = time.monotonic() + timeout_s if timeout_s is not None else float("inf")
        while True:
            ready, _ = ray.wait([ref], timeout=POLL_S)
            if ready:
                return ray.get(ref)
            if not self._fit.is_alive():
                log.error("the Ray Train learners stopped: %s", self._error)
                raise LearnerFailed(f"the Ray Train learners stopped ({_last_line(self._error)}; the log has the "
                                    "traceback); restart the run with --resume")
            if time.monotonic() > deadline:
                raise LearnerFailed(what)

    def _train_elsewhere(self, state, view):
        view_ref = ray.put(view)  # once per round; every learner maps it (on its own node, one copy)
        self._board.post_job.remote(self._round, (state, [view_ref]))
        result = self._await(self._board.result.remote(self._round))
        self._round += 1
        return result

    def close(self) -> None:
        """Stop the group (its learners leave their loop, or their collective fails) and remove Ray
        Train's run directory."""
        ray.get(self._board.stop.remote())
        self._fit.join(timeout=60)
        if self._fit.is_alive():
            log.warning("the Ray Train learners did not stop within 60 s; they end with this driver")
        ray.kill(self._board)
        shutil.rmtree(self._storage, ignore_errors=True)

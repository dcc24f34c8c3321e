"""Data-parallel learners on one machine: N processes, one torch thread each, one gloo all-reduce
of the flat gradient per step (``training.num_learners``).

Why processes and not threads: a learner with two intra-op threads stalls at every operation
when anything else runs on its cores (a thread waits for a descheduled sibling), and its float
sums change from run to run; processes of one thread each do neither. They pay an all-reduce per
step and wait for the slowest, so on few cores they only gain with large batches (docs/results.md,
Speed). Each process holds a full replica; rank 0 is the driver's own ``Learner`` (it checkpoints and hands out the weights), the
others are spawned once per run and live until ``close``. Every round the driver copies the
training view into shared memory once and the helpers map it (no copy per helper), rank 0
broadcasts weights, BatchNorm statistics and Adam moments, and all learners then walk the same
epoch order, each its slice of every global batch (``learner.trainer``). Without BatchNorm the
optimisation is that of one learner with the same ``batch_size`` (``num_learners`` changes only
the order of floating-point sums); BatchNorm layers normalise each learner's slice by its own
statistics, as DistributedDataParallel does without SyncBatchNorm, and their running statistics
are averaged over the learners at the end of each round.

The collective engine is gloo (``torch.distributed.ProcessGroupGloo``) on a device bound to
127.0.0.1, with a file store in a private temporary directory: nothing listens beyond this machine
(gloo's loopback port itself has no authentication, like any local service). Across nodes, a
Ray cluster's learners go through Ray Train instead (``learner.ray_train``).
"""

from __future__ import annotations

import copy
import dataclasses
import os
import queue
import shutil
import tempfile
import time
from datetime import timedelta
from typing import Callable

import torch
import torch.distributed as dist
import torch.multiprocessing as mp
from torch import nn

from gpl_dist.config import TrainingConfig
from gpl_dist.errors import UserError
from gpl_dist.records import LearnerState
from learner.batches import TensorView
from learner.trainer import Learner, RoundStats, available_cpus, resolve_device

#: how long a collective waits for a slow learner before it fails (a helper that died fails at once)
COLLECTIVE_TIMEOUT = timedelta(minutes=10)
#: how long the learners wait for each other to start (a spawned process imports torch: seconds)
RENDEZVOUS_TIMEOUT = timedelta(seconds=120)
#: how often an idle helper checks that its driver is still alive
HELPER_POLL_SECONDS = 2.0


class LearnerFailed(UserError):
    """A data-parallel learner process died or could not start."""


def resolve_num_learners(cfg: TrainingConfig) -> int:
    """How many learner processes ``cfg`` asks for on this machine: ``num_learners``, 0 meaning one
    per available core; one on a GPU (the whole batch fits one device); never so many that a
    learner's share of a batch falls below 2 states (BatchNorm needs two)."""
    if resolve_device(cfg.device).type == "cuda":
        return 1
    n = cfg.num_learners or available_cpus()
    return max(1, min(n, cfg.batch_size // 2))


class ProcessGroup:
    """Rank ``rank`` of ``size`` learners; implements ``learner.trainer.Group`` with gloo.

    ``store_dir`` is a directory every rank can reach (a private temporary one): the rendezvous is
    a file there, so no port is opened for it, and gloo's own connections use loopback.
    """

    def __init__(self, rank: int, size: int, store_dir: str):
        self.rank, self.size = rank, size
        store = dist.FileStore(os.path.join(store_dir, "rendezvous"), size)
        store.set_timeout(RENDEZVOUS_TIMEOUT)
        options = dist.ProcessGroupGloo._Options()  # type: ignore[attr-defined]  # missing from torch's stubs
        options._timeout = COLLECTIVE_TIMEOUT
        # bound to loopback whatever GLOO_SOCKET_IFNAME says (cluster images often name eth0)
        options._devices = [dist.ProcessGroupGloo.create_device(hostname="127.0.0.1")]  # type: ignore[attr-defined]
        self._pg = dist.ProcessGroupGloo(store, rank, size, options)

    def all_reduce_sum_(self, tensor: torch.Tensor) -> None:
        self._pg.allreduce([tensor]).wait()  # type: ignore[attr-defined]  # missing from torch's stubs

    def broadcast_(self, tensor: torch.Tensor) -> None:
        self._pg.broadcast(tensor, 0).wait()  # type: ignore[attr-defined]  # missing from torch's stubs


def _shared(tv: TensorView) -> TensorView:
    """A copy of ``tv`` in shared memory: the helpers map it instead of receiving copies. A
    ``LearnerFailed`` in one line when /dev/shm cannot hold it (containers often give 64 MB)."""
    need = tv.nbytes
    if os.path.isdir("/dev/shm") and shutil.disk_usage("/dev/shm").free < need:
        raise LearnerFailed(f"/dev/shm has {shutil.disk_usage('/dev/shm').free / 2**20:.0f} MiB free, the training "
                            f"view needs {need / 2**20:.0f} MiB in shared memory for the data-parallel learners; "
                            "give the container more (docker --shm-size) or set training.num_learners=1")
    def share(t: torch.Tensor) -> torch.Tensor:
        return torch.empty_like(t).share_memory_().copy_(t)
    return dataclasses.replace(tv, **{k: share(v) for k, v in tv._tensors().items() if v is not None})  # type: ignore[arg-type]


def _serve(rank: int, size: int, store_dir: str, model: nn.Module, cfg: TrainingConfig, inbox, driver_pid: int) -> None:
    """A helper learner: join the group, then train on every view that arrives until told to stop
    (None) or until the driver is gone."""
    learner = Learner(model, cfg, group=ProcessGroup(rank, size, store_dir))
    while True:
        try:
            view = inbox.get(timeout=HELPER_POLL_SECONDS)
        except queue.Empty:  # still idle; leave when the driver died without a word
            if os.getppid() != driver_pid:
                return
            continue
        # any other error (a view that cannot arrive) ends this process: rank 0 then fails at once
        if view is None:
            learner.close()
            return
        learner.train_round(view)
        view = None  # free this round's shared memory while idle


class DataParallelLearner:
    """``num_learners`` learner processes training one model; implements ``gpl_dist.roles.Learner``
    and exposes rank 0's ``model``, ``optimizer`` and ``generator`` as ``Learner`` does."""

    def __init__(self, model: nn.Module, cfg: TrainingConfig, num_learners: int, seed: int = 0):
        if num_learners < 2:
            raise ValueError("a data-parallel learner needs at least 2 processes; use Learner")
        self._dir = tempfile.mkdtemp(prefix="gpl-learners-")
        ctx = mp.get_context("spawn")  # never fork a process that may hold Ray's or torch's threads
        self._inboxes, self._procs = [], []
        try:
            for rank in range(1, num_learners):
                inbox = ctx.Queue()
                proc = ctx.Process(target=_serve, name=f"gpl-learner-{rank}", daemon=True,
                                   args=(rank, num_learners, self._dir, copy.deepcopy(model), cfg, inbox, os.getpid()))
                proc.start()
                self._inboxes.append(inbox)
                self._procs.append(proc)
            self._local = Learner(model, cfg, seed, group=ProcessGroup(0, num_learners, self._dir))
        except (RuntimeError, dist.DistError) as exc:  # the rendezvous failed: say which helper never came
            codes = {p.name: p.exitcode for p in self._procs if not p.is_alive()}
            self.close()
            raise LearnerFailed(f"data-parallel learners did not start ({exc}); exited: {codes or 'none'} "
                                "(a script that starts them needs an `if __name__ == '__main__':` guard)") from exc
        except BaseException:
            self.close()
            raise
        self.num_learners = num_learners

    #: rank 0's model (read it; its state goes through ``state`` / ``load_state``)
    model = property(lambda self: self._local.model)
    cfg = property(lambda self: self._local.cfg)

    def state(self) -> LearnerState:
        """Rank 0's state: every rank holds the same after a round."""
        return self._local.state()

    def load_state(self, state: LearnerState) -> None:
        self._local.load_state(state)  # the helpers receive it at the next round's start

    def weights(self) -> dict:
        return self._local.weights()

    def train_round(self, view, on_epoch: Callable[[int, float, float], None] | None = None) -> RoundStats:
        tv = view if isinstance(view, TensorView) else TensorView.from_view(
            view, previous_steps=bool(getattr(self._local.model, "uses_previous_step", False)))
        dead = [p.name for p in self._procs if not p.is_alive()]
        if dead:
            raise LearnerFailed(f"learner process(es) {', '.join(dead)} exited; restart the run with --resume")
        tv = _shared(tv)  # rank 0 trains on the shared copy too: one copy of the view, not two
        for inbox in self._inboxes:
            inbox.put(tv)
        try:
            return self._local.train_round(tv, on_epoch)
        except RuntimeError as exc:  # gloo: a peer closed its connection or timed out
            codes = {p.name: p.exitcode for p in self._procs if not p.is_alive()}
            raise LearnerFailed(f"data-parallel training failed ({exc}); exited learners: {codes or 'none'}; "
                                "restart the run with --resume") from exc

    def close(self) -> None:
        """Stop the helpers (within a few seconds) and remove the rendezvous directory."""
        for inbox in self._inboxes:
            try:
                inbox.put(None)
            except (OSError, ValueError):
                pass
        deadline = time.monotonic() + 10
        for proc in self._procs:
            proc.join(timeout=max(0.0, deadline - time.monotonic()))
        for proc in self._procs:
            if proc.is_alive():
                proc.terminate()
                proc.join(timeout=5)
        self._procs, self._inboxes = [], []
        shutil.rmtree(self._dir, ignore_errors=True)
        if hasattr(self, "_local"):
            self._local.close()


def make_learner(model: nn.Module, cfg: TrainingConfig, seed: int = 0) -> Learner | DataParallelLearner:
    """The learner ``cfg`` asks for: one process, or ``resolve_num_learners(cfg)`` of them."""
    n = resolve_num_learners(cfg)
    return Learner(model, cfg, seed) if n == 1 else DataParallelLearner(model, cfg, n, seed)

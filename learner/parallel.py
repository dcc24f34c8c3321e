"""Data-parallel training over several processes of one machine.

Why processes: at this model size a gradient step is hundreds of small tensor ops (50-500 us
each), which torch's intra-op threads barely speed up (1.05-1.2x from the second core, measured),
and Python threads serialise on the GIL. Splitting each batch over processes, one core each, and
summing the gradients is what makes a second (or sixteenth) core pay.

How: rank 0 is the learner in the driver process; ranks 1..P-1 are helper processes started once
(``multiprocessing`` spawn) and joined in a gloo process group over loopback. Each round rank 0
moves the tensor view into shared memory and sends it, its weights, Adam's state and the shuffling
generator's state down a pipe, so all ranks start identical and draw the same batch order. Every
step each rank takes its contiguous share of the batch, computes the gradient of its share of
the batch-mean loss, and one all-reduce of a flat buffer (gradients plus the loss and accuracy
counters) gives every rank the full batch's gradient: the same Adam step everywhere. BatchNorm
statistics are per share (as torch's DistributedDataParallel); rank 0's running statistics are
the ones kept.

Failure: a helper that dies makes rank 0's next all-reduce fail (gloo sees the closed
connection); ``Learner`` then restores the round's starting state and trains it in one process.
Helpers exit when the pipe to rank 0 closes, so a killed driver leaves no processes behind.
"""

from __future__ import annotations

import datetime
import logging
import multiprocessing as mp
import os
from dataclasses import dataclass, fields
from typing import Any

import torch
import torch.multiprocessing  # noqa: F401 - registers the reductions that share tensors through pipes

from learner.batches import TensorView

log = logging.getLogger(__name__)

#: How long a rank waits for the others in one collective before giving up.
COLLECTIVE_TIMEOUT = datetime.timedelta(seconds=120)


@dataclass(frozen=True)
class ModelSpec:
    """What a helper needs to build the same network as rank 0 (weights come each round)."""

    domain: str
    variant: str
    embedding_dim: int


class ParallelFailure(RuntimeError):
    """A helper process or a collective failed; the round can be retrained in one process."""


def resolve_num_processes(requested: int) -> int:
    """``0`` means one process per CPU core available to this process."""
    if requested > 0:
        return requested
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


class ProcessGroup:
    """Rank 0's side: the helper processes, the pipes to them and the gloo group."""

    def __init__(self, spec: ModelSpec, cfg: Any, num_processes: int, threads_per_process: int = 1):
        from torch.distributed import ProcessGroupGloo, TCPStore

        self.size = num_processes
        self._store = TCPStore("127.0.0.1", 0, num_processes, is_master=True, wait_for_workers=False,
                               timeout=COLLECTIVE_TIMEOUT)
        ctx = mp.get_context("spawn")
        self._procs, self._conns = [], []
        for rank in range(1, num_processes):
            parent, child = ctx.Pipe()
            proc = ctx.Process(target=_helper_main, name=f"gpl-learner-{rank}", daemon=True,
                               args=(rank, num_processes, self._store.port, child, spec, cfg, threads_per_process))
            proc.start()
            child.close()
            self._procs.append(proc)
            self._conns.append(parent)
        try:
            self.group = ProcessGroupGloo(self._store, 0, num_processes, COLLECTIVE_TIMEOUT)
        except Exception as err:
            self.close()
            raise ParallelFailure(f"learner processes did not join: {err}") from err

    def allreduce_(self, flat: torch.Tensor) -> None:
        """Sum ``flat`` over all ranks, in place."""
        try:
            self.group.allreduce([flat]).wait()
        except Exception as err:  # gloo raises RuntimeError subclasses on a lost peer
            raise ParallelFailure(f"all-reduce failed: {err}") from err

    def start_round(self, tv: TensorView, model_state: dict, optimizer_state: dict, generator_state: torch.Tensor,
                    num_epochs: int) -> None:
        """Send every helper the view (shared, not copied) and the state to start the round from."""
        shared = TensorView(**{f.name: _shared_copy(getattr(tv, f.name)) for f in fields(TensorView)})
        for conn, proc in zip(self._conns, self._procs):
            if not proc.is_alive():
                raise ParallelFailure(f"learner process {proc.name} exited with code {proc.exitcode}")
            try:
                conn.send(("train", shared, model_state, optimizer_state, generator_state, num_epochs))
            except (BrokenPipeError, EOFError, OSError) as err:
                raise ParallelFailure(f"learner process {proc.name} is gone: {err}") from err

    def finish_round(self) -> None:
        """Wait for every helper to report the round done (they drop the shared view first)."""
        for conn, proc in zip(self._conns, self._procs):
            try:
                status = conn.recv()
            except (EOFError, OSError) as err:
                raise ParallelFailure(f"learner process {proc.name} is gone: {err}") from err
            if status != "done":
                raise ParallelFailure(f"learner process {proc.name}: {status}")

    def close(self) -> None:
        for conn in self._conns:
            try:
                conn.send(("stop",))
            except (BrokenPipeError, EOFError, OSError):
                pass
            conn.close()
        for proc in self._procs:
            proc.join(timeout=10)
            if proc.is_alive():
                proc.kill()
                proc.join()
        self._conns, self._procs = [], []


def _shared_copy(t: torch.Tensor) -> torch.Tensor:
    """``t`` copied once into shared memory (the view's tensors may wrap numpy memory, which cannot move)."""
    return torch.empty_like(t, memory_format=torch.contiguous_format).share_memory_().copy_(t)


def _helper_main(rank: int, size: int, port: int, conn, spec: ModelSpec, cfg: Any, threads: int) -> None:
    """A helper rank: build the model once, then train every round it is sent, in step with rank 0."""
    torch.set_num_threads(threads)
    from torch.distributed import ProcessGroupGloo, TCPStore

    from gpl_dist.allocator import keep_freed_memory
    from gpl_dist.domains import get_domain
    from gpl_dist.models.gpl import build_model
    from learner.trainer import make_optimizer, run_epochs

    keep_freed_memory()
    store = TCPStore("127.0.0.1", port, size, is_master=False, timeout=COLLECTIVE_TIMEOUT)
    group = ProcessGroupGloo(store, rank, size, COLLECTIVE_TIMEOUT)
    model = build_model(get_domain(spec.domain), spec.variant, spec.embedding_dim)
    optimizer = make_optimizer(model, cfg)
    generator = torch.Generator()

    def allreduce_(flat: torch.Tensor) -> None:
        group.allreduce([flat]).wait()

    while True:
        try:
            message = conn.recv()
        except (EOFError, OSError):  # rank 0 is gone
            return
        if message[0] != "train":
            return
        _, tv, model_state, optimizer_state, generator_state, num_epochs = message
        try:
            model.load_state_dict(model_state)
            optimizer.load_state_dict(optimizer_state)
            generator.set_state(generator_state)
            run_epochs(model, optimizer, tv, cfg, generator, num_epochs, rank=rank, world=size, allreduce_=allreduce_)
            del tv, message
            conn.send("done")
        except Exception as err:  # noqa: BLE001 - report, then leave: rank 0 falls back to one process
            try:
                conn.send(f"failed: {type(err).__name__}: {err}")
            finally:
                return

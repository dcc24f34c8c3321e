"""The central learner: supervised training on expert labels over the committed buffer view.

Each round trains ``num_epochs_per_round`` epochs over the whole view (the paper's "five epochs
over the data buffer"), minimising the cross-entropy between the policy and the expert's action
with Adam. The view sits in memory for all epochs: the disk is read once per round.

Shuffling keeps ``states_per_chunk`` states of one attempt together: every state is still seen
exactly once per epoch in random order, but a batch of 512 states then spans about 32 attempts
instead of about 500, and the correction module (whose input is the attempt's history, not the
state) runs once per attempt in the batch. That is most of the cost of a step at this model size.
"""

from __future__ import annotations

import copy
import logging
import math
import time
from dataclasses import dataclass
from typing import Callable

import torch
from torch import nn

from gpl_dist.allocator import keep_freed_memory
from gpl_dist.config import TrainingConfig
from learner.batches import TensorView
from learner.parallel import ModelSpec, ParallelFailure, ProcessGroup, resolve_num_processes

log = logging.getLogger(__name__)


def resolve_device(name: str) -> torch.device:
    """``auto`` picks CUDA when present."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise RuntimeError("training.device is cuda but no CUDA device is available")
    return torch.device(name)


@dataclass(frozen=True)
class RoundStats:
    """What one round of training did.

    Attributes:
        loss: mean cross-entropy over the last epoch.
        accuracy: fraction of states whose argmax action equals the expert's, last epoch.
        num_states: states in the view.
        num_steps: gradient steps taken.
        seconds: wall time of the round's training.
    """

    loss: float
    accuracy: float
    num_states: int
    num_steps: int
    seconds: float


def epoch_order(attempt_rows: torch.Tensor, chunk: int, generator: torch.Generator) -> torch.Tensor:
    """A permutation of all states in which runs of ``chunk`` states share an attempt.

    States are shuffled within their attempt, cut into chunks of ``chunk`` consecutive states, and
    the chunks are shuffled. ``chunk=1`` is a plain random permutation.
    """
    n = attempt_rows.numel()
    if chunk <= 1:
        return torch.randperm(n, generator=generator)
    key = attempt_rows.double() + torch.rand(n, generator=generator, dtype=torch.float64)
    order = torch.argsort(key)
    pad = (-n) % chunk
    order = torch.cat([order, order.new_full((pad,), -1)]).view(-1, chunk)
    order = order[torch.randperm(order.shape[0], generator=generator)].flatten()
    return order[order >= 0]


def make_optimizer(model: nn.Module, cfg: TrainingConfig) -> torch.optim.Optimizer:
    """Adam; fused: one kernel for all parameters instead of ~10 ops per tensor (1.5 ms a step on a CPU)."""
    return torch.optim.Adam(model.parameters(), lr=cfg.learning_rate, fused=True)


def load_optimizer_state(optimizer: torch.optim.Optimizer, state: dict) -> None:
    """Adam's moments from a checkpoint, keeping this optimizer's fused setting (a saved one may differ)."""
    optimizer.load_state_dict(state)
    for group in optimizer.param_groups:
        group["fused"], group["foreach"] = True, None


def run_epochs(model: nn.Module, optimizer: torch.optim.Optimizer, tv: TensorView, cfg: TrainingConfig,
               generator: torch.Generator, num_epochs: int, rank: int = 0, world: int = 1,
               allreduce_: Callable[[torch.Tensor], None] | None = None,
               on_epoch: Callable[[int, float, float], None] | None = None) -> RoundStats:
    """``num_epochs`` passes over ``tv``; with ``world > 1`` this rank trains its share of every batch.

    Every rank draws the same batch order from ``generator`` and takes the ``rank``-th contiguous
    share of each batch; ``allreduce_`` sums the shares' gradients (and loss counters) so every
    rank applies the whole batch's mean gradient. ``world == 1`` is ordinary training.
    """
    n = tv.num_states
    params = [p for p in model.parameters() if p.requires_grad]
    start = time.perf_counter()
    steps, loss_sum, correct, seen = 0, 0.0, 0, 0
    model.train()
    for epoch in range(num_epochs):
        perm = epoch_order(tv.attempt_rows, cfg.states_per_chunk, generator)
        loss_sum, correct, seen = 0.0, 0, 0
        for b in range(math.ceil(n / cfg.batch_size)):
            idx = perm[b * cfg.batch_size:(b + 1) * cfg.batch_size]
            if idx.numel() < 2 and n >= 2:
                continue  # BatchNorm needs two samples
            share = idx if world == 1 else idx.tensor_split(world)[rank]
            batch_loss, batch_hits = _step(model, optimizer, params, tv, share, idx.numel(), allreduce_)
            loss_sum += batch_loss
            correct += batch_hits
            seen += idx.numel()
            steps += 1
        if on_epoch is not None and seen:
            on_epoch(epoch, loss_sum / seen, correct / seen)
    model.eval()
    return RoundStats(loss=loss_sum / max(seen, 1), accuracy=correct / max(seen, 1), num_states=n,
                      num_steps=steps, seconds=time.perf_counter() - start)


def _step(model: nn.Module, optimizer: torch.optim.Optimizer, params: list[torch.Tensor], tv: TensorView,
          share: torch.Tensor, batch_size: int, allreduce_: Callable[[torch.Tensor], None] | None) -> tuple[float, int]:
    """One gradient step on a batch of ``batch_size`` states, of which this rank holds ``share``.

    Returns the batch's summed loss and number of correct argmax actions (over all ranks).
    """
    device = next(model.parameters()).device
    loss_sum, hits = torch.zeros((), device=device), torch.zeros((), device=device)
    if share.numel() >= min(2, batch_size):  # a share of one state cannot go through BatchNorm
        obs, labels, cond, rows = tv.batch(share)
        labels = labels.to(device)
        logits = model(obs.to(device), cond.to(device), rows.to(device))
        per_state = nn.functional.cross_entropy(logits, labels, reduction="none")
        loss_sum = per_state.sum()
        (loss_sum / batch_size).backward()  # the whole batch's mean, whatever this rank's share
        loss_sum = loss_sum.detach()
        hits = (logits.detach().argmax(1) == labels).sum()
    if allreduce_ is not None:
        # gradients, a has-gradient flag per tensor (a share without earlier attempts leaves the
        # correction module's gradients at None; Adam must skip a tensor only if every share did),
        # and the counters, in one buffer: one collective per step
        flat = torch.cat([p.grad.reshape(-1) if p.grad is not None else p.new_zeros(p.numel()) for p in params]
                         + [torch.tensor([float(p.grad is not None) for p in params], device=device),
                            torch.stack([loss_sum.float(), hits.float()])])
        allreduce_(flat)
        offset = 0
        for i, p in enumerate(params):
            has_grad = flat[flat.numel() - 2 - len(params) + i] > 0
            p.grad = flat[offset:offset + p.numel()].view_as(p) if has_grad else None
            offset += p.numel()
        loss_sum, hits = flat[-2], flat[-1]
    optimizer.step()
    optimizer.zero_grad(set_to_none=True)
    return float(loss_sum), int(hits)


class Learner:
    """Trains a ``GPLPolicy``; implements ``gpl_dist.roles.Learner``.

    With ``cfg.num_processes`` other than 1 (and a ``spec`` to rebuild the model from) each round
    is trained data-parallel over that many processes (``learner.parallel``); if a helper process
    fails, the round is restarted from its initial state in this process alone.
    """

    def __init__(self, model: nn.Module, cfg: TrainingConfig, seed: int = 0, spec: ModelSpec | None = None):
        self.cfg = cfg
        keep_freed_memory()  # the step's MB-sized temporaries would page-fault afresh every step
        self.device = resolve_device(cfg.device)
        self.num_processes = resolve_num_processes(cfg.num_processes) if spec is not None and self.device.type == "cpu" else 1
        if cfg.num_threads:
            torch.set_num_threads(cfg.num_threads)
        elif self.num_processes > 1:
            torch.set_num_threads(max(1, resolve_num_processes(0) // self.num_processes))
        self.model = model.to(self.device)
        self.optimizer = make_optimizer(self.model, cfg)
        self.generator = torch.Generator().manual_seed(seed)
        self._group: ProcessGroup | None = None
        if self.num_processes > 1:
            try:
                threads = cfg.num_threads or max(1, resolve_num_processes(0) // self.num_processes)
                self._group = ProcessGroup(spec, cfg, self.num_processes, threads)
            except ParallelFailure as err:
                log.warning("%s; the learner trains in one process", err)
                self.num_processes = 1

    def load_optimizer_state(self, state: dict) -> None:
        load_optimizer_state(self.optimizer, state)

    def weights(self) -> dict:
        from gpl_dist.models.gpl import state_dict_to_numpy
        return state_dict_to_numpy(self.model)

    def train_round(self, view, on_epoch: Callable[[int, float, float], None] | None = None) -> RoundStats:
        tv = view if isinstance(view, TensorView) else TensorView.from_view(view)
        if self.num_processes > 1:
            try:
                return self._train_round_parallel(tv, on_epoch)
            except ParallelFailure as err:
                log.warning("data-parallel training failed (%s); training this round in one process", err)
                self.close()
                self.num_processes = 1
        return run_epochs(self.model, self.optimizer, tv, self.cfg, self.generator, self.cfg.num_epochs_per_round,
                          on_epoch=on_epoch)

    def _train_round_parallel(self, tv: TensorView, on_epoch) -> RoundStats:
        model_state = copy.deepcopy(self.model.state_dict())
        optimizer_state = copy.deepcopy(self.optimizer.state_dict())
        generator_state = self.generator.get_state()
        try:
            self._group.start_round(tv, model_state, optimizer_state, generator_state, self.cfg.num_epochs_per_round)
            stats = run_epochs(self.model, self.optimizer, tv, self.cfg, self.generator,
                               self.cfg.num_epochs_per_round, rank=0, world=self.num_processes,
                               allreduce_=self._group.allreduce_, on_epoch=on_epoch)
            self._group.finish_round()
            return stats
        except ParallelFailure:
            self.optimizer.zero_grad(set_to_none=True)  # a step cut short leaves its local gradients
            self.model.load_state_dict(model_state)
            load_optimizer_state(self.optimizer, optimizer_state)
            self.generator.set_state(generator_state)
            raise

    def close(self) -> None:
        """Stop the helper processes, if any."""
        if self._group is not None:
            self._group.close()
            self._group = None

"""The central learner: supervised training on expert labels over the committed buffer view.

Each round trains ``num_epochs_per_round`` epochs over the whole view (the paper's "five epochs
over the data buffer"), minimising with Adam the cross-entropy from the expert's action
distribution to the policy's (KL up to a constant, as the paper's code trained toward its
experts' distributions; with one-hot labels, the plain cross-entropy to the expert's action).
The view sits in memory for all epochs: the disk is read once per round.

Shuffling keeps ``states_per_chunk`` states of one attempt together: every state is still seen
exactly once per epoch in random order, but a batch of 512 states then spans about 32 attempts
instead of about 500, and the correction module (whose input is the attempt's history, not the
state) runs once per attempt in the batch. That is most of the cost of a step at this model size.

Adam runs over one flat tensor holding every parameter (``flatten_parameters``). A tensor that
gets no gradient in a step (the correction module, when a batch holds only first attempts) then
takes a zero gradient, as in frameworks with dense gradients, where per-tensor Adam would skip it.

Data parallel (``learner.parallel``): with a ``group`` of N learners, every learner walks the same
epoch order (rank 0's, broadcast) and takes its contiguous slice of each global batch of
``batch_size`` states; its loss is weighted by its share of the batch, so the one all-reduce (sum)
of the flat gradient per step gives every learner the gradient of the whole batch, and their
identical Adam steps keep identical weights. Without BatchNorm the optimisation is that of one
learner with the same ``batch_size``, up to the order of floating-point sums (and a last batch
of fewer than 2N states, which is skipped); BatchNorm normalises each slice by its own statistics.

``torch.set_num_threads`` is process-wide: building a learner sets the threads of its whole
process (the driver's, for rank 0).
"""

from __future__ import annotations

import contextlib
import copy
import os
import time
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Callable, Iterator, Protocol

import torch
from torch import nn

from gpl_dist.allocator import keep_freed_memory
from gpl_dist.config import ConfigError, TrainingConfig
from gpl_dist.models.layers import Conditioning
from gpl_dist.models.mivoa import PreviousStep
from gpl_dist.records import LearnerState
from learner.batches import TensorView
from learner.health import PROBE_STATES, EncoderHealth, encoder_health

#: A step's inputs: observations, labels, conditioning, attempt rows, targets, previous steps.
Batch = tuple[torch.Tensor, torch.Tensor, Conditioning, torch.Tensor, torch.Tensor, PreviousStep | None]
#: Batches built ahead of the step being trained (``Learner._prefetched``; 0 builds them in line).
PREFETCH = 2


def resolve_device(name: str) -> torch.device:
    """``auto`` picks CUDA when present."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"training.device is cuda, but torch {torch.__version__} finds no CUDA device here "
                          "(use training.device=auto or cpu)")
    return torch.device(name)


@dataclass(frozen=True)
class RoundStats:
    """What one round of training did.

    Attributes:
        loss: mean cross-entropy to the expert's distribution over the last epoch.
        accuracy: fraction of states whose argmax action equals the expert's, last epoch.
        num_states: states in the view.
        num_steps: gradient steps taken.
        seconds: wall time of the round's training.
        correction_spread: mean distance of an attempt's correction-module output from their mean,
            over the attempts with corrections in the round's last batch; 0 means the module's
            output no longer depends on the corrections (dead units) and the policy cannot use
            them. None when the batch had fewer than two such attempts or the variant has none.
        encoder_health: dead ReLU units of each conditioning encoder after the round, over up to
            ``learner.health.PROBE_STATES`` states of the view (``learner.health``; MIVOA: its LSTM).
    """

    loss: float
    accuracy: float
    num_states: int
    num_steps: int
    seconds: float
    correction_spread: float | None = None
    encoder_health: tuple[EncoderHealth, ...] = ()


def flatten_parameters(model: nn.Module) -> tuple[nn.Parameter, torch.Tensor]:
    """Re-home every parameter of ``model`` as a view of one flat tensor, and its ``.grad`` as a
    view of another; returns both (the flat one as the optimiser's single parameter).

    The module is unchanged for everything else: ``state_dict``/``load_state_dict`` copy values,
    and autograd accumulates into the existing ``.grad`` views in place (so zero them, never
    set them to None). Move the model to its device first: ``.to`` would re-allocate.
    """
    params = [p for p in model.parameters() if p.requires_grad]
    flat = torch.cat([p.detach().reshape(-1) for p in params])
    grads = torch.zeros_like(flat)
    offset = 0
    for p in params:
        n = p.numel()
        p.data = flat[offset:offset + n].view_as(p)
        p.grad = grads[offset:offset + n].view_as(p)
        offset += n
    flat_parameters = nn.Parameter(flat)
    flat_parameters.grad = grads
    return flat_parameters, grads


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


def autocast_context(cfg: TrainingConfig, device: torch.device) -> Callable[[], contextlib.AbstractContextManager]:
    """A factory of the context each forward of the learner runs in (``training.autocast``):
    ``torch.autocast`` to bf16, or nothing. bf16 on a CPU needs native bf16 dot products
    (``learner.cpu.native_bf16``); elsewhere it would be emulated in fp32 and only add conversions,
    so ``ConfigError`` says so before anything trains. Autocast is per thread: each thread that
    runs a forward enters its own."""
    if cfg.autocast == "none":
        return contextlib.nullcontext
    from learner.cpu import BF16_FLAGS, native_bf16

    if device.type == "cpu" and not native_bf16():
        raise ConfigError(f"training.autocast={cfg.autocast} needs a CPU with native bf16 ({' or '.join(BF16_FLAGS)}); "
                          "this one has neither: use training.autocast=none")
    return lambda: torch.autocast(device.type, dtype=torch.bfloat16)


def available_cpus() -> int:
    """CPU cores this process may run on (its affinity mask: a container's or ``taskset``'s share)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # macOS has no affinity masks
        return os.cpu_count() or 1


def threads_per_learner(cfg: TrainingConfig) -> int:
    """``training.num_threads``, or with 0 the available cores shared out among the learners.

    One by default: a learner with two intra-op threads stalls at every operation when anything
    else runs on its cores (an OpenMP thread waits for a descheduled sibling), and its parallel
    sums change from run to run. On a Ray node the learner always shares its cores, so further
    cores go to further learner processes (``training.num_learners``); docs/results.md, Speed.
    """
    if cfg.num_threads:
        return cfg.num_threads
    return max(1, available_cpus() // max(1, cfg.num_learners or available_cpus()))


class Group(Protocol):
    """The collective operations a data-parallel learner needs (``learner.parallel.ProcessGroup``)."""

    rank: int
    size: int

    def all_reduce_sum_(self, tensor: torch.Tensor) -> None: ...

    def broadcast_(self, tensor: torch.Tensor) -> None:
        """Overwrite ``tensor`` with rank 0's."""
        ...


class Learner:
    """Trains a ``GPLPolicy``; implements ``gpl_dist.roles.Learner``.

    ``group``: the data-parallel learners this one trains with (None alone); see the module doc.
    """

    def __init__(self, model: nn.Module, cfg: TrainingConfig, seed: int = 0, group: Group | None = None):
        self.cfg = cfg
        self.group = group
        keep_freed_memory()  # the step's MB-sized temporaries would page-fault afresh every step
        self.device = resolve_device(cfg.device)
        torch.set_num_threads(threads_per_learner(cfg))
        self._autocast = autocast_context(cfg, self.device)
        self.model = model.to(self.device)
        self.flat_parameters, self.flat_grads = flatten_parameters(self.model)
        # one fused Adam kernel over one tensor: the per-tensor bookkeeping of a 45-tensor step
        # cost more than the update itself on a CPU
        self.optimizer = torch.optim.Adam([self.flat_parameters], lr=cfg.learning_rate, fused=True)
        self.generator = torch.Generator().manual_seed(seed)
        self._builder: ThreadPoolExecutor | None = None  # builds the next batches (``_prefetched``)
        # the conditioning branch of each step (``_two_branch_step``), when asked for
        self._branches: ThreadPoolExecutor | None = self._thread("gpl-branch") if cfg.conditioning_thread else None
        #: the parameters of the head, where ``_two_branch_step`` cuts the graph (found once, not per step)
        self._head_params = [p for p in getattr(self.model, "head", nn.Sequential()).parameters() if p.requires_grad]

    def _thread(self, name: str) -> ThreadPoolExecutor:
        """A helper thread of this learner whose ops run on as many intra-op threads as its own
        (OpenMP's thread count is per thread: a new thread would otherwise use every core, sum
        in another order and oversubscribe them)."""
        threads = torch.get_num_threads()
        return ThreadPoolExecutor(max_workers=1, thread_name_prefix=name, initializer=torch.set_num_threads,
                                  initargs=(threads,))

    def load_optimizer_state(self, state: dict) -> None:
        """Adam's moments over the flat parameter (``flatten_parameters``; a checkpoint's, as
        ``learner.checkpoint.load_checkpoint`` gives them), keeping this learner's fused setting and
        its config's learning rate (``training.learning_rate``, which a resume may change)."""
        # a copy: load_state_dict keeps the given tensors, so two learners loading one in-memory
        # state would update the same moments twice (a checkpoint read from disk is private anyway)
        state = copy.deepcopy(state)
        self.optimizer.load_state_dict(state)
        for group in self.optimizer.param_groups:
            group["fused"], group["foreach"] = True, None
            # the run's learning rate, not the one saved with the moments: a --resume that changes
            # training.learning_rate applies it from the next round (learner.driver, RESUMABLE)
            group["lr"] = self.cfg.learning_rate

    def state(self) -> LearnerState:
        """Model, Adam and batch-generator state (``gpl_dist.roles.Learner``); the tensors are this
        learner's own: copy them before training on if they must stay as they are."""
        return LearnerState(self.model.state_dict(), self.optimizer.state_dict(), self.generator.get_state())

    def load_state(self, state: LearnerState) -> None:
        """Continue from ``state``; the model's ``load_state_dict`` raises on another architecture."""
        self.model.load_state_dict(dict(state.model))
        if state.optimizer is not None:
            self.load_optimizer_state(dict(state.optimizer))
        self.generator.set_state(state.generator)

    def close(self) -> None:
        """Stop the helper threads (``learner.parallel.DataParallelLearner`` also stops its processes)."""
        for pool in (self._builder, self._branches):
            if pool is not None:
                pool.shutdown(cancel_futures=True)
        self._builder = self._branches = None

    def weights(self) -> dict:
        from gpl_dist.models.build import state_dict_to_numpy
        return state_dict_to_numpy(self.model)

    def train_round(self, view, on_epoch: Callable[[int, float, float], None] | None = None) -> RoundStats:
        if not isinstance(view, TensorView):
            view = TensorView.from_view(view, previous_steps=bool(getattr(self.model, "uses_previous_step", False)))
        tv = self._on_device(self._with_inputs(view))
        n = tv.num_states
        start = time.perf_counter()
        steps, loss_sum, correct, seen = 0, 0.0, 0, 0
        self.model.train()
        self._sync_state()
        rank, size = (0, 1) if self.group is None else (self.group.rank, self.group.size)
        last_conditioning = None
        for epoch in range(self.cfg.num_epochs_per_round):
            perm = self._epoch_order(tv)  # on the host: batches are indexed from there (TensorView.batch)
            # summed on the device: reading a GPU's loss every step would wait for every step
            loss_total = torch.zeros((), dtype=torch.float64, device=self.device)
            correct_total, seen = torch.zeros((), dtype=torch.long, device=self.device), 0
            steps_of_epoch = []
            for idx in perm.split(self.cfg.batch_size):
                if idx.numel() < 2 * size and (size > 1 or n >= 2):
                    continue  # BatchNorm needs two samples on every learner
                steps_of_epoch.append((idx[rank * idx.numel() // size:(rank + 1) * idx.numel() // size], idx.numel()))
            for (mine, whole), batch in zip(steps_of_epoch, self._prefetched(tv, [m for m, _ in steps_of_epoch])):
                loss, hits = self._train_on(*batch, share=mine.numel() / whole)
                last_conditioning = batch[2]
                loss_total += loss * mine.numel()
                correct_total += hits
                seen += mine.numel()
                steps += 1
            loss_sum, correct, seen = self._sum_over_learners(float(loss_total), int(correct_total), seen)
            if on_epoch is not None and seen:
                on_epoch(epoch, loss_sum / seen, correct / seen)
        self._average_batchnorm_statistics()
        self.model.eval()
        spread = None if last_conditioning is None else self.correction_spread(last_conditioning)
        seconds = time.perf_counter() - start
        return RoundStats(loss=loss_sum / max(seen, 1), accuracy=correct / max(seen, 1), num_states=n,
                          num_steps=steps, seconds=seconds, correction_spread=spread,
                          encoder_health=self.encoder_health(tv))

    def _prefetched(self, tv: TensorView, steps: list[torch.Tensor]) -> Iterator[Batch]:
        """``_gather(tv, idx)`` of each of ``steps``, built ``PREFETCH`` steps ahead on a second
        thread while this one trains: the batch's index structure (its distinct attempts and
        earlier attempts) and its gathers run beside the step on another core. Each batch is a
        function of its indices only, so the steps see exactly what they would see built in line."""
        if PREFETCH < 1:
            yield from (self._gather(tv, idx) for idx in steps)
            return
        if self._builder is None:
            self._builder = self._thread("gpl-batches")
        ahead: deque[Future] = deque()
        try:
            for i in range(len(steps)):
                while len(ahead) <= PREFETCH and i + len(ahead) < len(steps):
                    ahead.append(self._builder.submit(self._gather, tv, steps[i + len(ahead)]))
                yield ahead.popleft().result()
        finally:
            for future in ahead:
                future.cancel()

    def encoder_health(self, tv: TensorView) -> tuple[EncoderHealth, ...]:
        """See ``RoundStats.encoder_health``: states spread evenly over the view (no random draw, so
        the training's random stream is untouched)."""
        if tv.num_states == 0:
            return ()
        idx = torch.linspace(0, tv.num_states - 1, min(tv.num_states, PROBE_STATES)).long().unique()
        return encoder_health(self.model, tv.batch(idx.to(tv.observations.device))[2].to(self.device))

    def correction_spread(self, cond) -> float | None:
        """See ``RoundStats.correction_spread``."""
        if not self.model.uses_corrections:
            return None
        with torch.no_grad():
            z = self.model.encode_conditioning(cond)[:, self.model.instruction.out_dim:]  # type: ignore[operator,union-attr]
        z = z[(cond.slots >= 0).any(1)]
        if z.shape[0] < 2:
            return None
        return float((z - z.mean(0)).norm(dim=1).mean())

    def _epoch_order(self, tv: TensorView) -> torch.Tensor:
        """This epoch's order of states: rank 0's, on every learner of a group."""
        if self.group is None or self.group.rank == 0:
            # drawn on the host, from the learner's CPU generator, whatever the view's device
            perm = epoch_order(tv.attempt_rows.cpu(), self.cfg.states_per_chunk, self.generator)
        else:
            perm = torch.empty(tv.num_states, dtype=torch.long)
        if self.group is not None:
            self.group.broadcast_(perm)
        return perm

    def _sum_over_learners(self, loss_sum: float, correct: int, seen: int) -> tuple[float, int, int]:
        if self.group is None:
            return loss_sum, correct, seen
        totals = torch.tensor([loss_sum, correct, seen], dtype=torch.float64)
        self.group.all_reduce_sum_(totals)
        return float(totals[0]), int(totals[1]), int(totals[2])

    def _sync_state(self) -> None:
        """Give every learner of a group rank 0's weights, buffers (BatchNorm statistics) and Adam
        moments: after a checkpoint was loaded on rank 0, and against any drift."""
        if self.group is None:
            return
        state = self.optimizer.state[self.flat_parameters]
        if not state:  # a fresh Adam state equals zero moments at step 0
            state.update(step=torch.zeros((), dtype=torch.float32, device=self.device),
                         exp_avg=torch.zeros_like(self.flat_parameters),
                         exp_avg_sq=torch.zeros_like(self.flat_parameters))
        for tensor in (self.flat_parameters.data, state["exp_avg"], state["exp_avg_sq"], state["step"],
                       *self.model.buffers()):
            self.group.broadcast_(tensor)

    def _average_batchnorm_statistics(self) -> None:
        """Each learner's BatchNorm running statistics saw only its slices: average them."""
        if self.group is None:
            return
        for module in self.model.modules():
            if isinstance(module, nn.modules.batchnorm._BatchNorm):
                for stat in (module.running_mean, module.running_var):
                    if isinstance(stat, torch.Tensor):
                        self.group.all_reduce_sum_(stat)
                        stat.div_(self.group.size)

    def step(self, tv: TensorView, idx: torch.Tensor) -> tuple[float, int]:
        """One gradient step on states ``idx``; returns (loss, number of correct argmax actions)."""
        loss, hits = self._train_on(*self._gather(tv, idx))
        return float(loss), int(hits)

    def _with_inputs(self, tv: TensorView) -> TensorView:
        """The view with what this model reads beyond the buffer (numeric full information)."""
        if getattr(self.model, "numeric_full_information", False) and tv.instruction_values is None:
            from gpl_dist.domains import get_domain

            values_of_task = get_domain(str(self.model.domain_name)).full_information_values
            assert values_of_task is not None  # the model is numeric only for such a domain
            return tv.with_full_information(values_of_task)
        return tv

    def _on_device(self, tv: TensorView) -> TensorView:
        """The view in the memory of the learner's GPU when it takes under half of what is free there
        (each batch is then gathered on the GPU, with no host-to-device copy per step); else as it is."""
        if self.device.type != "cuda":
            return tv
        free_bytes, _ = torch.cuda.mem_get_info(self.device)
        return tv.to(self.device) if tv.nbytes < free_bytes // 2 else tv

    def _gather(self, tv: TensorView, idx: torch.Tensor) -> Batch:
        """The batch of states ``idx``, on the learner's device (with each state's previous step
        for a model that reads it)."""
        obs, labels, cond, rows = tv.batch(idx)
        dev = self.device
        idx = idx.to(tv.observations.device, non_blocking=True)
        previous = tv.previous(idx).to(dev) if self.model.uses_previous_step else None
        return obs.to(dev), labels.to(dev), cond.to(dev), rows.to(dev), tv.targets(idx).to(dev), previous

    def _two_branch_step(self, obs, cond, rows, targets, previous, share: float) -> tuple[torch.Tensor, torch.Tensor]:
        """Forward and backward of one step with the conditioning branch (``encode_conditioning``,
        per attempt) on a second thread beside the state branch (``encode_states``, per state):
        the graph is cut where they meet the head, the head's backward hands each branch its
        gradient, and the branches run their backward each on its thread. They share no
        parameter, so every op and sum is the one-thread step's: bitwise the same result."""
        model: Any = self.model  # a GPLPolicy or MIVOAPolicy (gpl_dist.roles.Policy)
        assert self._branches is not None
        z_future = self._branches.submit(self._encode_conditioning, cond)
        with self._autocast():
            states = model.encode_states(obs, previous)
        z = z_future.result()
        z_in, states_in = z.detach().requires_grad_(z.requires_grad), states.detach().requires_grad_(states.requires_grad)
        with self._autocast():
            logits = model.head_logits(states_in, z_in[rows], previous)
            loss = nn.functional.cross_entropy(logits, targets)
        self.flat_grads.zero_()
        # the gradients at the cut as the head's backward makes them (a .grad would be re-laid out
        # as a contiguous copy, and a BatchNorm's backward sums a strided gradient in another order)
        head = self._head_params
        cut = [t for t in (states_in, z_in) if t.requires_grad]
        grads = torch.autograd.grad(loss * share if share != 1.0 else loss, cut + head)
        for p, g in zip(head, grads[len(cut):]):
            p.grad.add_(g)  # type: ignore[union-attr]  # a view of flat_grads, as backward would add
        at_cut = dict(zip((id(t) for t in cut), grads))
        back = self._branches.submit(torch.autograd.backward, z, at_cut[id(z_in)]) if z.requires_grad else None
        if states.requires_grad:
            torch.autograd.backward(states, at_cut[id(states_in)])
        if back is not None:
            back.result()
        return logits, loss

    def _encode_conditioning(self, cond: Conditioning) -> torch.Tensor:
        """``encode_conditioning`` under the learner's autocast (entered on the calling thread)."""
        with self._autocast():
            return self.model.encode_conditioning(cond)  # type: ignore[operator]

    def _train_on(self, obs, labels, cond, rows, targets, previous=None,
                  share: float = 1.0) -> tuple[torch.Tensor, torch.Tensor]:
        """One step on a batch; ``share`` is this learner's fraction of a group's global batch.
        Returns the batch's mean loss and its number of correct argmax actions, as 0-d tensors on
        the learner's device."""
        if self._branches is None:
            with self._autocast():
                logits = self.model(obs, cond, rows, previous)
                loss = nn.functional.cross_entropy(logits, targets)
            self.flat_grads.zero_()  # the parameters' grads are views of it: backward adds in place
            (loss * share if share != 1.0 else loss).backward()
        else:
            logits, loss = self._two_branch_step(obs, cond, rows, targets, previous, share)
        if self.group is not None:
            self.group.all_reduce_sum_(self.flat_grads)
        self.optimizer.step()
        return loss.detach(), (logits.detach().argmax(1) == labels).sum()

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
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import torch
from torch import nn

from gpl_dist.allocator import keep_freed_memory
from gpl_dist.config import ConfigError, TrainingConfig
from learner.batches import TensorView


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
    """

    loss: float
    accuracy: float
    num_states: int
    num_steps: int
    seconds: float
    correction_spread: float | None = None


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


class Learner:
    """Trains a ``GPLPolicy``; implements ``gpl_dist.roles.Learner``."""

    def __init__(self, model: nn.Module, cfg: TrainingConfig, seed: int = 0):
        self.cfg = cfg
        keep_freed_memory()  # the step's MB-sized temporaries would page-fault afresh every step
        self.device = resolve_device(cfg.device)
        if cfg.num_threads:
            torch.set_num_threads(cfg.num_threads)
        self.model = model.to(self.device)
        self.flat_parameters, self.flat_grads = flatten_parameters(self.model)
        # one fused Adam kernel over one tensor: the per-tensor bookkeeping of a 45-tensor step
        # cost more than the update itself on a CPU
        self.optimizer = torch.optim.Adam([self.flat_parameters], lr=cfg.learning_rate, fused=True)
        self.generator = torch.Generator().manual_seed(seed)

    def load_optimizer_state(self, state: dict) -> None:
        """Adam's moments from a checkpoint (also one written with one entry per parameter tensor,
        before the parameters were flattened: exact when every tensor has taken the same number
        of steps, as they do in gpl-dist's rounds), keeping this learner's fused setting."""
        params = state["param_groups"][0]["params"]
        if len(params) > 1:  # per-tensor moments, in model.parameters() order: concatenate them
            per = [state["state"].get(i) for i in params]
            sizes = [p.numel() for p in self.model.parameters() if p.requires_grad]
            zeros = lambda n: torch.zeros(n, device=self.device)  # noqa: E731 - a tensor that never had a gradient
            flat = {key: torch.cat([x[key].reshape(-1) if x is not None else zeros(n) for x, n in zip(per, sizes)])
                    for key in ("exp_avg", "exp_avg_sq")}
            flat["step"] = max((x["step"] for x in per if x is not None), default=torch.tensor(0.0)).clone()
            state = {"state": {0: flat} if any(x is not None for x in per) else {},
                     "param_groups": [{**state["param_groups"][0], "params": [0]}]}
        self.optimizer.load_state_dict(state)
        for group in self.optimizer.param_groups:
            group["fused"], group["foreach"] = True, None

    def weights(self) -> dict:
        from gpl_dist.models.gpl import state_dict_to_numpy
        return state_dict_to_numpy(self.model)

    def train_round(self, view, on_epoch: Callable[[int, float, float], None] | None = None) -> RoundStats:
        tv = view if isinstance(view, TensorView) else TensorView.from_view(view)
        n = tv.num_states
        start = time.perf_counter()
        steps, loss_sum, correct, seen = 0, 0.0, 0, 0
        self.model.train()
        last_conditioning = None
        for epoch in range(self.cfg.num_epochs_per_round):
            perm = epoch_order(tv.attempt_rows, self.cfg.states_per_chunk, self.generator)
            loss_sum, correct, seen = 0.0, 0, 0
            for idx in perm.split(self.cfg.batch_size):
                if idx.numel() < 2 and n >= 2:
                    continue  # BatchNorm needs two samples
                batch = self._gather(tv, idx)
                loss, hits = self._train_on(*batch)
                last_conditioning = batch[2]
                loss_sum += loss * idx.numel()
                correct += hits
                seen += idx.numel()
                steps += 1
            if on_epoch is not None and seen:
                on_epoch(epoch, loss_sum / seen, correct / seen)
        self.model.eval()
        spread = None if last_conditioning is None else self.correction_spread(last_conditioning)
        return RoundStats(loss=loss_sum / max(seen, 1), accuracy=correct / max(seen, 1), num_states=n,
                          num_steps=steps, seconds=time.perf_counter() - start, correction_spread=spread)

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

    def step(self, tv: TensorView, idx: torch.Tensor) -> tuple[float, int]:
        """One gradient step on states ``idx``; returns (loss, number of correct argmax actions)."""
        return self._train_on(*self._gather(tv, idx))

    def _gather(self, tv: TensorView, idx: torch.Tensor) -> tuple:
        """The batch of states ``idx``, on the learner's device."""
        obs, labels, cond, rows = tv.batch(idx)
        dev = self.device
        return obs.to(dev), labels.to(dev), cond.to(dev), rows.to(dev), tv.targets(idx).to(dev)

    def _train_on(self, obs, labels, cond, rows, targets) -> tuple[float, int]:
        logits = self.model(obs, cond, rows)
        loss = nn.functional.cross_entropy(logits, targets)
        self.flat_grads.zero_()  # the parameters' grads are views of it: backward adds in place
        loss.backward()
        self.optimizer.step()
        return float(loss.detach()), int((logits.detach().argmax(1) == labels).sum())

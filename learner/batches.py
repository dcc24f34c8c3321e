"""Turn the buffer's in-memory training view into model batches.

The view is converted to torch tensors once per round (``TensorView``); a batch of state indices
then becomes observations, labels, and one ``Conditioning`` row per distinct attempt among them,
so each attempt's instruction and correction history is encoded once per batch.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, fields
from typing import Callable

import numpy as np
import torch

from gpl_dist.models.layers import Conditioning
from gpl_dist.models.mivoa import PreviousStep


@dataclass(frozen=True)
class TensorView:
    """Torch views (no copies) of a ``storage.TrainingView``.

    Attributes:
        observations: ``(N, *O)`` states.
        expert_actions: int64 ``(N,)`` labels.
        expert_probs: float32 ``(N, A)`` the expert's action distributions, the training target;
            None when every one is one-hot (then ``expert_actions`` says the same, more cheaply).
        attempt_rows: int64 ``(N,)`` each state's attempt row.
        instruction_ids: int64 ``(A, L)``.
        correction_ids: int64 ``(A, L)``.
        context_rows: int64 ``(A, K)`` rows of the earlier attempts, -1 padded.
        trajectories: ``(A, S, *O)`` subsampled attempts.
        previous_rows: int64 ``(N,)`` row of the state before each one in its attempt (its own
            row at t = 0); None unless built with ``previous_steps``.
        previous_actions: int64 ``(N,)`` the action executed in that state; -1 at t = 0.
        attempt_task_ids: int64 ``(A,)`` each attempt's task; None when the view has none.
        instruction_values: float32 ``(A, F)`` numeric full information of each attempt
            (``with_full_information``), or None.
        attempt_rewards: float32 ``(A,)`` each attempt's summed reward (NaN where not recorded), or None.
        host_index: host copies of ``(attempt_rows, context_rows)`` when the view lives on a GPU
            (``to``): each batch's index structure is then built on the host (``batch``), so the
            host never waits for the GPU to finish a ``torch.unique``; None on the host.
    """

    observations: torch.Tensor
    expert_actions: torch.Tensor
    attempt_rows: torch.Tensor
    instruction_ids: torch.Tensor
    correction_ids: torch.Tensor
    context_rows: torch.Tensor
    trajectories: torch.Tensor
    expert_probs: torch.Tensor | None = None
    previous_rows: torch.Tensor | None = None
    previous_actions: torch.Tensor | None = None
    attempt_task_ids: torch.Tensor | None = None
    instruction_values: torch.Tensor | None = None
    attempt_rewards: torch.Tensor | None = None
    host_index: tuple[torch.Tensor, torch.Tensor] | None = None

    @classmethod
    def from_view(cls, view, previous_steps: bool = False) -> "TensorView":
        """Torch views of ``view``'s arrays; ``previous_steps`` also finds each state's previous
        step (a sort over the states: only for a model that reads it)."""
        # np.array(copy) only when the loader handed out read-only memory
        t = lambda a: torch.from_numpy(a if a.flags.writeable and a.flags.c_contiguous else np.array(a))  # noqa: E731
        probs = getattr(view, "expert_probs", None)
        if probs is not None and bool((probs.max(axis=1) == 1.0).all()):
            probs = None
        prev_rows, prev_actions = find_previous_steps(view) if previous_steps else (None, None)
        return cls(t(view.observations), t(view.expert_actions).long(), t(view.attempt_rows).long(),
                   t(view.instruction_ids).long(), t(view.correction_ids).long(), t(view.context_rows).long(),
                   t(view.trajectories), expert_probs=None if probs is None else t(probs),
                   previous_rows=None if prev_rows is None else torch.from_numpy(prev_rows),
                   previous_actions=None if prev_actions is None else torch.from_numpy(prev_actions),
                   attempt_task_ids=t(view.task_id).long() if hasattr(view, "task_id") else None,
                   attempt_rewards=t(view.reward_sum).float() if hasattr(view, "reward_sum") else None)

    def with_full_information(self, values_of_task: Callable[[int], np.ndarray]) -> "TensorView":
        """This view with each attempt's numeric full information, ``values_of_task(task_id)``."""
        if self.attempt_task_ids is None:
            raise ValueError("this view has no task ids: the full information of its attempts is unknown")
        tasks = self.attempt_task_ids.cpu().numpy()
        table = {t: values_of_task(int(t)) for t in np.unique(tasks)}
        values = torch.from_numpy(np.stack([table[t] for t in tasks]) if tasks.size else np.zeros((0, 0), np.float32))
        return dataclasses.replace(self, instruction_values=values.to(self.observations.device))

    def to(self, device: torch.device) -> "TensorView":
        """This view on ``device`` (one copy of every tensor; itself when already there)."""
        if self.observations.device == device:
            return self
        host = None if device.type == "cpu" else (self.attempt_rows.cpu(), self.context_rows.cpu())
        return dataclasses.replace(self, host_index=host,
                                   **{k: x.to(device) for k, x in self._tensors().items() if x is not None})

    @property
    def nbytes(self) -> int:
        """Bytes held by the view's tensors."""
        return sum(x.numel() * x.element_size() for x in self._tensors().values() if x is not None)

    def _tensors(self) -> dict[str, torch.Tensor | None]:
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "host_index"}

    @property
    def num_states(self) -> int:
        return int(self.expert_actions.shape[0])

    def targets(self, idx: torch.Tensor) -> torch.Tensor:
        """The training target of states ``idx``: ``(B, A)`` probabilities, or ``(B,)`` actions."""
        return self.expert_actions[idx] if self.expert_probs is None else self.expert_probs[idx]

    def previous(self, idx: torch.Tensor) -> PreviousStep:
        """The step before each of states ``idx`` (for ``MIVOAPolicy``)."""
        if self.previous_rows is None or self.previous_actions is None:
            raise ValueError("this view was built without previous steps (TensorView.from_view(view, previous_steps=True))")
        return PreviousStep(self.observations[self.previous_rows[idx]], self.previous_actions[idx])

    def batch(self, idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, Conditioning, torch.Tensor]:
        """``(observations, labels, conditioning, attempt_rows_in_conditioning)`` of states ``idx``
        (host or device indices), on the view's device."""
        if self.host_index is None:
            rows_of, ctx_of, put = self.attempt_rows, self.context_rows, lambda t: t  # noqa: E731
        else:  # the index structure on the host, then only index tensors go to the device
            rows_of, ctx_of = self.host_index
            device, pin = self.observations.device, self.observations.is_cuda
            put = lambda t: (t.pin_memory() if pin else t).to(device, non_blocking=pin)  # noqa: E731
            idx = idx.cpu()
        rows = rows_of[idx]
        uniq, inverse = torch.unique(rows, return_inverse=True)
        ctx = ctx_of[uniq]
        valid = ctx >= 0
        # each earlier attempt is encoded once, however many later attempts in the batch use it
        earlier, slot_of = torch.unique(ctx[valid], return_inverse=True)
        slots = torch.full_like(ctx, -1)
        slots[valid] = slot_of
        idx, uniq, earlier = put(idx), put(uniq), put(earlier)
        cond = Conditioning(
            instruction_ids=self.instruction_ids[uniq],
            trajectories=self.trajectories[earlier],
            correction_ids=self.correction_ids[earlier],
            slots=put(slots),
            instruction_values=None if self.instruction_values is None else self.instruction_values[uniq],
            correction_values=None if self.attempt_rewards is None else self.attempt_rewards[earlier],
        )
        return self.observations[idx], self.expert_actions[idx], cond, put(inverse)


def find_previous_steps(view) -> tuple[np.ndarray, np.ndarray]:
    """``(previous_rows, previous_actions)`` of every state of ``view`` (see ``TensorView``): found
    by sorting on (attempt, t), so they hold in whatever order the view lists its states."""
    rows, t = np.asarray(view.attempt_rows), np.asarray(view.timesteps)
    order = np.lexsort((t, rows))
    prev = np.arange(rows.size, dtype=np.int64)
    actions = np.full(rows.size, -1, dtype=np.int64)
    follows = np.zeros(rows.size, dtype=bool)
    if rows.size > 1:
        follows[1:] = (rows[order[1:]] == rows[order[:-1]]) & (t[order[1:]] == t[order[:-1]] + 1)
    prev[order[follows]] = order[np.flatnonzero(follows) - 1]
    actions[order[follows]] = np.asarray(view.actions)[order[np.flatnonzero(follows) - 1]]
    return prev, actions

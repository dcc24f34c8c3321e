"""Turn the buffer's in-memory training view into model batches.

The view is converted to torch tensors once per round (``TensorView``); a batch of state indices
then becomes observations, labels, and one ``Conditioning`` row per distinct attempt among them,
so each attempt's instruction and correction history is encoded once per batch.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
import torch

from gpl_dist.models.gpl import Conditioning


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
    """

    observations: torch.Tensor
    expert_actions: torch.Tensor
    attempt_rows: torch.Tensor
    instruction_ids: torch.Tensor
    correction_ids: torch.Tensor
    context_rows: torch.Tensor
    trajectories: torch.Tensor
    expert_probs: torch.Tensor | None = None

    @classmethod
    def from_view(cls, view) -> "TensorView":
        # np.array(copy) only when the loader handed out read-only memory
        t = lambda a: torch.from_numpy(a if a.flags.writeable and a.flags.c_contiguous else np.array(a))  # noqa: E731
        probs = getattr(view, "expert_probs", None)
        if probs is not None and bool((probs.max(axis=1) == 1.0).all()):
            probs = None
        return cls(t(view.observations), t(view.expert_actions).long(), t(view.attempt_rows).long(),
                   t(view.instruction_ids).long(), t(view.correction_ids).long(), t(view.context_rows).long(),
                   t(view.trajectories), None if probs is None else t(probs))

    def to(self, device: torch.device) -> "TensorView":
        """This view on ``device`` (one copy of every tensor; itself when already there)."""
        if self.observations.device == device:
            return self
        return TensorView(**{k: None if x is None else x.to(device) for k, x in self._tensors().items()})

    @property
    def nbytes(self) -> int:
        """Bytes held by the view's tensors."""
        return sum(x.numel() * x.element_size() for x in self._tensors().values() if x is not None)

    def _tensors(self) -> dict[str, torch.Tensor | None]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @property
    def num_states(self) -> int:
        return int(self.expert_actions.shape[0])

    def targets(self, idx: torch.Tensor) -> torch.Tensor:
        """The training target of states ``idx``: ``(B, A)`` probabilities, or ``(B,)`` actions."""
        return self.expert_actions[idx] if self.expert_probs is None else self.expert_probs[idx]

    def batch(self, idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, Conditioning, torch.Tensor]:
        """``(observations, labels, conditioning, attempt_rows_in_conditioning)`` of states ``idx``."""
        rows = self.attempt_rows[idx]
        uniq, inverse = torch.unique(rows, return_inverse=True)
        ctx = self.context_rows[uniq]
        valid = ctx >= 0
        # each earlier attempt is encoded once, however many later attempts in the batch use it
        earlier, slot_of = torch.unique(ctx[valid], return_inverse=True)
        slots = torch.full_like(ctx, -1)
        slots[valid] = slot_of
        cond = Conditioning(
            instruction_ids=self.instruction_ids[uniq],
            trajectories=self.trajectories[earlier],
            correction_ids=self.correction_ids[earlier],
            slots=slots,
        )
        return self.observations[idx], self.expert_actions[idx], cond, inverse

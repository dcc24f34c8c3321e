"""MIVOA, the paper's instruction-following baseline from Misra, Langford & Artzi, "Mapping
Instructions and Visual Observations to Actions with Reinforcement Learning" (EMNLP 2017).

Their architecture, at this domain's sizes, trained by DAgger like every method here:

- **instruction**: word embeddings -> an LSTM; the mean of its hidden states over the words
  (padding skipped) is the instruction's vector;
- **observation**: the current and the previous state stacked (the authors' env option stacks 2
  frames) through a state encoder: on grids the GPL state encoder's 2x2 CNN -> MLP over both
  frames' channels, on vectors the two states concatenated and normalised;
- **previous action**: its one-hot (one more slot for "none" at an attempt's first step), as the
  authors' env option feeds it;
- the three concatenated -> the policy MLP -> action logits.

Choices that are ours (Misra et al. name none for these domains, the authors' code no sizes):
the LSTM's hidden size is the GPL instruction module's output size; the state encoder and the
policy MLP are GPL's (``DomainSpec.model_sizes``), so the two models differ in the architecture,
not in capacity; ``mivoa_full_information`` reads the full-information text in place of the
instruction, as GPL's full-information baseline does. MIVOA takes no corrections: one attempt
per task in collection and at meta-test.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from gpl_dist.models.layers import Conditioning, GridStateEncoder, VectorStateEncoder, grid_categories, mlp
from gpl_dist.models.sizes import Sizes
from gpl_dist.roles import DomainSpec
from gpl_dist.variants import MIVOA

MIVOA_VARIANTS = MIVOA


@dataclass(frozen=True)
class PreviousStep:
    """What a state-history policy sees of the step before each state.

    Attributes:
        observations: ``(B, *O)`` the state before each one (the state itself at t = 0).
        actions: int64 ``(B,)`` the action taken there; -1 at t = 0 (no previous action).
    """

    observations: torch.Tensor
    actions: torch.Tensor

    def to(self, device: torch.device | str) -> "PreviousStep":
        return PreviousStep(self.observations.to(device, non_blocking=True), self.actions.to(device, non_blocking=True))


class InstructionLSTM(nn.Module):
    """Token ids ``(B, L)`` -> the mean of the LSTM's hidden states over the non-padding tokens ``(B, H)``."""

    def __init__(self, vocab_size: int, pad_id: int, embedding_dim: int, hidden: int):
        super().__init__()
        self.pad_id = pad_id
        self.embedding = nn.Embedding(vocab_size, embedding_dim, padding_idx=pad_id)
        self.lstm = nn.LSTM(embedding_dim, hidden, batch_first=True)
        self.out_dim = hidden

    def forward(self, ids: torch.Tensor) -> torch.Tensor:
        states, _ = self.lstm(self.embedding(ids))  # (B, L, H); padding follows the words, so it
        words = (ids != self.pad_id).unsqueeze(-1).to(states.dtype)  # never feeds a word's state
        return (states * words).sum(1) / words.sum(1).clamp(min=1.0)


class MIVOAPolicy(nn.Module):
    """MIVOA for one domain (module doc); the same calls as ``GPLPolicy`` plus each state's
    ``PreviousStep``."""

    uses_corrections = False
    uses_previous_step = True
    #: full information is read as text here, on every domain (the paper has no numeric MIVOA)
    numeric_full_information = False

    def __init__(self, domain: DomainSpec, variant: str = "mivoa", embedding_dim: int = 16,
                 policy_batchnorm: bool = False, paraphrases: bool = False, conv_batchnorm: bool = False,
                 sizes: Sizes | None = None):
        super().__init__()
        if variant not in MIVOA_VARIANTS:
            raise ValueError(f"MIVOA variant must be one of {MIVOA_VARIANTS}, got {variant!r}")
        self.domain_name, self.variant, self.num_actions = domain.name, variant, domain.num_actions
        sizes, vocab = sizes or domain.model_sizes, domain.vocabulary_for(paraphrases)
        self.vocabulary = vocab  # the words this network reads: text is encoded with it
        self.instruction = InstructionLSTM(vocab.size, vocab.pad_id, embedding_dim, sizes.instruction_mlp[-1])
        if len(domain.obs_shape) == 3:
            h, w, c = domain.obs_shape
            self.state: nn.Module = GridStateEncoder((h, w, 2 * c), grid_categories(domain) * 2, sizes.state_channels,
                                                     sizes.state_mlp, conv_batchnorm)
        else:
            self.state = VectorStateEncoder((2 * domain.obs_shape[0],))
        self.conditioning_dim = self.instruction.out_dim
        head, head_dim = mlp(sizes.policy_mlp, self.state.out_dim + self.conditioning_dim + self.num_actions + 1,
                             batchnorm=policy_batchnorm)
        self.head = nn.Sequential(head, nn.Linear(head_dim, domain.num_actions))

    def encode_conditioning(self, cond: Conditioning) -> torch.Tensor:
        """``(A, H)``: each attempt row's instruction vector (no corrections)."""
        return self.instruction(cond.instruction_ids)

    def action_logits(self, obs: torch.Tensor, z: torch.Tensor, previous: PreviousStep | None = None) -> torch.Tensor:
        """Logits ``(B, num_actions)``; ``previous`` is required (the state before each one)."""
        return self.head_logits(self.encode_states(obs, previous), z, previous)

    def encode_states(self, obs: torch.Tensor, previous: PreviousStep | None = None) -> torch.Tensor:
        """``(B, S)``: the current and previous frames through the state encoder (what
        ``action_logits`` computes without ``z``)."""
        if previous is None:
            raise ValueError("MIVOA acts on the current and the previous step: pass previous=PreviousStep(...)")
        return self.state(torch.cat([obs, previous.observations], dim=-1))  # channels (grid) or features (vector)

    def head_logits(self, states: torch.Tensor, z: torch.Tensor, previous: PreviousStep | None = None) -> torch.Tensor:
        """Logits from ``encode_states``'s output, ``z`` and the previous action."""
        if previous is None:
            raise ValueError("MIVOA acts on the current and the previous step: pass previous=PreviousStep(...)")
        none = torch.full_like(previous.actions, self.num_actions)
        action = nn.functional.one_hot(torch.where(previous.actions < 0, none, previous.actions), self.num_actions + 1)
        return self.head(torch.cat([states, z, action.to(z.dtype)], dim=1))

    def forward(self, obs: torch.Tensor, cond: Conditioning, attempt_rows: torch.Tensor,
                previous: PreviousStep | None = None) -> torch.Tensor:
        """Logits for states ``obs (B, *O)``; ``attempt_rows (B,)`` picks each state's row of ``cond``."""
        return self.action_logits(obs, self.encode_conditioning(cond)[attempt_rows], previous)

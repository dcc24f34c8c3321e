"""The GPL network (paper §4 and appendix "Training and Architecture Details") and its variants.

Three modules:

- **instruction module**: shared word embeddings -> 1-D CNN -> MLP, giving ``z_im``;
- **correction module**: for every earlier attempt ``j`` of the task, its trajectory subsampled every
  ``trajectory_stride`` states (``gpl_dist.roles.trajectory_times``: from t = 0, or ending at the
  attempt's last state with ``ModelConfig.trajectory_ends_at_last_state``) goes through a per-state
  encoder and a 1-D CNN over time -> MLP; the
  correction given after it goes through the shared embeddings, a 1-D CNN and an MLP; each
  (trajectory, correction) pair goes through an MLP, and the pairs are averaged: ``z_cm``;
- **policy module**: state encoder, concatenated with ``z_im`` and ``z_cm`` -> MLP -> action logits.

``z_im`` and ``z_cm`` depend only on the attempt, not on the state, so ``encode_conditioning`` runs
once per attempt in a batch (``Conditioning`` holds one row per distinct attempt) and
``forward`` gathers the rows each state needs.

Variants (``ModelConfig.variant``): ``gpl`` (the paper's model), ``instruction_only`` (no correction
module), ``full_information`` (the instruction is the full-information text, no corrections),
``no_instruction``, ``no_trajectory`` and ``latest_correction`` (only the newest pair) ablations;
``gpr`` (the paper's reward-guided variant: each earlier attempt's summed reward, through an MLP,
in place of its correction; the trajectory path stays).
``mivoa`` and ``mivoa_full_information`` build another network, ``gpl_dist.models.mivoa``.
"""

from __future__ import annotations

import dataclasses

import torch
from torch import nn

from gpl_dist.models.layers import (
    ACTIVATIONS,
    Conditioning,
    GridStateEncoder,
    TextEncoder,
    ValueEncoder,
    VectorStateEncoder,
    conv1d_k2_channels_last,
    grid_categories,
    mlp,
)
from gpl_dist.models.sizes import Sizes
from gpl_dist.roles import DomainSpec
from gpl_dist.variants import FULL_INFORMATION, WITHOUT_CORRECTIONS

VARIANTS_WITHOUT_CORRECTIONS = WITHOUT_CORRECTIONS
#: Variants conditioned on the oracle's full-information text in place of the instruction.
FULL_INFORMATION_VARIANTS = FULL_INFORMATION


class TrajectoryEncoder(nn.Module):
    """Subsampled trajectory ``(B, S, *O)`` -> vector: per-state encoder, 1-D CNN over time, MLP."""

    def __init__(self, domain: DomainSpec, sizes: Sizes, final_activation: bool = True, conv_batchnorm: bool = False,
                 hidden_layernorm: bool = False, activation: str = "relu"):
        super().__init__()
        if len(domain.obs_shape) == 3:
            self.state: nn.Module = GridStateEncoder(domain.obs_shape, grid_categories(domain), sizes.traj_state_channels,
                                                     sizes.traj_state_mlp, conv_batchnorm, activation)
        else:
            self.state = VectorStateEncoder(domain.obs_shape)
        steps = domain.trajectory_samples
        self.conv = nn.Conv1d(self.state.out_dim, sizes.traj_conv, kernel_size=min(2, steps))
        self.conv_activation = ACTIVATIONS[activation]()
        self.mlp, self.out_dim = mlp(sizes.traj_mlp, sizes.traj_conv * (steps - min(2, steps) + 1), final_activation,
                                     hidden_layernorm=hidden_layernorm, activation=activation)

    def forward(self, traj: torch.Tensor) -> torch.Tensor:
        b, s = traj.shape[:2]
        x = self.state(traj.reshape(b * s, *traj.shape[2:])).reshape(b, s, -1)
        if self.conv.kernel_size[0] == 2:
            x = self.conv_activation(conv1d_k2_channels_last(self.conv, x)).transpose(1, 2)
        else:  # a one-sample trajectory
            x = self.conv_activation(self.conv(x.transpose(1, 2)))
        return self.mlp(x.flatten(1))


class GPLPolicy(nn.Module):
    """The GPL network for one domain; ``variant`` selects the paper's baselines and ablations."""

    def __init__(self, domain: DomainSpec, variant: str = "gpl", embedding_dim: int = 16,
                 policy_batchnorm: bool = False, paraphrases: bool = False, linear_encodings: bool = False,
                 conv_batchnorm: bool = False, encoder_layernorm: bool = False, correction_width: int = 0,
                 encoder_activation: str = "relu", sizes: Sizes | None = None):
        super().__init__()
        act = encoder_activation
        self.domain_name = domain.name
        relu_out = not linear_encodings  # the last layer of each conditioning encoder
        self.variant = variant
        sizes = sizes or domain.model_sizes
        if correction_width:
            sizes = dataclasses.replace(sizes, correction_mlp=sizes.correction_mlp[:-1] + (correction_width,))
        #: the words this network reads (``DomainSpec.vocabulary_for``): text is encoded with it
        self.vocabulary = vocab = domain.vocabulary_for(paraphrases)
        self.embedding = nn.Embedding(vocab.size, embedding_dim, padding_idx=vocab.pad_id)
        #: full information as numbers (relocation's block and coordinates), read by an MLP
        self.numeric_full_information = variant == "full_information" and domain.full_information_values is not None
        if self.numeric_full_information:
            width = len(domain.full_information_values(0))  # type: ignore[misc]
            self.instruction: TextEncoder | ValueEncoder = ValueEncoder(width, sizes.instruction_mlp, relu_out,
                                                                        encoder_layernorm, act)
        else:
            self.instruction = TextEncoder(self.embedding, vocab.max_tokens, sizes.text_conv, sizes.instruction_mlp,
                                           relu_out, encoder_layernorm, act)
        # GPR: the summed reward of each earlier attempt, in place of its correction
        self.correction: TextEncoder | ValueEncoder = (
            ValueEncoder(1, sizes.correction_mlp, relu_out, encoder_layernorm, act) if variant == "gpr"
            else TextEncoder(self.embedding, vocab.max_tokens, sizes.text_conv, sizes.correction_mlp, relu_out,
                             encoder_layernorm, act))
        self.trajectory = TrajectoryEncoder(domain, sizes, relu_out, conv_batchnorm, encoder_layernorm, act)
        self.pair, pair_dim = mlp(sizes.pair_mlp, self.trajectory.out_dim + self.correction.out_dim,
                                  final_activation=sizes.pair_final_relu and relu_out, hidden_layernorm=encoder_layernorm,
                                  activation=act)
        if len(domain.obs_shape) == 3:
            self.state: nn.Module = GridStateEncoder(domain.obs_shape, grid_categories(domain), sizes.state_channels,
                                                     sizes.state_mlp, conv_batchnorm)
        else:
            self.state = VectorStateEncoder(domain.obs_shape)
        self.conditioning_dim = self.instruction.out_dim + pair_dim
        head, head_dim = mlp(sizes.policy_mlp, self.state.out_dim + self.conditioning_dim, batchnorm=policy_batchnorm)
        self.head = nn.Sequential(head, nn.Linear(head_dim, domain.num_actions))

    #: Whether ``action_logits`` needs each state's ``PreviousStep`` (``gpl_dist.models.mivoa``): no.
    uses_previous_step = False

    @property
    def uses_corrections(self) -> bool:
        return self.variant not in VARIANTS_WITHOUT_CORRECTIONS

    def encode_conditioning(self, cond: Conditioning) -> torch.Tensor:
        """``(A, conditioning_dim)``: ``[z_im, z_cm]`` for each attempt row of ``cond``."""
        if self.numeric_full_information:
            if cond.instruction_values is None:
                raise ValueError(f"the {self.domain_name} full-information model reads numbers: "
                                 "Conditioning.instruction_values is missing")
            z_im = self.instruction(cond.instruction_values)
        else:
            z_im = self.instruction(cond.instruction_ids)
        if self.variant == "no_instruction":
            z_im = torch.zeros_like(z_im)
        a = z_im.shape[0]
        pair_dim = self.conditioning_dim - z_im.shape[1]
        mask = cond.slots >= 0
        if not self.uses_corrections or cond.trajectories.shape[0] == 0 or not bool(mask.any()):
            return torch.cat([z_im, z_im.new_zeros(a, pair_dim)], dim=1)
        if self.variant == "latest_correction":
            newest = mask.long().cumsum(1) == mask.long().sum(1, keepdim=True)
            mask = mask & newest
        z_traj = self.trajectory(cond.trajectories)
        if self.variant == "no_trajectory":
            z_traj = torch.zeros_like(z_traj)
        pairs = self.pair(torch.cat([z_traj, self._encode_corrections(cond)], dim=1))  # (U, P)
        gathered = pairs[cond.slots.clamp(min=0)] * mask.unsqueeze(-1).to(pairs.dtype)  # (A, K, P)
        counts = mask.sum(1, keepdim=True).clamp(min=1).to(pairs.dtype)
        return torch.cat([z_im, gathered.sum(1) / counts], dim=1)

    def _encode_corrections(self, cond: Conditioning) -> torch.Tensor:
        """``(U, C)``: each earlier attempt's correction, or for GPR its summed reward (symlog:
        sums span -1e3..5e2 across domains and attempts)."""
        if self.variant != "gpr":
            return self.correction(cond.correction_ids)
        if cond.correction_values is None:
            raise ValueError("GPR reads each earlier attempt's summed reward: Conditioning.correction_values is missing")
        r = cond.correction_values.float()
        if bool(torch.isnan(r).any()):
            raise ValueError("GPR got an attempt without a recorded reward sum (a buffer written before schema 3): "
                             "train GPR on a buffer collected by this version")
        return self.correction((torch.sign(r) * torch.log1p(r.abs())).unsqueeze(1))

    def action_logits(self, obs: torch.Tensor, z: torch.Tensor, previous=None) -> torch.Tensor:
        """Logits ``(B, num_actions)`` for states ``obs`` under per-state conditioning ``z``
        (``previous``, the step before each state, is for policies that use it; GPL does not)."""
        return self.head_logits(self.encode_states(obs, previous), z, previous)

    def encode_states(self, obs: torch.Tensor, previous=None) -> torch.Tensor:
        """``(B, S)``: the state encoder's output for ``obs`` (the part of ``action_logits`` that
        does not read ``z``; the learner runs it beside ``encode_conditioning``)."""
        return self.state(obs)

    def head_logits(self, states: torch.Tensor, z: torch.Tensor, previous=None) -> torch.Tensor:
        """Logits from ``encode_states``'s output and per-state conditioning ``z``."""
        return self.head(torch.cat([states, z], dim=1))

    def forward(self, obs: torch.Tensor, cond: Conditioning, attempt_rows: torch.Tensor, previous=None) -> torch.Tensor:
        """Logits for states ``obs (B, *O)``; ``attempt_rows (B,)`` picks each state's row of ``cond``."""
        z = self.encode_conditioning(cond)
        return self.action_logits(obs, z[attempt_rows])

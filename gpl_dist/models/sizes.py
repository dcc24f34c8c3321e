"""Layer sizes of the GPL network: each domain declares its own in its ``DomainSpec.model_sizes``.

Kept apart from the network (no torch here) so that a domain's declaration can name its sizes.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Sizes:
    """Layer sizes of one domain (appendix values)."""

    state_channels: tuple[int, ...]  # 2-D CNN filters of the policy's state encoder (grid obs)
    state_mlp: tuple[int, ...]
    traj_state_channels: tuple[int, ...]  # 2-D CNN filters of the per-state trajectory encoder
    traj_state_mlp: tuple[int, ...]
    traj_conv: int  # 1-D CNN filters over time
    traj_mlp: tuple[int, ...]
    text_conv: int  # 1-D CNN filters over words
    correction_mlp: tuple[int, ...]
    instruction_mlp: tuple[int, ...]
    pair_mlp: tuple[int, ...]
    # whether the pair MLP's last layer has a ReLU. Relocation: no. With it, all 32 output units
    # of that layer died in round 1 of one run (relocation's early corrections carry little
    # signal) and a dead layer never recovers: the policy then ignored every correction.
    pair_final_relu: bool
    policy_mlp: tuple[int, ...]

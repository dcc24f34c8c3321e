"""Layer sizes of the GPL network: each domain declares its own in its ``DomainSpec.model_sizes``.

Kept apart from the network (no torch here) so that a domain's declaration can name its sizes.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Mapping


@dataclass(frozen=True)
class Sizes:
    """Layer sizes of one domain (appendix values). A run may override each field under ``model.``
    in its config (``gpl_dist.config.ModelConfig``; ``Sizes.overridden``).

    Attributes:
        state_channels: filters of each 2-D convolution of the policy's state encoder (grid
            observations; the first is a 2x2 convolution over the one-hot codes); unused for vectors.
        state_mlp: hidden widths of the MLP after the policy's state convolutions (grid observations).
        traj_state_channels: filters of each 2-D convolution that encodes one state of an earlier
            attempt (grid observations).
        traj_state_mlp: widths of the MLP after those convolutions (grid observations).
        traj_conv: filters of the 1-D convolution over an earlier attempt's encoded states (time).
        traj_mlp: widths of the MLP after it; the last is the trajectory encoding's width.
        text_conv: filters of the 1-D convolution over the words of an instruction or correction.
        correction_mlp: widths of the correction encoder's MLP; the last is its encoding's width.
        instruction_mlp: widths of the instruction encoder's MLP; the last is its encoding's width.
        pair_mlp: widths of the MLP that reads an (attempt, correction) pair; the last is its width.
        pair_final_relu: whether that MLP's last layer ends in a ReLU (relocation: no; narrow
            last layers can die whole, and a dead layer never recovers).
        policy_mlp: hidden widths of the policy's MLP over the state and the conditioning.
    """

    state_channels: tuple[int, ...]
    state_mlp: tuple[int, ...]
    traj_state_channels: tuple[int, ...]
    traj_state_mlp: tuple[int, ...]
    traj_conv: int
    traj_mlp: tuple[int, ...]
    text_conv: int
    correction_mlp: tuple[int, ...]
    instruction_mlp: tuple[int, ...]
    pair_mlp: tuple[int, ...]
    pair_final_relu: bool
    policy_mlp: tuple[int, ...]

    def overridden(self, values: Mapping[str, Any]) -> "Sizes":
        """These sizes with every field of ``values`` that is not None put in its place."""
        return dataclasses.replace(self, **{k: v for k, v in values.items() if v is not None})


#: The field names of ``Sizes``, in order (each is also a ``model.`` config key).
SIZE_FIELDS = tuple(f.name for f in dataclasses.fields(Sizes))

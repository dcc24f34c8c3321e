"""Dead ReLU units in GPL's conditioning encoders: a failure that the loss does not show.

A ReLU unit that is never positive gets no gradient; only a later round's different states can
bring it back. When the narrow output of an encoder dies whole, the policy stops seeing what the
encoder reads (a run whose correction encoding dies whole never uses a correction); when most
hidden units of the trajectory path die, it reads the earlier attempts through a few units
(``docs/history.md`` has the runs where both happened). The learner counts them after each round
on a probe of the round's states; the driver logs the counts and warns. A unit that is positive but
the same for every input counts as alive here, though it carries nothing either.

MIVOA's instruction encoder is an LSTM, whose units are never "never positive" (tanh): there a unit
is dead when it is constant over the probe's attempts (saturated gates, or weights that ignore the
words), and the one layer counted is the instruction vector the policy reads (``mivoa_health``).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from gpl_dist.models.gpl import GPLPolicy
from gpl_dist.models.layers import ACTIVATIONS
from gpl_dist.models.mivoa import MIVOAPolicy

#: The activation modules whose units are counted: a unit is dead when it is never positive (for
#: LeakyReLU, one that only passes its small negative slope).
ACTIVATION_MODULES = tuple(ACTIVATIONS.values())

#: The conditioning encoders of ``gpl_dist.models.gpl.GPLPolicy`` that are checked, in this order.
ENCODERS = ("instruction", "correction", "trajectory", "pair")
#: States of the round's training view the counts are taken over (spread evenly over the view).
PROBE_STATES = 4096
#: A MIVOA instruction unit is constant when its range over the probe is at most this fraction of
#: the largest magnitude of the instruction vector (float32 noise of an input-independent unit).
CONSTANT_TOLERANCE = 1e-5


@dataclass(frozen=True)
class EncoderHealth:
    """Dead units of one conditioning encoder over a probe batch.

    Attributes:
        encoder: one of ``ENCODERS``.
        units: ReLU units in the encoder's MLP layers (``nn.ReLU`` modules; convolutions not counted).
        dead_units: of those, the units never positive over the probe.
        output_units: units of the encoder's last layer when that layer ends in a ReLU, else 0
            (a linear encoding cannot die).
        dead_output_units: of those, the units never positive.
        dead_layers: ReLU layers whose every unit is dead. One is enough to make the encoding the
            same for every input: the layers run one after another.
    """

    encoder: str
    units: int
    dead_units: int
    output_units: int
    dead_output_units: int
    dead_layers: int

    @property
    def constant(self) -> bool:
        """A whole ReLU layer is dead: the encoding no longer depends on the encoder's input (a
        linear encoding too), so the policy no longer sees that input."""
        return self.dead_layers > 0

    @property
    def output_dead(self) -> bool:
        """Every unit of a ReLU encoding is dead: the policy no longer sees this input."""
        return self.output_units > 0 and self.dead_output_units == self.output_units

    def to_list(self) -> list:
        return [self.encoder, self.units, self.dead_units, self.output_units, self.dead_output_units, self.dead_layers]

    @classmethod
    def from_list(cls, row: list) -> "EncoderHealth":
        """The six values ``to_list`` writes (a round's record of any shape: ``learner.rounds.read_round``);
        ``ValueError`` for another number."""
        if len(row) != 6:
            raise ValueError(f"an encoder's health is 6 values, not {len(row)}")
        return cls(str(row[0]), int(row[1]), int(row[2]), int(row[3]), int(row[4]), int(row[5]))


def encoder_health(model: nn.Module, cond) -> tuple[EncoderHealth, ...]:
    """Dead units of each of ``ENCODERS`` that ``model.encode_conditioning(cond)`` runs (MIVOA:
    ``mivoa_health``); ``()`` for another model. The model's mode is left as it was."""
    if isinstance(model, MIVOAPolicy):
        return mivoa_health(model, cond)
    if not isinstance(model, GPLPolicy):
        return ()
    encoders = [(name, getattr(model, name)) for name in ENCODERS]
    alive: dict[tuple[str, int], torch.Tensor] = {}
    output_layer: dict[str, int] = {}  # the index of the ReLU that is the encoder's last layer, if one is
    hooks = []
    for name, mod in encoders:
        relus = [m for m in mod.modules()
                 if isinstance(m, ACTIVATION_MODULES) and m is not getattr(mod, "conv_activation", None)]
        for i, relu in enumerate(relus):
            if relu is _last_layer(mod):
                output_layer[name] = i
            def seen(_m, _inp, out, key=(name, i)):
                positive = (out.detach().reshape(-1, out.shape[-1]) > 0).any(0)
                alive[key] = positive if key not in alive else alive[key] | positive
            hooks.append(relu.register_forward_hook(seen))
    was_training = model.training
    model.eval()
    try:
        with torch.no_grad():
            model.encode_conditioning(cond)
    finally:
        model.train(was_training)
        for h in hooks:
            h.remove()
    return tuple(_count(name, alive, output_layer.get(name)) for name, _ in encoders if any(k[0] == name for k in alive))


def mivoa_health(model: MIVOAPolicy, cond) -> tuple[EncoderHealth, ...]:
    """MIVOA's instruction encoder (an LSTM, then the mean over words): its units are the
    instruction vector's, dead when constant over the probe's attempts; its one layer is dead
    whole when the vector is the same for every instruction. ``()`` for a probe of fewer than two
    distinct instructions (nothing could vary)."""
    if len({tuple(row.tolist()) for row in cond.instruction_ids}) < 2:
        return ()
    was_training = model.training
    model.eval()
    try:
        with torch.no_grad():
            z = model.encode_conditioning(cond).float().cpu()
    finally:
        model.train(was_training)
    spread = z.max(0).values - z.min(0).values
    dead = int((spread <= CONSTANT_TOLERANCE * max(float(z.abs().max()), 1e-12)).sum())
    units = int(z.shape[1])
    return (EncoderHealth("instruction", units, dead, units, dead, int(dead == units)),)


def _count(name: str, alive: dict[tuple[str, int], torch.Tensor], output_layer: int | None) -> EncoderHealth:
    layers = [alive[k].cpu() for k in sorted(k for k in alive if k[0] == name)]
    units = sum(int(a.numel()) for a in layers)
    dead = sum(int((~a).sum()) for a in layers)
    out = alive[(name, output_layer)].cpu() if output_layer is not None else None
    return EncoderHealth(name, units, dead, 0 if out is None else int(out.numel()),
                         0 if out is None else int((~out).sum()), sum(not bool(a.any()) for a in layers))


def _last_layer(mod: nn.Module) -> nn.Module | None:
    """The last layer of the encoder's output MLP (``mod.mlp`` for the text, value and trajectory
    encoders; the pair MLP is itself a Sequential)."""
    seq = mod if isinstance(mod, nn.Sequential) else getattr(mod, "mlp", None)
    return seq[-1] if isinstance(seq, nn.Sequential) and len(seq) else None


def format_health(health: tuple[EncoderHealth, ...]) -> str:
    """``dead i 0/32 c 4/20 t 18/52 p 31/32`` (dead / ReLU units per encoder)."""
    return "dead " + " ".join(f"{h.encoder[0]} {h.dead_units}/{h.units}" for h in health)

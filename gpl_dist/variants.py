"""The methods a run can train (``model.variant``): the one table every module reads.

GPL (the paper's model), its baselines and ablations, GPR, and MIVOA. A new method is a row here
and, where it changes the network, a branch in ``gpl_dist.models`` (``docs/design.md``).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Variant:
    """One method.

    Attributes:
        name: its ``model.variant`` value.
        network: ``gpl`` (``gpl_dist.models.gpl.GPLPolicy``) or ``mivoa`` (``gpl_dist.models.mivoa``).
        corrections: it reads earlier attempts and their feedback, so a task gets several attempts.
        full_information: it reads the oracle's full information in place of the instruction.
        instruction: it reads the task's instruction (so the instruction-swap control applies).
        teachable: a person can correct it (``gpl-dist teach``): it reads the text of corrections.
        summary: what it is, in a line.
    """

    name: str
    network: str
    corrections: bool
    full_information: bool
    instruction: bool
    teachable: bool
    summary: str


VARIANTS: dict[str, Variant] = {v.name: v for v in (
    Variant("gpl", "gpl", True, False, True, True, "the paper's model: instruction, earlier attempts and their corrections"),
    Variant("instruction_only", "gpl", False, False, True, False, "baseline: the instruction alone, one attempt"),
    Variant("full_information", "gpl", False, True, False, False, "baseline: the oracle's full information, one attempt"),
    Variant("no_instruction", "gpl", True, False, False, True, "ablation: corrections without the instruction"),
    Variant("no_trajectory", "gpl", True, False, True, True, "ablation: corrections without the earlier trajectories"),
    Variant("latest_correction", "gpl", True, False, True, True, "ablation: only the newest (trajectory, correction) pair"),
    Variant("gpr", "gpl", True, False, True, False, "GPR: each earlier attempt's summed reward in place of its correction"),
    Variant("mivoa", "mivoa", False, False, True, False, "MIVOA (Misra et al. 2017): the instruction through an LSTM"),
    Variant("mivoa_full_information", "mivoa", False, True, False, False, "MIVOA reading the full information"),
)}

#: Names of the variants with each property (read from ``VARIANTS``).
WITHOUT_CORRECTIONS = tuple(n for n, v in VARIANTS.items() if not v.corrections and v.network == "gpl")
FULL_INFORMATION = tuple(n for n, v in VARIANTS.items() if v.full_information)
MIVOA = tuple(n for n, v in VARIANTS.items() if v.network == "mivoa")
TEACHABLE = tuple(n for n, v in VARIANTS.items() if v.teachable)
READS_INSTRUCTION = tuple(n for n, v in VARIANTS.items() if v.instruction)

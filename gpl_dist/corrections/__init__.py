"""Correction oracles: the paper's computational proxy for a human giving corrections.

``make_corrector(domain, kind)`` returns an object with ``correct(env, rng) -> Correction`` (called
once an attempt has ended, on the env in its final state) and ``full_information(env) -> str``.
Each domain declares its kinds and its oracle factory in its ``DomainSpec`` (``gpl_dist.domains``).
"""

from __future__ import annotations

from gpl_dist.domains import get_domain
from gpl_dist.errors import UsageError
from gpl_dist.roles import CorrectionOracle

#: Kinds whose text is the same after every attempt, whatever it did (the retry control): an
#: encoder of such a correction is constant by design, which the report's health gate allows.
CONSTANT_KINDS = ("retry",)


def make_corrector(domain: str, kind: str = "default") -> CorrectionOracle:
    """Correction oracle of ``domain``; ``kind`` picks the variant (``default`` = the paper's)."""
    spec = get_domain(domain)
    if kind not in spec.correction_kinds:
        raise UsageError(f"unknown {domain} correction kind '{kind}' (known: {', '.join(spec.correction_kinds)})")
    return spec.make_corrector(kind)

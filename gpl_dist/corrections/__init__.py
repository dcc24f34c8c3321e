"""Correction oracles: the paper's computational proxy for a human giving corrections.

``make_corrector(domain, kind)`` returns an object with ``correct(env, rng) -> Correction`` (called
once an attempt has ended, on the env in its final state) and ``full_information(env) -> str``.
"""

from __future__ import annotations

import importlib

from gpl_dist.roles import CorrectionOracle

_ORACLES = {
    "multiroom": "gpl_dist.corrections.multiroom:make_multiroom_corrector",
    "relocation": "gpl_dist.corrections.relocation:make_relocation_corrector",
}


def correction_kinds(domain: str) -> tuple[str, ...]:
    """The correction kinds ``make_corrector(domain, kind)`` accepts (``default`` is the paper's oracle)."""
    if domain not in _ORACLES:
        raise ValueError(f"unknown domain '{domain}' (known: {', '.join(_ORACLES)})")
    module = _ORACLES[domain].split(":")[0]
    return tuple(importlib.import_module(module).KINDS)


def make_corrector(domain: str, kind: str = "default") -> CorrectionOracle:
    """Correction oracle of ``domain``; ``kind`` picks the variant (``default`` = the paper's)."""
    if domain not in _ORACLES:
        raise ValueError(f"unknown domain '{domain}' (known: {', '.join(_ORACLES)})")
    module, fn = _ORACLES[domain].split(":")
    return getattr(importlib.import_module(module), fn)(kind)

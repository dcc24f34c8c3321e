"""Look up a domain's ``DomainSpec`` by name; the env module is imported only when asked for."""

from __future__ import annotations

import importlib

from gpl_dist.roles import DomainSpec

_MODULES = {
    "multiroom": "gpl_dist.envs.multiroom",
    "relocation": "gpl_dist.envs.relocation",
}

DOMAIN_NAMES = tuple(_MODULES)


def get_domain(name: str) -> DomainSpec:
    """The ``DomainSpec`` of ``name`` (``multiroom`` or ``relocation``)."""
    if name not in _MODULES:
        raise ValueError(f"unknown domain '{name}' (known: {', '.join(DOMAIN_NAMES)})")
    return importlib.import_module(_MODULES[name]).DOMAIN

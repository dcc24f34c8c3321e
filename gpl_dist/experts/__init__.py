"""Experts: near-optimal actions from any state, with privileged access to the env.

``make_expert(env, kind)`` returns an expert of ``env``'s domain; ``expert.act(env)`` gives the
action for the env's current state, ``expert.label(env)`` the action and the distribution the
learner fits. ``env`` may be wrapped (as ``gymnasium.make`` returns it) or not. Kinds:
``scripted`` (every domain: planners over the simulator's state) and, for relocation, ``learned``
(an MLP given the exact target, trained by DAgger on the scripted expert and then by PPO, like
the authors' learned experts; ``gpl_dist.experts.relocation_learned``).
"""

from __future__ import annotations

import importlib
from typing import Any

from gpl_dist.roles import Expert

_EXPERTS = {
    "multiroom": {"scripted": "gpl_dist.experts.multiroom:MultiRoomExpert"},
    "relocation": {"scripted": "gpl_dist.experts.relocation:RelocationExpert",
                   "learned": "gpl_dist.experts.relocation_learned:LearnedRelocationExpert"},
}


def expert_kinds(domain: str) -> tuple[str, ...]:
    """The expert kinds ``make_expert`` accepts for ``domain``."""
    if domain not in _EXPERTS:
        raise ValueError(f"unknown domain '{domain}' (known: {', '.join(_EXPERTS)})")
    return tuple(_EXPERTS[domain])


def check_expert_kind(domain: str, kind: str) -> None:
    """Raise ``ValueError`` naming the known kinds unless ``domain`` has an expert of ``kind``."""
    if domain not in _EXPERTS:
        raise ValueError(f"unknown domain '{domain}' (known: {', '.join(_EXPERTS)})")
    if kind not in _EXPERTS[domain]:
        raise ValueError(f"unknown expert '{kind}' for {domain} (known: {', '.join(_EXPERTS[domain])})")


def domain_of(env: Any) -> str:
    """The domain name of a (possibly wrapped) gpl-dist env."""
    name = getattr(getattr(env, "unwrapped", env), "domain_name", None)
    if name not in _EXPERTS:
        raise TypeError(f"{type(env).__name__} is not a gpl-dist env (no known domain_name)")
    return name


def make_expert(env: Any, kind: str = "scripted") -> Expert:
    """The ``kind`` expert for ``env``'s domain (one instance can serve every task of the domain)."""
    domain = domain_of(env)
    check_expert_kind(domain, kind)
    module, cls = _EXPERTS[domain][kind].split(":")
    return getattr(importlib.import_module(module), cls)()

"""Experts: near-optimal actions from any state, with privileged access to the env.

``make_expert(env)`` returns the expert of ``env``'s domain; ``expert.act(env)`` gives the action
for the env's current state. ``env`` may be wrapped (as ``gymnasium.make`` returns it) or not.
"""

from __future__ import annotations

import importlib
from typing import Any

from gpl_dist.roles import Expert

_EXPERTS = {
    "multiroom": "gpl_dist.experts.multiroom:MultiRoomExpert",
    "relocation": "gpl_dist.experts.relocation:RelocationExpert",
}


def domain_of(env: Any) -> str:
    """The domain name of a (possibly wrapped) gpl-dist env."""
    name = getattr(getattr(env, "unwrapped", env), "domain_name", None)
    if name not in _EXPERTS:
        raise TypeError(f"{type(env).__name__} is not a gpl-dist env (no known domain_name)")
    return name


def make_expert(env: Any) -> Expert:
    """The expert for ``env``'s domain (one instance can serve every task of the domain)."""
    module, cls = _EXPERTS[domain_of(env)].split(":")
    return getattr(importlib.import_module(module), cls)()

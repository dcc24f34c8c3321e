"""Experts: near-optimal actions from any state, with privileged access to the env.

``make_expert(env, kind)`` returns an expert of ``env``'s domain; ``expert.act(env)`` gives the
action for the env's current state, ``expert.label(env)`` the action and the distribution the
learner fits. ``env`` may be wrapped (as ``gymnasium.make`` returns it) or not. Kinds:
``scripted`` (every domain: planners over the simulator's state) and, for relocation, ``learned``
(an MLP given the exact target, trained by DAgger on the scripted expert and then by PPO, like
the authors' learned experts; ``gpl_dist.experts.relocation_learned``).
"""

from __future__ import annotations

from typing import Any

from gpl_dist.domains import get_domain
from gpl_dist.errors import UsageError
from gpl_dist.roles import Expert


def expert_kinds(domain: str) -> tuple[str, ...]:
    """The expert kinds ``make_expert`` accepts for ``domain`` (the first is the default)."""
    return tuple(get_domain(domain).experts)


def check_expert_kind(domain: str, kind: str) -> None:
    """Raise ``ValueError`` naming the known kinds unless ``domain`` has an expert of ``kind``."""
    kinds = expert_kinds(domain)
    if kind not in kinds:
        raise UsageError(f"unknown expert '{kind}' for {domain} (known: {', '.join(kinds)})")


def domain_of(env: Any) -> str:
    """The domain name of a (possibly wrapped) gpl-dist env."""
    name = getattr(getattr(env, "unwrapped", env), "domain_name", None)
    try:
        get_domain(str(name))
    except ValueError:
        raise TypeError(f"{type(env).__name__} is not a gpl-dist env (no known domain_name)") from None
    return str(name)


def make_expert(env: Any, kind: str | None = None) -> Expert:
    """The ``kind`` expert for ``env``'s domain (default: the domain's first kind, ``scripted`` for
    the built-in domains); one instance can serve every task of the domain."""
    domain = domain_of(env)
    kind = kind or expert_kinds(domain)[0]
    check_expert_kind(domain, kind)
    return get_domain(domain).experts[kind]()

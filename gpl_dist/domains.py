"""The domain registry: each domain is one ``DomainSpec``, declared once and looked up by name.

Config validation, the CLI, the worker, the model, the learner and evaluation all read a domain's
facts from here (experts, correction kinds, model sizes, splits, the paper's figures). The built-in
domains are imported only when first asked for; ``register_domain`` adds another one (a new
module's ``DOMAIN``, or one defined in a test), and registers its gymnasium id too. See
``docs/adding-a-domain.md``.
"""

from __future__ import annotations

import importlib

from gpl_dist.errors import UsageError
from gpl_dist.roles import DomainSpec

#: Built-in domains: name -> module whose import registers its ``DOMAIN``.
BUILTIN_DOMAINS = {
    "multiroom": "gpl_dist.envs.multiroom",
    "relocation": "gpl_dist.envs.relocation",
}

_REGISTERED: dict[str, DomainSpec] = {}


def register_domain(spec: DomainSpec) -> DomainSpec:
    """Add ``spec`` to the registry (and its env id to gymnasium's); returns it.

    Registering the same spec again is a no-op; another spec under a taken name is an error.
    """
    from gymnasium.envs.registration import register, registry

    taken = _REGISTERED.get(spec.name)
    if taken is not None and taken is not spec:
        raise ValueError(f"a different domain named '{spec.name}' is already registered")
    problems = _spec_problems(spec)
    if problems:
        raise ValueError(f"domain '{spec.name}': {'; '.join(problems)}")
    _REGISTERED[spec.name] = spec
    if spec.env_id not in registry:
        register(id=spec.env_id, entry_point=spec.make_env, max_episode_steps=spec.steps_per_attempt)
    return spec


def unregister_domain(name: str) -> None:
    """Remove a domain registered with ``register_domain`` (tests); built-ins come back on next use."""
    from gymnasium.envs.registration import registry

    spec = _REGISTERED.pop(name, None)
    if spec is not None:
        registry.pop(spec.env_id, None)


def domain_names() -> tuple[str, ...]:
    """Every known domain name (built-in first), without importing any domain."""
    return tuple(BUILTIN_DOMAINS) + tuple(n for n in _REGISTERED if n not in BUILTIN_DOMAINS)


def get_domain(name: str) -> DomainSpec:
    """The ``DomainSpec`` of ``name``; ``ValueError`` naming the known domains otherwise."""
    if name not in _REGISTERED and name in BUILTIN_DOMAINS:
        register_domain(importlib.import_module(BUILTIN_DOMAINS[name]).DOMAIN)
    if name not in _REGISTERED:
        raise UsageError(f"unknown domain '{name}' (known: {', '.join(domain_names())})")
    return _REGISTERED[name]


def _spec_problems(spec: DomainSpec) -> list[str]:
    checks = [
        (bool(spec.experts), "declares no expert"),
        ("default" in spec.correction_kinds, "correction_kinds must include 'default' (the paper's oracle)"),
        (spec.num_tasks >= 1 and spec.num_actions >= 1 and spec.steps_per_attempt >= 1, "needs tasks, actions and steps"),
        (spec.trajectory_stride >= 1, "trajectory_stride must be at least 1"),
        (len(spec.obs_shape) != 3 or spec.obs_categories is not None, "grid observations need obs_categories"),
        (spec.splits is None or set(spec.splits) == set(spec.split_names), "splits must name exactly split_names"),
    ]
    return [message for ok, message in checks if not ok]

"""The domain registry: each domain is one ``DomainSpec``, declared once and looked up by name.

Config validation, the CLI, the worker, the model, the learner and evaluation all read a domain's
facts from here (experts, correction kinds, model sizes, splits, the paper's figures). The built-in
domains are imported only when first asked for; ``register_domain`` adds another one (a new
module's ``DOMAIN``, or one defined in a test), and registers its gymnasium id too.

A domain from outside the package comes in one of two ways (``docs/adding-a-domain.md``):

- an installed package declares it under the entry-point group ``gpl_dist.domains``
  (``corridor = "mypkg.corridor"``: the name is the domain's, the module defines ``DOMAIN``);
  every process finds it by name, Ray actors too;
- a run's config names the module or ``.py`` file that defines it, ``env.domain_module``; the
  config travels with the run (its workers, ``eval``, ``--resume``), so each imports it again.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import sys
from importlib.metadata import entry_points
from pathlib import Path

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


#: The entry-point group an installed package declares its domains under.
ENTRY_POINT_GROUP = "gpl_dist.domains"


def _plugins() -> dict[str, str]:
    """Domain name -> module of every installed plug-in (entry points), without importing any."""
    return {ep.name: ep.value for ep in entry_points(group=ENTRY_POINT_GROUP)}


def domain_names() -> tuple[str, ...]:
    """Every known domain name (built-in first, then plug-ins and registered ones), importing none."""
    names = list(BUILTIN_DOMAINS)
    for name in (*_plugins(), *_REGISTERED):
        if name not in names:
            names.append(name)
    return tuple(names)


def get_domain(name: str) -> DomainSpec:
    """The ``DomainSpec`` of ``name``; ``UsageError`` naming the known domains otherwise."""
    if name not in _REGISTERED and name in BUILTIN_DOMAINS:
        register_domain(importlib.import_module(BUILTIN_DOMAINS[name]).DOMAIN)
    if name not in _REGISTERED and name in _plugins():
        load_domain_module(_plugins()[name].split(":")[0])
    if name not in _REGISTERED:
        raise UsageError(f"unknown domain '{name}' (known: {', '.join(domain_names())})")
    return _REGISTERED[name]


def load_domain_module(ref: str) -> tuple[str, ...]:
    """Import ``ref`` (a dotted module name, or the path of a ``.py`` file) and register the
    ``DomainSpec`` it defines as ``DOMAIN``; returns the names registered. Importing it again (the
    same path, in a worker that already has it) registers nothing new."""
    ref = str(ref).strip()
    if ref.endswith(".py"):
        path = Path(ref).expanduser().resolve()
        if not path.is_file():
            raise UsageError(f"domain module {ref}: no such file")
        name = f"gpl_dist_domain_{path.stem}_{hashlib.sha256(str(path).encode()).hexdigest()[:12]}"
        module = sys.modules.get(name)
        if module is None:
            spec = importlib.util.spec_from_file_location(name, path)
            if spec is None or spec.loader is None:
                raise UsageError(f"domain module {ref}: not a Python file")
            module = importlib.util.module_from_spec(spec)
            sys.modules[name] = module
            try:
                spec.loader.exec_module(module)
            except Exception:
                del sys.modules[name]
                raise
    else:
        try:
            module = importlib.import_module(ref)
        except ModuleNotFoundError as err:
            raise UsageError(f"domain module {ref}: {err}") from None
    domain = getattr(module, "DOMAIN", None)
    if not isinstance(domain, DomainSpec):
        raise UsageError(f"domain module {ref} defines no DOMAIN (a gpl_dist.roles.DomainSpec)")
    return (register_domain(domain).name,)


def _spec_problems(spec: DomainSpec) -> list[str]:
    checks = [
        (bool(spec.experts), "declares no expert"),
        ("default" in spec.correction_kinds, "correction_kinds must include 'default' (the paper's oracle)"),
        (spec.num_tasks >= 1 and spec.num_actions >= 1 and spec.steps_per_attempt >= 1, "needs tasks, actions and steps"),
        (spec.trajectory_stride >= 1, "trajectory_stride must be at least 1"),
        (len(spec.obs_shape) != 3 or spec.obs_categories is not None, "grid observations need obs_categories"),
        (spec.splits is None or set(spec.splits) == set(spec.split_names), "splits must name exactly split_names"),
        (set(spec.valid_splits) | set(spec.valid_splits.values()) <= set(spec.split_names),
         "valid_splits must map split_names to split_names"),
        (not any("test" in v for v in spec.valid_splits.values()), "a valid split must not be a test split"),
    ]
    return [message for ok, message in checks if not ok]

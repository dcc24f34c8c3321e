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

Reading data never runs code: a config read from a run dir or a checkpoint (data, which anyone may
have written) imports its ``env.domain_module`` only when ``domain_module_allowed`` says so: the
module is an installed entry point's, or was imported already in this process, or this machine
trained with that very file (the path and sha256 that ``trust_domain_module`` recorded when a user's
own config named it), or the user passed ``--trust-domain-module`` (``trust_all_domain_modules``).
Otherwise ``PluginRefused`` names the file and its sha256. Commands that only read a run (``verify``,
``inspect``, ``suite report|status|restore``) never import it at all.
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import importlib.util
import json
import os
import sys
from importlib.metadata import entry_points
from pathlib import Path

from gpl_dist.atomic import write_atomic
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
        register(id=spec.env_id, entry_point=_env_maker(spec), max_episode_steps=spec.steps_per_attempt)
    return spec


def _env_maker(spec: DomainSpec):
    """``gym.make``'s entry point of a domain: its ``make_env``, which needs the task; without one,
    a ``TypeError`` that says how to name it (a gpl-dist env is one task, never a drawn one)."""
    def make(task_id: int | None = None, **kwargs):
        if task_id is None:
            raise TypeError(f"{spec.env_id} is one task of {spec.num_tasks}: name it, e.g. "
                            f"gymnasium.make('{spec.env_id}', task_id=0) (task ids 0..{spec.num_tasks - 1}; "
                            "gpl_dist.splits.load_splits gives each split's)")
        return spec.make_env(task_id, **kwargs)

    return make


def make_task_env(domain: str, task_id: int, **kwargs):
    """The env of ``domain``'s task ``task_id``: an importable entry point for an env spec that
    travels with data (a Minari dataset's ``env_spec``: ``recover_environment(task_id=...)``)."""
    return get_domain(domain).make_env(task_id, **kwargs)


def unregister_domain(name: str) -> None:
    """Remove a domain registered with ``register_domain`` (tests); built-ins come back on next use."""
    from gymnasium.envs.registration import registry

    spec = _REGISTERED.pop(name, None)
    if spec is not None:
        registry.pop(spec.env_id, None)


#: The entry-point group an installed package declares its domains under.
ENTRY_POINT_GROUP = "gpl_dist.domains"


@functools.lru_cache(maxsize=1)
def _plugins() -> dict[str, str]:
    """Domain name -> module of every installed plug-in (entry points), without importing any
    (read once per process: installing a package takes a new process to be seen)."""
    return {ep.name: ep.value for ep in entry_points(group=ENTRY_POINT_GROUP)}


def domain_names() -> tuple[str, ...]:
    """Every known domain name (built-in first, then plug-ins and registered ones), importing none."""
    names = list(BUILTIN_DOMAINS)
    for name in (*_plugins(), *_REGISTERED):
        if name not in names:
            names.append(name)
    return tuple(names)


def is_loaded(name: str) -> bool:
    """Whether ``name`` is known without importing anything that is not gpl-dist's own: a built-in
    domain, or one registered in this process (an installed plug-in is not, until looked up)."""
    return name in _REGISTERED or name in BUILTIN_DOMAINS


def get_domain(name: str) -> DomainSpec:
    """The ``DomainSpec`` of ``name``; ``UsageError`` naming the known domains otherwise."""
    if name not in _REGISTERED and name in BUILTIN_DOMAINS:
        register_domain(importlib.import_module(BUILTIN_DOMAINS[name]).DOMAIN)
    if name not in _REGISTERED and name in _plugins():
        load_domain_module(_plugins()[name].split(":")[0])
    if name not in _REGISTERED:
        raise UsageError(f"unknown domain '{name}' (known: {', '.join(domain_names())})")
    return _REGISTERED[name]


class PluginRefused(UsageError):
    """A run's config names a domain module that this process may not import unasked."""


#: Environment variable naming the file of trusted plug-in files (default: under XDG_CONFIG_HOME).
TRUST_FILE_ENV = "GPL_DIST_TRUST_FILE"
_TRUST_ALL = False


def trust_file() -> Path:
    """The file that lists the plug-in files this machine's user trained with (path and sha256)."""
    if os.environ.get(TRUST_FILE_ENV):
        return Path(os.environ[TRUST_FILE_ENV])
    base = os.environ.get("XDG_CONFIG_HOME") or os.path.join(os.path.expanduser("~"), ".config")
    return Path(base) / "gpl-dist" / "trusted-domain-modules.json"


def trust_all_domain_modules(on: bool = True) -> None:
    """``--trust-domain-module``: let this process import the domain module a run's config names."""
    global _TRUST_ALL
    _TRUST_ALL = on


def _module_key(ref: str) -> tuple[str, str]:
    """What a domain module reference is trusted as: (resolved path, sha256 of its bytes) for a file;
    (dotted name, "") for a module."""
    ref = str(ref).strip()
    if not ref.endswith(".py"):
        return ref, ""
    path = Path(ref).expanduser().resolve()
    try:
        digest = hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        digest = ""
    return str(path), digest


def _trusted() -> list[dict]:
    """The entries of the trust file (``trust_file``): a JSON list of ``{"module", "sha256"}``, the
    one shape it has been written in (``trust_domain_module``). A file that is missing or no JSON
    list trusts nothing, and an entry that is no object is left out: trust is then asked for again."""
    try:
        entries = json.loads(trust_file().read_text()[: 1 << 20])
    except (OSError, ValueError):
        return []
    return [e for e in entries if isinstance(e, dict)] if isinstance(entries, list) else []


def trust_domain_module(ref: str) -> None:
    """Record ``ref`` (its path and the sha256 of the bytes this process ran, or its module name)
    as trusted by this machine's user: a run made from the user's own config."""
    name, digest = _module_key(ref)
    digest = _RAN.get(name, digest)
    entry = {"module": name, "sha256": digest}
    entries = _trusted()
    if entry in entries:
        return
    path = trust_file()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(path, json.dumps([*entries, entry], indent=1) + "\n")
    except OSError:
        pass  # trust is then asked for again next time; nothing else is lost


def _loaded(ref: str) -> bool:
    ref = str(ref).strip()
    if not ref.endswith(".py"):
        return ref in sys.modules
    return _file_module_name(Path(ref).expanduser().resolve()) in sys.modules


def _entry_point_modules() -> set[str]:
    return {value.split(":")[0] for value in _plugins().values()}


def domain_module_allowed(ref: str) -> str | None:
    """Return when the domain module ``ref`` that a run's data names may be imported (see the module
    docstring): the sha256 of the file approved (its import must run exactly those bytes,
    ``load_domain_module(ref, sha256)``), None for a module or one imported already;
    ``PluginRefused`` naming it otherwise."""
    name, digest = _module_key(ref)
    if _loaded(ref):
        return None
    if _TRUST_ALL:
        return digest or None
    if not digest and name in _entry_point_modules():
        return None
    if {"module": name, "sha256": digest} in _trusted():
        return digest
    if digest:
        raise PluginRefused(f"this run's config names the plug-in file {name} (sha256 {digest}), which no run of "
                            "this machine was started from: read it, then pass --trust-domain-module to import it")
    if ref.strip().endswith(".py"):
        raise PluginRefused(f"domain module {ref}: no such file")
    raise PluginRefused(f"this run's config names the module {name[:200]}, which no installed package declares as a "
                        f"'{ENTRY_POINT_GROUP}' entry point: pass --trust-domain-module to import it")


def _file_module_name(path: Path) -> str:
    return f"gpl_dist_domain_{path.stem}_{hashlib.sha256(str(path).encode()).hexdigest()[:12]}"


#: resolved path of each plug-in file this process ran -> the sha256 of the bytes it ran
_RAN: dict[str, str] = {}


def load_domain_module(ref: str, sha256: str | None = None) -> tuple[str, ...]:
    """Import ``ref`` (a dotted module name, or the path of a ``.py`` file) and register the
    ``DomainSpec`` it defines as ``DOMAIN``; returns the names registered. Importing it again (the
    same path, in a worker that already has it) registers nothing new. A file is read once and
    those bytes run (never a cached ``.pyc`` beside it); with ``sha256`` (the digest approved,
    ``domain_module_allowed``) they must have it, or nothing runs (``PluginRefused``)."""
    ref = str(ref).strip()
    if ref.endswith(".py"):
        path = Path(ref).expanduser().resolve()
        if not path.is_file():
            raise UsageError(f"domain module {ref}: no such file")
        name = _file_module_name(path)
        module = sys.modules.get(name)
        if module is None:
            data = path.read_bytes()
            digest = hashlib.sha256(data).hexdigest()
            if sha256 is not None and digest != sha256:
                raise PluginRefused(f"the plug-in file {path} changed while it was checked (sha256 {digest}, "
                                    f"approved {sha256}): not imported")
            spec = importlib.util.spec_from_loader(name, loader=None, origin=str(path))
            if spec is None:
                raise UsageError(f"domain module {ref}: not a Python file")
            module = importlib.util.module_from_spec(spec)
            module.__file__ = str(path)
            sys.modules[name] = module
            try:
                exec(compile(data, str(path), "exec"), module.__dict__)  # noqa: S102 - the approved bytes, as asked
            except Exception:
                del sys.modules[name]
                raise
            _RAN[str(path)] = digest
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

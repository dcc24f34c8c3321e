"""Run configuration: frozen dataclasses whose fields each carry a one-line docstring.

YAML files in ``configs/`` hold values only. ``load_config`` rejects an unknown key, a value of the
wrong type or a missing file with one line naming it (``ConfigError``). Each component receives
only its own section (``cfg.collection`` for workers, ``cfg.training`` for the learner, ...), and
the resolved config is written next to every run as ``config.yaml``.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import os
import re
import reprlib
import textwrap
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import yaml

from gpl_dist.errors import UserError
from gpl_dist.language import PHRASINGS
from gpl_dist.variants import VARIANTS


class ConfigError(UserError, ValueError):
    """A config file or override is invalid; the message is one line naming the culprit."""


@dataclass(frozen=True)
class EnvConfig:
    """The ``env`` section: domain, tasks, correction oracle and expert."""

    domain: str = "multiroom"
    """Domain to meta-train on: ``multiroom``, ``relocation`` or a registered plug-in domain."""
    domain_module: str = ""
    """Module (dotted name) or .py file whose import registers ``domain`` (a domain from outside gpl-dist)."""
    train_split: str = ""
    """Versioned split whose tasks are collected on during meta-training ("": the domain's ``train_split``)."""
    max_train_tasks: int = 0
    """Use only the first N tasks of the training split (0 uses all of them)."""
    task_ids: tuple[int, ...] = ()
    """Meta-train on exactly these task ids instead of the training split (empty uses the split)."""
    correction_kind: str = "default"
    """Correction oracle variant: default (the domain's paper oracle) or a kind the domain lists."""
    expert: str = ""
    """Expert that labels visited states ("": the domain's first; relocation also has learned, a PPO-tuned MLP)."""


@dataclass(frozen=True)
class CollectionConfig:
    """The ``collection`` section: rollout workers and how they act."""

    num_workers: int = 2
    """Rollout actors on Ray (ignored with --serial, which runs one in-process worker)."""
    num_corrections: int = 5
    """Corrections per task per round; a task gets at most num_corrections + 1 attempts."""
    tasks_per_unit: int = 64
    """Tasks in one work unit; a worker steps all of them in lockstep with one batched forward."""
    greedy_actions: bool = False
    """Act with the policy's most likely action instead of sampling during collection."""
    max_unit_retries: int = 3
    """How often a failed work unit is handed out again before the round fails."""
    unit_timeout_s: float = 1800.0
    """Most seconds a unit may be out on a Ray actor with no result before it is a failed try and the actor replaced."""
    unit_timeout_multiple: float = 10.0
    """A unit's timeout on Ray: this many times the run's median unit time so far (within the floor and unit_timeout_s)."""
    unit_timeout_floor_s: float = 60.0
    """Least seconds a unit may be out on a Ray actor with no result (the adaptive timeout's floor; unit_timeout_s caps it)."""


@dataclass(frozen=True)
class BufferConfig:
    """The ``buffer`` section: where the buffer lives and how much the learner reads."""

    capacity_tuples: int = 1_000_000
    """First-in-first-out capacity of the training view, in labelled states."""
    location: str = ""
    """Buffer root (local path or fsspec URL); empty puts it at RUN_DIR/buffer."""


#: ``ModelConfig.encoder_activation``'s values (``gpl_dist.models.layers.ACTIVATIONS`` maps them to modules).
ENCODER_ACTIVATIONS = ("relu", "leaky_relu")


@dataclass(frozen=True)
class ModelConfig:
    """The ``model`` section: the variant and the architecture's switches."""

    variant: str = "gpl"
    """gpl, gpr, a baseline (instruction_only, full_information, mivoa, mivoa_full_information) or an ablation (no_*)."""
    embedding_dim: int = 16
    """Size of the word embeddings shared by the instruction and correction modules."""
    trajectory_ends_at_last_state: bool = False
    """Sample earlier attempts every stride-th state ending at their last (the state its correction describes)."""
    policy_batchnorm: bool = False
    """BatchNorm1d after every hidden layer of the policy module's MLP (the authors' code has it)."""
    paraphrases: bool = False
    """Train on the domain's training paraphrases of instructions and corrections (their words join the vocabulary)."""
    linear_encodings: bool = False
    """End GPL's instruction, correction, trajectory and pair encoders linear, not in a ReLU (narrow ReLU outputs can all die)."""
    conv_batchnorm: bool = False
    """BatchNorm2d after each 2-D conv of the grid state encoders (policy, trajectory, MIVOA's), as in the authors' code."""
    encoder_layernorm: bool = False
    """LayerNorm before each hidden ReLU of GPL's instruction, correction, trajectory and pair MLPs (narrow layers die whole)."""
    correction_width: int = 0
    """Output width of GPL's correction encoder (0: the domain's appendix value, 4 in multi-room; the authors' code: 32)."""
    encoder_activation: str = "relu"
    """Activation of GPL's conditioning encoders (convolutions and MLPs): relu (the paper's) or leaky_relu (no dead zone)."""
    # Layer sizes (``gpl_dist.models.sizes.Sizes``): null keeps the domain's (``gpl-dist config --domain NAME`` shows them).
    state_channels: tuple[int, ...] | None = None
    """Filters of each 2-D convolution of the policy's state encoder, grid observations (null: the domain's)."""
    state_mlp: tuple[int, ...] | None = None
    """Hidden widths of the MLP after the policy's state convolutions, grid observations (null: the domain's)."""
    traj_state_channels: tuple[int, ...] | None = None
    """Filters of each 2-D convolution encoding one state of an earlier attempt, grid observations (null: the domain's)."""
    traj_state_mlp: tuple[int, ...] | None = None
    """Widths of the MLP after the trajectory's state convolutions, grid observations (null: the domain's)."""
    traj_conv: int | None = None
    """Filters of the 1-D convolution over an earlier attempt's states in time (null: the domain's)."""
    traj_mlp: tuple[int, ...] | None = None
    """Widths of the trajectory encoder's MLP; the last is the encoding's width (null: the domain's)."""
    text_conv: int | None = None
    """Filters of the 1-D convolution over the words of an instruction or correction (null: the domain's)."""
    correction_mlp: tuple[int, ...] | None = None
    """Widths of the correction encoder's MLP, the last its encoding's (null: the domain's; correction_width sets the last)."""
    instruction_mlp: tuple[int, ...] | None = None
    """Widths of the instruction encoder's MLP; the last is the encoding's width (null: the domain's)."""
    pair_mlp: tuple[int, ...] | None = None
    """Widths of the MLP over an (attempt, correction) pair; the last is its encoding's width (null: the domain's)."""
    pair_final_relu: bool | None = None
    """Whether that pair MLP's last layer ends in a ReLU (null: the domain's; narrow last layers can die whole)."""
    policy_mlp: tuple[int, ...] | None = None
    """Hidden widths of the policy's MLP over the state and the conditioning (null: the domain's)."""


#: ``ModelConfig``'s layer sizes: the fields of ``gpl_dist.models.sizes.Sizes`` (a test checks they match).
LAYER_SIZE_KEYS = tuple(f.name for f in dataclasses.fields(ModelConfig) if f.default is None)


@dataclass(frozen=True)
class TrainingConfig:
    """The ``training`` section: DAgger rounds and the learner."""

    num_rounds: int = 10
    """DAgger rounds (collect, commit, train) to run."""
    num_epochs_per_round: int = 5
    """Full passes over the committed buffer view after each round's collection."""
    learning_rate: float = 1e-3
    """Adam learning rate."""
    batch_size: int = 512
    """Labelled states per gradient step."""
    states_per_chunk: int = 16
    """States of one attempt kept together when shuffling (1 shuffles states independently)."""
    device: str = "auto"
    """Torch device for the learner: auto (CUDA when present), cpu or cuda."""
    num_threads: int = 1
    """Torch threads per learner process; more stall beside other busy processes, sum irreproducibly (0: cores / learners)."""
    conditioning_thread: bool = False
    """Encode each step's conditioning (per attempt) on a second thread beside the states (per state): bitwise the same."""
    num_learners: int = 1
    """Data-parallel learner processes, batch_size split among them (0: one per core of the driver's machine)."""
    engine: str = "processes"
    """Where the learners run: processes on the driver's machine, or ray-train (a Ray Train group anywhere on the cluster)."""
    autocast: str = "none"
    """Learner arithmetic: none (fp32) or bf16 (torch.autocast; on a CPU only with native bf16: avx512_bf16 or amx_bf16)."""


@dataclass(frozen=True)
class EvalConfig:
    """The ``eval`` section: meta-test settings."""

    split: str = ""
    """Split of held-out tasks for meta-testing ("": the domain's ``eval_split``)."""
    num_corrections: int = 5
    """Corrections given at meta-test time (completion is reported after 0..num_corrections)."""
    seeds: tuple[int, ...] = (0, 1, 2)
    """Seeds of the meta-test repetitions; the table reports their mean."""
    greedy_actions: bool = False
    """Act with the most likely action at meta-test time instead of sampling (greedy policies loop)."""
    max_tasks: int = 0
    """Evaluate only the first N tasks of the split (0 evaluates all of them)."""
    phrasings: str = "canonical"
    """Say instructions and corrections as the oracle does (canonical), or as train or heldout paraphrases."""


#: The (section, key) fields a config may leave "" for its domain to fill (``RunConfig.__post_init__``:
#: its first expert, its training and evaluation splits); they stay "" while a plug-in domain is not
#: loaded (a read-only command).
DOMAIN_FILLED = (("env", "expert"), ("env", "train_split"), ("eval", "split"))


@dataclass(frozen=True)
class RunConfig:
    """A whole run's config: the seed and one section per component."""

    seed: int = 0
    """Seed of the run; tasks, rollouts, corrections and weights derive theirs from it."""
    env: EnvConfig = field(default_factory=EnvConfig)
    """Domain and task selection."""
    collection: CollectionConfig = field(default_factory=CollectionConfig)
    """Rollout workers."""
    buffer: BufferConfig = field(default_factory=BufferConfig)
    """Sharded buffer."""
    model: ModelConfig = field(default_factory=ModelConfig)
    """GPL network and its variants."""
    training: TrainingConfig = field(default_factory=TrainingConfig)
    """Central learner."""
    eval: EvalConfig = field(default_factory=EvalConfig)
    """Meta-test evaluation."""

    def __post_init__(self) -> None:
        """Fields left "" take the domain's defaults (its first expert, its training and evaluation
        splits), once the domain is known (a plug-in's module loads in ``config_from_dict``)."""
        from gpl_dist.domains import get_domain, is_loaded

        if any(getattr(getattr(self, part), key) == "" for part, key in DOMAIN_FILLED) and is_loaded(self.env.domain):
            spec = get_domain(self.env.domain)
            object.__setattr__(self, "env", dataclasses.replace(
                self.env, expert=self.env.expert or next(iter(spec.experts)),
                train_split=self.env.train_split or spec.train_split))
            object.__setattr__(self, "eval", dataclasses.replace(self.eval, split=self.eval.split or spec.eval_split))


def field_docs(cls: type) -> dict[str, str]:
    """The docstring under each field of dataclass ``cls`` (fields without one are absent)."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    body = tree.body[0].body  # type: ignore[attr-defined]
    docs: dict[str, str] = {}
    for stmt, nxt in zip(body, body[1:]):
        if isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name):
            if isinstance(nxt, ast.Expr) and isinstance(nxt.value, ast.Constant) and isinstance(nxt.value.value, str):
                docs[stmt.target.id] = nxt.value.value.strip()
    return docs


@dataclass(frozen=True)
class KeyDoc:
    """One config key as ``gpl-dist config`` lists it: its dotted name, type, default and doc."""

    key: str
    type: str
    default: Any
    doc: str


def describe_keys(section: str | None = None, domain: str | None = None) -> list[KeyDoc]:
    """Every config key (of ``section`` only, when given) with its type, default and one-line doc.
    With ``domain`` (a registered domain), the defaults it gives are filled in: its expert, its
    training and evaluation splits, and its layer sizes (``model.*``)."""
    sections = {f.name: f for f in dataclasses.fields(RunConfig)}
    if section is not None and section not in sections:
        raise ConfigError(f"no config section '{section}' (sections: {', '.join(sections)})")
    defaults = RunConfig() if domain is None else config_from_dict({"env": {"domain": domain}}, plugins="none")
    sizes: dict[str, Any] = {}
    if domain is not None:
        from gpl_dist.domains import get_domain

        spec = get_domain(domain)
        sizes = {f.name: getattr(spec.model_sizes, f.name) for f in dataclasses.fields(spec.model_sizes)}
    out = []
    top_docs = field_docs(RunConfig)
    for name, f in sections.items():
        if section is not None and name != section:
            continue
        value = getattr(defaults, name)
        if not dataclasses.is_dataclass(value):
            out.append(KeyDoc(name, _type_name(typing.get_type_hints(RunConfig)[name]), value, top_docs.get(name, "")))
            continue
        cls = type(value)
        hints, docs = typing.get_type_hints(cls), field_docs(cls)
        for sub in dataclasses.fields(value):
            default = getattr(value, sub.name)
            if name == "model" and default is None and sub.name in sizes:
                default = sizes[sub.name]
            tp = hints[sub.name]
            out.append(KeyDoc(f"{name}.{sub.name}", str(tp).replace("typing.", "") if typing.get_origin(tp) else
                              _type_name(tp), default, docs.get(sub.name, "")))
    return out


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", str(tp))


_SCIENTIFIC = re.compile(r"^[+-]?(\d+(\.\d*)?|\.\d+)[eE][+-]?\d+$")


def _coerce(value: Any, tp: Any, where: str) -> Any:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType) and type(None) in typing.get_args(tp):  # X | None: null allowed
        if value is None:
            return None
        (inner,) = [a for a in typing.get_args(tp) if a is not type(None)]
        return _coerce(value, inner, where)
    if tp in (int, float) and isinstance(value, str) and _SCIENTIFIC.match(value.strip()):
        # YAML 1.1 reads "1e6" as a string; people write buffer sizes that way.
        value = float(value)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, Mapping):
            raise ConfigError(f"{where}: expected a mapping for section, got {type(value).__name__}")
        return _build(typing.cast(type, tp), value, where)
    if origin is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: expected a list, got {type(value).__name__} {bounded_repr(value)}")
        item_tp = args[0]
        return tuple(_coerce(v, item_tp, f"{where}[{i}]") for i, v in enumerate(value))
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected bool, got {type(value).__name__} {bounded_repr(value)}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            # 1e6 is a float in YAML; accept it when it is integral, as people write buffer sizes so.
            if isinstance(value, float) and value.is_integer():
                return int(value)
            raise ConfigError(f"{where}: expected int, got {type(value).__name__} {bounded_repr(value)}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected float, got {type(value).__name__} {bounded_repr(value)}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected str, got {type(value).__name__} {bounded_repr(value)}")
        return value
    raise ConfigError(f"{where}: unsupported config type {_type_name(tp)}")


def _build(cls: type, values: Mapping[str, Any], where: str) -> Any:
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    for key in values:
        if key not in names:
            prefix = f"{where}." if where else ""
            raise ConfigError(f"unknown config key '{prefix}{key}' (known: {', '.join(sorted(names))})")
    kwargs = {}
    for key, value in values.items():
        kwargs[key] = _coerce(value, hints[key], f"{where}.{key}" if where else key)
    return cls(**kwargs)


def eval_config_from_dict(values: Mapping[str, Any], where: str = "eval") -> EvalConfig:
    """An ``EvalConfig`` from a mapping (a suite's named evaluation): unknown keys and wrong types
    fail in one line naming ``where``; the split is checked with the run's domain."""
    if not isinstance(values, Mapping):
        raise ConfigError(f"{where}: expected a mapping, got {type(values).__name__}")
    cfg = _build(EvalConfig, values, where)
    checks = [
        _one_of(f"{where}.phrasings", cfg.phrasings, PHRASINGS),
        (0 <= cfg.num_corrections <= MAX_CORRECTIONS, f"{where}.num_corrections must be in 0..{MAX_CORRECTIONS}"),
        (cfg.max_tasks >= 0, f"{where}.max_tasks must be >= 0 (0 evaluates every task of the split)"),
    ]
    for ok, message in checks:
        if not ok:
            raise ConfigError(message)
    return cfg


#: How a config's ``env.domain_module`` is treated (``config_from_dict``'s ``plugins``):
#: ``own``: the user's own config file: import it (and remember the file as trusted, ``gpl_dist.domains``);
#: ``run``: a config read from a run dir or a checkpoint (data): import it only where
#: ``gpl_dist.domains.domain_module_allowed`` says so, else ``PluginRefused`` in one line;
#: ``none``: import nothing (commands that only read a run): a domain that is not known without it
#: keeps the values the saved config holds, unchecked against the domain.
PLUGIN_POLICIES = ("own", "run", "none")


def config_from_dict(values: Mapping[str, Any] | None, source: str = "<dict>", plugins: str = "run") -> RunConfig:
    """Build a ``RunConfig`` from nested mappings; unspecified fields keep their defaults.
    ``plugins`` (``PLUGIN_POLICIES``) says whether its domain module may be imported."""
    values = values or {}
    if not isinstance(values, Mapping):
        raise ConfigError(f"{source}: top level must be a mapping, got {type(values).__name__}")
    try:
        cfg = _build(RunConfig, values, "")
    except ConfigError as err:
        raise ConfigError(f"{source}: {err}") from None
    cfg = _with_domain_defaults(cfg, source, plugins)
    from gpl_dist.domains import is_loaded

    if plugins == "none" and not is_loaded(cfg.env.domain):
        return cfg  # a plug-in domain (a file's or an installed package's), read without importing it
    validate(cfg, source)
    return cfg


def _with_domain_defaults(cfg: RunConfig, source: str, plugins: str = "run") -> RunConfig:
    """``cfg`` with its domain's module imported (``env.domain_module``, as ``plugins`` allows) and
    the fields left "" set to the domain's defaults (expert, training and evaluation splits); an
    unknown domain is left for ``validate`` to name."""
    from gpl_dist.domains import domain_module_allowed, domain_names, get_domain, load_domain_module, trust_domain_module

    if plugins not in PLUGIN_POLICIES:
        raise ValueError(f"plugins must be one of {PLUGIN_POLICIES}, got {plugins!r}")
    if cfg.env.domain_module and plugins != "none":
        try:
            approved = domain_module_allowed(cfg.env.domain_module) if plugins == "run" else None
            load_domain_module(cfg.env.domain_module, approved)
            if plugins == "own":
                trust_domain_module(cfg.env.domain_module)
        except UserError as err:
            raise ConfigError(f"{source}: env.domain_module: {err}") from None
    if plugins == "own" and cfg.env.domain_module.strip().endswith(".py"):
        # the user's own file, recorded absolute: the run's eval, teach and --resume find it from any folder
        absolute = str(Path(cfg.env.domain_module.strip()).expanduser().resolve())
        cfg = dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, domain_module=absolute))
    if plugins != "none" and cfg.env.domain in domain_names():
        get_domain(cfg.env.domain)  # an installed plug-in's module: imported to build the domain, never to read a run
    return dataclasses.replace(cfg)  # __post_init__ again, now that a plug-in domain is registered


def set_override(tree: dict, dotted: str, raw: str) -> None:
    """Set the dotted key ``dotted`` of the config ``tree`` to the YAML value ``raw`` (``--set``);
    ``ConfigError`` in one line for a value too long, malformed, or under a non-section."""
    keys = dotted.split(".")
    node = tree
    for key in keys[:-1]:
        node = node.setdefault(key, {})
        if not isinstance(node, dict):
            raise ConfigError(f"override {dotted}: '{key}' is not a section")
    if len(raw) > MAX_OVERRIDE_CHARS:
        raise ConfigError(f"override {dotted}: the value is {len(raw)} characters long; at most {MAX_OVERRIDE_CHARS}")
    try:
        node[keys[-1]] = yaml.load(raw, Loader=_UniqueKeyLoader)
    except yaml.YAMLError as err:
        problem = getattr(err, "problem", None)
        reason = f" ({problem})" if isinstance(problem, str) and problem.startswith(_OWN_PROBLEMS) else ""
        raise ConfigError(f"override {dotted}={raw[:80]!r}: the value is not valid YAML{reason}") from None
    except ValueError:  # e.g. an integer of more than 4300 digits
        raise ConfigError(f"override {dotted}={raw[:80]!r}: the value is not valid YAML") from None


def load_config(path: str | os.PathLike | None, overrides: Mapping[str, str] | None = None,
                plugins: str = "run") -> RunConfig:
    """Load a YAML config, then apply ``overrides`` (dotted key -> YAML-typed value string).
    ``plugins``: ``own`` for the user's own config file, ``run`` (default) for a run's
    ``config.yaml``, ``none`` to read it without importing its domain module (``PLUGIN_POLICIES``)."""
    tree: dict = {}
    source = "<defaults>"
    if path is not None:
        p = Path(path)
        source = str(p)
        if not p.is_file():
            raise ConfigError(f"config file not found: {p}")
        try:
            tree = load_yaml_text(p.read_text(), p) or {}
        except UnicodeDecodeError:
            raise ConfigError(f"{p} is not a text file") from None
        if not isinstance(tree, dict):
            raise ConfigError(f"{p}: top level must be a mapping")
    for dotted, raw in (overrides or {}).items():
        set_override(tree, dotted, raw)
    if overrides:
        source += " with --set " + " ".join(sorted(overrides))[:120]
    return config_from_dict(tree, source, plugins)


#: Corrections per task, in collection and at meta-test: the paper goes to 10; each one adds a
#: whole attempt and grows the conditioning of every later one.
MAX_CORRECTIONS = 100

# ablations: no_instruction, no_trajectory, latest_correction (gpl_dist.models.gpl)
_VARIANTS = tuple(VARIANTS)
_DEVICES = ("auto", "cpu", "cuda")
#: where the learners run (``training.engine``): the driver's machine, or a Ray Train worker group
ENGINES = ("processes", "ray-train")
#: the learner's arithmetic (``training.autocast``): fp32, or bf16 under ``torch.autocast``
AUTOCASTS = ("none", "bf16")


def _one_of(key: str, value: str, choices: tuple[str, ...], scope: str = "") -> tuple[bool, str]:
    return value in choices, f"{key} must be one of {', '.join(choices)}{scope}, got '{value}'"


def validate(cfg: RunConfig, source: str = "<config>") -> None:
    """Range and choice checks that types alone do not catch; the first failure raises ``ConfigError``.

    Choices that depend on the domain (correction kind, expert, splits, task ids) are checked
    against the domain's own tables, so a misspelt or domain-foreign value fails here, in one line,
    before anything is started or written.
    """
    from gpl_dist.domains import domain_names

    checks = [
        _one_of("env.domain", cfg.env.domain, domain_names()),
        _one_of("model.variant", cfg.model.variant, _VARIANTS),
        _one_of("training.device", cfg.training.device, _DEVICES),
        _one_of("training.engine", cfg.training.engine, ENGINES),
        _one_of("training.autocast", cfg.training.autocast, AUTOCASTS),
        _one_of("eval.phrasings", cfg.eval.phrasings, PHRASINGS),
        _one_of("model.encoder_activation", cfg.model.encoder_activation, ENCODER_ACTIVATIONS),
        (cfg.env.max_train_tasks >= 0, "env.max_train_tasks must be >= 0 (0 uses every task of the split)"),
        (cfg.collection.num_workers >= 1, "collection.num_workers must be at least 1"),
        (0 <= cfg.collection.num_corrections <= MAX_CORRECTIONS,
         f"collection.num_corrections must be in 0..{MAX_CORRECTIONS}, got {cfg.collection.num_corrections}"),
        (cfg.collection.tasks_per_unit >= 1, "collection.tasks_per_unit must be at least 1"),
        (cfg.collection.max_unit_retries >= 0, "collection.max_unit_retries must be >= 0"),
        (cfg.collection.unit_timeout_s > 0, "collection.unit_timeout_s must be positive"),
        (cfg.collection.unit_timeout_multiple >= 1,
         f"collection.unit_timeout_multiple must be at least 1, got {cfg.collection.unit_timeout_multiple:g}"),
        (cfg.collection.unit_timeout_floor_s > 0, "collection.unit_timeout_floor_s must be positive"),
        (cfg.buffer.capacity_tuples >= 1, "buffer.capacity_tuples must be at least 1"),
        (cfg.model.embedding_dim >= 1, "model.embedding_dim must be at least 1"),
        (cfg.model.correction_width >= 0, "model.correction_width must be >= 0 (0: the domain's appendix value)"),
        *_size_checks(cfg.model),
        (cfg.training.num_rounds >= 1, "training.num_rounds must be at least 1"),
        (cfg.training.num_epochs_per_round >= 0, "training.num_epochs_per_round must be >= 0"),
        (cfg.training.learning_rate > 0, "training.learning_rate must be positive"),
        (cfg.training.batch_size >= 1, "training.batch_size must be at least 1"),
        (cfg.training.states_per_chunk >= 1, "training.states_per_chunk must be at least 1"),
        (cfg.training.num_threads >= 0, "training.num_threads must be >= 0 (0 shares the cores out among the learners)"),
        (0 <= cfg.training.num_learners <= 64, "training.num_learners must be in 0..64 (0: one per available core)"),
        (cfg.training.engine != "ray-train" or cfg.training.num_learners >= 1,
         "training.num_learners must be at least 1 with training.engine=ray-train (0 counts this machine's cores)"),
        (0 <= cfg.eval.num_corrections <= MAX_CORRECTIONS,
         f"eval.num_corrections must be in 0..{MAX_CORRECTIONS}, got {cfg.eval.num_corrections}"),
        (len(cfg.eval.seeds) >= 1, "eval.seeds must name at least one seed"),
        (len(set(cfg.eval.seeds)) == len(cfg.eval.seeds), "eval.seeds must not repeat a seed"),
        (cfg.eval.max_tasks >= 0, "eval.max_tasks must be >= 0 (0 evaluates every task of the split)"),
    ]
    for ok, message in checks:
        if not ok:
            raise ConfigError(f"{source}: {message}")
    for ok, message in _domain_checks(cfg):
        if not ok:
            raise ConfigError(f"{source}: {message}")


def _size_checks(model: ModelConfig) -> list[tuple[bool, str]]:
    """Each layer size the ``model`` section sets: widths of at least 1, MLPs of at least one layer
    where the network needs an output width."""
    checks = []
    needs_a_layer = ("traj_mlp", "correction_mlp", "instruction_mlp", "pair_mlp")
    for name in LAYER_SIZE_KEYS:
        value = getattr(model, name)
        if value is None or isinstance(value, bool):
            continue
        widths = value if isinstance(value, tuple) else (value,)
        checks.append((all(1 <= w <= 65536 for w in widths),
                       f"model.{name} must hold widths in 1..65536, got {bounded_repr(value)}"))
        checks.append((len(widths) <= 16, f"model.{name} may have at most 16 layers, got {len(widths)}"))
        if name in needs_a_layer:
            checks.append((len(widths) >= 1, f"model.{name} needs at least one layer (its last width is its encoding's)"))
    return checks


def _domain_checks(cfg: RunConfig) -> list[tuple[bool, str]]:
    from gpl_dist.domains import get_domain
    from gpl_dist.splits import load_splits

    domain = cfg.env.domain
    spec = get_domain(domain)
    scope = f" for {domain}"
    splits = tuple(sorted(load_splits(domain)))
    num_tasks = spec.num_tasks
    bad_ids = [t for t in cfg.env.task_ids if not 0 <= t < num_tasks]
    return [
        _one_of("env.correction_kind", cfg.env.correction_kind, spec.correction_kinds, scope),
        _one_of("env.expert", cfg.env.expert, tuple(spec.experts), scope),
        _one_of("env.train_split", cfg.env.train_split, splits, scope),
        _one_of("eval.split", cfg.eval.split, splits, scope),
        (not bad_ids, f"env.task_ids {bad_ids[:5]} are outside {domain}'s tasks 0..{num_tasks - 1}"),
        (len(set(cfg.env.task_ids)) == len(cfg.env.task_ids), "env.task_ids must not repeat a task"),
        (spec.paraphrases is not None or not cfg.model.paraphrases, f"model.paraphrases: {domain} declares no paraphrases"),
        (spec.paraphrases is not None or cfg.eval.phrasings == "canonical",
         f"eval.phrasings {cfg.eval.phrasings}: {domain} declares no paraphrases"),
    ]


#: Deepest nesting of mappings and lists a config, suite file or ``--set`` value may hold.
MAX_YAML_DEPTH = 32
#: Longest config or suite file read, in characters (the shipped ones are a few kB).
MAX_YAML_CHARS = 1 << 20
#: Longest ``--set`` value, in characters.
MAX_OVERRIDE_CHARS = 10_000
_OWN_PROBLEMS = ("YAML aliases", "nested deeper")


class _UniqueKeyLoader(yaml.SafeLoader):
    """YAML's safe loader, refusing a mapping that repeats a key (PyYAML keeps the last one
    silently), aliases (``*name``: a few hundred bytes of them expand to gigabytes) and nesting
    deeper than ``MAX_YAML_DEPTH`` (which would exhaust Python's recursion limit)."""

    _depth = 0

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):
            mark = self.peek_event().start_mark
            raise yaml.composer.ComposerError(None, None, "YAML aliases (*name) are not accepted: write the value out",
                                              mark)
        if self._depth >= MAX_YAML_DEPTH:
            mark = self.peek_event().start_mark
            raise yaml.composer.ComposerError(None, None, f"nested deeper than {MAX_YAML_DEPTH} levels", mark)
        self._depth += 1
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def load_yaml_text(text: str, source: str | os.PathLike) -> Any:
    """``text`` parsed by the bounded loader (``_UniqueKeyLoader``); ``ConfigError`` in one line,
    naming ``source`` and the line, for anything it refuses or cannot parse."""
    if len(text) > MAX_YAML_CHARS:
        raise ConfigError(f"{source} is {len(text)} characters long; a config or suite file may have {MAX_YAML_CHARS}")
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)
    except (yaml.YAMLError, ValueError) as err:  # ValueError: e.g. an integer of more than 4300 digits
        mark = getattr(err, "problem_mark", None)
        line = f" line {mark.line + 1}" if mark is not None else ""
        problem = getattr(err, "problem", None)
        reason = f": {problem[:200]}" if isinstance(problem, str) else ""
        raise ConfigError(f"{source}:{line} is not valid YAML{reason}") from None


def bounded_repr(value: Any, limit: int = 80) -> str:
    """``repr(value)`` cut to about ``limit`` characters, without ever formatting more than a few
    items of a container (a value can be huge: an error message must not be)."""
    r = reprlib.Repr()
    r.maxlevel, r.maxstring, r.maxother, r.maxlong = 3, limit, limit, limit
    text = r.repr(value)
    return text if len(text) <= limit else text[:limit] + "..."


def _unique_mapping(loader: yaml.SafeLoader, node: yaml.MappingNode) -> dict:
    seen: set = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node)  # type: ignore[no-untyped-call]
        if key in seen:
            raise yaml.constructor.ConstructorError(None, None, f"repeated key '{str(key)[:80]}'", key_node.start_mark)
        seen.add(key)
    return loader.construct_mapping(node)


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _unique_mapping)


def config_to_dict(cfg: Any) -> dict:
    """Plain nested dict of a config (tuples become lists), for YAML. A field left None (a layer
    size the domain gives) is left out: the dict says only what the config sets."""
    out = {}
    for f in dataclasses.fields(cfg):
        value = getattr(cfg, f.name)
        if value is None:
            continue
        if dataclasses.is_dataclass(value):
            value = config_to_dict(value)
        elif isinstance(value, tuple):
            value = list(value)
        out[f.name] = value
    return out


#: Settings that change how fast a run trains, never what it computes (tested bitwise): a run
#: made with other values of these is the same run (``results_dict``).
SPEED_ONLY = (("training", "conditioning_thread"), ("collection", "num_workers"))


def results_dict(cfg: RunConfig) -> dict:
    """``config_to_dict(cfg)`` without the ``SPEED_ONLY`` settings: what a run's results depend on."""
    out = config_to_dict(cfg)
    for section, key in SPEED_ONLY:
        out[section].pop(key, None)
    return out


def save_config(cfg: RunConfig, path: str | os.PathLike) -> None:
    """Write the resolved config as YAML (atomically, so a crash never leaves half a file)."""
    from gpl_dist.atomic import write_atomic

    write_atomic(Path(path), yaml.safe_dump(config_to_dict(cfg), sort_keys=False))

"""What a run's own files say beside its evaluations: its health, its budget, its learning curve.

Read from an (archived) run dir: ``metrics.jsonl`` (one row a DAgger round, ``learner.rounds.RoundMetrics``),
``checkpoints/latest.pt`` (the final weights) and, where the suite computed it, ``curve-valid.json``
(completion on the run's valid split after each round, ``gpl_dist.app.suite.curves``). A curve or
swap file measured on another split than the run's valid split (``run_valid_split``) is not read as
one: such a split may hold tasks the run trained on, or test tasks.

**Health as a gate.** A run whose conditioning encoder (GPL's, or MIVOA's LSTM) has a layer dead
whole at its final round acts without that input: a policy blind to its instruction is no
instruction-only baseline. The report marks such a run as not valid and leaves it out of every
mean; a run whose rounds recorded no health (trained before MIVOA was instrumented) is kept but
marked uninstrumented.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from gpl_dist.app.suite.records import CURVE_FILE, SWAP_FILE, read_curve, read_swap
from gpl_dist.config import load_config
from gpl_dist.corrections import CONSTANT_KINDS
from gpl_dist.domains import is_loaded
from gpl_dist.errors import RunDirError, UserError
from gpl_dist.splits import valid_split
from learner.checkpoint import LATEST, load_checkpoint
from learner.health import EncoderHealth
from learner.rounds import METRICS_FILE, RoundMetrics
from learner.rounds import read_metrics as read_round_metrics

#: Entries of a state dict that are not trained parameters (BatchNorm's running statistics).
_NOT_PARAMETERS = ("running_mean", "running_var", "num_batches_tracked")


@dataclass(frozen=True)
class RunHealth:
    """A run's conditioning encoders over its rounds.

    Attributes:
        rounds: rounds recorded in ``metrics.jsonl``.
        instrumented: every round recorded its encoders' health.
        final: the last round's health, one per encoder.
        dead_layers: ``(round, encoder)`` for every round and encoder with a layer dead whole.
        constant_inputs: encoders whose input is the same for every attempt by design (the retry
            control's correction: one fixed sentence), so their encoding is constant whatever
            training does: not counted against the run.
    """

    rounds: int
    instrumented: bool
    final: tuple[EncoderHealth, ...]
    dead_layers: tuple[tuple[int, str], ...]
    constant_inputs: tuple[str, ...] = ()

    @property
    def dead_at_end(self) -> tuple[str, ...]:
        """Encoders with a layer dead whole at the final round (those of ``constant_inputs`` aside)."""
        return tuple(h.encoder for h in self.final if h.constant and h.encoder not in self.constant_inputs)

    @property
    def valid(self) -> bool:
        """No layer dead whole at the final round (an uninstrumented run counts as valid, marked so)."""
        return not self.dead_at_end

    def text(self) -> str:
        """``i 10/16 c 0/16 ...`` (dead / units per encoder at the final round) and what died whole."""
        if not self.instrumented and not self.final:
            return "not instrumented"
        units = " ".join(f"{h.encoder[0]} {h.dead_units}/{h.units}" for h in self.final)
        if not self.dead_layers:
            return f"{units}; no layer dead whole in any round"
        rounds: dict[str, list[int]] = {}
        for r, enc in self.dead_layers:
            rounds.setdefault(enc, []).append(r)
        died = "; ".join(f"{enc} dead whole in rounds {', '.join(map(str, rs))}"
                         + (" (its input is one fixed sentence: not counted)" if enc in self.constant_inputs else "")
                         for enc, rs in rounds.items())
        return f"{units}; {died}" + ("; NOT VALID (dead at the final round)" if not self.valid else "")


@dataclass(frozen=True)
class RunBudget:
    """What a run spent.

    Attributes:
        rounds: DAgger rounds trained.
        tuples: labelled tuples collected over all rounds (those of a round resumed after its
            collection are not recorded again: then ``tuples_complete`` is False).
        tuples_complete: every round recorded its collected tuples.
        gradient_steps: optimiser steps over all rounds.
        parameters: trained parameters of the final weights (None without a checkpoint).
        train_seconds: the learner's wall time over all rounds.
        collection_seconds: collection's wall time over all rounds.
    """

    rounds: int
    tuples: int
    tuples_complete: bool
    gradient_steps: int
    parameters: int | None
    train_seconds: float
    collection_seconds: float


@dataclass(frozen=True)
class LearningCurve:
    """Completion after each DAgger round.

    Attributes:
        rounds: the round indices.
        train: train-task completion during collection, ``train[i][k]`` after k corrections (the
            rollouts of round ``i``, with the weights of round ``i - 1``).
        valid: completion of each round's weights on the run's valid split, ``valid[i][k]``; ()
            when not computed, or computed on another split (``off_split``).
        valid_rounds: the rounds of ``valid``.
        off_split: the split a curve file measured when it is not the run's valid split (its
            points are then left out of ``valid``); "" otherwise.
    """

    rounds: tuple[int, ...]
    train: tuple[tuple[float, ...], ...]
    valid: tuple[tuple[float, ...], ...] = ()
    valid_rounds: tuple[int, ...] = ()
    off_split: str = ""


@dataclass(frozen=True)
class InstructionSwap:
    """Valid-split completion of a run's final weights with the tasks' own instructions and told
    another task's (``gpl_dist.app.suite.swap``).

    Attributes:
        own: completion after 0..K corrections with their own instructions.
        swapped: the same, each task told another task's instruction.
        split: the split measured (the run's valid split, ``run_valid_split``, unless measured
            before it was).
        rule: how partners were chosen (``learner.evaluate.SWAP_RULE``).
        weights_sha256: the SHA-256 of the weights measured (``checkpoints/latest.pt`` then).
    """

    own: tuple[float, ...]
    swapped: tuple[float, ...]
    split: str
    rule: str
    weights_sha256: str


def instruction_swap(run_dir: Path) -> InstructionSwap | None:
    """``InstructionSwap`` of one run dir (its ``SWAP_FILE``, ``records.SwapRecord``); None when it has none."""
    path = run_dir / SWAP_FILE
    if not path.is_file():
        return None
    record = read_swap(path)
    return InstructionSwap(tuple(float(x) for x in record.own.completion),
                           tuple(float(x) for x in record.swapped.completion),
                           record.settings.split, record.rule, record.weights_sha256)


def read_metrics(run_dir: Path) -> list[RoundMetrics]:
    """The rounds of ``run_dir/metrics.jsonl`` in the current shape (``learner.rounds.read_metrics``:
    the last record of each round, whichever shape it was written in); a missing file or a damaged
    line fails in one line naming the file."""
    path = run_dir / METRICS_FILE
    if not path.is_file():
        raise RunDirError(f"{path} is missing: the run's health and budget cannot be read")
    rounds = read_round_metrics(run_dir)
    return [rounds[r] for r in sorted(rounds)]


def run_health(run_dir: Path) -> RunHealth:
    """``RunHealth`` of one run dir (its ``config.yaml`` says whether the correction is constant)."""
    rounds = read_metrics(run_dir)
    dead = tuple((m.round_index, h.encoder) for m in rounds for h in m.encoder_health if h.constant)
    constant: tuple[str, ...] = ()
    if (run_dir / "config.yaml").is_file():
        import yaml

        try:
            env = (yaml.safe_load((run_dir / "config.yaml").read_text()) or {}).get("env") or {}
        except yaml.YAMLError as err:
            raise RunDirError(f"{run_dir / 'config.yaml'} is not YAML ({err})") from None
        if env.get("correction_kind") in CONSTANT_KINDS:
            constant = ("correction",)
    return RunHealth(len(rounds), bool(rounds) and all(m.encoder_health for m in rounds),
                     rounds[-1].encoder_health if rounds else (), dead, constant)


def run_budget(run_dir: Path) -> RunBudget:
    """``RunBudget`` of one run dir."""
    rounds = read_metrics(run_dir)
    ckpt = run_dir / "checkpoints" / LATEST
    params = None
    if ckpt.is_file():
        state = load_checkpoint(ckpt).model_state
        params = sum(int(v.numel()) for k, v in state.items()
                     if v.is_floating_point() and not k.endswith(_NOT_PARAMETERS))
    return RunBudget(len(rounds), sum(m.collected_tuples or 0 for m in rounds),
                     all(m.collected_tuples is not None for m in rounds), sum(m.train_steps for m in rounds),
                     params, sum(m.train_seconds for m in rounds), sum(m.collection_seconds for m in rounds))


@dataclass(frozen=True)
class RunSetup:
    """What a run's ``config.yaml`` says the report groups and labels it by.

    Attributes:
        domain: the run's domain (``env.domain``).
        rounds: the DAgger rounds it was configured to train (``training.num_rounds``).
        train_split: the split it trained on (the domain's default filled in where known).
        known: whether this process knows the domain without importing its module (a built-in,
            installed or registered one); where not, the domain's splits are not known here.
        valid_split: the split the run is chosen on (``gpl_dist.splits.valid_split``); None when
            its training split has none, or the domain is not known.
    """

    domain: str
    rounds: int
    train_split: str
    known: bool
    valid_split: str | None


#: What each config file says (domain, rounds, training split), keyed by its path, modification
#: time and size: a report reads each run's config once, however many of its tables ask.
_CONFIGS: dict[tuple[str, int, int], tuple[str, int, str]] = {}


def run_setup(run_dir: Path) -> RunSetup:
    """``RunSetup`` of one run dir, from its ``config.yaml`` read with no plug-in imported
    (``load_config(..., plugins="none")``): never from the name of its entry. Whether the domain
    is known is this process's answer now (a domain registered later is known from then on)."""
    path = run_dir / "config.yaml"
    try:
        stat = path.stat()
        key = (str(path.resolve()), stat.st_mtime_ns, stat.st_size)
        if key not in _CONFIGS:
            cfg = load_config(path, plugins="none")
            _CONFIGS[key] = (cfg.env.domain, cfg.training.num_rounds, cfg.env.train_split)
    except (OSError, UserError) as err:
        raise RunDirError(f"{path}: cannot read the run's domain, rounds and training split "
                          f"({type(err).__name__}: {err})") from None
    domain, rounds, train_split = _CONFIGS[key]
    known = is_loaded(domain)  # an installed plug-in is not imported to read a run
    return RunSetup(domain, rounds, train_split, known, valid_split(domain, train_split) if known else None)


def run_valid_split(run_dir: Path, unknown: str | None = None) -> str | None:
    """The split the run is chosen on: the valid split of the training split its ``config.yaml``
    names (``gpl_dist.splits.valid_split``); None when that has none. Reading a run imports no
    plug-in: for a domain this process does not know without its module, ``unknown``."""
    setup = run_setup(run_dir)
    return setup.valid_split if setup.known else unknown


def learning_curve(run_dir: Path, setup: RunSetup | None = None) -> LearningCurve:
    """``LearningCurve`` of one run dir (its valid part from ``CURVE_FILE`` when present and
    measured on the run's valid split); ``setup``: the run's ``run_setup``, where already read."""
    rounds = read_metrics(run_dir)
    valid: tuple[tuple[float, ...], ...] = ()
    valid_rounds: tuple[int, ...] = ()
    off_split = ""
    path = run_dir / CURVE_FILE
    if path.is_file():
        record = read_curve(path)
        valid_rounds = tuple(record.rounds)
        valid = tuple(tuple(float(x) for x in c) for c in record.completion)
        measured = record.settings.split
        setup = setup or run_setup(run_dir)
        if measured != (setup.valid_split if setup.known else measured):
            valid, valid_rounds, off_split = (), (), measured
    return LearningCurve(tuple(m.round_index for m in rounds), tuple(tuple(m.completion_by_corrections) for m in rounds),
                         valid, valid_rounds, off_split)

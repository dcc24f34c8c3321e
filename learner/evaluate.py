"""Meta-test evaluation (paper Algorithm 2) on held-out tasks.

For every test task and seed: attempt 0 with the instruction alone, then a correction from the
oracle after each attempt, up to ``num_corrections``; a task stops once solved and carries its
completion forward. Actions are sampled from the policy by default, as during collection
(``eval.greedy_actions: false``; the paper does not say): a greedy multi-room policy repeats the
same action in the same state and gets stuck in loops (``docs/results.md``), and the policy was
trained on the states its sampled rollouts reach. Seeds make the sampling reproducible. The expert is not queried.

``evaluate_run`` writes the evaluation file (``EvalRecord``) into the run dir: ``eval.json`` when the
run's own ``eval`` settings and latest checkpoint are used; any other setting gets its own name
(``eval-greedy.json``, ``eval-c2-seeds0_1-first3.json``, ...), so a side evaluation never replaces
the run's result. ``plot`` draws a record's curve beside the paper's (the CLI writes it as
``<stem>.png``).
"""

from __future__ import annotations

import copy
import dataclasses
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gpl_dist.atomic import savefig_atomic, write_atomic
from gpl_dist.config import ConfigError, RunConfig, config_from_dict, load_config
from gpl_dist.corrections import make_corrector
from gpl_dist.domains import get_domain
from gpl_dist.errors import CheckpointError, RunDirError, UsageError
from gpl_dist.metrics import completion_by_attempt
from gpl_dist.models.build import PolicyNetwork, build_model_from_config
from gpl_dist.models.gpl import FULL_INFORMATION_VARIANTS
from gpl_dist.seeding import evaluation_seed
from gpl_dist.splits import split_tasks, valid_split
from gpl_dist.variants import READS_INSTRUCTION
from learner.checkpoint import LATEST, Checkpoint, load_checkpoint, load_model_state
from learner.identity import read_identity, refuse_linked_folders, resolve_identity, why_not_recorded_run
from workers.rollout import Rollout


@dataclass(frozen=True)
class CorrectionEffort:
    """What it took a person (here, the oracle) to get the tasks solved, over every (seed, task).

    Attributes:
        corrections_to_solve: mean number of corrections before the first successful attempt,
            over the tasks solved within the budget; None when none was.
        unsolved_fraction: fraction of the tasks not solved within the budget.
        words_per_solved_task: mean number of words of correction given before the success, over
            the solved tasks; None when none was.
        completion_auc: area under the completion-against-corrections curve divided by its
            length (the mean of the curve by the trapezoid rule; the one value for a policy
            without corrections), in [0, 1].
    """

    corrections_to_solve: float | None
    unsolved_fraction: float
    words_per_solved_task: float | None
    completion_auc: float


def correction_effort(attempts_per_seed: list[list], completion: list[float]) -> CorrectionEffort:
    """``CorrectionEffort`` of the attempts of every seed and the mean completion curve."""
    to_solve, words, unsolved = [], [], 0
    for attempts in attempts_per_seed:
        by_task: dict[int, list] = {}
        for a in attempts:
            by_task.setdefault(a.task_id, []).append(a)
        for per in by_task.values():
            per.sort(key=lambda a: a.attempt_index)
            first = next((a.attempt_index for a in per if a.success), None)
            if first is None:
                unsolved += 1
                continue
            to_solve.append(first)
            words.append(sum(len(a.correction.split()) for a in per if a.attempt_index < first))
    total = len(to_solve) + unsolved
    n = len(completion)  # the trapezoid rule, over unit steps
    auc = (sum(completion) - (completion[0] + completion[-1]) / 2) / (n - 1) if n > 1 else float(completion[0])
    return CorrectionEffort(float(np.mean(to_solve)) if to_solve else None, unsolved / max(total, 1),
                            float(np.mean(words)) if words else None, auc)


@dataclass(frozen=True)
class EvalResult:
    """Meta-test results.

    Attributes:
        completion: mean completion after 0..K corrections, averaged over seeds.
        completion_std: standard deviation over seeds of each entry.
        success: fraction of tasks solved after 0..K corrections, averaged over seeds.
        per_seed: completion curve of each seed.
        num_tasks: tasks evaluated per seed.
        seconds: wall time.
        effort: what the corrections cost (``CorrectionEffort``).
    """

    completion: list
    completion_std: list
    success: list
    per_seed: list
    num_tasks: int
    seconds: float
    effort: CorrectionEffort


#: The evaluation file's schema (``EvalRecord.schema_version``).
EVAL_SCHEMA = 2
#: ``EvalRecord.instructions`` of an evaluation with the tasks' own instructions.
OWN_INSTRUCTIONS = "own"
#: What a version-1 file (one without ``schema_version``) may lack, and the value it was made with:
#: files written before run ids lack ``run_id``, before the swap control ``instructions``, and the
#: oldest ``success``, ``correction_effort``, ``max_tasks`` and ``phrasings``.
_V1_DEFAULTS: dict[str, Any] = {"run_id": None, "instructions": OWN_INSTRUCTIONS, "success": [],
                                "correction_effort": None, "max_tasks": 0, "phrasings": "canonical"}


@dataclass(frozen=True)
class EvalRecord:
    """One evaluation, as its file (``<stem>.json``, ``report_stem``) holds it.

    Attributes:
        run_dir: the run dir evaluated, as given.
        run_id: the run id of the checkpoint evaluated; None when not known.
        domain, variant: the run's domain and model variant.
        split: the split whose tasks were evaluated.
        round: the DAgger round the checkpoint ends.
        checkpoint: the checkpoint file as given, or ``latest``.
        num_corrections: corrections given (K).
        seeds: evaluation seeds.
        max_tasks: the first N tasks of the split only (0: all).
        greedy_actions: actions taken greedily (else sampled).
        phrasings: how instructions and corrections were said (``language.PHRASINGS``).
        trained_with_paraphrases: the run's ``model.paraphrases``.
        instructions: ``own``, or ``swapped (<rule>)`` for the instruction-swap control.
        num_tasks: tasks evaluated per seed.
        completion, completion_std, success: ``EvalResult``'s, after 0..K corrections.
        per_seed: each seed's completion curve.
        seconds: wall time.
        correction_effort: what the corrections cost; None where not recorded.
        paper_completion: the paper's completion figures, as (corrections, value) pairs.
        reduced_scale: what the run left out of the paper's setting (``reduced_scale``); None at full scale.
        schema_version: the file's schema (``EVAL_SCHEMA``; a file read from an older one is upgraded
            by ``from_json`` and carries the version it was read from).
    """

    run_dir: str
    run_id: str | None
    domain: str
    variant: str
    split: str
    round: int
    checkpoint: str
    num_corrections: int
    seeds: tuple[int, ...]
    max_tasks: int
    greedy_actions: bool
    phrasings: str
    trained_with_paraphrases: bool
    instructions: str
    num_tasks: int
    completion: tuple[float, ...]
    completion_std: tuple[float, ...]
    success: tuple[float, ...]
    per_seed: tuple[tuple[float, ...], ...]
    seconds: float
    correction_effort: CorrectionEffort | None
    paper_completion: tuple[tuple[str, float], ...]
    reduced_scale: str | None
    schema_version: int = EVAL_SCHEMA

    @property
    def swapped(self) -> bool:
        """The instruction-swap control: each task was told another task's instruction."""
        return self.instructions != OWN_INSTRUCTIONS

    @property
    def with_paper(self) -> bool:
        """The paper's figures compare with it: a full-scale run told its own instructions."""
        return self.reduced_scale is None and not self.swapped

    def to_json(self) -> str:
        """The file's text: one key a line, in the field order, ending in a newline."""
        payload = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        payload["correction_effort"] = None if self.correction_effort is None else dataclasses.asdict(self.correction_effort)
        payload["paper_completion"] = dict(self.paper_completion)
        return json.dumps(payload, indent=1) + "\n"

    @classmethod
    def from_json(cls, text: str) -> EvalRecord:
        """The record of a file's text, of any schema version (a version-1 file's missing keys take
        ``_V1_DEFAULTS``); ``ValueError`` naming what is wrong when it is not an evaluation record."""
        raw = json.loads(text)
        if not isinstance(raw, dict):
            raise ValueError("not a JSON object")
        version = raw.get("schema_version", 1)
        if version == 1:
            raw = {**_V1_DEFAULTS, **raw, "schema_version": 1}
        elif version != EVAL_SCHEMA:
            raise ValueError(f"schema_version {str(version)[:20]}; this code reads versions 1 to {EVAL_SCHEMA}")
        try:
            effort = raw["correction_effort"]
            return cls(
                run_dir=_text(raw["run_dir"]), run_id=None if raw["run_id"] is None else _text(raw["run_id"]),
                domain=_text(raw["domain"]), variant=_text(raw["variant"]), split=_text(raw["split"]),
                round=_integer(raw["round"]), checkpoint=_text(raw["checkpoint"]),
                num_corrections=_integer(raw["num_corrections"]), seeds=tuple(_integer(x) for x in _list(raw["seeds"])),
                max_tasks=_integer(raw["max_tasks"]), greedy_actions=_flag(raw["greedy_actions"]),
                phrasings=_text(raw["phrasings"]), trained_with_paraphrases=_flag(raw["trained_with_paraphrases"]),
                instructions=_text(raw["instructions"]), num_tasks=_integer(raw["num_tasks"]),
                completion=_numbers(raw["completion"]), completion_std=_numbers(raw["completion_std"]),
                success=_numbers(raw["success"]), per_seed=tuple(_numbers(row) for row in _list(raw["per_seed"])),
                seconds=_number(raw["seconds"]),
                correction_effort=None if effort is None else _effort(_mapping(effort)),
                paper_completion=tuple((_text(k), _number(v)) for k, v in _mapping(raw["paper_completion"]).items()),
                reduced_scale=None if raw["reduced_scale"] is None else _text(raw["reduced_scale"]),
                schema_version=version)
        except KeyError as err:
            raise ValueError(f"no {err.args[0]!r}") from None


def read_eval(path: str | Path) -> EvalRecord:
    """The ``EvalRecord`` of the file at ``path``; one that cannot be read or is not one fails in
    one line naming it (``RunDirError``)."""
    try:
        return EvalRecord.from_json(Path(path).read_text())
    except (OSError, UnicodeDecodeError, ValueError, TypeError, RecursionError) as err:
        raise RunDirError(f"{path}: not an evaluation record ({type(err).__name__}: {str(err)[:200]})") from None


def _effort(raw: dict) -> CorrectionEffort:
    optional = lambda key: None if raw[key] is None else _number(raw[key])  # noqa: E731
    return CorrectionEffort(optional("corrections_to_solve"), _number(raw["unsolved_fraction"]),
                            optional("words_per_solved_task"), _number(raw["completion_auc"]))


def _list(value: Any) -> list:
    if not isinstance(value, list):
        raise ValueError(f"expected a list, got {str(value)[:40]}")
    return value


def _mapping(value: Any) -> dict:
    if not isinstance(value, dict):
        raise ValueError(f"expected a mapping, got {str(value)[:40]}")
    return value


def _number(value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"expected a number, got {str(value)[:40]}")
    return value


def _numbers(value: Any) -> tuple[float, ...]:
    return tuple(_number(x) for x in _list(value))


def _integer(value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"expected an integer, got {str(value)[:40]}")
    return value


def _flag(value: Any) -> bool:
    if not isinstance(value, bool):
        raise ValueError(f"expected true or false, got {str(value)[:40]}")
    return value


def _text(value: Any) -> str:
    if not isinstance(value, str):
        raise ValueError(f"expected a string, got {str(value)[:40]}")
    return value


def why_foreign(run_dir: str | Path, ckpt: Checkpoint, ckpt_file: str | Path) -> str | None:
    """Why ``ckpt`` (read from ``ckpt_file``) is not a checkpoint of the run in ``run_dir``, in
    words; None when it is one: the same run identity (``run.json``'s; for a run without one, what
    its buffer's marker, other checkpoints, evaluation files and metrics record:
    ``learner.identity.why_not_recorded_run``), and the same domain, model and seed as the run's
    ``config.yaml``."""
    run_dir = Path(run_dir)
    identity = read_identity(run_dir)
    if identity is not None and ckpt.run_id is not None and ckpt.run_id != identity.run_id:
        return f"{ckpt_file} is a checkpoint of run {ckpt.run_id[:64]}, not of {run_dir} (run {identity.run_id[:64]})"
    saved = run_dir / "config.yaml"
    if not saved.is_file():
        return f"{run_dir} holds no run (no config.yaml) to evaluate {ckpt_file} as"
    try:
        own = load_config(saved)
        theirs = config_from_dict(ckpt.config, f"{ckpt_file} (its config)")
    except ConfigError as err:
        if "--trust-domain-module" in str(err):  # a refused plug-in: not a question of whose checkpoint it is
            raise
        return f"cannot compare {ckpt_file} with {run_dir}: {err}"
    if identity is None:
        why = why_not_recorded_run(run_dir, ckpt, ckpt_file, own.buffer.location or str(run_dir / "buffer"))
        if why is not None:
            return why
    differ = [f"env.domain {theirs.env.domain} (the run: {own.env.domain})"] if theirs.env.domain != own.env.domain else []
    differ += [f"model.{f.name} {getattr(theirs.model, f.name)} (the run: {getattr(own.model, f.name)})"
               for f in dataclasses.fields(own.model) if getattr(theirs.model, f.name) != getattr(own.model, f.name)]
    differ += [f"seed {theirs.seed} (the run: {own.seed})"] if theirs.seed != own.seed else []
    if differ:
        return f"{ckpt_file} was trained with {', '.join(differ[:3])}: it is not a checkpoint of {run_dir}"
    return None


def load_trained_policy(run_dir: str | Path, checkpoint: str | None = None, *,
                        allow_foreign: bool = False) -> tuple[RunConfig, PolicyNetwork, int]:
    """A run's config, its policy with a checkpoint's weights (the latest unless ``checkpoint``
    names one), and the round that checkpoint ends. A checkpoint of another run, domain or model
    (``foreign_checkpoint``) is refused with ``CheckpointError`` unless ``allow_foreign``."""
    cfg, model, ckpt = _load_policy(run_dir, checkpoint, allow_foreign)
    return cfg, model, ckpt.round_index


def _load_policy(run_dir: str | Path, checkpoint: str | None, allow_foreign: bool) -> tuple[RunConfig, PolicyNetwork, Checkpoint]:
    refuse_linked_folders(run_dir)
    ckpt_file = Path(checkpoint) if checkpoint else Path(run_dir) / "checkpoints" / LATEST
    ckpt = load_checkpoint(ckpt_file)
    why = why_foreign(run_dir, ckpt, ckpt_file) if checkpoint or (Path(run_dir) / "config.yaml").is_file() else None
    if why is not None and not allow_foreign:
        raise CheckpointError(f"{why}; pass --foreign-checkpoint to use it anyway (nothing is then written into {run_dir})")
    cfg = config_from_dict(ckpt.config, f"{ckpt_file} (its config)")
    model = build_model_from_config(get_domain(cfg.env.domain), cfg.model)
    load_model_state(model, ckpt, ckpt_file)
    return cfg, model, ckpt


def meta_test_rollout(cfg: RunConfig, model: PolicyNetwork, greedy: bool = False, phrasings: str = "canonical",
                      told_instructions: dict[int, str] | None = None) -> Rollout:
    """The rollout loop as Algorithm 2 runs it: the run's oracle corrects (said in ``phrasings``),
    and the policy is conditioned as the run's ``model`` section says (told ``told_instructions``
    in place of their own instructions, where given)."""
    domain = get_domain(cfg.env.domain)
    return Rollout(domain, model, make_corrector(domain.name, cfg.env.correction_kind), greedy=greedy,
                   end_aligned=cfg.model.trajectory_ends_at_last_state,
                   full_information=cfg.model.variant in FULL_INFORMATION_VARIANTS, phrasings=phrasings,
                   told_instructions=told_instructions)


#: The rule ``swapped_instructions`` picks partners by (recorded in what measures with it, so that a
#: changed rule is measured again).
SWAP_RULE = "most-different-next"


def swapped_instructions(domain_name: str, tasks: tuple[int, ...]) -> dict[int, str]:
    """The instruction-swap control: each task of ``tasks`` is told another task's instruction, the
    one most different from its own (fewest words in common, position by position: in multi-room
    another object and another goal where the list has one), taken from the first task after it in
    the list (cyclically) that has such an instruction. Completion with these against completion
    with their own says how much a policy reads its instruction (a policy blind to it scores the
    same). A function of the task list; fails when every task has the same instruction."""
    domain = get_domain(domain_name)
    own = [domain.instruction_of(t) for t in tasks]
    if len(set(own)) < 2:
        raise UsageError(f"the {len(tasks)} tasks share one instruction: there is none to swap in")

    def shared(a: str, b: str) -> int:
        return sum(x == y for x, y in zip(a.lower().split(), b.lower().split()))

    fewest = {a: min(shared(a, b) for b in set(own) if b != a) for a in set(own)}
    n, told = len(tasks), {}
    for i, t in enumerate(tasks):
        told[t] = next(own[j % n] for j in range(i + 1, i + n)
                       if own[j % n] != own[i] and shared(own[i], own[j % n]) == fewest[own[i]])
    return told


def evaluate_policy(cfg: RunConfig, model: PolicyNetwork, *, num_corrections: int, seeds: tuple[int, ...], split: str = "test",
                    max_tasks: int = 0, greedy: bool = False, chunk: int = 128,
                    tasks: tuple[int, ...] | None = None, phrasings: str = "canonical",
                    swap_instructions: bool = False) -> EvalResult:
    """Algorithm 2 on ``tasks`` (default: the split's tasks, the first ``max_tasks`` of them).

    ``model`` is rolled out as it is, in eval mode (its training mode is restored afterwards),
    conditioned as the run's ``model`` section says; the run's oracle gives the corrections,
    and the instruction and corrections are said in ``phrasings`` (``language.PHRASINGS``). With
    ``swap_instructions`` each task is told another task's instruction (``swapped_instructions``).
    """
    domain = get_domain(cfg.env.domain)
    tasks = tasks or split_tasks(domain.name, split)
    if max_tasks:
        tasks = tasks[:max_tasks]
    if any(p.device.type != "cpu" for p in model.parameters()):
        model = copy.deepcopy(model).cpu()  # rollouts run on the CPU, beside the envs
    if swap_instructions and cfg.model.variant not in READS_INSTRUCTION:
        raise UsageError(f"variant {cfg.model.variant} reads no instruction: there is none to swap "
                         f"(the swap control applies to {', '.join(READS_INSTRUCTION)})")
    told = swapped_instructions(domain.name, tuple(tasks)) if swap_instructions else None
    rollout = meta_test_rollout(cfg, model, greedy, phrasings, told)
    was_training = model.training
    model.eval()
    start = time.perf_counter()
    max_attempts = num_corrections + 1 if model.uses_corrections else 1
    curves, successes, per_seed = [], [], []
    try:
        for seed in seeds:
            attempts: list = []
            for s in range(0, len(tasks), chunk):
                attempts += rollout.run(tasks[s:s + chunk], num_corrections, evaluation_seed(seed), split=split,
                                        policy_version=0).attempts
            curves.append(completion_by_attempt(attempts, max_attempts))
            successes.append(_success_by_attempt(attempts, max_attempts))
            per_seed.append(attempts)
    finally:
        model.train(was_training)
    curves_arr = np.array(curves)
    completion = curves_arr.mean(0).tolist()
    return EvalResult(completion=completion, completion_std=curves_arr.std(0).tolist(),
                      success=np.mean(successes, axis=0).tolist(), per_seed=curves_arr.tolist(),
                      num_tasks=len(tasks), seconds=time.perf_counter() - start,
                      effort=correction_effort(per_seed, completion))


def _success_by_attempt(attempts: list, max_attempts: int) -> np.ndarray:
    """Fraction of the tasks solved after 0..max_attempts-1 corrections (a solved task stays solved)."""
    solved: dict[int, np.ndarray] = {}
    for a in attempts:
        solved.setdefault(a.task_id, np.zeros(max_attempts, dtype=bool))
        if a.success:
            solved[a.task_id][a.attempt_index:] = True
    return np.mean(list(solved.values()), axis=0)


def format_table(domain: str, result: EvalResult | EvalRecord, with_paper: bool = True) -> str:
    """The meta-test table: completion, its spread over seeds, success, and (``with_paper``) the
    paper's figure; then the correction effort, where recorded."""
    paper = get_domain(domain).paper_completion if with_paper else {}
    lines = [f"{'corrections':>11} {'completion':>10} {'± std':>7} {'success':>8}" + (f" {'paper':>6}" if with_paper else "")]
    for k, (c, sd, s) in enumerate(zip(result.completion, result.completion_std, result.success)):
        p = (f" {paper[k]:>6.3f}" if k in paper else f" {'-':>6}") if with_paper else ""
        lines.append(f"{'c' + str(k):>11} {c:10.3f} {sd:7.3f} {s:8.3f}{p}")
    e = result.effort if isinstance(result, EvalResult) else result.correction_effort
    if e is not None:
        show = lambda x: "-" if x is None else f"{x:.2f}"  # noqa: E731
        lines.append(f"correction effort: {show(e.corrections_to_solve)} corrections and {show(e.words_per_solved_task)} "
                     f"words per solved task, {e.unsolved_fraction:.3f} unsolved, completion AUC {e.completion_auc:.3f}")
    return "\n".join(lines)


def reduced_scale(cfg: RunConfig) -> str | None:
    """What a run left out of the paper's setting (fewer training tasks), in words; None for a
    full-scale run. A reduced run checks the pipeline: its figures are not comparable to the paper's."""
    split = split_tasks(cfg.env.domain, cfg.env.train_split)
    used = len(cfg.env.task_ids) if cfg.env.task_ids else min(cfg.env.max_train_tasks or len(split), len(split))
    if used >= len(split):
        return None
    return (f"this run trained on {used} of the {len(split)} {cfg.env.train_split} tasks for {cfg.training.num_rounds} "
            "rounds: a check of the pipeline, not a result. The paper's figures and what a full run reaches "
            f"are in docs/results.md (configs/{cfg.env.domain}.yaml trains at the paper's scale).")


def plot(record: EvalRecord, path: Path) -> None:
    """A record's completion against corrections (± its spread over seeds), beside the paper's
    where ``record.with_paper``, as a PNG at ``path`` (written whole or not at all)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ks = np.arange(len(record.completion))
    fig, ax = plt.subplots(figsize=(5, 3.5), dpi=120)
    ax.errorbar(ks, record.completion, yerr=record.completion_std, marker="o", capsize=3, label="gpl-dist")
    paper = get_domain(record.domain).paper_completion if record.with_paper else {}
    pk = [int(k) for k in ks if int(k) in paper]
    if pk:
        ax.plot(pk, [paper[k] for k in pk], "s--", color="grey", label="paper (GPL)")
    ax.set_xlabel("corrections")
    ax.set_ylabel("mean completion (test tasks)")
    ax.set_ylim(0, 1.02)
    told = ", told other tasks' instructions" if record.swapped else ""
    ax.set_title(f"{record.domain} {record.variant}, {record.num_tasks} {record.split} tasks, round {record.round}{told}")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    fig.tight_layout()
    savefig_atomic(fig, path)
    plt.close(fig)


def report_stem(cfg: RunConfig, *, split: str, greedy: bool, num_corrections: int, seeds: tuple[int, ...],
                max_tasks: int, checkpoint: str | None, phrasings: str = "canonical",
                swap_instructions: bool = False) -> str:
    """``eval`` for the run's own evaluation settings, else ``eval-`` plus what differs from them."""
    e = cfg.eval
    tags = [split if split != e.split else "", ("greedy" if greedy else "sampled") if greedy != e.greedy_actions else "",
            f"c{num_corrections}" if num_corrections != e.num_corrections else "",
            "seeds" + "_".join(str(s) for s in seeds) if tuple(seeds) != tuple(e.seeds) else "",
            f"first{max_tasks}" if max_tasks != e.max_tasks else "", Path(checkpoint).stem if checkpoint else "",
            f"{phrasings}-phrasings" if phrasings != e.phrasings else "",
            "swapped-instructions" if swap_instructions else ""]
    return "-".join(["eval", *(t for t in tags if t)])


def evaluate_run(run_dir: str | Path, *, num_corrections: int | None = None, seeds: tuple[int, ...] | None = None,
                 split: str | None = None, max_tasks: int | None = None, checkpoint: str | None = None,
                 greedy: bool | None = None, phrasings: str | None = None, foreign_checkpoint: bool = False,
                 out_dir: str | Path | None = None, swap_instructions: bool = False) -> tuple[EvalRecord, Path]:
    """Evaluate a run's latest (or given) checkpoint; writes its ``EvalRecord`` as ``<stem>.json``
    (see ``report_stem``) into the run dir (or ``out_dir``, made if missing), atomically, and
    returns the record and the file's path. Each setting left None is the run's own ``eval``
    setting. A checkpoint of another run, domain or model is refused (``CheckpointError``) unless
    ``foreign_checkpoint``. ``swap_instructions`` tells each task another task's instruction
    (``swapped_instructions``), on the run's valid split (``splits.valid_split`` of its training
    split) unless ``split`` says otherwise (a diagnostic: choose on valid). The arguments are taken
    as given (the CLI checks them: ``gpl_dist.cli``)."""
    run_dir = Path(run_dir)
    target = Path(out_dir) if out_dir is not None else run_dir
    cfg, model, ckpt = _load_policy(run_dir, checkpoint, foreign_checkpoint)
    round_index, ckpt_run = ckpt.round_index, ckpt.run_id
    # A checkpoint that records no run id, found above to be this run's (why_foreign), is recorded as
    # the run's. Not load_checkpoint's to say: a file alone does not know the run it is read for.
    if ckpt_run is None and not foreign_checkpoint:
        ckpt_run = resolve_identity(run_dir, cfg.buffer.location or str(run_dir / "buffer")).run_id
    k = cfg.eval.num_corrections if num_corrections is None else num_corrections
    if split is None and swap_instructions:  # a diagnostic: the run's valid split, never a test split
        split = valid_split(cfg.env.domain, cfg.env.train_split)
        if split is None:
            raise UsageError(f"{run_dir} trained on '{cfg.env.train_split}', which has no valid split: "
                             "name the split to swap instructions on with --split")
    split = split or cfg.eval.split
    greedy = cfg.eval.greedy_actions if greedy is None else greedy
    seeds = tuple(seeds or cfg.eval.seeds)
    max_tasks = cfg.eval.max_tasks if max_tasks is None else max_tasks
    phrasings = phrasings or cfg.eval.phrasings
    if phrasings != "canonical" and get_domain(cfg.env.domain).paraphrases is None:
        raise UsageError(f"{cfg.env.domain} declares no paraphrases: only canonical phrasings can be evaluated")
    if phrasings != "canonical" and not cfg.model.paraphrases:
        print(f"warning: {run_dir} was trained without paraphrases (model.paraphrases: false): it reads the words "
              f"of the {phrasings} phrasings it never saw as <unk>, so this measures unseen words, not new phrasings "
              "of known ones (train with --set model.paraphrases=true to compare)", flush=True)
    result = evaluate_policy(cfg, model, num_corrections=k, seeds=seeds, split=split,
                             max_tasks=max_tasks, greedy=greedy, phrasings=phrasings,
                             swap_instructions=swap_instructions)
    stem = report_stem(cfg, split=split, greedy=greedy, num_corrections=k, seeds=seeds, max_tasks=max_tasks,
                       checkpoint=checkpoint, phrasings=phrasings, swap_instructions=swap_instructions)
    record = EvalRecord(
        run_dir=str(run_dir), run_id=ckpt_run, domain=cfg.env.domain, variant=cfg.model.variant, split=split,
        round=round_index, checkpoint=str(checkpoint or "latest"), num_corrections=k, seeds=seeds,
        max_tasks=max_tasks, greedy_actions=greedy, phrasings=phrasings,
        trained_with_paraphrases=cfg.model.paraphrases,
        instructions=f"swapped ({SWAP_RULE})" if swap_instructions else OWN_INSTRUCTIONS,
        num_tasks=result.num_tasks, completion=tuple(result.completion), completion_std=tuple(result.completion_std),
        success=tuple(result.success), per_seed=tuple(tuple(c) for c in result.per_seed), seconds=result.seconds,
        correction_effort=result.effort,
        paper_completion=tuple((str(k2), v) for k2, v in get_domain(cfg.env.domain).paper_completion.items()),
        reduced_scale=reduced_scale(cfg))
    target.mkdir(parents=True, exist_ok=True)
    path = write_atomic(target / f"{stem}.json", record.to_json())
    return record, path

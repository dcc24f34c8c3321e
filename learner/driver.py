"""The DAgger driver (paper Algorithm 1): collect, commit, train, checkpoint, once per round.

Run directory layout::

    RUN_DIR/run.json             the run's identity (``learner.identity``), written when it is created
    RUN_DIR/config.yaml          resolved config of the run as it was created (its first round's)
    RUN_DIR/buffer/              sharded buffer (unless buffer.location points elsewhere)
    RUN_DIR/checkpoints/         latest.pt and round-NNNNNN.pt (atomic), each with the config its round used
    RUN_DIR/metrics.jsonl        one JSON line per round
    RUN_DIR/tb/                  TensorBoard scalars

``--resume`` continues after the last checkpointed round. A round whose manifest was committed
before the driver died is not collected again: training resumes on the committed buffer.

What ``--resume`` changes. A resume continues with the config of the run's latest checkpoint (what
its last round used; ``resume_config``), with ``--set`` on top. A setting in ``RESUMABLE`` is one
the driver and the learner read afresh for every round (the number of rounds, Adam's learning
rate, epochs and batches, the view's capacity, the collection's workers and timeouts, where and on
how many threads and processes the learner runs, the evaluation's settings): a new value applies
from the next round on, and a line says so (``--resume changes training.learning_rate 0.001 ->
0.5 from round 2``). Any other change (the seed, the domain and its tasks, oracle and expert, the
model, how units are collected, where the buffer lives, and a setting added later until it is
listed) would change what the rounds already trained or committed mean: it is refused in one line
naming the key, the old and the new value, before anything is written. The record, per round:
``config.yaml`` is the run's config as created and is never rewritten by a resume; every round's
checkpoint holds the config that round used; and the ``metrics.jsonl`` line of the first round a
change applies to records it (``config_changes``: key -> [old, new]). The config of round R is
``config.yaml`` with the ``config_changes`` of rounds 0..R applied, and is ``round-R.pt``'s.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import logging
import os
import time
from collections.abc import Mapping
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from gpl_dist.config import (
    ConfigError,
    RunConfig,
    bounded_repr,
    config_from_dict,
    config_to_dict,
    load_config,
    save_config,
    set_override,
)
from gpl_dist.corrections import CONSTANT_KINDS
from gpl_dist.domains import get_domain
from gpl_dist.errors import RunDirError, UserError
from gpl_dist.metrics import ROUND_LINE_LEGEND, completion_by_corrections
from gpl_dist.models.build import build_model_from_config
from gpl_dist.records import WorkUnit
from gpl_dist.seeding import derive_seed
from gpl_dist.splits import split_tasks
from learner.checkpoint import (
    LATEST,
    Checkpoint,
    capture_rng,
    check_checkpoint_run,
    load_checkpoint,
    load_learner_state,
    restore_rng,
    save_checkpoint,
)
from learner.health import format_health
from learner.identity import RunIdentity, create_identity, read_identity, refuse_linked_folders, resolve_identity
from learner.parallel import make_learner
from learner.rounds import RoundMetrics, read_round
from learner.trainer import autocast_context, resolve_device
from storage import BufferIntegrityError, BufferReader, commit_round, committed_rounds, recover_pending
from storage.fs import resolve
from storage.lease import Lease
from storage.manifest import buffer_run_id, mark_buffer
from storage.verify import verify_buffer
from workers.collector import SerialCollector, UnitResult
from workers.worker import RolloutSettings

log = logging.getLogger(__name__)


def buffer_root(cfg: RunConfig, run_dir: Path) -> str:
    """Where the run's buffer lives: ``buffer.location``, or ``RUN_DIR/buffer``."""
    return cfg.buffer.location or str(run_dir / "buffer")


def training_tasks(cfg: RunConfig) -> tuple[int, ...]:
    """The task ids a run collects on: ``env.task_ids``, or the split's first ``max_train_tasks``."""
    tasks = cfg.env.task_ids or split_tasks(cfg.env.domain, cfg.env.train_split)
    return tasks[: cfg.env.max_train_tasks] if cfg.env.max_train_tasks else tasks


def make_units(tasks: tuple[int, ...], round_index: int, cfg: RunConfig, split: str, policy_version: int) -> list[WorkUnit]:
    """Round ``round_index``'s work units of ``collection.tasks_per_unit`` tasks each."""
    per = cfg.collection.tasks_per_unit
    return [
        WorkUnit(round_index=round_index, unit_index=u, task_ids=tuple(int(t) for t in tasks[s:s + per]), split=split,
                 seed=derive_seed(cfg.seed, round_index), policy_version=policy_version)
        for u, s in enumerate(range(0, len(tasks), per))
    ]


def completion_curve(reader, round_index: int, max_attempts: int) -> list[float]:
    """Mean completion after 0..max_attempts-1 corrections over the tasks collected in a round.

    Read from the round's committed attempts table (all of it, small), not from the training view,
    which may hold only part of the round.
    """
    att = reader.read_table("attempts", rounds=[round_index], columns=["task_id", "attempt_index", "completion"])
    curve = completion_by_corrections(att.column("task_id").to_numpy(), att.column("attempt_index").to_numpy(),
                                      att.column("completion").to_numpy(), max_attempts)
    return [float(x) for x in curve]


@dataclass(frozen=True)
class TrainingResult:
    """Outcome of ``run_training``.

    Attributes:
        run_dir: where everything was written.
        history: one record per round so far, resumed rounds included (the lines of metrics.jsonl).
    """

    run_dir: Path
    history: tuple[RoundMetrics, ...]


class _Progress:
    """tqdm bars for collection (tasks, tuples/s) and training (epochs, loss); silent when off."""

    def __init__(self, enabled: bool):
        self.enabled = enabled

    def collection(self, round_index: int, num_tasks: int):
        if not self.enabled:
            return None
        from tqdm import tqdm
        return tqdm(total=num_tasks, desc=f"round {round_index} collect", unit="task", leave=False)

    def training(self, round_index: int, num_epochs: int):
        if not self.enabled:
            return None
        from tqdm import tqdm
        return tqdm(total=num_epochs, desc=f"round {round_index} train", unit="epoch", leave=False)


def preflight(cfg: RunConfig, address: str | None = None) -> tuple[int, ...]:
    """Checks that need more than the config itself (the device, the task list, a cluster's
    address); returns the tasks. Runs before anything is written: a run that fails them leaves
    no trace."""
    if cfg.training.engine == "ray-train" and not address:
        # on one machine the same learners run as training.engine=processes, on loopback; Ray Train's
        # rendezvous store and gloo listen on every interface of the node
        raise ConfigError("training.engine=ray-train places learners on a Ray cluster: give its --address, or use "
                          "training.engine=processes on one machine (the same learners, bound to loopback)")
    if not address or cfg.training.device != "cuda":  # a cluster's GPUs are counted once joined
        device = resolve_device(cfg.training.device)
        if cfg.training.engine == "processes":  # the learners run here: bf16 needs this CPU's native bf16
            autocast_context(cfg.training, device)
    if address:
        from workers.ray_collector import check_reachable  # Ray is imported only where a run uses it

        check_reachable(address)
    tasks = training_tasks(cfg)
    if not tasks:
        raise ConfigError(f"no training tasks: split '{cfg.env.train_split}' with env.max_train_tasks={cfg.env.max_train_tasks}")
    return tasks


def check_fresh(run_dir: Path, root: str) -> None:
    """``RunDirError`` when ``run_dir`` or the buffer at ``root`` already holds a run (a new run
    must never train on another run's rounds; ``--resume`` continues one)."""
    from storage.layout import DATA, MANIFESTS, STAGING

    found = [name for name in ("config.yaml", "metrics.jsonl", "checkpoints") if (run_dir / name).exists()]
    loc = resolve(root)
    rounds = committed_rounds(loc)
    if rounds:
        found.append(f"committed rounds {rounds[0]}..{rounds[-1]} in {loc.url}")
    elif any(loc.listdir(d) for d in (DATA, MANIFESTS, STAGING)):
        found.append(f"buffer files in {loc.url}")
    if found:
        raise RunDirError(f"{run_dir} already holds a run ({', '.join(found)}); pass --resume to continue it "
                          "or choose another --run-dir")


def verify_for_resume(root: str, ckpt: Checkpoint | None, run_dir: Path, identity: RunIdentity | None = None) -> None:
    """Finish a half-done commit, then check every committed file before any new work: each must
    belong to this run (``identity``, default the one its files record), as the checkpoint must."""
    hint = f"no new work was started; see `gpl-dist verify {run_dir}` and docs/buffer.md (Recovering)"
    identity = identity or resolve_identity(run_dir, root)
    if ckpt is not None:
        check_checkpoint_run(ckpt, run_dir / "checkpoints" / LATEST, identity.run_id, run_dir)
    marked = buffer_run_id(root)
    if marked is not None and marked != identity.run_id:
        raise BufferIntegrityError(f"the buffer {root} belongs to run {marked[:64]}, not to {run_dir} (run "
                                   f"{identity.run_id[:64]}); {hint}")
    recover_pending(root)
    report = verify_buffer(root, run_id=identity.run_id)
    report.raise_if_bad(hint)
    if ckpt is not None:
        have = set(report.rounds) | set(report.quarantined)
        missing = [r for r in range(ckpt.round_index + 1) if r not in have]
        if missing:
            raise BufferIntegrityError(f"{report.root}: the checkpoint is of round {ckpt.round_index} but rounds "
                                       f"{missing} are not committed (a different buffer?); {hint}")


#: What ``--resume`` may change (dotted keys; a section's name covers all its keys): settings read
#: afresh for every round, so that a new value applies from the next round on (module docstring).
RESUMABLE = frozenset({
    "training.num_rounds", "training.learning_rate", "training.num_epochs_per_round", "training.batch_size",
    "training.states_per_chunk", "training.device", "training.num_threads", "training.conditioning_thread",
    "training.num_learners", "training.engine",
    "collection.num_workers", "collection.max_unit_retries", "collection.unit_timeout_s",
    "collection.unit_timeout_multiple", "collection.unit_timeout_floor_s",
    "buffer.capacity_tuples",
    "eval",
})


def resumable(key: str) -> bool:
    """Whether ``--resume`` may change the dotted config ``key`` (``RESUMABLE``)."""
    return key in RESUMABLE or key.split(".", 1)[0] in RESUMABLE


def _dotted(tree: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in tree.items():
        if isinstance(value, Mapping):
            out.update(_dotted(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def config_changes(before: RunConfig, after: RunConfig) -> tuple[tuple[str, Any, Any], ...]:
    """``(dotted key, old, new)`` of every setting that differs between two configs (as YAML writes them)."""
    old, new = _dotted(config_to_dict(before)), _dotted(config_to_dict(after))
    return tuple((key, old.get(key), value) for key, value in new.items() if old.get(key) != value)


def _show(value: Any) -> str:
    """A config value in a message: as YAML would read it back, cut (a value can be long)."""
    if value == "":
        return '""'
    return bounded_repr(value, 80) if isinstance(value, (list, tuple, dict)) else str(value)[:160]


def resume_config(run_dir: str | Path, overrides: Mapping[str, str] | None = None) -> RunConfig:
    """The config ``train --resume`` continues a run with when no ``--config`` is given: the one its
    latest checkpoint holds (its last round's, changes of earlier resumes included), else, before a
    first checkpoint, its ``config.yaml``; ``overrides`` (``--set``) on top."""
    run_dir = Path(run_dir)
    refuse_linked_folders(run_dir)
    latest = run_dir / "checkpoints" / LATEST
    if not latest.is_file():
        return load_config(run_dir / "config.yaml", overrides)
    tree = copy.deepcopy(load_checkpoint(latest).config)
    for dotted, raw in (overrides or {}).items():
        set_override(tree, dotted, raw)
    source = f"{latest} (its config)" + (" with --set " + " ".join(sorted(overrides))[:120] if overrides else "")
    return config_from_dict(tree, source)


def check_resumable(cfg: RunConfig, run_dir: Path, ckpt: Checkpoint | None) -> tuple[tuple[str, Any, Any], ...]:
    """What ``--resume`` must refuse before any work: a run whose latest checkpoint is gone while
    it has trained rounds (starting over would overwrite them), and a change that it cannot apply
    honestly (not ``resumable``: it would change what the rounds already done mean; module
    docstring). Returns the changes it applies, against the checkpoint's config (else, before a
    first checkpoint, ``config.yaml``'s)."""
    if ckpt is None:
        trained = sorted((run_dir / "checkpoints").glob("round-*.pt"))
        metrics = run_dir / "metrics.jsonl"
        if trained or (metrics.exists() and metrics.stat().st_size > 0):
            newest = trained[-1].name if trained else "none"
            raise RunDirError(f"{run_dir / 'checkpoints' / LATEST} is missing but the run has trained rounds "
                              f"(newest round checkpoint: {newest}); copy that file to {LATEST} to resume from it, "
                              "or train into another --run-dir")
        if not (run_dir / "config.yaml").is_file():
            return ()  # a run stopped before it wrote anything but run.json: nothing was done with any config
        saved, what = load_config(run_dir / "config.yaml"), "the run was started"
    else:
        saved = config_from_dict(ckpt.config, "the checkpoint's config")
        what = "round 0 was trained" if ckpt.round_index == 0 else f"rounds 0..{ckpt.round_index} were trained"
    changes = config_changes(saved, cfg)
    refused = [f"{key} ({_show(old)} -> {_show(new)})" for key, old, new in changes if not resumable(key)]
    if refused:
        raise ConfigError(f"--resume cannot change {', '.join(refused[:4])}{' ...' if len(refused) > 4 else ''}: {what} "
                          "so, and a resume must not change what the rounds done mean; start a new run (another "
                          "--run-dir) for that")
    return changes


def run_training(cfg: RunConfig, run_dir: str | Path, *, serial: bool = False, address: str | None = None,
                 resume: bool = False, progress: bool = True, collector=None) -> TrainingResult:
    """Meta-train ``cfg`` into ``run_dir`` (Algorithm 1), serially or on Ray.

    Holds the run dir's and the buffer's leases throughout: a second driver or a ``clean`` of the
    same run is refused. Nothing but the leases' lock files is written before the config, the
    device, the cluster's address and (with ``resume``) the checkpoint and every committed file
    have been checked; a resumed run that has reached ``training.num_rounds`` changes nothing.
    """
    run_dir = Path(run_dir)
    refuse_linked_folders(run_dir)
    tasks = preflight(cfg, None if serial else address)
    root = buffer_root(cfg, run_dir)
    ckpt_path = run_dir / "checkpoints" / LATEST
    if not resume:
        check_fresh(run_dir, root)  # before the leases create anything
    else:  # before the leases create anything (a changed buffer.location's folder, say); again under them
        _check_resume(cfg, run_dir, ckpt_path, resolve_identity(run_dir, root),
                      load_checkpoint(ckpt_path) if ckpt_path.exists() else None)
    with ExitStack() as held:
        held.enter_context(Lease(run_dir, "gpl-dist train"))
        if not _same_location(root, run_dir):
            held.enter_context(Lease(root, "gpl-dist train"))
        if not resume:
            check_fresh(run_dir, root)  # again, now that no other driver can start one meanwhile
            # a run.json alone is a driver stopped right after creating the run: it is still this run
            identity = read_identity(run_dir) or create_identity(run_dir)
        else:
            identity = resolve_identity(run_dir, root)
        ckpt = load_checkpoint(ckpt_path) if resume and ckpt_path.exists() else None
        changes: tuple[tuple[str, Any, Any], ...] = ()
        if resume:
            changes = _check_resume(cfg, run_dir, ckpt_path, identity, ckpt)
            if ckpt is not None and ckpt.round_index + 1 >= cfg.training.num_rounds:
                rebuild_metrics(run_dir, ckpt)
                print(f"{run_dir} has finished {ckpt.round_index + 1} rounds (training.num_rounds is "
                      f"{cfg.training.num_rounds}): nothing to do", flush=True)
                return TrainingResult(run_dir, tuple(read_round(m) for m in ckpt.history))
            verify_for_resume(root, ckpt, run_dir, identity)
            start_round = 0 if ckpt is None else ckpt.round_index + 1
            for key, old, new in changes:
                print(f"--resume changes {key} {_show(old)} -> {_show(new)} from round {start_round}", flush=True)
        return _train(cfg, run_dir, root, tasks, ckpt, identity, serial=serial, address=address, progress=progress,
                      collector=collector, changes=changes)


def _check_resume(cfg: RunConfig, run_dir: Path, ckpt_path: Path, identity: RunIdentity,
                  ckpt: Checkpoint | None) -> tuple[tuple[str, Any, Any], ...]:
    """``check_resumable``, after checking that ``ckpt`` is the run's (another run's checkpoint is
    named as such, not by how its config differs); the changes the resume applies."""
    if ckpt is not None:
        check_checkpoint_run(ckpt, ckpt_path, identity.run_id, run_dir)
    return check_resumable(cfg, run_dir, ckpt)


def _same_location(a: str | Path, b: str | Path) -> bool:
    la, lb = resolve(str(a)), resolve(str(b))
    return type(la.fs) is type(lb.fs) and la.root.rstrip("/") == lb.root.rstrip("/")


def rebuild_metrics(run_dir: Path, ckpt: Checkpoint) -> None:
    """Rewrite ``metrics.jsonl`` from the rounds ``ckpt`` records (atomically, only when it differs):
    a driver stopped between saving a checkpoint and appending its round's line, or a line
    appended for a round no checkpoint kept, leaves the file as the checkpoints say."""
    path = run_dir / "metrics.jsonl"
    text = "".join(json.dumps(m) + "\n" for m in ckpt.history)
    try:
        if path.read_text() == text:
            return
    except (FileNotFoundError, UnicodeDecodeError):
        pass
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    tmp.write_text(text)
    tmp.replace(path)


def _train(cfg: RunConfig, run_dir: Path, root: str, tasks: tuple[int, ...], ckpt: Checkpoint | None,
           identity: RunIdentity, *, serial: bool, address: str | None, progress: bool, collector,
           changes: tuple[tuple[str, Any, Any], ...] = ()) -> TrainingResult:
    torch.manual_seed(cfg.seed)
    np.random.seed(cfg.seed % (2**32))
    model = build_model_from_config(get_domain(cfg.env.domain), cfg.model, seed=cfg.seed)
    owns_collector = collector is None
    learner = None
    try:
        if owns_collector:  # before anything is written: joining a cluster can fail
            collector = _make_collector(cfg, RolloutSettings.of_run(cfg), root, identity.run_id, serial=serial,
                                        address=address)
        learner = _make_learner(cfg, model, on_ray=not serial)
        start_round, history = 0, []
        if ckpt is not None:
            load_learner_state(learner, ckpt, run_dir / "checkpoints" / LATEST)
            restore_rng(ckpt.rng_state)
            start_round, history = ckpt.round_index + 1, [read_round(m) for m in ckpt.history]
            rebuild_metrics(run_dir, ckpt)
            log.info("resuming %s at round %d", run_dir, start_round)
        return _train_rounds(cfg, run_dir, root, tasks, learner, model.uses_corrections, collector, start_round, history,
                             progress, identity.run_id, changes)
    finally:
        if learner is not None:
            learner.close()
        if owns_collector and collector is not None:
            collector.close()


def _make_learner(cfg: RunConfig, model, on_ray: bool):
    """The learner in this process (with its data-parallel helpers); on a Ray cluster, a Ray Train
    group (``training.engine: ray-train``), or a Ray actor on a GPU node when this node has none
    (``learner.remote.placement``)."""
    if on_ray:
        from learner import remote  # imports Ray: only for a run that uses it

        if cfg.training.engine == "ray-train":
            from learner.ray_train import RayTrainLearner, wants_gpu

            use_gpu = wants_gpu(cfg.training.device, remote.cluster_gpus(), cfg.training.num_learners)
            return RayTrainLearner(model, cfg.training, seed=cfg.seed, use_gpu=use_gpu)
        if remote.placement(cfg.training.device, torch.cuda.is_available(), remote.cluster_gpus()) == remote.GPU_ACTOR:
            log.info("training on a GPU of the Ray cluster (this node has none)")
            return remote.RemoteLearner(model, cfg.training, seed=cfg.seed)
    return make_learner(model, cfg.training, seed=cfg.seed)


def _train_rounds(cfg: RunConfig, run_dir: Path, root: str, tasks: tuple[int, ...], learner, uses_corrections: bool,
                  collector,
                  start_round: int, history: list[RoundMetrics], progress: bool, run_id: str,
                  changes: tuple[tuple[str, Any, Any], ...] = ()) -> TrainingResult:
    domain = get_domain(cfg.env.domain)
    ckpt_dir = run_dir / "checkpoints"
    tb = None
    try:
        if not (run_dir / "config.yaml").exists():  # the run as created: a resume never rewrites it
            first = _first_config(ckpt_dir) if start_round else cfg  # (lost with trained rounds: round 0's)
            if first is not None:
                save_config(first, run_dir / "config.yaml")
        mark_buffer(root, run_id, replace=not committed_rounds(root))
        round_loop = _RoundLoop(cfg, domain, tasks, learner, uses_corrections, collector, root,
                                _Progress(progress))
        tb = _tensorboard(run_dir)
        for r in range(start_round, cfg.training.num_rounds):
            metrics = round_loop.run(r)
            if r == start_round and changes:
                metrics = dataclasses.replace(metrics, config_changes=changes)
            history.append(metrics)
            state = learner.state()
            save_checkpoint(ckpt_dir, Checkpoint(
                round_index=r, policy_version=r + 1, model_state=dict(state.model),
                optimizer_state=dict(state.optimizer or {}), rng_state=capture_rng(state.generator),
                config=config_to_dict(cfg), history=[m.to_dict() for m in history], run_id=run_id))
            if r == start_round:
                print(ROUND_LINE_LEGEND)
            _log_round(run_dir, tb, metrics, ("correction",) if cfg.env.correction_kind in CONSTANT_KINDS else ())
    finally:
        if tb is not None:
            tb.close()
    return TrainingResult(run_dir, tuple(history))


def _first_config(ckpt_dir: Path) -> RunConfig | None:
    """The config round 0 used (``round-000000.pt``'s), or None without a readable one."""
    try:
        return config_from_dict(load_checkpoint(ckpt_dir / "round-000000.pt").config, "round 0's checkpoint")
    except UserError:
        return None


def _make_collector(cfg: RunConfig, settings: RolloutSettings, root: str, run_id: str, *, serial: bool,
                    address: str | None):
    if serial:
        return SerialCollector(cfg.env.domain, settings, root, run_id)
    from workers.ray_collector import RayCollector  # Ray is imported only where a run uses it
    c = cfg.collection
    return RayCollector(cfg.env.domain, settings, root, run_id, c.num_workers, address, c.max_unit_retries,
                        c.unit_timeout_s, c.unit_timeout_floor_s, c.unit_timeout_multiple)


class _RoundLoop:
    """One DAgger round: collect with the current weights (unless committed before a restart),
    commit, load the training view, train."""

    def __init__(self, cfg: RunConfig, domain, tasks: tuple[int, ...], learner, uses_corrections: bool, collector,
                 root: str, bars: "_Progress"):
        self.cfg, self.domain, self.tasks, self.learner = cfg, domain, tasks, learner
        self.collector, self.root, self.bars = collector, root, bars
        self.reader = BufferReader(root)
        self.max_attempts = cfg.collection.num_corrections + 1 if uses_corrections else 1

    def run(self, r: int) -> RoundMetrics:
        t0 = time.perf_counter()
        collected, failed = self._collect(r, t0)
        collection_seconds = time.perf_counter() - t0
        t1 = time.perf_counter()
        cfg = self.cfg
        view = self.reader.load_training_view(cfg.buffer.capacity_tuples, self.domain.trajectory_stride,
                                              cfg.model.trajectory_ends_at_last_state)
        load_seconds = time.perf_counter() - t1
        curve = completion_curve(self.reader, r, self.max_attempts)
        stats = self._train(r, view)
        return RoundMetrics(round_index=r, collected_tuples=collected, failed_tasks=failed,
                            collection_seconds=collection_seconds, load_seconds=load_seconds,
                            completion_by_corrections=tuple(curve), buffer_tuples=stats.num_states, loss=stats.loss,
                            accuracy=stats.accuracy, train_seconds=stats.seconds, train_steps=stats.num_steps,
                            correction_spread=stats.correction_spread, encoder_health=stats.encoder_health)

    def _collect(self, r: int, t0: float) -> tuple[int | None, tuple[int, ...]]:
        """Collect and commit round ``r``; ``(tuples, failed task ids)``, or ``(None, ())`` when it was
        committed before a restart."""
        if r in committed_rounds(self.root):
            log.info("round %d was committed before a restart; not collecting it again", r)
            return None, ()
        units = make_units(self.tasks, r, self.cfg, self.cfg.env.train_split, policy_version=r)
        bar = self.bars.collection(r, len(self.tasks))
        tuples = 0
        failures: list[tuple[int, str]] = []  # (task id, message) of the tasks dropped so far

        def on_result(res: UnitResult) -> None:
            nonlocal tuples
            tuples += int(res.shard.num_tuples)
            failures.extend(res.failed_tasks)
            if bar is not None:
                bar.update(res.num_tasks)
                bar.set_postfix(tuples_per_s=f"{tuples / max(time.perf_counter() - t0, 1e-9):.0f}")

        results = self.collector.collect_round(units, self.learner.weights(), r, on_result)
        if bar is not None:
            bar.close()
        for _, message in failures:
            log.error("round %d: %s", r, message)
        failed = tuple(t for t, _ in failures)
        commit_round(self.root, r, [res.shard for res in results], extra={"policy_version": r, "failed_tasks": list(failed)})
        return tuples, failed

    def _train(self, r: int, view):
        bar = self.bars.training(r, self.cfg.training.num_epochs_per_round)

        def on_epoch(epoch: int, loss: float, acc: float) -> None:
            if bar is not None:
                bar.update(1)
                bar.set_postfix(loss=f"{loss:.4f}", acc=f"{acc:.3f}")

        stats = self.learner.train_round(view, on_epoch)
        if bar is not None:
            bar.close()
        return stats


def _tensorboard(run_dir: Path):
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:  # tensorboard is a dependency, but a stripped install should still train
        return None
    return SummaryWriter(str(run_dir / "tb"))


def format_round(m: RoundMetrics, constant_inputs: tuple[str, ...] = ()) -> str:
    """The one-line summary of a round that ``gpl-dist train`` prints (``ROUND_LINE_LEGEND``).
    ``constant_inputs``: encoders whose input is one fixed value by design (the retry control's
    correction, ``gpl_dist.corrections.CONSTANT_KINDS``): a dead layer there is noted, not warned."""
    curve = " ".join(f"c{k}={v:.3f}" for k, v in enumerate(m.completion_by_corrections))
    collected = "resumed" if m.collected_tuples is None else f"{m.collected_tuples} tuples"
    spread = m.correction_spread
    line = (f"round {m.round_index}: {collected} in {m.collection_seconds:.1f}s, buffer {m.buffer_tuples}, "
            f"train {m.train_seconds:.1f}s loss {m.loss:.4f} acc {m.accuracy:.3f}"
            + ("" if spread is None else f" corr-spread {spread:.3f}")
            + (f" {format_health(m.encoder_health)}" if m.encoder_health else "") + f" | train tasks {curve}")
    if spread is not None and spread < 1e-6:
        line += ("\nwarning: the correction module's output no longer varies between attempts (dead units);"
                 " the policy cannot use corrections")
    for h in m.encoder_health:
        if h.encoder in constant_inputs and (h.output_dead or h.constant):
            line += (f"\nnote: the {h.encoder} encoder's input is one fixed sentence here (a constant correction kind),"
                     " so its encoding is constant by design; not a dead encoder")
        elif h.output_dead:
            line += (f"\nwarning: all {h.output_units} output units of the {h.encoder} encoder are dead (never positive;"
                     " for MIVOA's LSTM, constant): the policy no longer sees its input (for GPL, model.linear_encodings keeps"
                     " encodings linear)")
        elif h.constant:
            line += (f"\nwarning: every unit of a hidden layer of the {h.encoder} encoder is dead (never positive): its"
                     " encoding is the same for every input, so the policy no longer sees that input")
    return line


def _log_round(run_dir: Path, tb, m: RoundMetrics, constant_inputs: tuple[str, ...] = ()) -> None:
    with open(run_dir / "metrics.jsonl", "a") as fh:
        fh.write(json.dumps(m.to_dict()) + "\n")
    print(format_round(m, constant_inputs), flush=True)
    if tb is not None:
        r = m.round_index
        tb.add_scalar("train/loss", m.loss, r)
        tb.add_scalar("train/accuracy", m.accuracy, r)
        if m.correction_spread is not None:
            tb.add_scalar("train/correction_spread", m.correction_spread, r)
        for h in m.encoder_health:
            tb.add_scalar(f"health/dead_fraction_{h.encoder}", h.dead_units / max(h.units, 1), r)
        tb.add_scalar("collect/seconds", m.collection_seconds, r)
        tb.add_scalar("train/seconds", m.train_seconds, r)
        for k, v in enumerate(m.completion_by_corrections):
            tb.add_scalar(f"completion/train_c{k}", v, r)
        tb.flush()

"""The DAgger driver (paper Algorithm 1): collect, commit, train, checkpoint, once per round.

Run directory layout::

    RUN_DIR/config.yaml          resolved config of the run
    RUN_DIR/buffer/              sharded buffer (unless buffer.location points elsewhere)
    RUN_DIR/checkpoints/         latest.pt and round-NNNNNN.pt (atomic)
    RUN_DIR/metrics.jsonl        one JSON line per round
    RUN_DIR/tb/                  TensorBoard scalars

``--resume`` continues after the last checkpointed round. A round whose manifest was committed
before the driver died is not collected again: training resumes on the committed buffer.
"""

from __future__ import annotations

import json
import logging
import time
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from gpl_dist.config import ConfigError, RunConfig, config_to_dict, save_config
from gpl_dist.domains import get_domain
from gpl_dist.errors import RunDirError
from gpl_dist.metrics import completion_by_corrections
from gpl_dist.models.gpl import build_model_from_config
from gpl_dist.records import WorkUnit
from gpl_dist.seeding import derive_seed
from gpl_dist.splits import split_tasks
from learner.checkpoint import (LATEST, Checkpoint, capture_rng, load_checkpoint, load_model_state, restore_rng,
                                save_checkpoint)
from learner.collectors import SerialCollector, UnitResult
from learner.trainer import Learner, resolve_device
from storage import BufferIntegrityError, BufferReader, commit_round, committed_rounds, recover_pending
from storage.fs import resolve
from storage.lease import Lease
from storage.manifest import mark_buffer
from storage.verify import verify_buffer
from workers.rollout import RolloutSettings

log = logging.getLogger(__name__)


def buffer_root(cfg: RunConfig, run_dir: Path) -> str:
    return cfg.buffer.location or str(run_dir / "buffer")


def training_tasks(cfg: RunConfig) -> tuple[int, ...]:
    tasks = cfg.env.task_ids or split_tasks(cfg.env.domain, cfg.env.train_split)
    return tasks[: cfg.env.max_train_tasks] if cfg.env.max_train_tasks else tasks


def make_units(tasks: tuple[int, ...], round_index: int, cfg: RunConfig, split: str, policy_version: int) -> list[WorkUnit]:
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
        history: one metrics dict per round (the lines of metrics.jsonl).
    """

    run_dir: Path
    history: list


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


def preflight(cfg: RunConfig) -> tuple[int, ...]:
    """Checks that need more than the config itself (the device, the task list); returns the tasks.

    Runs before anything is written, so a run that cannot start leaves no trace.
    """
    resolve_device(cfg.training.device)
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


def verify_for_resume(root: str, ckpt: Checkpoint | None, run_dir: Path) -> None:
    """Finish a half-done commit, then check every committed file before any new work."""
    recover_pending(root)
    report = verify_buffer(root)
    hint = f"nothing was changed; see `gpl-dist verify {run_dir}` and docs/buffer.md (Recovering)"
    report.raise_if_bad(hint)
    if ckpt is not None:
        have = set(report.rounds) | set(report.quarantined)
        missing = [r for r in range(ckpt.round_index + 1) if r not in have]
        if missing:
            raise BufferIntegrityError(f"{report.root}: the checkpoint is of round {ckpt.round_index} but rounds "
                                       f"{missing} are not committed (a different buffer?); {hint}")


def run_training(cfg: RunConfig, run_dir: str | Path, *, serial: bool = False, address: str | None = None,
                 resume: bool = False, progress: bool = True, collector=None) -> TrainingResult:
    """Meta-train ``cfg`` into ``run_dir`` (Algorithm 1), serially or on Ray.

    Holds the run dir's and the buffer's leases throughout: a second driver or a ``clean`` of the
    same run is refused. Nothing is written before the config, the device and (with ``resume``)
    the checkpoint and every committed file have been checked.
    """
    run_dir = Path(run_dir)
    tasks = preflight(cfg)
    root = buffer_root(cfg, run_dir)
    ckpt_path = run_dir / "checkpoints" / LATEST
    if not resume:
        check_fresh(run_dir, root)
    with ExitStack() as held:
        held.enter_context(Lease(run_dir, "gpl-dist train"))
        if resolve(root).url != resolve(run_dir).url:
            held.enter_context(Lease(root, "gpl-dist train"))
        ckpt = load_checkpoint(ckpt_path) if resume and ckpt_path.exists() else None
        if resume:
            verify_for_resume(root, ckpt, run_dir)
        return _train(cfg, run_dir, root, tasks, ckpt, serial=serial, address=address, progress=progress,
                      collector=collector)


def _train(cfg: RunConfig, run_dir: Path, root: str, tasks: tuple[int, ...], ckpt: Checkpoint | None, *,
           serial: bool, address: str | None, progress: bool, collector) -> TrainingResult:
    domain = get_domain(cfg.env.domain)
    ckpt_dir = run_dir / "checkpoints"
    run_id = run_dir.name
    settings = RolloutSettings.from_config(cfg)
    torch.manual_seed(cfg.seed)
    np.random.seed(cfg.seed % (2**32))
    model = build_model_from_config(domain, cfg.model, seed=cfg.seed)
    learner = Learner(model, cfg.training, seed=cfg.seed)
    start_round, history = 0, []
    if ckpt is not None:
        load_model_state(learner.model, ckpt, ckpt_dir / LATEST)
        learner.load_optimizer_state(ckpt.optimizer_state)
        restore_rng(ckpt.rng_state, learner.generator)
        start_round, history = ckpt.round_index + 1, list(ckpt.history)
        log.info("resuming %s at round %d", run_dir, start_round)
    save_config(cfg, run_dir / "config.yaml")
    mark_buffer(root, run_id)

    owns_collector = collector is None
    if collector is None:
        if serial:
            collector = SerialCollector(domain.name, settings, root, run_id)
        else:
            from learner.distributed import RayCollector
            collector = RayCollector(domain.name, settings, root, run_id, cfg.collection.num_workers, address,
                                     cfg.collection.max_unit_retries)
    tb = _tensorboard(run_dir)
    bars = _Progress(progress)
    max_attempts = cfg.collection.num_corrections + 1 if learner.model.uses_corrections else 1
    reader = BufferReader(root)
    try:
        for r in range(start_round, cfg.training.num_rounds):
            version = r
            metrics: dict = {"round": r}
            t0 = time.perf_counter()
            if r in committed_rounds(root):
                log.info("round %d was committed before a restart; not collecting it again", r)
                metrics["collected_tuples"] = None
            else:
                units = make_units(tasks, r, cfg, cfg.env.train_split, version)
                bar = bars.collection(r, len(tasks))
                tuples = [0]
                failures: list = []

                def on_result(res: UnitResult, bar=bar, tuples=tuples, failures=failures) -> None:
                    tuples[0] += int(res.shard.num_tuples)
                    failures.extend(res.failed_tasks)
                    if bar is not None:
                        bar.update(res.num_tasks)
                        bar.set_postfix(tuples_per_s=f"{tuples[0] / max(time.perf_counter() - t0, 1e-9):.0f}")

                results = collector.collect_round(units, learner.weights(), version, on_result)
                if bar is not None:
                    bar.close()
                for task_id, message in failures:
                    log.error("round %d: %s", r, message)
                commit_round(root, r, [res.shard for res in results],
                             extra={"policy_version": version, "failed_tasks": [t for t, _ in failures]})
                metrics["collected_tuples"] = tuples[0]
                metrics["failed_tasks"] = [t for t, _ in failures]
            metrics["collection_seconds"] = time.perf_counter() - t0

            t1 = time.perf_counter()
            view = reader.load_training_view(cfg.buffer.capacity_tuples, domain.trajectory_stride,
                                              cfg.model.trajectory_ends_at_last_state)
            metrics["load_seconds"] = time.perf_counter() - t1
            metrics["completion_by_corrections"] = completion_curve(reader, r, max_attempts)
            bar = bars.training(r, cfg.training.num_epochs_per_round)

            def on_epoch(epoch: int, loss: float, acc: float, bar=bar) -> None:
                if bar is not None:
                    bar.update(1)
                    bar.set_postfix(loss=f"{loss:.4f}", acc=f"{acc:.3f}")

            stats = learner.train_round(view, on_epoch)
            if bar is not None:
                bar.close()
            metrics.update(buffer_tuples=stats.num_states, loss=stats.loss, accuracy=stats.accuracy,
                           train_seconds=stats.seconds, train_steps=stats.num_steps,
                           correction_spread=stats.correction_spread)
            history.append(metrics)
            save_checkpoint(ckpt_dir, Checkpoint(
                round_index=r, policy_version=version + 1, model_state=learner.model.state_dict(),
                optimizer_state=learner.optimizer.state_dict(), rng_state=capture_rng(learner.generator),
                config=config_to_dict(cfg), history=history))
            _log_round(run_dir, tb, metrics)
    finally:
        if tb is not None:
            tb.close()
        if owns_collector:
            collector.close()
    return TrainingResult(run_dir, history)


def _tensorboard(run_dir: Path):
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:  # tensorboard is a dependency, but a stripped install should still train
        return None
    return SummaryWriter(str(run_dir / "tb"))


def format_round(m: dict) -> str:
    curve = " ".join(f"c{k}={v:.3f}" for k, v in enumerate(m["completion_by_corrections"]))
    collected = "resumed" if m.get("collected_tuples") is None else f"{m['collected_tuples']} tuples"
    spread = m.get("correction_spread")
    line = (f"round {m['round']}: {collected} in {m['collection_seconds']:.1f}s, buffer {m['buffer_tuples']}, "
            f"train {m['train_seconds']:.1f}s loss {m['loss']:.4f} acc {m['accuracy']:.3f}"
            + ("" if spread is None else f" corr-spread {spread:.3f}") + f" | train tasks {curve}")
    if spread is not None and spread < 1e-6:
        line += ("\nwarning: the correction module's output no longer varies between attempts (dead units);"
                 " the policy cannot use corrections")
    return line


def _log_round(run_dir: Path, tb, m: dict) -> None:
    with open(run_dir / "metrics.jsonl", "a") as fh:
        fh.write(json.dumps(m) + "\n")
    print(format_round(m), flush=True)
    if tb is not None:
        r = m["round"]
        tb.add_scalar("train/loss", m["loss"], r)
        tb.add_scalar("train/accuracy", m["accuracy"], r)
        if m.get("correction_spread") is not None:
            tb.add_scalar("train/correction_spread", m["correction_spread"], r)
        tb.add_scalar("collect/seconds", m["collection_seconds"], r)
        tb.add_scalar("train/seconds", m["train_seconds"], r)
        for k, v in enumerate(m["completion_by_corrections"]):
            tb.add_scalar(f"completion/train_c{k}", v, r)
        tb.flush()

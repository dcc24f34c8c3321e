"""Learner throughput: 5 epochs over 1e6 multi-room tuples loaded from the buffer, beside the same
model on synthetic in-memory tensors of the same shapes, measured in one run.

    python benchmarks/learner_speed.py [--tuples 1000000] [--epochs 5] [--threads 2]

The buffer is filled once with real rollouts (a freshly initialised policy, expert labels, the
real correction oracle) by the serial worker, committed as one round, then loaded through
``BufferReader.load_training_view``. The synthetic side uses random codes within each observation
channel's range, the same number of attempts and the same history structure, so the two differ
only in where the arrays came from. Targets (issue): at most 60 s for the 5 epochs from the
buffer, and at least 0.8x the synthetic rate.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np


def fill_buffer(root: str, num_tuples: int, tasks_per_unit: int = 64) -> None:
    from gpl_dist.config import CollectionConfig
    from gpl_dist.domains import get_domain
    from gpl_dist.models.gpl import build_model, state_dict_to_numpy
    from gpl_dist.records import WorkUnit
    from gpl_dist.splits import split_tasks
    from storage import ShardWriter, commit_round
    from workers.rollout import RolloutSettings, RolloutWorker

    d = get_domain("multiroom")
    settings = RolloutSettings(collection=CollectionConfig(num_corrections=5))
    worker = RolloutWorker(d, settings, ShardWriter(root, "bench"), "bench-0")
    worker.set_weights(state_dict_to_numpy(build_model(d, seed=0)), 0)
    tasks = split_tasks("multiroom", "train") + split_tasks("multiroom", "valid")
    records, collected, u = [], 0, 0
    while collected < num_tuples:
        chunk = tuple(int(tasks[(u * tasks_per_unit + i) % len(tasks)]) for i in range(tasks_per_unit))
        rec = worker.run_unit(WorkUnit(0, u, chunk, "train", seed=u, policy_version=0))
        records.append(rec)
        collected += rec.num_tuples
        u += 1
    commit_round(root, 0, records)


def synthetic_view_like(view):
    """Random arrays with the view's shapes, codes within each channel's range."""
    from gpl_dist.domains import get_domain

    g = np.random.default_rng(0)
    highs = np.array(get_domain("multiroom").obs_categories)
    obs = (g.random(view.observations.shape, dtype=np.float32) * highs).astype(np.uint8)
    traj = (g.random(view.trajectories.shape, dtype=np.float32) * highs).astype(np.uint8)

    class Synthetic:
        observations = obs
        expert_actions = g.integers(0, 6, view.expert_actions.shape)
        attempt_rows = view.attempt_rows.copy()
        instruction_ids = view.instruction_ids.copy()
        correction_ids = view.correction_ids.copy()
        context_rows = view.context_rows.copy()
        trajectories = traj

    return Synthetic


def train(view, epochs: int, batch_size: int, chunk: int, threads: int) -> tuple[float, float]:
    from gpl_dist.config import TrainingConfig
    from gpl_dist.domains import get_domain
    from gpl_dist.models.gpl import build_model
    from learner.batches import TensorView
    from learner.trainer import Learner

    cfg = TrainingConfig(num_epochs_per_round=epochs, batch_size=batch_size, states_per_chunk=chunk,
                         num_threads=threads)
    learner = Learner(build_model(get_domain("multiroom"), seed=0), cfg)
    tv = TensorView.from_view(view)
    t0 = time.perf_counter()
    stats = learner.train_round(tv)
    return time.perf_counter() - t0, stats.loss


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tuples", type=int, default=1_000_000)
    p.add_argument("--epochs", type=int, default=5)
    p.add_argument("--batch-size", type=int, default=512)
    p.add_argument("--chunk", type=int, default=16, help="training.states_per_chunk")
    p.add_argument("--threads", type=int, default=2, help="torch intra-op threads (training.num_threads)")
    p.add_argument("--buffer", help="reuse an existing buffer root instead of collecting one")
    args = p.parse_args()
    from storage import BufferReader

    root = args.buffer or str(Path(tempfile.mkdtemp(prefix="gpl-learner-bench-")) / "buffer")
    if not args.buffer:
        t0 = time.perf_counter()
        fill_buffer(root, args.tuples)
        print(f"filled buffer with real rollouts in {time.perf_counter() - t0:.1f} s ({root})")
    t0 = time.perf_counter()
    view = BufferReader(root).load_training_view(args.tuples, 25)
    load_s = time.perf_counter() - t0
    n = view.num_tuples
    print(f"loaded {n:,} tuples, {view.num_attempts:,} attempts in {load_s:.1f} s", flush=True)
    buf_s, buf_loss = train(view, args.epochs, args.batch_size, args.chunk, args.threads)
    syn_s, _ = train(synthetic_view_like(view), args.epochs, args.batch_size, args.chunk, args.threads)
    total = n * args.epochs
    print(f"threads {args.threads}, batch {args.batch_size}, states_per_chunk {args.chunk}, {args.epochs} epochs")
    print(f"from buffer   : {buf_s:7.1f} s  {total / buf_s:>10,.0f} samples/s  "
          f"(load {load_s:.1f} s; last-epoch loss {buf_loss:.3f})")
    print(f"synthetic     : {syn_s:7.1f} s  {total / syn_s:>10,.0f} samples/s")
    print(f"ratio buffer/synthetic: {syn_s / buf_s:.2f}x (target >= 0.8); 5 epochs over 1e6 from the buffer, load "
          f"included: {(buf_s * 5 / args.epochs + load_s) * 1e6 / n:.1f} s (target <= 60 s)")


if __name__ == "__main__":
    main()

"""Buffer speed: 2 writer processes write synthetic tuples concurrently, the driver commits, a fresh
process loads the training view. Prints throughputs, bytes on disk and the loader's peak memory.

    .venv/bin/python benchmarks/buffer_speed.py [--tuples 1000000] [--vector-tuples 200000] [--keep DIR]
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import resource
import shutil
import sys
import tempfile
import time

CTX = mp.get_context("spawn")


def _writer(root, kind, units, tasks_per_unit, attempts_per_task, steps, worker_id, barrier, queue):
    from storage import ShardWriter
    from storage.synthetic import synthetic_unit

    work = [synthetic_unit(0, u, [u * tasks_per_unit + t for t in range(tasks_per_unit)], kind,
                           attempts_per_task, steps, seed=1) for u in units]
    writer = ShardWriter(root, "bench")
    barrier.wait()
    t0 = time.perf_counter()
    records = [writer.write_unit(unit, attempts, worker_id) for unit, attempts in work]
    queue.put((time.perf_counter() - t0, records))


def _loader(root, capacity, stride, queue):
    from storage import BufferReader

    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t0 = time.perf_counter()
    view = BufferReader(root).load_training_view(capacity_tuples=capacity, trajectory_stride=stride)
    seconds = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    del view  # a learner replacing its view between rounds holds one at a time
    t1 = time.perf_counter()
    view = BufferReader(root).load_training_view(capacity_tuples=capacity, trajectory_stride=stride)
    seconds2 = time.perf_counter() - t1
    queue.put(dict(seconds=seconds, seconds_again=seconds2, tuples=view.num_tuples, attempts=view.num_attempts,
                   view_bytes=view.nbytes, base_kib=base, peak_kib=peak, obs=str(view.observations.shape),
                   traj=str(view.trajectories.shape)))


def run(kind, n_tuples, root, steps=100, attempts_per_task=5, tasks_per_unit=50, stride=25):
    from storage import commit_round
    from storage.fs import resolve

    per_unit = tasks_per_unit * attempts_per_task * steps
    n_units = max(2, -(-n_tuples // per_unit))
    barrier, queue = CTX.Barrier(3), CTX.Queue()
    procs = [CTX.Process(target=_writer, args=(root, kind, list(range(w, n_units, 2)), tasks_per_unit,
                                               attempts_per_task, steps, f"writer-{w}", barrier, queue))
             for w in range(2)]
    for p in procs:
        p.start()
    barrier.wait()
    t0 = time.perf_counter()
    results = [queue.get() for _ in procs]
    wall = time.perf_counter() - t0
    for p in procs:
        p.join()
    records = [r for _, rs in results for r in rs]
    total = sum(r.num_tuples for r in records)
    t0 = time.perf_counter()
    manifest = commit_round(root, 0, records)
    commit_s = time.perf_counter() - t0
    disk = resolve(root).du(["data", "manifests"])

    lq = CTX.Queue()
    lp = CTX.Process(target=_loader, args=(root, total, stride, lq))
    lp.start()
    load = lq.get()
    lp.join()
    print(f"[{kind}] {total} tuples, {manifest.num_attempts} attempts of {steps} steps, {len(records)} shards, "
          f"obs {manifest.obs_shape} {manifest.obs_dtype}")
    print(f"  write : {wall:.2f} s wall for 2 concurrent writer processes -> {total / wall:,.0f} tuples/s "
          f"(per-process write time {', '.join(f'{s:.2f}' for s, _ in results)} s)")
    print(f"  commit: {commit_s:.3f} s")
    print(f"  disk  : {disk / 2**20:.1f} MiB committed ({disk / total:.1f} bytes/tuple; raw observation "
          f"{_raw(manifest) / total:.0f} bytes/tuple)")
    print(f"  load  : {load['seconds']:.2f} s -> {load['tuples'] / load['seconds']:,.0f} tuples/s "
          f"(again: {load['seconds_again']:.2f} s); view obs {load['obs']}, trajectories {load['traj']}, "
          f"{load['attempts']} attempts, view {load['view_bytes'] / 2**20:.0f} MiB")
    print(f"  memory: loader peak RSS {load['peak_kib'] / 2**10:.0f} MiB, "
          f"{(load['peak_kib'] - load['base_kib']) / 2**10:.0f} MiB above its peak before loading")

def _raw(manifest):
    import numpy as np

    return manifest.num_tuples * int(np.prod(manifest.obs_shape)) * np.dtype(manifest.obs_dtype).itemsize


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--tuples", type=int, default=1_000_000)
    ap.add_argument("--vector-tuples", type=int, default=200_000)
    ap.add_argument("--keep", default=None, help="write here and keep it (default: a temp dir, removed)")
    args = ap.parse_args(argv)
    base = args.keep or tempfile.mkdtemp(prefix="gpl-buffer-bench-")
    try:
        run("grid", args.tuples, os.path.join(base, "grid"))
        if args.vector_tuples:
            run("vector", args.vector_tuples, os.path.join(base, "vector"), stride=70)
    finally:
        if not args.keep:
            shutil.rmtree(base, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())

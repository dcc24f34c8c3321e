"""Serial relocation collection with one BLAS thread (the worker's setting) against two, side by side.

    python benchmarks/serial_blas.py [--tasks 16] [--repeats 2]

``workers.worker.RolloutWorker`` puts the process's BLAS on one thread, as Ray gives a 1-CPU
rollout actor. In the serial collector the worker runs in the driver process, where numpy's
OpenBLAS would otherwise take every core for the learned relocation expert's batched forward
(``gpl_dist.experts.relocation_learned.batch_probs``, 64-128 rows through a 256 x 3 MLP). This
collects the same ``--tasks`` training tasks (one DAgger round of a fresh GPL network with the
shipped config's 5 corrections, every state labelled) alternately with BLAS on 1 and on 2 threads, quiet and then
beside one busy process that this script starts (a pure-Python loop: what a laptop's other work,
or a second training, does to the cores), and prints tuples/s and the ratio. The collected
attempts are compared too: the labels must be the same bits on 1 and 2 threads.

Run it alone: the figures are throughputs of the whole machine.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import time

import numpy as np
from threadpoolctl import threadpool_limits

from gpl_dist.config import load_config
from gpl_dist.domains import get_domain
from workers.worker import RolloutSettings, RolloutWorker

CONFIG = "configs/relocation.yaml"


def _busy(started, stop) -> None:
    started.set()
    x = 0
    while not stop.is_set():
        x = (x * 31 + 7) % 1_000_003


def _collect(worker: RolloutWorker, tasks: list[int], blas_threads: int) -> tuple[float, int, np.ndarray]:
    """One collection with the process's BLAS on ``blas_threads`` threads: the worker's own limit
    (one thread while it collects) is lifted for 2 by collecting through its rollout directly."""
    threadpool_limits(limits=blas_threads, user_api="blas")
    t0 = time.perf_counter()
    attempts = list(worker.rollout.run(tasks, worker.settings.collection.num_corrections, 0, split="train",
                                       policy_version=worker.policy_version).attempts)
    seconds = time.perf_counter() - t0
    labels = np.concatenate([a.expert_probs for a in attempts])
    return seconds, sum(len(a.expert_actions) for a in attempts), labels


def measure(tasks: list[int], repeats: int) -> dict[int, list[float]]:
    cfg = load_config(CONFIG)
    domain = get_domain(cfg.env.domain)
    worker = RolloutWorker(domain, RolloutSettings.of_run(cfg), num_threads=1)
    worker.set_weights({k: v.numpy() for k, v in worker.model.state_dict().items()}, 0)
    _collect(worker, tasks[:2], 1)  # imports, caches, first allocations
    rates: dict[int, list[float]] = {1: [], 2: []}
    labels: dict[int, np.ndarray] = {}
    for _ in range(repeats):
        for threads in (1, 2):
            seconds, n, lab = _collect(worker, tasks, threads)
            rates[threads].append(n / seconds)
            labels[threads] = lab
    assert np.array_equal(labels[1], labels[2]), "1 and 2 BLAS threads labelled differently"
    return rates


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tasks", type=int, default=16)
    p.add_argument("--repeats", type=int, default=2)
    args = p.parse_args()
    tasks = list(range(args.tasks))
    print(f"relocation, {args.tasks} training tasks, 1 collection round, best of {args.repeats}, tuples/s")
    for label in ("quiet", "beside one busy process"):
        ctx = mp.get_context("spawn")  # a forked child of a process with BLAS and torch threads can hang
        started, stop = ctx.Event(), ctx.Event()
        busy = ctx.Process(target=_busy, args=(started, stop)) if label != "quiet" else None
        if busy:
            busy.start()
            started.wait()  # its imports done: the loop runs from the first measurement on
        try:
            rates = measure(tasks, args.repeats)
        finally:
            if busy:
                stop.set()
                busy.join()
        one, two = max(rates[1]), max(rates[2])
        print(f"{label:24s} BLAS 1 thread {one:8.0f}   2 threads {two:8.0f}   1 / 2 = {one / two:.2f}x "
              "(labels the same bits)")


if __name__ == "__main__":
    main()

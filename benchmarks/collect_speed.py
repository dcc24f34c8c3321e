"""Collection throughput in labelled tuples/s, side by side in one run (multi-room).

    python benchmarks/collect_speed.py [--tasks 1700] [--tasks-per-unit 128] [--corrections 5]

Rows:
- bare env, random actions (the ceiling): one process, and two processes at once (the 2-core
  ceiling);
- gpl-dist with 1 and 2 Ray rollout actors: the whole path (batched policy inference, expert
  labels, corrections, shard writes, round commit) for one DAgger round over ``--tasks`` tasks,
  after a first round over the same tasks (as in a run, the actors' expert caches are warm);
- a naive loop, as the authors' code and the imitation library collect: one env at a time, a
  batch-1 policy forward and an expert query per step, corrections in the same process, no
  storage;
- for reference, the batched policy forward alone at the unit's batch size: every labelled tuple
  costs one state of it, next to one env step.

Targets on 2 cores (issue): 2 workers >= 0.5x the 2-core ceiling, >= 1.8x one worker, >= 10x naive.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import tempfile
import time

import numpy as np
import torch


def shipped_multiroom_model():
    """``(ModelConfig, network)``: the multi-room network that ``configs/multiroom.yaml`` ships,
    freshly initialised (seed 0), so the rollouts run the forward a real run runs."""
    from pathlib import Path

    from gpl_dist.config import load_config
    from gpl_dist.domains import get_domain
    from gpl_dist.models.gpl import build_model_from_config

    model_cfg = load_config(Path(__file__).resolve().parents[1] / "configs" / "multiroom.yaml").model
    return model_cfg, build_model_from_config(get_domain("multiroom"), model_cfg, seed=0)


def bare_env_rate(seconds: float, seed: int = 0) -> float:
    from gpl_dist.domains import get_domain

    d = get_domain("multiroom")
    env = d.make_env(seed % 3240)
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    actions = rng.integers(0, d.num_actions, 1 << 16)
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for a in actions[:1000]:
            if env.step(int(a))[3]:
                env.reset()
        n += 1000
    return n / (time.perf_counter() - t0)


def _bare_worker(args):
    return bare_env_rate(*args)


def bare_env_two_processes(seconds: float) -> float:
    with mp.get_context("spawn").Pool(2) as pool:
        return sum(pool.map(_bare_worker, [(seconds, 1), (seconds, 2)]))


def gpl_dist_rate(num_workers: int, tasks: tuple[int, ...], corrections: int, tasks_per_unit: int) -> tuple[float, int]:
    from gpl_dist.config import CollectionConfig, config_from_dict
    from gpl_dist.models.gpl import state_dict_to_numpy
    from learner.driver import make_units
    from storage import commit_round
    from workers.ray_pool import RayCollector
    from workers.rollout import RolloutSettings

    root = tempfile.mkdtemp(prefix="gpl-collect-bench-")
    cfg = config_from_dict({"collection": {"tasks_per_unit": tasks_per_unit, "num_corrections": corrections}})
    model_cfg, model = shipped_multiroom_model()
    weights = state_dict_to_numpy(model)
    settings = RolloutSettings(collection=CollectionConfig(num_corrections=corrections), model=model_cfg)
    collector = RayCollector("multiroom", settings, root, "bench", num_workers)
    try:
        # round 0 warms up (actors start, import torch, fill the expert's distance-map caches for
        # these tasks); round 1, timed, is the steady state of a DAgger run from its second round on
        collector.collect_round(make_units(tasks, 0, cfg, "train", 0), weights, 0)
        units = make_units(tasks, 1, cfg, "train", 0)
        t0 = time.perf_counter()
        results = collector.collect_round(units, weights, 0)
        commit_round(root, 1, [r.shard for r in results])
        seconds = time.perf_counter() - t0
    finally:
        collector.close()
    tuples = sum(r.shard.num_tuples for r in results)
    return tuples / seconds, tuples


def policy_forward_rate(batch: int, seconds: float) -> float:
    """States/s of the batched policy forward alone (one process), as a worker runs it each step."""
    from gpl_dist.allocator import keep_freed_memory
    from gpl_dist.domains import get_domain

    keep_freed_memory()
    d = get_domain("multiroom")
    model = shipped_multiroom_model()[1].eval()
    rng = np.random.default_rng(0)
    obs = torch.from_numpy((rng.random((batch,) + d.obs_shape) * np.array(d.obs_categories)).astype(np.uint8))
    z = torch.zeros(batch, model.conditioning_dim)
    n, t0 = 0, time.perf_counter()
    with torch.inference_mode():
        while time.perf_counter() - t0 < seconds:
            model.action_logits(obs, z)
            n += batch
    return n / (time.perf_counter() - t0)


def naive_rate(tasks: tuple[int, ...], corrections: int) -> float:
    """One env, batch-1 forward, per-step expert query (the original code's and imitation's loop)."""
    from gpl_dist.corrections import make_corrector
    from gpl_dist.domains import get_domain
    from gpl_dist.experts import make_expert
    from gpl_dist.models.gpl import Conditioning

    d = get_domain("multiroom")
    model = shipped_multiroom_model()[1].eval()
    oracle = make_corrector("multiroom")
    vocab = d.vocabulary
    n, t0 = 0, time.perf_counter()
    for task in tasks:
        env = d.make_env(task)
        expert = make_expert(env)
        history: list[tuple[np.ndarray, np.ndarray]] = []
        for k in range(corrections + 1):
            obs, info = env.reset(seed=k)
            traj = []
            cond = Conditioning(
                torch.from_numpy(vocab.encode(env.instruction)[None]),
                (torch.from_numpy(np.stack([h[0] for h in history])) if history
                 else torch.zeros((0, 4) + d.obs_shape, dtype=torch.uint8)),
                (torch.from_numpy(np.stack([h[1] for h in history])) if history
                 else torch.zeros((0, vocab.max_tokens), dtype=torch.long)),
                torch.arange(len(history)).view(1, -1),
            )
            for _ in range(d.steps_per_attempt):
                with torch.no_grad():
                    logits = model(torch.from_numpy(obs[None]), cond, torch.zeros(1, dtype=torch.long))
                action = int(torch.distributions.Categorical(logits=logits).sample())
                expert.act(env)  # the label
                traj.append(obs)
                obs, _, _, _, info = env.step(action)
                n += 1
            if info["success"]:
                break
            corr = oracle.correct(env, np.random.default_rng(k))
            history.append((np.stack(traj[::d.trajectory_stride]), vocab.encode(corr.text)))
    return n / (time.perf_counter() - t0)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tasks", type=int, default=1700, help="training tasks in the round (1700: all, as in the paper)")
    p.add_argument("--corrections", type=int, default=5)
    p.add_argument("--tasks-per-unit", type=int, default=128)
    p.add_argument("--seconds", type=float, default=3.0)
    p.add_argument("--naive-tasks", type=int, default=8)
    args = p.parse_args()
    torch.set_num_threads(1)
    from gpl_dist.splits import split_tasks

    tasks = split_tasks("multiroom", "train")[: args.tasks]
    bare1 = bare_env_rate(args.seconds)
    bare2 = bare_env_two_processes(args.seconds)
    w1, n1 = gpl_dist_rate(1, tasks, args.corrections, args.tasks_per_unit)
    w2, n2 = gpl_dist_rate(2, tasks, args.corrections, args.tasks_per_unit)
    naive = naive_rate(tasks[: args.naive_tasks], args.corrections)
    forward = policy_forward_rate(args.tasks_per_unit, args.seconds)
    print(f"{'bare env, random actions, 1 process':<44} {bare1:>10,.0f} steps/s")
    print(f"{'bare env, random actions, 2 processes':<44} {bare2:>10,.0f} steps/s   (2-core ceiling)")
    print(f"{'gpl-dist, 1 rollout actor':<44} {w1:>10,.0f} tuples/s  ({n1:,} tuples)")
    print(f"{'gpl-dist, 2 rollout actors':<44} {w2:>10,.0f} tuples/s  ({n2:,} tuples)")
    print(f"{'naive loop (batch-1 policy, per-step expert)':<44} {naive:>10,.0f} tuples/s")
    print(f"{f'policy forward alone, batch {args.tasks_per_unit}, 1 process':<44} {forward:>10,.0f} states/s"
          f"   ({1e6 / forward:.1f} us a state; a bare env step: {1e6 / bare1:.1f} us)")
    print(f"ratios: 2 actors / 2-core ceiling = {w2 / bare2:.2f} (target >= 0.5); 2 actors / 1 actor = {w2 / w1:.2f} "
          f"(target >= 1.8); 2 actors / naive = {w2 / naive:.1f} (target >= 10)")


if __name__ == "__main__":
    main()

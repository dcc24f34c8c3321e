"""Relocation expert (scripted, or ``--expert learned``): completion over the 1000 tasks from the start and from perturbed
states (a random prefix of 0-150 random actions, then the expert for the rest of the 350 steps),
and its labelling speed (expert.act calls per second, env stepping excluded). Labelling speed is
also measured on the states a DAgger worker labels early on: those visited by a uniformly random
policy, and by a "sticky" random policy (a random action repeated 10-30 steps, which pushes blocks
around more like a partly trained policy); the expert labels every state, the policy steps.

    .venv/bin/python research/relocation_expert.py [--tasks 1000] [--stride 1] [--policy-tasks 50] [--expert learned]
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def make_relocation_expert(kind: str):
    from gpl_dist.envs.relocation import RelocationEnv
    from gpl_dist.experts import make_expert

    return make_expert(RelocationEnv(0), kind)


def evaluate_expert(task_ids, perturb: bool, seed: int = 0, kind: str = "scripted") -> tuple[np.ndarray, float]:
    """Final completion per task, and expert labels per second (time inside ``act`` only)."""
    from gpl_dist.envs.relocation import RelocationEnv

    expert = make_relocation_expert(kind)
    out, labels, t_act = [], 0, 0.0
    for tid in task_ids:
        env = RelocationEnv(tid)
        env.reset(seed=seed * 100_003 + tid)
        rng = np.random.default_rng([seed, tid, int(perturb)])
        k = int(rng.integers(0, 151)) if perturb else 0
        for i in range(350):
            if i < k:
                a = int(rng.integers(4))
            else:
                t0 = time.perf_counter()
                a = expert.act(env)
                t_act += time.perf_counter() - t0
                labels += 1
            info = env.step(a)[4]
        out.append(info["completion"])
    return np.array(out), labels / max(t_act, 1e-9)


def label_rate_on_policy(task_ids, sticky: bool, seed: int = 0, kind: str = "scripted") -> float:
    """Expert labels per second (time inside ``act`` only) on the states a random policy visits."""
    from gpl_dist.envs.relocation import RelocationEnv

    expert = make_relocation_expert(kind)
    labels, t_act = 0, 0.0
    for tid in task_ids:
        env = RelocationEnv(tid)
        env.reset(seed=seed * 100_003 + tid)
        rng = np.random.default_rng([seed, tid, 7 + int(sticky)])
        a, left = 0, 0
        for _ in range(350):
            t0 = time.perf_counter()
            expert.act(env)
            t_act += time.perf_counter() - t0
            labels += 1
            if left <= 0:
                a, left = int(rng.integers(4)), (int(rng.integers(10, 31)) if sticky else 1)
            left -= 1
            env.step(a)
    return labels / max(t_act, 1e-9)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tasks", type=int, default=1000)
    p.add_argument("--stride", type=int, default=1)
    p.add_argument("--policy-tasks", type=int, default=50, help="tasks for the random-policy label rates")
    p.add_argument("--expert", default="scripted", choices=["scripted", "learned"])
    args = p.parse_args(argv)
    tasks = list(range(0, args.tasks, args.stride))
    for perturb in (False, True):
        t0 = time.perf_counter()
        comp, rate = evaluate_expert(tasks, perturb, kind=args.expert)
        name = "perturbed" if perturb else "start"
        print(f"{name:>9s}: {len(tasks)} tasks  mean completion {comp.mean():.3f}  median {np.median(comp):.3f}  "
              f">=0.9: {np.mean(comp >= 0.9):.2f}  labels/s {rate:,.0f}  "
              f"({time.perf_counter() - t0:.0f} s)")
    ptasks = list(range(0, 1000, max(1, 1000 // max(args.policy_tasks, 1))))[:args.policy_tasks]
    for sticky in (False, True):
        t0 = time.perf_counter()
        rate = label_rate_on_policy(ptasks, sticky, kind=args.expert)
        name = "sticky-random" if sticky else "random"
        print(f"{name:>13s} policy states: {len(ptasks)} tasks x 350  labels/s {rate:,.0f}  "
              f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()

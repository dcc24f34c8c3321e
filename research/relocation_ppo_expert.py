"""What would the authors' per-task PPO experts cost here? Train a few with their settings and time them.

The paper's relocation experts are one PPO policy per task (facts file, section 4): policy MLP
28 -> 32 -> 32 -> 4, value MLP 28 -> 64 -> 64 -> 1, 20 parallel copies of the task, 7000 steps
(20 episodes of 350) per iteration, up to 500 iterations, 10 epochs of minibatches of 128, clip
0.2, gamma 0.99, Monte-Carlo returns (no GAE), normalised advantages, one Adam at 1e-3 for both
networks, loss = policy + value MSE - 0.001 entropy, the dense reward
``-(|arm - block| + 5 |block - target|)``, stopping once every episode of an iteration finishes
(ends within 0.03 of the target). Their weights were not fetchable, so gpl-dist uses a scripted
expert instead; this benchmark measures what training the authors' kind would take on this
machine, per task and extrapolated to the 1000 tasks:

    .venv/bin/python research/relocation_ppo_expert.py [--tasks 2] [--max-iterations 500]

Printed per task: iterations run, whether and when all 20 episodes of an iteration finished, the
last iteration's mean completion, and seconds (one core). Deterministic for a given ``--seed``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
from torch import nn

from gpl_dist.envs.relocation import NUM_TASKS, SUCCESS_RADIUS, make_env
from gpl_dist.experts.relocation_training import sample_episodes
from gpl_dist.splits import split_tasks

NUM_COPIES = 20
GAMMA = 0.99
CLIP = 0.2
EPOCHS = 10
MINIBATCH = 128
ENTROPY_COEF = 0.001


def mlp(sizes: tuple[int, ...]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for a, b in zip(sizes[:-1], sizes[1:]):
        layers += [nn.Linear(a, b), nn.Tanh()]
    return nn.Sequential(*layers[:-1])


def discounted_returns(rewards: np.ndarray) -> np.ndarray:
    """``(T, N)`` rewards -> Monte-Carlo returns, no bootstrap (episodes end at the time limit)."""
    out = np.zeros_like(rewards)
    running = np.zeros(rewards.shape[1], dtype=rewards.dtype)
    for t in range(len(rewards) - 1, -1, -1):
        running = rewards[t] + GAMMA * running
        out[t] = running
    return out


def train_task(task_id: int, max_iterations: int, seed: int, log_every: int = 0) -> dict:
    """PPO on one task until all episodes of an iteration finish or ``max_iterations`` ran."""
    torch.manual_seed(seed)
    policy, value = mlp((28, 32, 32, 4)), mlp((28, 64, 64, 1))
    opt = torch.optim.Adam([*policy.parameters(), *value.parameters()], lr=1e-3)
    envs = [make_env(task_id) for _ in range(NUM_COPIES)]
    gen = torch.Generator().manual_seed(seed)
    start = time.perf_counter()
    finished_at, completion = None, 0.0
    it = 0
    for it in range(max_iterations):
        x_buf, act_buf, logp_buf, rew_buf = sample_episodes(
            policy, envs, [seed + NUM_COPIES * it + k for k in range(NUM_COPIES)], gen)
        finished = np.array([e.distance() < SUCCESS_RADIUS for e in envs])
        completion = float(np.mean([e.completion() for e in envs]))
        if finished.all():
            finished_at = it
            break
        if log_every and it % log_every == 0:
            print(f"  task {task_id} iteration {it}: completion {completion:.3f}, finished {finished.mean():.2f}", flush=True)
        x = torch.from_numpy(x_buf[:-1].reshape(-1, 28))
        acts = torch.from_numpy(act_buf.reshape(-1))
        old_logp = torch.from_numpy(logp_buf.reshape(-1))
        returns = torch.from_numpy(discounted_returns(rew_buf).reshape(-1))
        with torch.no_grad():
            adv = returns - value(x).squeeze(1)
        adv = (adv - adv.mean()) / (adv.std() + 1e-8)
        for _ in range(EPOCHS):
            perm = torch.randperm(len(acts), generator=gen)
            for b in range(0, len(perm), MINIBATCH):
                i = perm[b:b + MINIBATCH]
                logp_all = torch.log_softmax(policy(x[i]), 1)
                ratio = torch.exp(logp_all.gather(1, acts[i, None]).squeeze(1) - old_logp[i])
                surrogate = torch.min(ratio * adv[i], ratio.clamp(1 - CLIP, 1 + CLIP) * adv[i])
                entropy = -(logp_all.exp() * logp_all).sum(1)
                loss = (-surrogate.mean() + nn.functional.mse_loss(value(x[i]).squeeze(1), returns[i])
                        - ENTROPY_COEF * entropy.mean())
                opt.zero_grad()
                loss.backward()
                opt.step()
    return {"task": task_id, "iterations": it + 1, "finished_at": finished_at, "completion": completion,
            "seconds": time.perf_counter() - start}


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tasks", type=int, default=2, help="first N training tasks")
    p.add_argument("--max-iterations", type=int, default=500, help="the authors' cap")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--first", type=int, default=0, help="skip the first N training tasks")
    p.add_argument("--log-every", type=int, default=50, help="print progress every N iterations (0: never)")
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    results = []
    for task in split_tasks("relocation", "train")[args.first:args.first + args.tasks]:
        r = train_task(task, args.max_iterations, args.seed, args.log_every)
        results.append(r)
        done = f"all {NUM_COPIES} finished at iteration {r['finished_at']}" if r["finished_at"] is not None \
            else "never all finished"
        print(f"task {task}: {r['iterations']} iterations, {done}, last completion {r['completion']:.3f}, "
              f"{r['seconds']:.0f} s ({r['seconds'] / r['iterations']:.2f} s an iteration)", flush=True)
    per_task = float(np.mean([r["seconds"] for r in results]))
    print(f"mean {per_task:.0f} s a task on one core -> {NUM_TASKS} tasks: {per_task * NUM_TASKS / 3600:.1f} "
          f"core-hours ({per_task * NUM_TASKS / 3600 / 2:.1f} h on this machine's 2 cores)")


if __name__ == "__main__":
    main()

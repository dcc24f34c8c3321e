"""How well can a policy imitate the relocation expert? Two measurements that bound GPL's results.

1. **Privileged DAgger** (default): the GPL head (MLP 3 x 256 over the normalised 28-d observation)
   is given the exact target and goal block as 5 extra inputs (as the authors' full-information
   oracle), and trained by DAgger on ``--tasks`` training tasks: each round rolls the current
   policy out (sampled actions) on every task, labels every state with the expert's distribution,
   aggregates all rounds' states (or only the newest ``--keep-rounds``, like a FIFO buffer) and
   trains ``--epochs`` epochs with cross-entropy. Printed per round: completion on the training
   rollouts, the policy's KL to the expert on the states it has just visited (before training on
   them: DAgger's on-policy error), the KL on the training states, and completion on
   ``--test-tasks`` held-out tasks. Whatever this reaches is a ceiling for GPL, which must infer
   the target from language.
2. **Failure modes of a run** (``--run-dir``): rolls a GPL checkpoint out on test tasks with
   corrections and classifies the attempts that end below 0.9 completion by where the block
   stopped: past the target in x (the expert needs its back pose to push -x), short of it, or
   off in y only.

Both also print the expert's own completion on the same test tasks, hard and sampled from its
labels, so the gap is measured side by side. Deterministic for a given ``--seed``.

    .venv/bin/python benchmarks/relocation_imitation.py [--rounds 8] [--tasks 250] [--test-tasks 100]
    .venv/bin/python benchmarks/relocation_imitation.py --run-dir runs/rl-v4
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
from torch import nn

from gpl_dist.envs.relocation import BLOCK_QPOS, EPISODE_STEPS, SUCCESS_RADIUS, make_env, make_task
from gpl_dist.experts.relocation import RelocationExpert
from gpl_dist.splits import split_tasks

TEST_SEED = 99_999  # reset seed of test task k: TEST_SEED + k, for the expert and the policy alike


def privileged_inputs(task_ids) -> np.ndarray:
    """``(N, 5)`` float32: exact target xy and the goal block one-hot of each task."""
    tasks = [make_task(int(t)) for t in task_ids]
    return np.array([[*t.target, *np.eye(3)[t.block]] for t in tasks], dtype=np.float32)


def build_policy(in_dim: int, width: int) -> nn.Module:
    """GPL's relocation head (3 hidden ReLU layers) behind the same input BatchNorm as its state encoder."""
    return nn.Sequential(nn.BatchNorm1d(in_dim), nn.Linear(in_dim, width), nn.ReLU(), nn.Linear(width, width),
                         nn.ReLU(), nn.Linear(width, width), nn.ReLU(), nn.Linear(width, 4))


def rollout(policy: nn.Module | None, task_ids, seed: int, label: bool, expert_sampled: bool = True):
    """Roll out ``policy`` on every task; when it is None, the expert itself: its actions sampled
    from its labels, or (``expert_sampled=False``) its own actions.

    Returns ``(completion (N,), solved (N,) bool: within the success radius at the end,
    inputs (S, 33) | None, expert probs (S, 4) | None)``."""
    envs = [make_env(t) for t in task_ids]
    expert = RelocationExpert()
    obs = np.stack([e.reset(seed=seed + k)[0] for k, e in enumerate(envs)]).astype(np.float32)
    priv = privileged_inputs(task_ids)
    gen = torch.Generator().manual_seed(seed)
    rng = np.random.default_rng(seed)
    xs, ys = [], []
    for _ in range(EPISODE_STEPS):
        x = np.concatenate([obs, priv], 1)
        if label or policy is None:
            labels = [expert.label(e) for e in envs]
            probs = np.stack([lab[1] for lab in labels])
        if label:
            xs.append(x)
            ys.append(probs)
        if policy is None:
            acts = ([int(rng.choice(4, p=p / p.sum())) for p in probs] if expert_sampled
                    else [lab[0] for lab in labels])
        else:
            with torch.no_grad():
                logits = policy(torch.from_numpy(x))
            acts = torch.multinomial(torch.softmax(logits, 1), 1, generator=gen).squeeze(1).tolist()
        obs = np.stack([e.step(a)[0] for e, a in zip(envs, acts)]).astype(np.float32)
    completion = np.array([e.unwrapped.completion() for e in envs])
    solved = np.array([e.unwrapped.distance() < SUCCESS_RADIUS for e in envs])
    if not label:
        return completion, solved, None, None
    return completion, solved, np.concatenate(xs), np.concatenate(ys)


def expert_on(task_ids, seed: int) -> tuple[float, float]:
    """The expert's mean completion with its own actions and sampled from its labels."""
    hard, _, _, _ = rollout(None, task_ids, seed, label=False, expert_sampled=False)
    sampled, _, _, _ = rollout(None, task_ids, seed, label=False)
    return float(hard.mean()), float(sampled.mean())


def report_expert(task_ids) -> None:
    """Print the expert's completion on ``task_ids``, reset as every test rollout here is."""
    hard, sampled = expert_on(task_ids, TEST_SEED)
    print(f"expert on {len(task_ids)} test tasks: completion {hard:.3f} (its actions), "
          f"{sampled:.3f} (sampled from its labels)")


def privileged_dagger(args) -> None:
    torch.manual_seed(args.seed)
    train = split_tasks("relocation", "train")[:args.tasks]
    test = split_tasks("relocation", "test")[:args.test_tasks]
    report_expert(test)
    policy = build_policy(33, args.width)
    opt = torch.optim.Adam(policy.parameters(), lr=1e-3)
    xs, ys = [], []
    start = time.perf_counter()
    for r in range(args.rounds):
        policy.eval()
        c_train, _, x, y = rollout(policy, train, 1000 * r + args.seed, label=True)
        kl_new = float("nan")
        if r > 0:
            with torch.no_grad():
                logp = torch.log_softmax(policy(torch.from_numpy(x)), 1).numpy()
            kl_new = float((y * (np.log(np.clip(y, 1e-8, None)) - logp)).sum(1).mean())
        xs.append(x)
        ys.append(y)
        if args.keep_rounds:  # a FIFO buffer: only the newest rounds' states
            xs, ys = xs[-args.keep_rounds:], ys[-args.keep_rounds:]
        xa, ya = torch.from_numpy(np.concatenate(xs)), torch.from_numpy(np.concatenate(ys))
        policy.train()
        total = 0.0
        for _ in range(args.epochs):
            perm = torch.randperm(len(ya))
            total = 0.0
            for b in range(0, len(perm), 512):
                i = perm[b:b + 512]
                loss = nn.functional.cross_entropy(policy(xa[i]), ya[i])
                opt.zero_grad()
                loss.backward()
                opt.step()
                total += float(loss.detach()) * len(i)
        entropy = float(-(ya * torch.log(ya.clamp_min(1e-8))).sum(1).mean())
        policy.eval()
        c_test, solved, _, _ = rollout(policy, test, TEST_SEED, label=False)
        print(f"round {r}: train rollouts {c_train.mean():.3f} | on-policy KL {kl_new:.3f} | {len(ya):,} states, "
              f"KL on them {total / len(ya) - entropy:.3f} | test completion {c_test.mean():.3f} "
              f"(solved at the end: {solved.mean():.2f}) ({time.perf_counter() - start:.0f} s)",
              flush=True)
        if args.save_policy:  # weights only (torch.load(..., weights_only=True) reads them back)
            torch.save(policy.state_dict(), args.save_policy)


def failure_modes(args) -> None:
    from gpl_dist.config import config_from_dict
    from gpl_dist.corrections import make_corrector
    from gpl_dist.domains import get_domain
    from gpl_dist.models.gpl import build_model_from_config
    from learner.checkpoint import load_checkpoint
    from workers.loop import Rollout

    ckpt = load_checkpoint(f"{args.run_dir}/checkpoints")
    cfg = config_from_dict(ckpt.config, f"{args.run_dir}/config.yaml")
    if cfg.env.domain != "relocation":
        raise SystemExit(f"{args.run_dir} is a {cfg.env.domain} run; this benchmark analyses relocation runs")
    model = build_model_from_config(get_domain("relocation"), cfg.model)
    model.load_state_dict(ckpt.model_state)
    model.eval()
    rollout = Rollout(get_domain("relocation"), model, make_corrector("relocation", cfg.env.correction_kind),
                      end_aligned=cfg.model.trajectory_ends_at_last_state)
    test = split_tasks("relocation", "test")[:args.test_tasks]
    report_expert(test)
    attempts = rollout.run(tuple(test), args.corrections, args.seed, split="test",
                           policy_version=ckpt.policy_version).attempts
    print(f"{args.run_dir} (round {ckpt.round_index}), attempts ending below 0.9 completion, "
          "by where the block stopped:")
    for k in range(args.corrections + 1):
        rows = []
        for a in (a for a in attempts if a.attempt_index == k):
            task = make_task(a.task_id)
            q = BLOCK_QPOS[task.block]
            final = a.observations[-1]
            rows.append((task.target[0] - final[q], task.target[1] - final[q + 1], a.completion))
        arr = np.array(rows).reshape(-1, 3)
        bad = arr[arr[:, 2] < 0.9]
        past, short = int((bad[:, 0] < -0.03).sum()), int((bad[:, 0] > 0.03).sum())
        print(f"  c{k}: {len(arr)} attempts (unsolved tasks), {len(bad)} below 0.9: past the target in x {past}, "
              f"short in x {short}, off in y only {len(bad) - past - short}; mean |dy| of these "
              f"{np.abs(bad[:, 1]).mean() if len(bad) else 0.0:.3f}")


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rounds", type=int, default=8, help="DAgger rounds")
    p.add_argument("--tasks", type=int, default=250, help="training tasks rolled out per round")
    p.add_argument("--test-tasks", type=int, default=100)
    p.add_argument("--epochs", type=int, default=5, help="epochs over the aggregate per round")
    p.add_argument("--width", type=int, default=256, help="hidden units of the 3-layer head")
    p.add_argument("--keep-rounds", type=int, default=0, help="train on the newest N rounds only (0: all)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--save-policy", default="", help="write the privileged policy's state_dict here after every round")
    p.add_argument("--run-dir", default="", help="analyse this GPL run's failure modes instead")
    p.add_argument("--corrections", type=int, default=5)
    p.add_argument("--threads", type=int, default=1, help="torch threads")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    if args.run_dir:
        failure_modes(args)
    else:
        privileged_dagger(args)


if __name__ == "__main__":
    main()

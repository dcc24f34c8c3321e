"""How well can a policy imitate the relocation expert? Two measurements that bound GPL's results.

1. **Privileged DAgger** (default): the GPL head (MLP 3 x 256 over the normalised 28-d observation)
   is given the exact target and goal block as 5 extra inputs (as the authors' full-information
   oracle), and trained by DAgger on ``--tasks`` training tasks: each round rolls the current
   policy out (sampled actions) on every task, labels every state with the expert's distribution,
   aggregates all rounds' states (or only the newest ``--keep-rounds``, like a FIFO buffer) and
   trains ``--epochs`` epochs with cross-entropy. Printed per round: completion on the training
   rollouts, the policy's KL to the expert on the states it has just visited (before training on
   them: DAgger's on-policy error), the KL on the training states, and completion on
   ``--valid-tasks`` held-out tasks of the valid split. Whatever this reaches is a ceiling for GPL,
   which must infer the target from language.
2. **Failure modes of a run** (``--run-dir``): rolls a GPL checkpoint out on valid tasks with
   corrections and classifies the attempts that end below 0.9 completion by where the block
   stopped: past the target in x (the expert needs its back pose to push -x), short of it, or
   off in y only.

Both also print the expert's own completion on the same valid tasks, hard and sampled from its
labels, so the gap is measured side by side. Deterministic for a given ``--seed``. Both read the
valid split, never test: what they show informs choices.

    .venv/bin/python research/relocation_imitation.py [--rounds 8] [--tasks 250] [--valid-tasks 100]
    .venv/bin/python research/relocation_imitation.py --run-dir runs/rl-v4
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from gpl_dist.envs.relocation_core import BLOCK_QPOS, make_task
from gpl_dist.splits import split_tasks
from learner.relocation_expert_training import MONITOR_SEED, DaggerSettings, expert_on, privileged_dagger


def report_expert(task_ids) -> None:
    """Print the expert's completion on ``task_ids``, reset as every rollout here is."""
    hard, sampled = expert_on(task_ids, MONITOR_SEED)
    print(f"expert on {len(task_ids)} valid tasks: completion {hard:.3f} (its actions), "
          f"{sampled:.3f} (sampled from its labels)")


def dagger(args) -> None:
    settings = DaggerSettings(rounds=args.rounds, tasks=args.tasks, valid_tasks=args.valid_tasks, epochs=args.epochs,
                              width=args.width, keep_rounds=args.keep_rounds, seed=args.seed)
    save = (lambda policy: torch.save(policy.state_dict(), args.save_policy)) if args.save_policy else None
    privileged_dagger(settings, lambda line: print(line, flush=True), on_round=save)


def failure_modes(args) -> None:
    from gpl_dist.config import config_from_dict
    from gpl_dist.corrections import make_corrector
    from gpl_dist.domains import get_domain
    from gpl_dist.models.build import build_model_from_config
    from learner.checkpoint import load_checkpoint
    from workers.rollout import Rollout

    ckpt = load_checkpoint(f"{args.run_dir}/checkpoints")
    cfg = config_from_dict(ckpt.config, f"{args.run_dir}/config.yaml")
    if cfg.env.domain != "relocation":
        raise SystemExit(f"{args.run_dir} is a {cfg.env.domain} run; this benchmark analyses relocation runs")
    model = build_model_from_config(get_domain("relocation"), cfg.model)
    model.load_state_dict(ckpt.model_state)
    model.eval()
    rollout = Rollout(get_domain("relocation"), model, make_corrector("relocation", cfg.env.correction_kind),
                      end_aligned=cfg.model.trajectory_ends_at_last_state)
    valid = split_tasks("relocation", "valid")[:args.valid_tasks]
    report_expert(valid)
    attempts = rollout.run(tuple(valid), args.corrections, args.seed, split="valid",
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
    p.add_argument("--valid-tasks", type=int, default=100, help="first N valid tasks for the printed completions")
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
        dagger(args)


if __name__ == "__main__":
    main()

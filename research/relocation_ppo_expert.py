"""What would the authors' per-task PPO experts cost here? Train a few with their settings (on
stable-baselines3's PPO) and time them.

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

from gpl_dist.app.suite.rl.per_task import CompletionRecorder
from gpl_dist.envs.relocation_core import EPISODE_STEPS, NUM_TASKS
from gpl_dist.splits import split_tasks
from learner.ppo import PPOSettings, make_sb3_ppo

NUM_COPIES = 20


#: The authors' per-task PPO (the project's PPO defaults, ``learner.ppo``): one episode of each of
#: 20 copies per iteration, GAE with lambda 1 (their Monte-Carlo returns, except that SB3
#: bootstraps the value at the time limit), one Adam at 1e-3, the value loss at full weight and a
#: small entropy bonus; their value network (2 x 64, Tanh, with the policy 2 x 32 in ``train_task``)
#: and minibatches of 128.
AUTHORS_PPO = PPOSettings(n_envs=NUM_COPIES, batch_size=128, value_hidden=64, value_layers=2, share_trunk=True)


def train_task(task_id: int, max_iterations: int, seed: int, log_every: int = 0) -> dict:
    """SB3 PPO on one task until all episodes of an iteration finish or ``max_iterations`` ran (the
    seconds include the update after the finishing iteration, which SB3 runs before it stops)."""
    import gymnasium
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import DummyVecEnv

    recorders: list[CompletionRecorder] = []

    def make(k: int):
        def build():
            recorders.append(CompletionRecorder(gymnasium.make("gpl/Relocation-v0", task_id=task_id)))
            return recorders[-1]
        return build

    env = DummyVecEnv([make(k) for k in range(AUTHORS_PPO.n_envs)])
    env.seed(seed)
    model = make_sb3_ppo(env, AUTHORS_PPO, episode_steps=EPISODE_STEPS, seed=seed, pi=[32, 32], activation_fn=nn.Tanh)
    state = {"iterations": 0, "finished_at": None, "completion": 0.0}

    class UntilAllFinish(BaseCallback):
        def _on_step(self) -> bool:
            return state["finished_at"] is None  # the next rollout's first step ends learn()

        def _on_rollout_end(self) -> None:
            it = state["iterations"]
            state["iterations"] = it + 1
            state["completion"] = float(np.mean([r.completion[-1] for r in recorders]))
            if all(r.success[-1] for r in recorders):
                state["finished_at"] = it
            elif log_every and it % log_every == 0:
                done = np.mean([r.success[-1] for r in recorders])
                print(f"  task {task_id} iteration {it}: completion {state['completion']:.3f}, finished {done:.2f}",
                      flush=True)

    start = time.perf_counter()
    model.learn(total_timesteps=max_iterations * NUM_COPIES * EPISODE_STEPS, callback=UntilAllFinish())
    return {"task": task_id, "iterations": state["iterations"], "finished_at": state["finished_at"],
            "completion": state["completion"], "seconds": time.perf_counter() - start}


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

"""Multi-room expert: labels/s and completion over all 3240 tasks, from the start and perturbed.

- labels/s on learner-like states (a random policy's trajectories, the states DAgger labels),
  timing ``expert.act`` only, with the per-(target, door mask) path cache cold and warm;
- success and mean steps of the expert from every task's start state (within 100 steps);
- success from perturbed states: a random prefix of 0-60 random actions, then the expert;
  success within the 100-step episode, and eventually (optimality check: the expert's steps
  equal its planned cost-to-go).

Run: ``python benchmarks/expert_speed.py``.
"""

from __future__ import annotations

import time

import numpy as np

from gpl_dist.envs.multiroom import MAX_STEPS, MultiRoomEnv
from gpl_dist.experts.multiroom import MultiRoomExpert, cache_size, clear_cache

NUM_TASKS = 3240


def label_speed(expert: MultiRoomExpert, tasks, steps_per_task: int, seed: int) -> tuple[float, int]:
    rng = np.random.default_rng(seed)
    spent, n = 0.0, 0
    for t in tasks:
        env = MultiRoomEnv(int(t))
        env.reset()
        for a in rng.integers(0, 6, size=steps_per_task):
            t0 = time.perf_counter()
            expert.act(env)
            spent += time.perf_counter() - t0
            n += 1
            env.step(a)
    return n / spent, n


def main() -> None:
    expert = MultiRoomExpert()
    rng = np.random.default_rng(0)
    clear_cache()
    tasks = rng.permutation(NUM_TASKS)
    cold, n = label_speed(expert, tasks, 100, seed=1)
    warm, _ = label_speed(expert, tasks, 100, seed=1)
    print("== multiroom expert ==")
    print(f"labels/s on random-policy states: {cold:,.0f} (cold cache, {n} labels), {warm:,.0f} (warm); "
          f"{cache_size()} cached path maps")

    t0 = time.perf_counter()
    steps, ok = [], 0
    for t in range(NUM_TASKS):
        env = MultiRoomEnv(t)
        env.reset()
        for k in range(1, MAX_STEPS + 1):
            env.step(expert.act(env))
            if env.success:
                break
        ok += env.success
        steps.append(k)
    print(f"from start: {ok}/{NUM_TASKS} solved within {MAX_STEPS} steps, steps min {min(steps)} "
          f"mean {np.mean(steps):.2f} max {max(steps)} ({time.perf_counter() - t0:.2f} s)")

    t0 = time.perf_counter()
    within, eventually, optimal, completion, expert_steps = 0, 0, 0, [], []
    for t in range(NUM_TASKS):
        env = MultiRoomEnv(t)
        env.reset()
        for a in rng.integers(0, 6, size=int(rng.integers(0, 61))):
            env.step(a)
        planned = expert.cost_to_go(env) if not env.success else 0
        k = 0
        while not env.success and k < 400:
            env.step(expert.act(env))
            k += 1
            if env.steps == MAX_STEPS:
                completion.append(env.completion)
        if env.steps < MAX_STEPS:
            completion.append(env.completion)
        within += env.success and env.steps <= MAX_STEPS
        eventually += env.success
        optimal += k == planned
        expert_steps.append(k)
    print(f"perturbed (0-60 random actions, then expert): {within}/{NUM_TASKS} solved within {MAX_STEPS} steps, "
          f"{eventually}/{NUM_TASKS} eventually, {optimal}/{NUM_TASKS} in exactly the planned cost; "
          f"mean completion at step {MAX_STEPS} {np.mean(completion):.4f}; expert steps mean "
          f"{np.mean(expert_steps):.2f} max {max(expert_steps)} ({time.perf_counter() - t0:.2f} s)")


if __name__ == "__main__":
    main()

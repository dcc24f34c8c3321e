"""BabyAI expert (the plug-in ``plugins/gpl-babyai``): labels/s per level and success rate.

    pip install -e plugins/gpl-babyai
    python benchmarks/babyai_expert_speed.py [--tasks-per-level 20] [--levels GoTo,Unlock] [--no-stock]

For each level of the plug-in's task table, over ``--tasks-per-level`` of its tasks (spread over
its seeds, every split):

- **from start**: the expert (``gpl_babyai.expert.BotExpert``: minigrid's BabyAI bot over the
  plug-in's cached grid, replanning each step) labels its own trajectory from the task's start:
  labels/s (the time of ``expert.act`` alone), success within an attempt (128 steps), mean steps;
- **DAgger states**: a policy that takes the expert's action with probability 0.5 and a random one
  otherwise, as an early DAgger round does, for a whole attempt; labels/s of ``expert.act`` on the
  states before the attempt succeeded (after it, the label is ``done`` without asking the bot),
  bot takeovers per 1000 of those labels, fallbacks (``done`` because no bot could plan) per 1000,
  the fraction of attempts that became unsolvable (the policy opened a box the mission needs:
  the expert then says ``done``), and the success of such attempts;
- **takeover**: 30 random actions, then the expert alone: success within the attempt's remaining
  98 steps (how well the bot finishes from states it did not lead to);
- **stock**, for reference (``--no-stock`` skips it): minigrid's own ``BabyAIBot.replan`` on
  minigrid's own env along the expert's from-start trajectory: labels/s (its replan recomputes the
  agent's view, and its search slices lists);
- **env**: the plug-in env's steps/s alone (random actions), for scale.

The figures are throughputs of one process: run it alone (2-core machines share their cores).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import time

import numpy as np


def _tasks(level: str, n: int) -> list[int]:
    from gpl_babyai import tasks as task_table

    ids = task_table.tasks_of_level(level)
    return [ids[int(i)] for i in np.linspace(0, len(ids) - 1, num=min(n, len(ids))).round()]


def from_start(task_ids: list[int]) -> dict:
    from gpl_babyai.domain import STEPS
    from gpl_babyai.env import BabyAIEnv
    from gpl_babyai.expert import BotExpert

    expert, spent, labels, solved, steps, traces = BotExpert(), 0.0, 0, 0, [], {}
    for task_id in task_ids:
        env = BabyAIEnv(task_id)
        env.reset(seed=0)
        actions = []
        for t in range(STEPS):
            t0 = time.perf_counter()
            a = expert.act(env)
            spent += time.perf_counter() - t0
            labels += 1
            actions.append(a)
            env.step(a)
            if env.success:
                break
        solved += env.success
        steps.append(t + 1)
        traces[task_id] = actions
    return {"labels_per_s": labels / spent, "success": solved / len(task_ids), "mean_steps": float(np.mean(steps)),
            "traces": traces}


def dagger_states(task_ids: list[int], seed: int = 0) -> dict:
    from gpl_babyai.domain import STEPS
    from gpl_babyai.env import BabyAIEnv
    from gpl_babyai.expert import BotExpert

    expert, spent, labels, solved, takeovers, fallbacks, gone = BotExpert(), 0.0, 0, 0, 0, 0, 0
    for task_id in task_ids:
        env = BabyAIEnv(task_id)
        env.reset(seed=seed)
        rng = np.random.default_rng([seed, task_id])
        for _ in range(STEPS):
            asked = not env.success
            t0 = time.perf_counter()
            a = expert.act(env)
            if asked:
                spent += time.perf_counter() - t0
                labels += 1
            env.step(a if rng.random() < 0.5 else int(rng.integers(7)))
        solved += env.success
        takeovers += env.expert_state.get("takeovers", 0)
        fallbacks += env.expert_state.get("fallbacks", 0)
        gone += bool(env.expert_state.get("target_gone"))
    return {"labels_per_s": labels / spent, "success": solved / len(task_ids),
            "takeovers_per_1000": 1000 * takeovers / labels, "fallbacks_per_1000": 1000 * fallbacks / labels,
            "target_gone": gone / len(task_ids)}


def takeover(task_ids: list[int], prefix: int = 30) -> float:
    from gpl_babyai.domain import STEPS
    from gpl_babyai.env import BabyAIEnv
    from gpl_babyai.expert import BotExpert

    expert, solved = BotExpert(), 0
    for task_id in task_ids:
        env = BabyAIEnv(task_id)
        env.reset(seed=0)
        rng = np.random.default_rng(task_id)
        for _ in range(prefix):
            env.step(int(rng.integers(7)))
        for _ in range(STEPS - prefix):
            env.step(expert.act(env))
        solved += env.success
    return solved / len(task_ids)


def stock(traces: dict[int, list[int]]) -> float:
    """minigrid's BabyAIBot on minigrid's env, told the same (its own) actions: labels/s of ``replan``."""
    import gymnasium as gym
    import minigrid  # noqa: F401
    from gpl_babyai import tasks as task_table
    from minigrid.utils.baby_ai_bot import BabyAIBot

    spent, labels = 0.0, 0
    for task_id, actions in traces.items():
        task = task_table.task(task_id)
        env = gym.make(f"BabyAI-{task.level}-v0").unwrapped
        with contextlib.redirect_stdout(io.StringIO()):
            env.reset(seed=task.seed)
        bot, taken = BabyAIBot(env), None
        for a in actions:
            t0 = time.perf_counter()
            bot.replan(taken)
            spent += time.perf_counter() - t0
            labels += 1
            env.step(a)
            taken = a
    return labels / spent


def env_speed(task_ids: list[int]) -> float:
    from gpl_babyai.domain import STEPS
    from gpl_babyai.env import BabyAIEnv

    n, spent = 0, 0.0
    for task_id in task_ids:
        env = BabyAIEnv(task_id)
        rng = np.random.default_rng(task_id)
        actions = rng.integers(7, size=STEPS).tolist()
        t0 = time.perf_counter()
        env.reset(seed=0)
        for a in actions:
            env.step(a)
        spent += time.perf_counter() - t0
        n += STEPS
    return n / spent


def main(argv: list[str] | None = None) -> None:
    from gpl_babyai import tasks as task_table

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tasks-per-level", type=int, default=20)
    p.add_argument("--levels", help="comma-separated levels (default: every level of the task table)")
    p.add_argument("--no-stock", action="store_true", help="skip minigrid's own bot (the reference)")
    args = p.parse_args(argv)
    levels = args.levels.split(",") if args.levels else task_table.table()["levels"]
    print(f"== BabyAI expert, {args.tasks_per_level} tasks a level (labels/s of one process) ==")
    from_start(_tasks(levels[0], 1))  # warm up: imports and first-call costs out of the figures
    head = (f"{'level':14s} {'start: lab/s':>12s} {'succ':>5s} {'steps':>6s} | {'dagger: lab/s':>13s} {'succ':>5s} "
            f"{'takeov/1k':>9s} {'fallb/1k':>8s} {'gone':>5s} | {'takeover succ':>13s} | {'stock lab/s':>11s} | "
            f"{'env steps/s':>11s}")
    print(head)
    totals = []
    for level in levels:
        ids = _tasks(level, args.tasks_per_level)
        start = from_start(ids)
        dagger = dagger_states(ids)
        taken = takeover(ids)
        ref = stock(start["traces"]) if not args.no_stock else float("nan")
        env = env_speed(ids)
        totals.append((start["labels_per_s"], dagger["labels_per_s"], start["success"], taken))
        print(f"{level:14s} {start['labels_per_s']:12,.0f} {start['success']:5.2f} {start['mean_steps']:6.1f} | "
              f"{dagger['labels_per_s']:13,.0f} {dagger['success']:5.2f} {dagger['takeovers_per_1000']:9.1f} "
              f"{dagger['fallbacks_per_1000']:8.1f} {dagger['target_gone']:5.2f} | {taken:13.2f} | {ref:11,.0f} | "
              f"{env:11,.0f}", flush=True)
    arr = np.array(totals)
    print(f"{'mean':14s} {arr[:, 0].mean():12,.0f} {arr[:, 2].mean():5.2f} {'':6s} | {arr[:, 1].mean():13,.0f} "
          f"{'':5s} {'':9s} {'':8s} {'':5s} | {arr[:, 3].mean():13.2f} |")
    steps = {level: np.array([t.bot_steps for t in task_table.tasks() if t.level == level]) for level in levels}
    print("bot steps from the start over the whole table (tasks were kept when <= 96): "
          + ", ".join(f"{lv} p50 {np.median(s):.0f} p90 {np.percentile(s, 90):.0f} max {s.max()}" for lv, s in steps.items()))


if __name__ == "__main__":
    main()

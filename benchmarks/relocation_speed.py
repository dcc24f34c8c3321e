"""Relocation env speed beside raw ``mj_step`` of the same model, measured side by side in one run.

    .venv/bin/python benchmarks/relocation_speed.py [--steps 50000]

``measure_relocation_speed()`` is reusable (e.g. by ``benchmarks/env_speed.py``).
"""

from __future__ import annotations

import argparse
import time

import mujoco
import numpy as np


def measure_relocation_speed(steps: int = 50_000, task_id: int = 0, seed: int = 0, repeats: int = 3) -> dict:
    """Best-of-``repeats`` env steps/s (random actions, resets every 350 steps included) and raw
    ``mj_step``/s of the same model with the same control pattern, interleaved in one process."""
    from gpl_dist.envs.relocation import _ACTION_CTRL, RelocationEnv, load_model

    actions = np.random.default_rng(seed).integers(4, size=steps).tolist()
    env = RelocationEnv(task_id)
    model = load_model()
    data = mujoco.MjData(model)
    env_rates, raw_rates = [], []
    for _ in range(repeats):
        env.reset(seed=seed)
        t0 = time.perf_counter()
        for a in actions:
            if env.step(a)[3]:
                env.reset()
        env_rates.append(steps / (time.perf_counter() - t0))
        data.qpos[:] = env.data.qpos
        data.qpos[3:9] = (0.3, 0.2, 0.3, 0.0, 0.3, -0.2)
        mujoco.mj_forward(model, data)
        ctrls = [_ACTION_CTRL[a] for a in actions]
        t0 = time.perf_counter()
        for cx, cy in ctrls:
            data.ctrl[0] = cx
            data.ctrl[1] = cy
            mujoco.mj_step(model, data)
        raw_rates.append(steps / (time.perf_counter() - t0))
    env_best, raw_best = max(env_rates), max(raw_rates)
    return {"env_steps_per_s": env_best, "raw_mj_step_per_s": raw_best, "ratio": env_best / raw_best}


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=50_000)
    p.add_argument("--repeats", type=int, default=3)
    args = p.parse_args(argv)
    r = measure_relocation_speed(args.steps, repeats=args.repeats)
    print(f"{'relocation env':>18s} {r['env_steps_per_s']:>12,.0f} steps/s")
    print(f"{'raw mj_step':>18s} {r['raw_mj_step_per_s']:>12,.0f} steps/s")
    print(f"{'ratio':>18s} {r['ratio']:>12.2f}x   (target >= 0.30x)")


if __name__ == "__main__":
    main()

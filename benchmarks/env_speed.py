"""Env step throughput, single core, random actions.

Multi-room: stock ``gymnasium.make("MiniGrid-MultiRoom-N6-v0")`` side by side with gpl-dist's
``MultiRoomEnv`` (unwrapped, and through ``gymnasium.make("gpl/MultiRoom-v0")`` with its wrappers);
prints steps/s of each and the ratio. Relocation: ``gpl/Relocation-v0`` beside raw ``mj_step`` of
the same MuJoCo model with the same controls.

Run: ``python benchmarks/env_speed.py [--seconds 3] [--only multiroom]``.
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np


def _steps_per_second(env, seconds: float, seed: int = 0) -> float:
    rng = np.random.default_rng(seed)
    n_actions = env.action_space.n
    actions = rng.integers(0, n_actions, size=1 << 16)
    env.reset(seed=seed)
    steps = 0
    t0 = time.perf_counter()
    deadline = t0 + seconds
    while True:
        for a in actions[:4096]:
            _, _, terminated, truncated, _ = env.step(int(a))
            if terminated or truncated:
                env.reset()
        steps += 4096
        actions = np.roll(actions, 4096)
        if time.perf_counter() > deadline:
            break
    return steps / (time.perf_counter() - t0)


def bench_multiroom(seconds: float) -> dict[str, float]:
    import minigrid  # noqa: F401  (registers MiniGrid-*)

    import gpl_dist  # noqa: F401
    from gpl_dist.envs.multiroom import MultiRoomEnv

    stock = _steps_per_second(gym.make("MiniGrid-MultiRoom-N6-v0"), seconds)
    ours = _steps_per_second(MultiRoomEnv(727), seconds)
    wrapped = _steps_per_second(gym.make("gpl/MultiRoom-v0", task_id=727), seconds)
    t0 = time.perf_counter()
    for t in range(3240):
        MultiRoomEnv(t)
    build_cold = (time.perf_counter() - t0) / 3240
    t0 = time.perf_counter()
    for t in range(3240):
        MultiRoomEnv(t)
    build_warm = (time.perf_counter() - t0) / 3240
    print("== multiroom (random actions, one core) ==")
    print(f"stock MiniGrid-MultiRoom-N6-v0 (gymnasium.make): {stock:12,.0f} steps/s")
    print(f"gpl MultiRoomEnv (unwrapped)                   : {ours:12,.0f} steps/s   ratio {ours / stock:6.1f}x")
    print(f"gpl/MultiRoom-v0 (gymnasium.make, wrapped)     : {wrapped:12,.0f} steps/s   ratio {wrapped / stock:6.1f}x")
    print(f"env construction: {build_cold * 1e6:.0f} us/env cold (first build of each task), {build_warm * 1e6:.0f} us/env warm")
    return {"stock": stock, "multiroom": ours, "multiroom_wrapped": wrapped,
            "ratio": ours / stock, "ratio_wrapped": wrapped / stock}


def bench_relocation(seconds: float) -> dict[str, float]:
    """gpl/Relocation-v0 steps/s beside raw ``mj_step`` of the same model (target: at least 0.3x)."""
    from relocation_speed import measure_relocation_speed  # benchmarks/ is on sys.path when run as a script

    print("== relocation (random actions, one core) ==")
    r = measure_relocation_speed(steps=max(5_000, int(seconds * 40_000)))
    print(f"raw mj_step (same model, same controls)        : {r['raw_mj_step_per_s']:>12,.0f} steps/s")
    print(f"gpl RelocationEnv (unwrapped)                  : {r['env_steps_per_s']:>12,.0f} steps/s   ratio {r['ratio']:7.2f}x")
    return r


SECTIONS = {"multiroom": bench_multiroom, "relocation": bench_relocation}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0, help="measuring time per env")
    parser.add_argument("--only", choices=sorted(SECTIONS), default=None)
    args = parser.parse_args()
    for name, fn in SECTIONS.items():
        if args.only in (None, name):
            fn(args.seconds)


if __name__ == "__main__":
    main()

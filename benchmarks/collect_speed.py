"""Collection throughput in labelled tuples/s, side by side in one run (multi-room, relocation).

    python benchmarks/collect_speed.py [--domain multiroom|relocation|both] [--tasks N]
        [--tasks-per-unit N] [--corrections 5] [--actors 1 2]

Rows, for each domain:
- bare env, random actions (the ceiling): one process, and two processes at once (the 2-core
  ceiling);
- gpl-dist with 1 and 2 Ray rollout actors (``--actors``): the whole path (batched policy
  inference, expert labels, corrections, shard writes, round commit) for one DAgger round over
  ``--tasks`` tasks (default: every training task, as in the paper), with the domain's shipped
  config (``configs/<domain>.yaml``: model, expert, ``tasks_per_unit`` unless given). Multi-room
  first collects a round over the same tasks (the actors' expert caches are warm, as in a run
  from its second round on); relocation's expert has no caches, so its first round is one task
  per actor (the actors start and import);
- a naive loop, as the authors' code and the imitation library collect: one env at a time, a
  batch-1 policy forward and an expert query per step, corrections in the same process, no
  storage;
- for reference, the batched policy forward alone at the unit's batch size, the expert labelling
  the unit's envs alone, and (MuJoCo) the simulator's own ``mj_step``: every labelled tuple costs
  one step, one state of the forward and one label, so their sum bounds the fraction of the 2-core
  ceiling that any collection with these networks and labels can reach (the ``bound`` line).

The networks are freshly initialised (seed 0): the policy then solves no task, every task runs
all its attempts, and the tuple count is the largest a round can have. Run it alone: the figures
are throughputs of the whole machine.

Targets on 2 cores (issue): 2 workers >= 0.5x the 2-core ceiling, >= 1.8x one worker, >= 10x naive.
"""

from __future__ import annotations

import argparse
import dataclasses
import multiprocessing as mp
import os
import tempfile
import time
from pathlib import Path

# one BLAS thread in this process, as Ray gives a 1-CPU rollout actor (OMP_NUM_THREADS=1): the naive
# loop's expert then runs as it would there (set before numpy starts OpenBLAS)
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def shipped_config(domain: str):
    """The run config ``configs/<domain>.yaml`` ships."""
    from gpl_dist.config import load_config

    return load_config(CONFIGS / f"{domain}.yaml")


def shipped_model(domain: str):
    """``(ModelConfig, network)``: the network that ``configs/<domain>.yaml`` ships, freshly
    initialised (seed 0), so the rollouts run the forward a real run runs."""
    from gpl_dist.domains import get_domain
    from gpl_dist.models.build import build_model_from_config

    model_cfg = shipped_config(domain).model
    return model_cfg, build_model_from_config(get_domain(domain), model_cfg, seed=0)


def bare_env_rate(seconds: float, seed: int = 0, domain: str = "multiroom") -> float:
    from gpl_dist.domains import get_domain

    d = get_domain(domain)
    env = d.make_env(seed % d.num_tasks)
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


def bare_env_two_processes(seconds: float, domain: str = "multiroom") -> float:
    with mp.get_context("spawn").Pool(2) as pool:
        return sum(pool.map(_bare_worker, [(seconds, 1, domain), (seconds, 2, domain)]))


def gpl_dist_rate(num_workers: int, tasks: tuple[int, ...], corrections: int, tasks_per_unit: int,
                  domain: str = "multiroom") -> tuple[float, int]:
    from gpl_dist.config import CollectionConfig, config_from_dict
    from gpl_dist.models.build import state_dict_to_numpy
    from learner.driver import make_units
    from storage import commit_round
    from workers.ray_collector import RayCollector
    from workers.worker import RolloutSettings

    root = tempfile.mkdtemp(prefix="gpl-collect-bench-")
    model_cfg, model = shipped_model(domain)
    weights = state_dict_to_numpy(model)
    if domain == "multiroom":  # the rows as they were first measured (the default expert and oracle)
        cfg = config_from_dict({"collection": {"tasks_per_unit": tasks_per_unit, "num_corrections": corrections}})
        settings = RolloutSettings(collection=CollectionConfig(num_corrections=corrections), model=model_cfg)
    else:
        shipped = shipped_config(domain)
        cfg = dataclasses.replace(shipped, collection=dataclasses.replace(
            shipped.collection, tasks_per_unit=tasks_per_unit, num_corrections=corrections))
        settings = RolloutSettings.of_run(cfg)
    collector = RayCollector(domain, settings, root, "bench", num_workers)
    try:
        # round 0 warms up (actors start, import torch; multi-room: fill the expert's distance-map
        # caches for these tasks); round 1, timed, is the steady state of a DAgger run from its
        # second round on
        warm = tasks if domain == "multiroom" else tasks[:num_workers]
        warm_cfg = cfg if domain == "multiroom" else dataclasses.replace(
            cfg, collection=dataclasses.replace(cfg.collection, tasks_per_unit=1))
        collector.collect_round(make_units(warm, 0, warm_cfg, "train", 0), weights, 0)
        units = make_units(tasks, 1, cfg, "train", 0)
        t0 = time.perf_counter()
        results = collector.collect_round(units, weights, 0)
        commit_round(root, 1, [r.shard for r in results])
        seconds = time.perf_counter() - t0
    finally:
        collector.close()
    tuples = sum(r.shard.num_tuples for r in results)
    return tuples / seconds, tuples


def policy_forward_rate(batch: int, seconds: float, domain: str = "multiroom") -> float:
    """States/s of the batched policy forward alone (one process), as a worker runs it each step."""
    from gpl_dist.allocator import keep_freed_memory
    from gpl_dist.domains import get_domain

    keep_freed_memory()
    d = get_domain(domain)
    model = shipped_model(domain)[1].eval()
    rng = np.random.default_rng(0)
    if d.obs_categories is not None:
        obs = torch.from_numpy((rng.random((batch,) + d.obs_shape) * np.array(d.obs_categories)).astype(np.uint8))
    else:
        obs = torch.from_numpy(rng.normal(size=(batch,) + d.obs_shape).astype(np.float32))
    z = torch.zeros(batch, model.conditioning_dim)
    n, t0 = 0, time.perf_counter()
    with torch.inference_mode():
        while time.perf_counter() - t0 < seconds:
            model.action_logits(obs, z)
            n += batch
    return n / (time.perf_counter() - t0)


def naive_rate(tasks: tuple[int, ...], corrections: int, domain: str = "multiroom") -> float:
    """One env, batch-1 forward, per-step expert query (the original code's and imitation's loop)."""
    from gpl_dist.corrections import make_corrector
    from gpl_dist.domains import get_domain
    from gpl_dist.experts import make_expert
    from gpl_dist.models.layers import Conditioning
    from gpl_dist.roles import trajectory_times

    d = get_domain(domain)
    model_cfg, model = shipped_model(domain)
    model.eval()
    env_cfg = shipped_config(domain).env
    oracle = make_corrector(domain, env_cfg.correction_kind)
    vocab = d.vocabulary
    times = trajectory_times(d.steps_per_attempt, d.trajectory_stride, model_cfg.trajectory_ends_at_last_state)
    n, t0 = 0, time.perf_counter()
    for task in tasks:
        env = d.make_env(task)
        expert = make_expert(env, env_cfg.expert)
        history: list[tuple[np.ndarray, np.ndarray]] = []
        for k in range(corrections + 1):
            obs, info = env.reset(seed=k)
            traj = []
            cond = Conditioning(
                torch.from_numpy(vocab.encode(env.instruction)[None]),
                (torch.from_numpy(np.stack([h[0] for h in history])) if history
                 else torch.zeros((0, len(times)) + d.obs_shape, dtype=getattr(torch, d.obs_dtype))),
                (torch.from_numpy(np.stack([h[1] for h in history])) if history
                 else torch.zeros((0, vocab.max_tokens), dtype=torch.long)),
                torch.arange(len(history)).view(1, -1),
            )
            for _ in range(d.steps_per_attempt):
                with torch.no_grad():
                    logits = model(torch.from_numpy(obs[None]), cond, torch.zeros(1, dtype=torch.long))
                action = int(torch.distributions.Categorical(logits=logits).sample())
                if expert.soft_labels:
                    expert.label(env)  # the label and its distribution
                else:
                    expert.act(env)  # the label
                traj.append(obs)
                obs, _, _, _, info = env.step(action)
                n += 1
            if info["success"]:
                break
            corr = oracle.correct(env, np.random.default_rng(k))
            history.append((np.stack([traj[i] for i in times]), vocab.encode(corr.text)))
    return n / (time.perf_counter() - t0)


def expert_label_rate(batch: int, seconds: float, domain: str = "multiroom") -> float:
    """States/s of the shipped config's expert labelling ``batch`` envs of training tasks alone (one
    process): one ``label_batch`` call for a ``BatchExpert`` with soft labels, else one call per env,
    as the rollout loop makes them each step."""
    from gpl_dist.domains import get_domain
    from gpl_dist.roles import BatchExpert
    from gpl_dist.splits import split_tasks

    d = get_domain(domain)
    expert = d.experts[shipped_config(domain).env.expert or next(iter(d.experts))]()
    envs = [d.make_env(t) for t in split_tasks(domain, "train")[:batch]]
    for i, env in enumerate(envs):
        env.reset(seed=i)
    batched = expert.soft_labels and isinstance(expert, BatchExpert)
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        if batched:
            expert.label_batch(envs)
        else:
            for env in envs:
                expert.label(env) if expert.soft_labels else expert.act(env)
        n += len(envs)
    return n / (time.perf_counter() - t0)


def physics_step_rate(seconds: float, domain: str) -> float | None:
    """Steps/s of the simulator's own step (``mujoco.mj_step`` on the env's model and data, no
    Python wrapper), for an env that has one; None otherwise."""
    from gpl_dist.domains import get_domain

    d = get_domain(domain)
    env = d.make_env(0)
    env.reset(seed=0)
    sim = getattr(env, "unwrapped", env)
    if not (hasattr(sim, "model") and hasattr(sim, "data")):
        return None
    import mujoco

    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for _ in range(1000):
            mujoco.mj_step(sim.model, sim.data)
        n += 1000
        sim.reset(seed=n)  # keep the scene in range
    return n / (time.perf_counter() - t0)


def run_domain(domain: str, args: argparse.Namespace) -> None:
    """Every row of ``domain``, printed once all are measured."""
    from gpl_dist.splits import split_tasks

    tasks = split_tasks(domain, "train")
    if args.tasks:
        tasks = tasks[: args.tasks]
    per = args.tasks_per_unit or (128 if domain == "multiroom" else shipped_config(domain).collection.tasks_per_unit)
    bare1 = bare_env_rate(args.seconds, domain=domain)
    bare2 = bare_env_two_processes(args.seconds, domain)
    rates = {w: gpl_dist_rate(w, tasks, args.corrections, per, domain) for w in args.actors}
    naive = naive_rate(tasks[: args.naive_tasks], args.corrections, domain)
    forward = policy_forward_rate(per, args.seconds, domain)
    labels = expert_label_rate(per, args.seconds, domain)
    physics = physics_step_rate(args.seconds, domain)
    print(f"== {domain}: {len(tasks)} tasks, {per} a unit, {args.corrections} corrections")
    print(f"{'bare env, random actions, 1 process':<44} {bare1:>10,.0f} steps/s")
    print(f"{'bare env, random actions, 2 processes':<44} {bare2:>10,.0f} steps/s   (2-core ceiling)")
    for w, (rate, n) in rates.items():
        print(f"{f'gpl-dist, {w} rollout actor' + ('s' if w > 1 else ''):<44} {rate:>10,.0f} tuples/s  ({n:,} tuples)")
    print(f"{'naive loop (batch-1 policy, per-step expert)':<44} {naive:>10,.0f} tuples/s")
    print(f"{f'policy forward alone, batch {per}, 1 process':<44} {forward:>10,.0f} states/s"
          f"   ({1e6 / forward:.1f} us a state; a bare env step: {1e6 / bare1:.1f} us)")
    print(f"{f'expert labels alone, batch {per}, 1 process':<44} {labels:>10,.0f} states/s   ({1e6 / labels:.1f} us a state)")
    if physics is not None:
        print(f"{'simulator step alone (mj_step), 1 process':<44} {physics:>10,.0f} steps/s   ({1e6 / physics:.1f} us a step)")
    # what a labelled tuple costs at least on one core: its step, its state's forward and its label
    floor_us = 1e6 / (physics or bare1) + 1e6 / forward + 1e6 / labels
    print(f"bound: a tuple costs at least {floor_us:.1f} us on one core (step + forward + label), so 2 actors reach at "
          f"most {2e6 / floor_us / bare2:.2f} of the 2-core ceiling")
    if 1 in rates and 2 in rates:
        w1, w2 = rates[1][0], rates[2][0]
        print(f"ratios: 2 actors / 2-core ceiling = {w2 / bare2:.2f} (target >= 0.5); 2 actors / 1 actor = {w2 / w1:.2f} "
              f"(target >= 1.8); 2 actors / naive = {w2 / naive:.1f} (target >= 10)", flush=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--domain", choices=("multiroom", "relocation", "both"), default="multiroom")
    p.add_argument("--tasks", type=int, default=0,
                   help="training tasks in the round (0: all, as in the paper: 1700 multi-room, 750 relocation)")
    p.add_argument("--corrections", type=int, default=5)
    p.add_argument("--tasks-per-unit", type=int, default=0,
                   help="0: 128 for multi-room (as first measured), the shipped config's for relocation")
    p.add_argument("--actors", type=int, nargs="+", default=[1, 2], help="rollout actor counts to measure")
    p.add_argument("--seconds", type=float, default=3.0)
    p.add_argument("--naive-tasks", type=int, default=8)
    args = p.parse_args()
    torch.set_num_threads(1)
    for domain in ("multiroom", "relocation") if args.domain == "both" else (args.domain,):
        run_domain(domain, args)


if __name__ == "__main__":
    main()

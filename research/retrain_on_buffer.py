"""Train one model on a finished run's committed buffer, then meta-test it: a cheap A/B for learner
and model settings.

A DAgger run takes most of an hour; this takes one round's training and one evaluation (relocation:
about 3 min and 40 s on 2 cores). Both arms of a comparison read the same states and labels, so
the difference is the setting's alone, not a different data path. What it cannot show is the
setting's effect on the states later rounds would collect; confirm a winner with a real run.

The run's saved ``config.yaml`` is loaded and ``--set`` overrides applied to it, exactly as
``gpl-dist train --set`` does (unknown keys fail in one line). The model is fresh (seeded with the
run's ``seed``) unless ``--from-checkpoint`` continues one, with its Adam moments. It trains
``training.num_epochs_per_round`` epochs on the newest ``buffer.capacity_tuples`` tuples and is
evaluated with the run's ``eval`` settings. ``--out-dir`` saves the resolved config and a checkpoint
there, so ``gpl-dist eval --run-dir OUT`` can look again.

    .venv/bin/python research/retrain_on_buffer.py --run-dir runs/rl-v6
    .venv/bin/python research/retrain_on_buffer.py --run-dir runs/rl-v6 --set model.policy_batchnorm=true
    .venv/bin/python research/retrain_on_buffer.py --run-dir runs/rl-v6 \\
        --from-checkpoint runs/rl-v6/checkpoints/round-000011.pt --set training.learning_rate=1e-4
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch

from gpl_dist.cli import parse_overrides
from gpl_dist.config import ConfigError, config_to_dict, load_config, save_config
from gpl_dist.domains import get_domain
from gpl_dist.models.build import build_model_from_config
from learner.checkpoint import Checkpoint, capture_rng, load_checkpoint, save_checkpoint
from learner.driver import buffer_root
from learner.evaluate import evaluate_policy, format_table
from learner.trainer import Learner
from storage import BufferReader


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--run-dir", required=True, help="a finished run (its config.yaml and committed buffer)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override the run's config")
    p.add_argument("--from-checkpoint", default="", help="continue these weights and Adam moments")
    p.add_argument("--out-dir", default="", help="save the resolved config and the trained checkpoint here")
    args = p.parse_args(argv)

    run_dir = Path(args.run_dir)
    try:
        cfg = load_config(run_dir / "config.yaml", parse_overrides(args.set))
    except (ConfigError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    domain = get_domain(cfg.env.domain)
    torch.manual_seed(cfg.seed)
    np.random.seed(cfg.seed % (2**32))
    model = build_model_from_config(domain, cfg.model, seed=cfg.seed)
    learner = Learner(model, cfg.training, seed=cfg.seed)
    if args.from_checkpoint:
        ckpt = load_checkpoint(args.from_checkpoint)
        learner.model.load_state_dict(ckpt.model_state)
        learner.load_optimizer_state(ckpt.optimizer_state)
        for group in learner.optimizer.param_groups:  # the checkpoint's rate is the old run's
            group["lr"] = cfg.training.learning_rate

    t0 = time.perf_counter()
    view = BufferReader(buffer_root(cfg, run_dir)).load_training_view(
        cfg.buffer.capacity_tuples, domain.trajectory_stride, cfg.model.trajectory_ends_at_last_state)
    print(f"loaded {view.num_tuples:,} tuples in {time.perf_counter() - t0:.1f} s", flush=True)
    stats = learner.train_round(view, lambda e, loss, acc: print(f"epoch {e}: loss {loss:.4f} accuracy {acc:.3f}",
                                                                  flush=True))
    print(f"trained {cfg.training.num_epochs_per_round} epochs in {stats.seconds:.0f} s", flush=True)

    result = evaluate_policy(cfg, learner.model, num_corrections=cfg.eval.num_corrections,
                             seeds=tuple(cfg.eval.seeds), split=cfg.eval.split, max_tasks=cfg.eval.max_tasks,
                             greedy=cfg.eval.greedy_actions)
    print(f"meta-test on {result.num_tasks} {cfg.eval.split} tasks x {len(cfg.eval.seeds)} seeds "
          f"({result.seconds:.0f} s):")
    print(format_table(cfg.env.domain, result))

    if args.out_dir:
        out = Path(args.out_dir)
        out.mkdir(parents=True, exist_ok=True)
        save_config(cfg, out / "config.yaml")
        save_checkpoint(out / "checkpoints", Checkpoint(
            round_index=0, policy_version=1, model_state=learner.model.state_dict(),
            optimizer_state=learner.optimizer.state_dict(), rng_state=capture_rng(learner.generator.get_state()),
            config=config_to_dict(cfg), history=[]), keep_round_copy=False)
        print(f"saved {out}/checkpoints/latest.pt")
    return 0


if __name__ == "__main__":
    sys.exit(main())

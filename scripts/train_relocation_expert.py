"""Train the learned relocation expert (``gpl_dist/experts/relocation_learned.py``) and export it.

Two steps, as committed (``gpl_dist/assets/relocation_learned_expert.npz``):

    python benchmarks/relocation_imitation.py --rounds 14 --save-policy runs/priv14.pt     # 17 min
    python scripts/train_relocation_expert.py --init runs/priv14.pt --iterations 600 \\
        --out gpl_dist/assets/relocation_learned_expert.npz                              # ~22 min

Step 1 imitates the scripted expert by DAgger with the exact target given (test completion
0.878). Step 2 is PPO with the paper's dense reward over all 750 training tasks: each iteration
rolls the policy out (sampled actions) on ``--envs`` training tasks drawn without replacement,
computes GAE advantages with a critic (MLP 256 x 2, tanh, behind the policy's frozen input
normalisation), and takes clipped policy steps (``--clip``) for ``--epochs`` epochs of
``--minibatch`` states, stopping an iteration's epochs once a minibatch's KL to the rollout
policy passes 0.02. The critic alone trains for the first ``--warmup`` iterations, so that the
first policy steps follow real advantages. Every ``--eval-every`` iterations it prints test
completion on the first ``--test-tasks`` test tasks (the imitation benchmark's seeds) and writes ``--out``.
Deterministic for given arguments and torch thread count: the packaged weights are this command's
output (test completion 0.969 at iteration 599), and an earlier run of the same loop, stopped at
iteration 419, printed the same test completions up to there (0.956 at iteration 279, then 0.960,
0.962, 0.965).
"""

from __future__ import annotations

import argparse
import copy
import sys
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from relocation_imitation import TEST_SEED, build_policy, privileged_inputs, rollout  # noqa: E402
from relocation_ppo_expert import sample_episodes  # noqa: E402

from gpl_dist.envs.relocation import EPISODE_STEPS, make_env  # noqa: E402
from gpl_dist.experts.relocation_learned import NUM_LAYERS  # noqa: E402
from gpl_dist.splits import split_tasks  # noqa: E402

GAMMA, GAE_LAMBDA = 0.99, 0.95
RETURN_SCALE = 20.0  # the critic predicts returns / 20 (they reach about -300)
MAX_KL = 0.02


def export(policy: nn.Sequential, path: str) -> None:
    """Write ``build_policy``'s weights as the plain arrays ``relocation_learned`` reads."""
    sd = {k: v.detach().cpu().numpy().astype(np.float32) for k, v in policy.state_dict().items()}
    arrays = {"norm_mean": sd["0.running_mean"], "norm_var": sd["0.running_var"], "norm_weight": sd["0.weight"],
              "norm_bias": sd["0.bias"]}
    linear = [k[:-len(".weight")] for k in sd if k.endswith(".weight") and k != "0.weight"]
    assert len(linear) == NUM_LAYERS, linear
    for i, name in enumerate(linear):
        arrays[f"w{i}"], arrays[f"b{i}"] = sd[f"{name}.weight"], sd[f"{name}.bias"]
    np.savez(path, **arrays)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--init", required=True, help="state_dict from relocation_imitation.py --save-policy")
    p.add_argument("--out", required=True, help=".npz to write")
    p.add_argument("--iterations", type=int, default=600)
    p.add_argument("--envs", type=int, default=100, help="training tasks rolled out per iteration")
    p.add_argument("--lr", type=float, default=5e-5)
    p.add_argument("--clip", type=float, default=0.1)
    p.add_argument("--epochs", type=int, default=4)
    p.add_argument("--minibatch", type=int, default=2048)
    p.add_argument("--warmup", type=int, default=8, help="iterations that train only the critic")
    p.add_argument("--eval-every", type=int, default=40)
    p.add_argument("--test-tasks", type=int, default=100, help="first N test tasks for the printed completion")
    p.add_argument("--threads", type=int, default=2)
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    policy = build_policy(33, 256)
    policy.load_state_dict(torch.load(a.init, weights_only=True))
    policy.eval()  # the input normalisation keeps DAgger's statistics
    norm = copy.deepcopy(policy[0]).eval()
    for q in norm.parameters():
        q.requires_grad_(False)
    critic = nn.Sequential(norm, nn.Linear(33, 256), nn.Tanh(), nn.Linear(256, 256), nn.Tanh(), nn.Linear(256, 1))
    policy_opt = torch.optim.Adam(policy.parameters(), lr=a.lr)
    critic_opt = torch.optim.Adam([q for q in critic.parameters() if q.requires_grad], lr=1e-3)
    train = np.array(split_tasks("relocation", "train"))
    test = split_tasks("relocation", "test")[:a.test_tasks]
    envs_by_task: dict[int, object] = {}
    gen = torch.Generator().manual_seed(0)

    def test_completion() -> tuple[float, float]:
        completion, solved, _, _ = rollout(policy, test, TEST_SEED, label=False)
        return float(completion.mean()), float(solved.mean())

    c, s = test_completion()
    print(f"start: test completion {c:.3f}, solved {s:.2f}", flush=True)
    start = time.perf_counter()
    T, N = EPISODE_STEPS, a.envs
    for it in range(a.iterations):
        tasks = rng.choice(train, N, replace=False)
        for t in tasks:
            if int(t) not in envs_by_task:
                envs_by_task[int(t)] = make_env(int(t))
        envs = [envs_by_task[int(t)] for t in tasks]
        x_buf, act_buf, logp_buf, rew_buf = sample_episodes(
            policy, envs, [10_000 + it * N + k for k in range(N)], gen, extra=privileged_inputs(tasks))
        train_completion = float(np.mean([e.completion() for e in envs]))
        with torch.no_grad():
            values = critic(torch.from_numpy(x_buf.reshape(-1, 33))).reshape(T + 1, N).numpy() * RETURN_SCALE
        adv = np.zeros((T, N), np.float32)
        running = np.zeros(N, np.float32)
        for t in range(T - 1, -1, -1):  # the time limit is not a terminal state: bootstrap from V(s_T)
            running = rew_buf[t] + GAMMA * values[t + 1] - values[t] + GAMMA * GAE_LAMBDA * running
            adv[t] = running
        returns = torch.from_numpy((adv + values[:T]).reshape(-1)) / RETURN_SCALE
        x = torch.from_numpy(x_buf[:T].reshape(-1, 33))
        acts = torch.from_numpy(act_buf.reshape(-1))
        old_logp = torch.from_numpy(logp_buf.reshape(-1))
        advantages = torch.from_numpy(adv.reshape(-1))
        advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
        kls = []
        for _ in range(a.epochs):
            perm = torch.randperm(len(acts), generator=gen)
            too_far = False
            for b in range(0, len(perm), a.minibatch):
                i = perm[b:b + a.minibatch]
                value_loss = nn.functional.mse_loss(critic(x[i]).squeeze(1), returns[i])
                critic_opt.zero_grad()
                value_loss.backward()
                critic_opt.step()
                if it < a.warmup:
                    continue
                new_logp = torch.log_softmax(policy(x[i]), 1).gather(1, acts[i, None]).squeeze(1)
                ratio = torch.exp(new_logp - old_logp[i])
                loss = -torch.min(ratio * advantages[i], ratio.clamp(1 - a.clip, 1 + a.clip) * advantages[i]).mean()
                policy_opt.zero_grad()
                loss.backward()
                policy_opt.step()
                kls.append(float((old_logp[i] - new_logp).mean().detach()))
                if kls[-1] > MAX_KL:
                    too_far = True
                    break
            if too_far:
                break
        line = (f"iteration {it}: train completion {train_completion:.3f} | KL {np.mean(kls) if kls else 0.0:.4f} "
                f"| {time.perf_counter() - start:.0f} s")
        if it % a.eval_every == a.eval_every - 1:
            c, s = test_completion()
            line += f" | test completion {c:.3f}, solved {s:.2f}"
            export(policy, a.out)
        print(line, flush=True)
    c, s = test_completion()
    export(policy, a.out)
    print(f"end: test completion {c:.3f}, solved {s:.2f}; wrote {a.out}", flush=True)


if __name__ == "__main__":
    main()

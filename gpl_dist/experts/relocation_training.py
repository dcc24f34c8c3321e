"""How the learned relocation expert (``gpl_dist.experts.relocation_learned``) is made.

Two steps, run by ``scripts/train_relocation_expert.py`` (``dagger``, then ``ppo``):

1. ``privileged_dagger``: DAgger on the scripted expert's soft labels with the exact target given:
   the policy (``build_policy``: an input BatchNorm and 3 hidden ReLU layers over the observation
   and ``privileged_inputs``) is rolled out with sampled actions on training tasks, every state is
   labelled with the expert's distribution, all rounds' states are aggregated, and it is trained
   for some epochs with cross-entropy.
2. ``ppo_finetune``: PPO with the paper's dense reward over the 750 training tasks, from step 1's
   weights: GAE advantages from a critic behind the policy's frozen input normalisation, clipped
   policy steps, an early stop on the policy's KL, the critic alone for the first iterations.

``export`` writes the policy as the plain arrays the packaged expert reads. Everything is
deterministic for given settings and torch thread count.

These two loops step the envs themselves: PPO needs per-step rewards and log-probabilities, which
the rollout loop of collection (``workers.loop``) does not record.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch
from torch import nn

from gpl_dist.envs.relocation import EPISODE_STEPS, SUCCESS_RADIUS, RelocationEnv, make_env, make_task
from gpl_dist.experts.relocation import RelocationExpert
from gpl_dist.experts.relocation_learned import NUM_LAYERS
from gpl_dist.splits import split_tasks

#: Reset seed of test task k is ``TEST_SEED + k``, for the expert and the policy alike.
TEST_SEED = 99_999
#: Inputs of the policy: the 28-d observation, the target (x, y) and the goal block's one-hot.
INPUT_DIM = 33


def privileged_inputs(task_ids) -> np.ndarray:
    """``(N, 5)`` float32: exact target xy and the goal block one-hot of each task."""
    tasks = [make_task(int(t)) for t in task_ids]
    return np.array([[*t.target, *np.eye(3)[t.block]] for t in tasks], dtype=np.float32)


def build_policy(in_dim: int = INPUT_DIM, width: int = 256) -> nn.Sequential:
    """GPL's relocation head (3 hidden ReLU layers) behind the same input BatchNorm as its state encoder."""
    return nn.Sequential(nn.BatchNorm1d(in_dim), nn.Linear(in_dim, width), nn.ReLU(), nn.Linear(width, width),
                         nn.ReLU(), nn.Linear(width, width), nn.ReLU(), nn.Linear(width, 4))


def privileged_rollout(policy: nn.Module | None, task_ids, seed: int, label: bool, expert_sampled: bool = True):
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
    completion = np.array([e.completion() for e in envs])
    solved = np.array([e.distance() < SUCCESS_RADIUS for e in envs])
    if not label:
        return completion, solved, None, None
    return completion, solved, np.concatenate(xs), np.concatenate(ys)


def expert_on(task_ids, seed: int) -> tuple[float, float]:
    """The scripted expert's mean completion with its own actions and sampled from its labels."""
    hard, _, _, _ = privileged_rollout(None, task_ids, seed, label=False, expert_sampled=False)
    sampled, _, _, _ = privileged_rollout(None, task_ids, seed, label=False)
    return float(hard.mean()), float(sampled.mean())


@dataclass(frozen=True)
class DaggerSettings:
    """Step 1.

    Attributes:
        rounds: DAgger rounds.
        tasks: training tasks rolled out per round (the first N of the split).
        test_tasks: first N test tasks for the printed completion.
        epochs: epochs over the aggregate per round.
        width: hidden units of the 3-layer head.
        keep_rounds: train on the newest N rounds only (0: all).
        seed: seed of the weights and the rollouts.
    """

    rounds: int = 14
    tasks: int = 250
    test_tasks: int = 100
    epochs: int = 5
    width: int = 256
    keep_rounds: int = 0
    seed: int = 0


def privileged_dagger(s: DaggerSettings, log: Callable[[str], None] = print,
                      on_round: Callable[[nn.Module], None] | None = None) -> nn.Sequential:
    """Step 1 (module docstring); ``log`` gets one line per round, ``on_round`` the policy after each."""
    torch.manual_seed(s.seed)
    train = split_tasks("relocation", "train")[:s.tasks]
    test = split_tasks("relocation", "test")[:s.test_tasks]
    hard, sampled = expert_on(test, TEST_SEED)
    log(f"expert on {len(test)} test tasks: completion {hard:.3f} (its actions), {sampled:.3f} (sampled from its labels)")
    policy = build_policy(INPUT_DIM, s.width)
    opt = torch.optim.Adam(policy.parameters(), lr=1e-3)
    xs: list[np.ndarray] = []
    ys: list[np.ndarray] = []
    start = time.perf_counter()
    for r in range(s.rounds):
        policy.eval()
        c_train, _, x, y = privileged_rollout(policy, train, 1000 * r + s.seed, label=True)
        kl_new = float("nan")
        if r > 0:
            with torch.no_grad():
                logp = torch.log_softmax(policy(torch.from_numpy(x)), 1).numpy()
            kl_new = float((y * (np.log(np.clip(y, 1e-8, None)) - logp)).sum(1).mean())
        xs.append(x)
        ys.append(y)
        if s.keep_rounds:  # a FIFO buffer: only the newest rounds' states
            xs, ys = xs[-s.keep_rounds:], ys[-s.keep_rounds:]
        xa, ya = torch.from_numpy(np.concatenate(xs)), torch.from_numpy(np.concatenate(ys))
        mean_loss = _fit(policy, opt, xa, ya, s.epochs)
        entropy = float(-(ya * torch.log(ya.clamp_min(1e-8))).sum(1).mean())
        policy.eval()
        c_test, solved, _, _ = privileged_rollout(policy, test, TEST_SEED, label=False)
        log(f"round {r}: train rollouts {c_train.mean():.3f} | on-policy KL {kl_new:.3f} | {len(ya):,} states, "
            f"KL on them {mean_loss - entropy:.3f} | test completion {c_test.mean():.3f} "
            f"(solved at the end: {solved.mean():.2f}) ({time.perf_counter() - start:.0f} s)")
        if on_round is not None:
            on_round(policy)
    return policy


def _fit(policy: nn.Module, opt: torch.optim.Optimizer, xa: torch.Tensor, ya: torch.Tensor, epochs: int) -> float:
    """``epochs`` of cross-entropy to the labels' distributions; the last epoch's mean loss."""
    policy.train()
    total = 0.0
    for _ in range(epochs):
        perm = torch.randperm(len(ya))
        total = 0.0
        for b in range(0, len(perm), 512):
            i = perm[b:b + 512]
            loss = nn.functional.cross_entropy(policy(xa[i]), ya[i])
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += float(loss.detach()) * len(i)
    return total / len(ya)


def sample_episodes(policy: nn.Module, envs: list, reset_seeds, gen: torch.Generator, extra: np.ndarray | None = None):
    """One episode of ``policy`` (sampled actions) on every env, in lockstep.

    Returns float32 inputs ``(T + 1, N, D)``: the observation, then ``extra`` ``(N, E)`` when given
    (row T is the state after the last step); int64 actions, float32 their log-probabilities and
    float32 rewards, each ``(T, N)``."""
    def inputs(obs: np.ndarray) -> np.ndarray:
        return obs if extra is None else np.concatenate([obs, extra], 1)

    obs = np.stack([e.reset(seed=int(s))[0] for e, s in zip(envs, reset_seeds)]).astype(np.float32)
    T, N = EPISODE_STEPS, len(envs)
    x_buf = np.zeros((T + 1, N, inputs(obs).shape[1]), np.float32)
    act_buf = np.zeros((T, N), np.int64)
    logp_buf = np.zeros((T, N), np.float32)
    rew_buf = np.zeros((T, N), np.float32)
    for t in range(T):
        x_buf[t] = inputs(obs)
        with torch.no_grad():
            logp = torch.log_softmax(policy(torch.from_numpy(x_buf[t])), 1)
        act = torch.multinomial(logp.exp(), 1, generator=gen).squeeze(1)
        act_buf[t] = act.numpy()
        logp_buf[t] = logp.gather(1, act[:, None]).squeeze(1).numpy()
        steps = [e.step(int(u)) for e, u in zip(envs, act_buf[t])]
        obs = np.stack([r[0] for r in steps]).astype(np.float32)
        rew_buf[t] = [r[1] for r in steps]
    x_buf[T] = inputs(obs)
    return x_buf, act_buf, logp_buf, rew_buf


@dataclass(frozen=True)
class PPOSettings:
    """Step 2.

    Attributes:
        iterations: PPO iterations.
        envs: training tasks rolled out per iteration (drawn without replacement).
        lr: the policy's Adam learning rate (the critic's is 1e-3).
        clip: PPO's ratio clip.
        epochs: epochs over an iteration's states (cut short once a minibatch's KL passes ``max_kl``).
        minibatch: states per step.
        warmup: iterations that train only the critic.
        eval_every: iterations between test completions (and exports).
        test_tasks: first N test tasks for the printed completion.
        gamma: discount.
        gae_lambda: GAE's lambda.
        return_scale: the critic predicts returns divided by this (they reach about -300).
        max_kl: KL to the rollout policy that ends an iteration's epochs.
    """

    iterations: int = 600
    envs: int = 100
    lr: float = 5e-5
    clip: float = 0.1
    epochs: int = 4
    minibatch: int = 2048
    warmup: int = 8
    eval_every: int = 40
    test_tasks: int = 100
    gamma: float = 0.99
    gae_lambda: float = 0.95
    return_scale: float = 20.0
    max_kl: float = 0.02


def ppo_finetune(policy: nn.Sequential, s: PPOSettings, log: Callable[[str], None] = print,
                 on_eval: Callable[[nn.Module], None] | None = None) -> nn.Sequential:
    """Step 2 (module docstring) on ``policy`` in place; ``on_eval`` gets the policy at every test.

    The critic's initial weights come from torch's global generator: seed it before building the
    policy (``scripts/train_relocation_expert.py`` seeds 0) to repeat a run.
    """
    rng = np.random.default_rng(0)
    policy.eval()  # the input normalisation keeps DAgger's statistics
    norm = copy.deepcopy(policy[0]).eval()
    for q in norm.parameters():
        q.requires_grad_(False)
    critic = nn.Sequential(norm, nn.Linear(INPUT_DIM, 256), nn.Tanh(), nn.Linear(256, 256), nn.Tanh(), nn.Linear(256, 1))
    policy_opt = torch.optim.Adam(policy.parameters(), lr=s.lr)
    critic_opt = torch.optim.Adam([q for q in critic.parameters() if q.requires_grad], lr=1e-3)
    train = np.array(split_tasks("relocation", "train"))
    test = split_tasks("relocation", "test")[:s.test_tasks]
    envs_by_task: dict[int, RelocationEnv] = {}
    gen = torch.Generator().manual_seed(0)

    def test_completion() -> tuple[float, float]:
        completion, solved, _, _ = privileged_rollout(policy, test, TEST_SEED, label=False)
        return float(completion.mean()), float(solved.mean())

    c, sv = test_completion()
    log(f"start: test completion {c:.3f}, solved {sv:.2f}")
    start = time.perf_counter()
    for it in range(s.iterations):
        tasks = rng.choice(train, s.envs, replace=False)
        for t in tasks:
            if int(t) not in envs_by_task:
                envs_by_task[int(t)] = make_env(int(t))
        envs = [envs_by_task[int(t)] for t in tasks]
        episodes = sample_episodes(policy, envs, [10_000 + it * s.envs + k for k in range(s.envs)], gen,
                                   extra=privileged_inputs(tasks))
        train_completion = float(np.mean([e.completion() for e in envs]))
        kls = _ppo_update(policy, critic, policy_opt, critic_opt, episodes, s, gen, train_critic_only=it < s.warmup)
        line = (f"iteration {it}: train completion {train_completion:.3f} | KL {np.mean(kls) if kls else 0.0:.4f} "
                f"| {time.perf_counter() - start:.0f} s")
        if it % s.eval_every == s.eval_every - 1:
            c, sv = test_completion()
            line += f" | test completion {c:.3f}, solved {sv:.2f}"
            if on_eval is not None:
                on_eval(policy)
        log(line)
    c, sv = test_completion()
    log(f"end: test completion {c:.3f}, solved {sv:.2f}")
    return policy


def _ppo_update(policy: nn.Module, critic: nn.Module, policy_opt: torch.optim.Optimizer, critic_opt: torch.optim.Optimizer,
                episodes: tuple, s: PPOSettings, gen: torch.Generator, train_critic_only: bool) -> list[float]:
    """One iteration's epochs of critic regression and clipped policy steps; the minibatches' KLs."""
    x_buf, act_buf, logp_buf, rew_buf = episodes
    T, N = act_buf.shape
    with torch.no_grad():
        values = critic(torch.from_numpy(x_buf.reshape(-1, INPUT_DIM))).reshape(T + 1, N).numpy() * s.return_scale
    adv = np.zeros((T, N), np.float32)
    running = np.zeros(N, np.float32)
    for t in range(T - 1, -1, -1):  # the time limit is not a terminal state: bootstrap from V(s_T)
        running = rew_buf[t] + s.gamma * values[t + 1] - values[t] + s.gamma * s.gae_lambda * running
        adv[t] = running
    returns = torch.from_numpy((adv + values[:T]).reshape(-1)) / s.return_scale
    x = torch.from_numpy(x_buf[:T].reshape(-1, INPUT_DIM))
    acts = torch.from_numpy(act_buf.reshape(-1))
    old_logp = torch.from_numpy(logp_buf.reshape(-1))
    advantages = torch.from_numpy(adv.reshape(-1))
    advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
    kls: list[float] = []
    for _ in range(s.epochs):
        perm = torch.randperm(len(acts), generator=gen)
        for b in range(0, len(perm), s.minibatch):
            i = perm[b:b + s.minibatch]
            value_loss = nn.functional.mse_loss(critic(x[i]).squeeze(1), returns[i])
            critic_opt.zero_grad()
            value_loss.backward()
            critic_opt.step()
            if train_critic_only:
                continue
            new_logp = torch.log_softmax(policy(x[i]), 1).gather(1, acts[i, None]).squeeze(1)
            ratio = torch.exp(new_logp - old_logp[i])
            loss = -torch.min(ratio * advantages[i], ratio.clamp(1 - s.clip, 1 + s.clip) * advantages[i]).mean()
            policy_opt.zero_grad()
            loss.backward()
            policy_opt.step()
            kls.append(float((old_logp[i] - new_logp).mean().detach()))
            if kls[-1] > s.max_kl:
                return kls
    return kls


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

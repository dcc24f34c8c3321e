"""How the learned relocation expert (``gpl_dist.experts.relocation_learned``) is made.

Two steps, run by ``scripts/train_relocation_expert.py`` (``dagger``, then ``ppo``):

1. ``privileged_dagger``: DAgger on the scripted expert's soft labels with the exact target given:
   the policy (``build_policy``: an input BatchNorm and 3 hidden ReLU layers over
   ``privileged_inputs``: the observation, the exact target and the goal block) is rolled out
   with sampled actions on training tasks, every state is labelled with the expert's
   distribution, all rounds' states are aggregated, and it is trained for some epochs with
   cross-entropy.
2. ``ppo_finetune``: stable-baselines3's PPO with the paper's dense reward over the 750 training
   tasks, from step 1's weights: value layers of their own (and their own learning rate) behind
   the policy's frozen input normalisation, clipped policy steps, an early stop on the KL
   (``target_kl``), the value layers alone for the first iterations.

``export`` writes the policy as the plain arrays the packaged expert reads. Everything is
deterministic for given settings and torch thread count.

Step 1 steps the envs itself (it labels every state with the scripted expert and feeds privileged
inputs, which the rollout loop of collection, ``workers.rollout``, does not); step 2 is SB3's loop.
"""

from __future__ import annotations

import copy
import hashlib
import os
import time
from dataclasses import asdict, dataclass
from typing import Any, Callable, Mapping

import gymnasium
import numpy as np
import torch
from torch import nn

from gpl_dist.envs.relocation import RelocationEnv, make_env
from gpl_dist.envs.relocation_core import EPISODE_STEPS, SUCCESS_RADIUS, make_task
from gpl_dist.experts.relocation import RelocationExpert
from gpl_dist.experts.relocation_learned import INPUT_DIM, NUM_LAYERS, input_rows
from gpl_dist.splits import split_tasks
from learner.ppo import PPOSettings, make_sb3_ppo

#: Reset seed of monitored task k is ``MONITOR_SEED + k``, for the expert and the policy alike. The
#: printed completions are on the valid split: whatever is chosen by watching them never reads test.
MONITOR_SEED = 99_999


def privileged_inputs(observations: np.ndarray, targets: np.ndarray, blocks: list[int]) -> np.ndarray:
    """``(N, INPUT_DIM)`` float32: the observations ``(N, 28)`` with the exact target xy and the goal
    block one-hot of each task (``relocation_learned.input_rows``, the packaged expert's input)."""
    return input_rows(observations, targets, blocks, np.float32)


def task_targets(task_ids) -> tuple[np.ndarray, list[int]]:
    """The target xy ``(N, 2)`` and goal block of each task."""
    tasks = [make_task(int(t)) for t in task_ids]
    return np.array([t.target for t in tasks]), [t.block for t in tasks]


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
    targets, blocks = task_targets(task_ids)
    gen = torch.Generator().manual_seed(seed)
    rng = np.random.default_rng(seed)
    xs, ys = [], []
    for _ in range(EPISODE_STEPS):
        x = privileged_inputs(obs, targets, blocks)
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
        valid_tasks: first N valid tasks for the printed completion.
        epochs: epochs over the aggregate per round.
        width: hidden units of the 3-layer head.
        keep_rounds: train on the newest N rounds only (0: all).
        seed: seed of the weights and the rollouts.
    """

    rounds: int = 14
    tasks: int = 250
    valid_tasks: int = 100
    epochs: int = 5
    width: int = 256
    keep_rounds: int = 0
    seed: int = 0


def privileged_dagger(s: DaggerSettings, log: Callable[[str], None] = print,
                      on_round: Callable[[nn.Module], None] | None = None) -> nn.Sequential:
    """Step 1 (module docstring); ``log`` gets one line per round, ``on_round`` the policy after each."""
    torch.manual_seed(s.seed)
    train = split_tasks("relocation", "train")[:s.tasks]
    valid = split_tasks("relocation", "valid")[:s.valid_tasks]
    hard, sampled = expert_on(valid, MONITOR_SEED)
    log(f"expert on {len(valid)} valid tasks: completion {hard:.3f} (its actions), {sampled:.3f} (sampled from its labels)")
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
        c_valid, solved, _, _ = privileged_rollout(policy, valid, MONITOR_SEED, label=False)
        log(f"round {r}: train rollouts {c_train.mean():.3f} | on-policy KL {kl_new:.3f} | {len(ya):,} states, "
            f"KL on them {mean_loss - entropy:.3f} | valid completion {c_valid.mean():.3f} "
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


class PrivilegedTasks(gymnasium.Env):
    """Relocation's training tasks for step 2: each reset draws a task and a reset seed from its
    own generator; observations are ``privileged_inputs`` (float32 ``(33,)``: the env's 28 values,
    the task's target and goal block); rewards are the paper's dense reward divided by ``reward_scale`` (the
    value function then learns returns of about -15 rather than -300; PPO's normalised
    advantages make the policy's steps the same either way)."""

    def __init__(self, tasks, seed: int, reward_scale: float = 20.0):
        super().__init__()
        self.tasks = np.asarray(tasks)
        self.rng = np.random.default_rng(seed)
        self.reward_scale = reward_scale
        self.observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (INPUT_DIM,), np.float32)
        self.action_space = gymnasium.spaces.Discrete(4)
        self.env: RelocationEnv | None = None
        self.target, self.block = np.zeros(2), 0
        #: the generator's state before the latest reset's draws: a checkpoint taken between
        #: episodes restores it, and the resumed run's first reset redraws the same task and seed
        self.rng_before_reset: Mapping[str, Any] = self.rng.bit_generator.state

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.rng_before_reset = self.rng.bit_generator.state
        task = int(self.rng.choice(self.tasks))
        # a new env per episode (about 4 ms): keeping one per task drawn grew to every training task
        # in each of the 100 envs (24 GB by iteration 480); reset with a seed fixes the whole state
        self.env = make_env(task)
        targets, blocks = task_targets([task])
        self.target, self.block = targets[0], blocks[0]
        obs, info = self.env.reset(seed=int(self.rng.integers(2**31)))
        return self._inputs(obs), info

    def _inputs(self, obs: np.ndarray) -> np.ndarray:
        return privileged_inputs(obs[None], self.target[None], [self.block])[0]

    def step(self, action):
        assert self.env is not None, "reset first"
        obs, reward, terminated, truncated, info = self.env.step(int(action))
        return self._inputs(obs), reward / self.reward_scale, terminated, truncated, info


#: Step 2's PPO, as SB3 runs it: 100 envs, one episode of each per iteration, the policy's Adam at
#: 5e-5 and the value layers' (2 x 256) at 1e-3, clip 0.1, 4 epochs of minibatches of 2048 cut
#: short once the KL to the rollout policy passes 0.02 (SB3 stops at 1.5 x ``target_kl``), no
#: gradient clipping, no entropy bonus, the value loss at SB3's 0.5; one extractor (the frozen
#: input normalisation) for both.
EXPERT_PPO = PPOSettings(n_envs=100, n_steps=0, learning_rate=5e-5, value_learning_rate=1e-3, batch_size=2048,
                         n_epochs=4, gamma=0.99, gae_lambda=0.95, clip_range=0.1, ent_coef=0.0, vf_coef=0.5,
                         target_kl=0.02 / 1.5, max_grad_norm=float("inf"), value_hidden=256, value_layers=2,
                         stop_when_solved=False, share_trunk=True)


@dataclass(frozen=True)
class FinetuneSettings:
    """Step 2: stable-baselines3's PPO (``ppo``) from step 1's policy, and the stage's own knobs."""

    ppo: PPOSettings = EXPERT_PPO
    """The PPO (``learner.ppo``): ``n_envs`` envs, each drawing a training task per episode; ``n_steps``
    one episode (0 or ``EPISODE_STEPS``); ``value_learning_rate`` the value layers' own rate."""
    iterations: int = 600
    """PPO iterations (each one episode of every env)."""
    warmup: int = 8
    """Iterations that train only the value layers."""
    eval_every: int = 40
    """Iterations between valid completions (and exports)."""
    valid_tasks: int = 100
    """First N valid tasks for the printed completion."""
    return_scale: float = 20.0
    """Rewards are divided by this (``PrivilegedTasks``)."""
    seed: int = 0
    """SB3's seed (the value layers' weights, minibatches, sampled actions) and the tasks'."""


class FrozenNorm(nn.Module):
    """SB3 features extractor: step 1's input BatchNorm with its statistics, never trained."""

    def __init__(self, observation_space, norm: nn.BatchNorm1d):
        super().__init__()
        self.features_dim = INPUT_DIM
        self.norm = copy.deepcopy(norm).eval()
        for q in self.norm.parameters():
            q.requires_grad_(False)

    def train(self, mode: bool = True) -> "FrozenNorm":
        super().train(mode)
        self.norm.eval()  # SB3 switches to training mode for updates: the statistics stay DAgger's
        return self

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.norm(obs)


def _extractor_class():
    """``FrozenNorm`` under SB3's ``BaseFeaturesExtractor``."""
    from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

    class Extractor(BaseFeaturesExtractor):
        def __init__(self, observation_space, norm: nn.BatchNorm1d):
            super().__init__(observation_space, INPUT_DIM)
            self.inner = FrozenNorm(observation_space, norm)

        def forward(self, obs: torch.Tensor) -> torch.Tensor:
            return self.inner(obs)

    return Extractor


def _linears(module: nn.Module) -> list[nn.Linear]:
    return [m for m in module.modules() if isinstance(m, nn.Linear)]


def sb3_ppo(policy: nn.Sequential, s: FinetuneSettings):
    """SB3 PPO (``learner.ppo``) over ``PrivilegedTasks`` whose policy is ``policy`` (``build_policy``):
    its input BatchNorm as the frozen features extractor, its hidden layers and output layer copied
    into SB3's policy network and action layer; fresh value layers (``s.ppo.value_arch()``, ReLU)
    with their own rate (``s.ppo.value_learning_rate``)."""
    from stable_baselines3.common.env_util import make_vec_env

    p = s.ppo
    if p.n_steps not in (0, EPISODE_STEPS) or p.stop_when_solved:
        raise ValueError(f"step 2's iterations are one episode of every env (n_steps 0 or {EPISODE_STEPS}, got "
                         f"{p.n_steps}) and it has no stop once solved (stop_when_solved {p.stop_when_solved})")
    train = split_tasks("relocation", "train")
    env = make_vec_env(PrivilegedTasks, n_envs=p.n_envs, seed=s.seed,
                       env_kwargs=dict(tasks=train, seed=s.seed, reward_scale=s.return_scale))
    for k, e in enumerate(env.envs):  # type: ignore[attr-defined]
        e.unwrapped.rng = np.random.default_rng([s.seed, k])  # each env its own task stream
    hidden = [m.out_features for m in _linears(policy)[:-1]]
    model = make_sb3_ppo(env, p, episode_steps=EPISODE_STEPS, seed=s.seed, pi=hidden,
                         features_extractor_class=_extractor_class(), features_extractor_kwargs=dict(norm=policy[0]),
                         activation_fn=nn.ReLU, ortho_init=False)
    sb3 = model.policy
    with torch.no_grad():
        for ours, theirs in zip(_linears(policy), [*_linears(sb3.mlp_extractor.policy_net), sb3.action_net]):
            theirs.weight.copy_(ours.weight)
            theirs.bias.copy_(ours.bias)
    return model


def policy_of(model, like: nn.Sequential) -> nn.Sequential:
    """The SB3 model's policy as a ``build_policy`` network (a copy of ``like`` with its weights)."""
    out = copy.deepcopy(like).eval()
    sb3 = model.policy
    with torch.no_grad():
        for theirs, ours in zip([*_linears(sb3.mlp_extractor.policy_net), sb3.action_net], _linears(out)):
            ours.weight.copy_(theirs.weight)
            ours.bias.copy_(theirs.bias)
    return out


#: Layout version of step 2's checkpoint (``save_ppo_checkpoint``). 2: the settings by
#: ``FinetuneSettings``' names (``ppo.<PPOSettings field>``); 1 (read too): the former flat names.
CHECKPOINT_FORMAT = 2
#: Settings a resumed run may change: ``iterations`` extends or shortens it; the other two only print.
_FREE_ON_RESUME = ("iterations", "eval_every", "valid_tasks")
#: Format 1's settings by their names now (its ``max_kl`` was 1.5 x SB3's ``target_kl``) ...
_FORMAT_1_NAMES = {"envs": "ppo.n_envs", "lr": "ppo.learning_rate", "critic_lr": "ppo.value_learning_rate",
                   "clip": "ppo.clip_range", "epochs": "ppo.n_epochs", "minibatch": "ppo.batch_size",
                   "gamma": "ppo.gamma", "gae_lambda": "ppo.gae_lambda", "max_kl": "ppo.target_kl",
                   "warmup": "warmup", "return_scale": "return_scale", "seed": "seed"}
#: ... and the PPO settings format 1 did not store, as its code fixed them.
_FORMAT_1_FIXED = {"ppo.n_steps": EPISODE_STEPS, "ppo.ent_coef": 0.0, "ppo.vf_coef": 0.5, "ppo.max_grad_norm": float("inf"),
                   "ppo.value_hidden": 256, "ppo.value_layers": 2, "ppo.stop_when_solved": False, "ppo.share_trunk": True}


def _checked_settings(s: FinetuneSettings) -> dict[str, Any]:
    """The settings a resumed run must keep, by name (``ppo.<field>`` for the PPO's; ``n_steps`` 0 as
    the episode it means)."""
    ppo = {f"ppo.{k}": v for k, v in asdict(s.ppo).items()}
    ppo["ppo.n_steps"] = s.ppo.n_steps or EPISODE_STEPS
    return {**ppo, **{k: v for k, v in asdict(s).items() if k != "ppo" and k not in _FREE_ON_RESUME}}


def _format_1_settings(old: Mapping[str, Any]) -> dict[str, Any]:
    """A format-1 checkpoint's settings by ``_checked_settings``' names."""
    out = {**_FORMAT_1_FIXED, **{_FORMAT_1_NAMES.get(k, k): v for k, v in old.items()}}
    if "ppo.target_kl" in out:
        out["ppo.target_kl"] = out["ppo.target_kl"] / 1.5  # as sb3_ppo gave SB3 then
    return out


def fingerprint(policy: nn.Module) -> str:
    """sha256 over ``policy``'s state_dict (names and bytes): which step-1 policy a run started from."""
    h = hashlib.sha256()
    for name, value in policy.state_dict().items():
        h.update(name.encode())
        h.update(value.detach().cpu().numpy().tobytes())
    return h.hexdigest()


def save_ppo_checkpoint(path: str, model, s: FinetuneSettings, init: str, iteration: int) -> None:
    """Write what step 2 needs to go on after ``iteration`` as if never stopped: SB3's policy
    (value layers too) and Adam state, the torch and numpy global generators (SB3 samples actions
    and shuffles minibatches with them), each env's task generator before its latest reset, the
    step count; with the settings and ``init`` (``fingerprint`` of the starting policy) to check.
    Atomic (a temporary file renamed); read with ``torch.load(weights_only=True)``."""
    name, keys, pos, has_gauss, cached = np.random.get_state(legacy=True)
    state = {"format": CHECKPOINT_FORMAT, "init": init, "iteration": iteration,
             "settings": _checked_settings(s),
             "num_timesteps": int(model.num_timesteps), "policy": model.policy.state_dict(),
             "optimizer": model.policy.optimizer.state_dict(), "torch_rng": torch.get_rng_state(),
             "numpy_rng": {"name": name, "keys": torch.from_numpy(np.asarray(keys, np.int64)), "pos": int(pos),
                           "has_gauss": int(has_gauss), "cached_gaussian": float(cached)},
             "env_rngs": [e.unwrapped.rng_before_reset for e in model.env.envs]}
    tmp = f"{path}.tmp"
    torch.save(state, tmp)
    os.replace(tmp, path)


def load_ppo_checkpoint(path: str, model, s: FinetuneSettings, init: str) -> int:
    """Restore ``save_ppo_checkpoint``'s state (format 2, or 1 with its former setting names) into a
    model fresh from ``sb3_ppo(policy, s)``; returns the iterations it had done. Raises
    ``ValueError`` naming what differs when the checkpoint is of another layout, starting policy or
    settings."""
    state = torch.load(path, weights_only=True)
    if state.get("format") not in (1, CHECKPOINT_FORMAT):
        raise ValueError(f"{path}: checkpoint format {state.get('format')!r}; this code reads 1 and {CHECKPOINT_FORMAT}")
    if state["init"] != init:
        raise ValueError(f"{path} started from another policy than --init")
    was = _format_1_settings(state["settings"]) if state["format"] == 1 else state["settings"]
    differ = [f"{k} {was.get(k)!r} (now {v!r})" for k, v in _checked_settings(s).items() if was.get(k) != v]
    if differ:
        raise ValueError(f"{path} was made with other settings: {', '.join(differ)}")
    model.policy.load_state_dict(state["policy"])
    model.policy.optimizer.load_state_dict(state["optimizer"])
    model.num_timesteps = state["num_timesteps"]
    torch.set_rng_state(state["torch_rng"])
    n = state["numpy_rng"]
    np.random.set_state((n["name"], n["keys"].numpy().astype(np.uint32), n["pos"], n["has_gauss"], n["cached_gaussian"]))
    for env, rng_state in zip(model.env.envs, state["env_rngs"], strict=True):
        env.unwrapped.rng.bit_generator.state = rng_state
    return int(state["iteration"])


def ppo_finetune(policy: nn.Sequential, s: FinetuneSettings, log: Callable[[str], None] = print,
                 on_eval: Callable[[nn.Module], None] | None = None, checkpoint: str | None = None,
                 resume: bool = False) -> nn.Sequential:
    """Step 2 (module docstring): SB3's PPO from ``policy``; returns the fine-tuned policy (a new
    network); ``on_eval`` gets it at every valid-split completion. With ``checkpoint``, the state is
    saved there after every iteration; ``resume`` goes on from it, and the result is the same as a
    run never stopped (for the same torch thread count)."""
    from stable_baselines3.common.callbacks import BaseCallback

    model = sb3_ppo(policy, s)
    init = fingerprint(policy)
    done = 0
    if resume and checkpoint is not None and os.path.exists(checkpoint):
        done = load_ppo_checkpoint(checkpoint, model, s, init)
        log(f"resumed after iteration {done - 1} from {checkpoint}")
    valid = split_tasks("relocation", "valid")[:s.valid_tasks]
    pi_params = [*model.policy.mlp_extractor.policy_net.parameters(), *model.policy.action_net.parameters()]

    def valid_completion(net: nn.Module) -> tuple[float, float]:
        completion, solved, _, _ = privileged_rollout(net, valid, MONITOR_SEED, label=False)
        return float(completion.mean()), float(solved.mean())

    if done == 0:
        c, sv = valid_completion(policy.eval())
        log(f"start: valid completion {c:.3f}, solved {sv:.2f}")
    start = time.perf_counter()

    class Progress(BaseCallback):
        """Counts iterations: the value layers alone for ``warmup``; one line per iteration after
        its update, with a valid-split completion every ``eval_every``, then the checkpoint."""

        iteration = done
        reported = done
        completion = 0.0

        def _on_training_start(self) -> None:
            for q in pi_params:
                q.requires_grad_(self.iteration >= s.warmup)

        def _on_step(self) -> bool:
            return True

        def _on_rollout_end(self) -> None:  # the iteration's update comes next
            infos = self.locals.get("infos") or []
            self.completion = float(np.mean([i.get("completion", 0.0) for i in infos]))
            self.iteration += 1
            for q in pi_params:
                q.requires_grad_(self.iteration > s.warmup)

        def _on_rollout_start(self) -> None:  # the previous iteration's update is done
            self.report()

        def report(self) -> None:
            if self.iteration == self.reported:
                return
            self.reported = self.iteration
            line = (f"iteration {self.iteration - 1}: train completion {self.completion:.3f} | "
                    f"{time.perf_counter() - start:.0f} s")
            if self.iteration % s.eval_every == 0:
                net = policy_of(self.model, policy)
                c, sv = valid_completion(net)
                line += f" | valid completion {c:.3f}, solved {sv:.2f}"
                if on_eval is not None:
                    on_eval(net)
            log(line)
            if checkpoint is not None:
                save_ppo_checkpoint(checkpoint, self.model, s, init, self.iteration)

    progress = Progress()
    if done < s.iterations:
        model.learn(total_timesteps=(s.iterations - done) * s.ppo.n_envs * EPISODE_STEPS, callback=progress,
                    reset_num_timesteps=False)
    progress.report()  # the last iteration's line
    tuned = policy_of(model, policy)
    c, sv = valid_completion(tuned)
    log(f"end: valid completion {c:.3f}, solved {sv:.2f}")
    return tuned


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

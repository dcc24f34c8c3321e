"""Reinforcement learning on one task with stable-baselines3's PPO: the paper's sample-complexity
baselines (its figure of completion against trajectories per task).

Two methods, one network: the instruction-only GPL network of the domain (its state encoder, the
task's instruction encoded once as a learnable vector, and its policy MLP) is SB3's features
extractor (``TaskFeatures``); SB3 adds the action layer on top, and the value head reads its own
copy of that trunk (the authors' value network was separate from the policy).

- ``rl-scratch``: the network freshly initialised (``seed``; SB3's orthogonal initialisation), PPO from there;
- ``rl-finetune``: the network and its final action layer loaded from an instruction-only policy
  meta-trained by DAgger (the suite's entry), so PPO starts from exactly that policy.

Both see the env's observation (multi-room: the 7x7 categorical window through the GPL grid
encoder, a small CNN) and its dense reward (the paper's: multi-room -0.01 x distance to the next
subgoal and +100 per newly completed subgoal; relocation -(gripper-to-block + 5 x block-to-target)).
PPO (``learner.ppo``, the project's one) runs the authors' expert settings (``PPOSettings``'
defaults), updates stopping once every copy of the task solved it, as theirs did. Every training
trajectory's final completion is recorded, in order (``RLCurve``), until ``trajectories`` have been
run. Everything is a function of the job's seed (SB3's, the env's resets and torch's); one torch
thread per job.
"""

from __future__ import annotations

import copy
import dataclasses
import time
from dataclasses import dataclass
from typing import Any

import gymnasium
import numpy as np
import torch
from torch import nn

from gpl_dist.config import ModelConfig
from gpl_dist.domains import get_domain
from gpl_dist.errors import UsageError
from gpl_dist.models.build import build_model_from_config
from gpl_dist.models.gpl import GPLPolicy
from gpl_dist.models.layers import Conditioning
from gpl_dist.roles import DomainSpec
from gpl_dist.seeding import rl_seed
from learner.ppo import PPOSettings, make_sb3_ppo

#: The RL methods: PPO from a fresh network, and PPO from a DAgger-pretrained instruction-only one.
RL_METHODS = ("rl-scratch", "rl-finetune")


@dataclass(frozen=True)
class RLJob:
    """One PPO run: a method on one task with one seed and a budget of trajectories.

    Attributes:
        method: one of ``RL_METHODS``.
        domain: domain name.
        task_id: the task (a test task: the policy has never seen it).
        seed: seeds SB3, the network's initialisation and the env's resets.
        trajectories: episodes to train for (each ``steps_per_attempt`` steps).
        pretrained: for ``rl-finetune``, the suite entry whose policy is loaded (recorded only).
    """

    method: str
    domain: str
    task_id: int
    seed: int
    trajectories: int
    pretrained: str = ""

    @property
    def key(self) -> str:
        """File stem of the job's result: ``<method>/<domain>/task<t>-seed<s>``."""
        return f"{self.method}/{self.domain}/task{self.task_id}-seed{self.seed}"


@dataclass(frozen=True)
class RLCurve:
    """What one RL job measured.

    Attributes:
        job: the job.
        completion: float ``(trajectories,)`` the final completion of each training trajectory, in order.
        success: bool ``(trajectories,)`` whether each solved the task.
        env_steps: env steps taken (the budget's trajectories, whole, and the rest of the last round).
        seconds: wall time.
        solved_at: trajectories run when updates stopped (``PPOSettings.stop_when_solved``), else None.
        settings: the ``PPOSettings`` it ran with, as a dict (a result made with others is redone;
            ``made_with`` compares).
    """

    job: RLJob
    completion: tuple[float, ...]
    success: tuple[bool, ...]
    env_steps: int
    seconds: float
    solved_at: int | None = None
    settings: dict | None = None

    def to_json(self) -> dict:
        """The curve as JSON (``from_json`` reads it back)."""
        return {"job": self.job.__dict__, "completion": list(self.completion), "success": list(self.success),
                "env_steps": self.env_steps, "seconds": self.seconds, "solved_at": self.solved_at,
                "settings": self.settings}

    @classmethod
    def from_json(cls, data: dict) -> "RLCurve":
        return cls(RLJob(**data["job"]), tuple(float(x) for x in data["completion"]),
                   tuple(bool(x) for x in data["success"]), int(data["env_steps"]), float(data["seconds"]),
                   data.get("solved_at"), data.get("settings"))


def made_with(recorded: Any, settings: PPOSettings) -> bool:
    """Whether a result's recorded settings (``RLCurve.settings``, as ``jobs.read_result`` gives
    them) are ``settings``."""
    return isinstance(recorded, dict) and recorded == dataclasses.asdict(settings)


class TaskFeatures(nn.Module):
    """SB3 features extractor: the instruction-only GPL network's trunk for one task.

    ``features = policy_mlp(cat(state_encoder(obs), z))`` with ``z`` the task's instruction
    encoding (a learnable vector initialised from the network's instruction encoder), i.e. the GPL
    head without its final linear layer, whose weights ``attach`` copies into SB3's action layer.
    """

    def __init__(self, observation_space: gymnasium.spaces.Box, network: GPLPolicy, instruction_ids: torch.Tensor,
                 obs_shape: tuple[int, ...]):
        super().__init__()
        self.state = network.state
        self.trunk = network.head[0]
        with torch.no_grad():
            z = network.encode_conditioning(_instruction_only(instruction_ids))
        self.z = nn.Parameter(z[0].clone())
        self.obs_shape = tuple(obs_shape)
        # SB3 hands channels-last images over channels-first (VecTransposeImage): undo that
        self.channels_first = tuple(observation_space.shape) != self.obs_shape
        self.features_dim = int([m for m in self.trunk.modules() if isinstance(m, nn.Linear)][-1].out_features)

    def train(self, mode: bool = True) -> "TaskFeatures":
        """SB3 switches to training mode for its updates; BatchNorm layers keep their statistics
        (else an update's log-probabilities would not be the rollout's, and the statistics would
        drift from the pretrained ones without a gradient step)."""
        super().train(mode)
        for m in self.modules():
            if isinstance(m, nn.modules.batchnorm._BatchNorm):
                m.eval()
        return self

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        if self.channels_first:
            obs = obs.permute(0, 2, 3, 1)
        if len(self.obs_shape) == 3:
            obs = obs.round().to(torch.uint8)  # categorical codes, as the grid encoder reads them
        state = self.state(obs)
        return self.trunk(torch.cat([state, self.z.expand(state.shape[0], -1)], dim=1))


def _instruction_only(instruction_ids: torch.Tensor) -> Conditioning:
    empty = torch.zeros((0,), dtype=torch.long)
    return Conditioning(instruction_ids=instruction_ids.reshape(1, -1), trajectories=empty,
                        correction_ids=empty.reshape(0, instruction_ids.numel()),
                        slots=torch.zeros((1, 0), dtype=torch.long))


def _features_class(observation_space, **kwargs):
    """SB3 wants a ``BaseFeaturesExtractor``: ``TaskFeatures`` under that base class."""
    from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

    class _Extractor(BaseFeaturesExtractor):
        def __init__(self, observation_space, network, instruction_ids, obs_shape):
            # SB3 builds one extractor for the policy and, unless they share it, one for the value:
            # each gets its own copy of the network
            inner = TaskFeatures(observation_space, copy.deepcopy(network), instruction_ids, obs_shape)
            super().__init__(observation_space, inner.features_dim)
            self.inner = inner

        def forward(self, obs: torch.Tensor) -> torch.Tensor:
            return self.inner(obs)

    return _Extractor


class CompletionRecorder(gymnasium.Wrapper):
    """Records each episode's final ``info["completion"]`` and ``info["success"]``; copies of a task
    may share one pair of lists (``completion``, ``success``), which then hold every copy's
    episodes in the order they end. ``horizon_is_terminal``: the time limit ends the episode as
    ``terminated`` (so PPO adds no value estimate after the last step, as Monte-Carlo returns)."""

    def __init__(self, env: gymnasium.Env, completion: list[float] | None = None, success: list[bool] | None = None,
                 horizon_is_terminal: bool = False):
        super().__init__(env)
        self.completion: list[float] = [] if completion is None else completion
        self.success: list[bool] = [] if success is None else success
        self.horizon_is_terminal = horizon_is_terminal

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        if terminated or truncated:
            self.completion.append(float(info.get("completion", 0.0)))
            self.success.append(bool(info.get("success", False)))
            if self.horizon_is_terminal:
                terminated, truncated = True, False
        return obs, reward, terminated, truncated, info


def task_network(domain: DomainSpec, weights: dict[str, np.ndarray] | None, seed: int,
                 model: ModelConfig | None = None) -> GPLPolicy:
    """The instruction-only GPL network: fresh (``seed``) or with ``weights`` (a pretrained policy's),
    built as ``model`` (the pretrained run's ``model`` section; None: the defaults) describes it."""
    cfg = dataclasses.replace(model or ModelConfig(), variant="instruction_only")
    network = build_model_from_config(domain, cfg, seed=seed)
    if weights is not None:
        network.load_state_dict({k: torch.as_tensor(np.asarray(v)) for k, v in weights.items()})
    assert isinstance(network, GPLPolicy)
    return network


def _fit_batchnorm(network: GPLPolicy, domain: DomainSpec, task_id: int, seed: int, episodes: int = 2) -> None:
    """A fresh network's input BatchNorm (relocation's state encoder) gets the statistics of
    ``episodes`` random-action episodes of the task: PPO keeps BatchNorm statistics fixed."""
    norms = [m for m in network.state.modules() if isinstance(m, nn.BatchNorm1d)]
    if not norms:
        return
    rng = np.random.default_rng(seed)
    env: Any = domain.make_env(task_id)
    states = []
    for _ in range(episodes):
        obs, _ = env.reset(seed=int(rng.integers(2**31)))
        for _ in range(domain.steps_per_attempt):
            states.append(np.asarray(obs, dtype=np.float32))
            obs = env.step(int(rng.integers(domain.num_actions)))[0]
    x = torch.from_numpy(np.stack(states))
    norms[0].running_mean = x.mean(0)
    norms[0].running_var = x.var(0).clamp_min(1e-6)


def _returns(env: gymnasium.Env):
    """A factory of ``env`` itself, as SB3's vectorised envs take factories."""
    return lambda: env


def make_ppo(job: RLJob, settings: PPOSettings = PPOSettings(), weights: dict[str, np.ndarray] | None = None,
             model: ModelConfig | None = None) -> tuple[Any, CompletionRecorder]:
    """SB3's PPO on ``settings.n_envs`` copies of ``job``'s task and the first copy (its lists record
    every copy's episodes); ``weights`` (an instruction-only policy's, as numpy) for ``rl-finetune``,
    with its run's ``model`` section (the architecture they fit)."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    if job.method not in RL_METHODS:
        raise UsageError(f"unknown RL method '{job.method}' (known: {', '.join(RL_METHODS)})")
    if (job.method == "rl-finetune") != (weights is not None):
        raise UsageError(f"{job.method} needs {'a pretrained policy' if weights is None else 'no weights'}")
    domain = get_domain(job.domain)
    if not 0 <= job.task_id < domain.num_tasks or job.trajectories < 1:
        raise UsageError(f"RL job {job.key}: task outside 0..{domain.num_tasks - 1} or no trajectories")
    if settings.n_envs < 1 or settings.n_steps < 0:
        raise UsageError(f"PPO settings: n_envs must be >= 1 and n_steps >= 0 (got {settings.n_envs}, {settings.n_steps})")
    seed = rl_seed(job.seed, job.task_id)
    torch.manual_seed(seed)
    network = task_network(domain, weights, seed, model)
    completion: list[float] = []
    success: list[bool] = []
    copies = [CompletionRecorder(gymnasium.make(domain.env_id, task_id=job.task_id), completion, success, True)
              for _ in range(settings.n_envs)]
    env = DummyVecEnv([_returns(e) for e in copies])  # SB3 resets copy k with seed + k
    if weights is None:
        _fit_batchnorm(network, domain, job.task_id, seed)
    instruction_ids = torch.from_numpy(network.vocabulary.encode(copies[0].unwrapped.instruction))  # type: ignore[attr-defined]
    ppo = make_sb3_ppo(env, settings, episode_steps=domain.steps_per_attempt, seed=seed, pi=[],
                       features_extractor_class=_features_class(copies[0].observation_space),
                       features_extractor_kwargs=dict(network=network, instruction_ids=instruction_ids,
                                                      obs_shape=domain.obs_shape),
                       normalize_images=False,
                       # SB3 re-initialises every layer orthogonally by default: right from scratch, wrong for pretrained weights
                       ortho_init=weights is None)
    if weights is not None:
        last: nn.Linear = network.head[1]  # type: ignore[assignment]
        action_net: nn.Linear = ppo.policy.action_net  # type: ignore[assignment]
        with torch.no_grad():  # start from exactly the pretrained policy: its last layer is SB3's action layer
            action_net.weight.copy_(last.weight)
            action_net.bias.copy_(last.bias)
    return ppo, copies[0]


def all_copies_solved(success: list[bool], n_envs: int) -> bool:
    """Whether the last ``n_envs`` episodes (one per copy, as the copies end theirs together) all succeeded."""
    return len(success) >= n_envs and all(success[-n_envs:])


def budget_callback(log: CompletionRecorder, budget: int, settings: PPOSettings, solved_at: list[int]):
    """SB3 callback: ends learning once ``budget`` episodes have ended; at the end of each rollout
    (before its update) it stops updates if every copy solved the task (``stop_when_solved``),
    appending the number of episodes run then to ``solved_at``."""
    from stable_baselines3.common.callbacks import BaseCallback

    class Budget(BaseCallback):
        def _on_step(self) -> bool:
            return len(log.completion) < budget

        def _on_rollout_end(self) -> None:
            if settings.stop_when_solved and not solved_at and all_copies_solved(log.success, settings.n_envs):
                solved_at.append(len(log.success))
                self.model.updating = False  # type: ignore[attr-defined]  # learner.ppo's PPO (make_ppo)

    return Budget()


def run_rl_job(job: RLJob, settings: PPOSettings = PPOSettings(), weights: dict[str, np.ndarray] | None = None,
               model: ModelConfig | None = None) -> RLCurve:
    """PPO on ``job``'s task until ``job.trajectories`` episodes have ended (``make_ppo``); the copies
    end their episodes together, so the last round may end up to ``n_envs - 1`` more (in
    ``env_steps``, not in the curve)."""
    torch.set_num_threads(1)
    ppo, log = make_ppo(job, settings, weights, model)
    solved_at: list[int] = []
    start = time.perf_counter()
    steps = get_domain(job.domain).steps_per_attempt
    ppo.learn(total_timesteps=(job.trajectories + settings.n_envs) * steps,
                callback=budget_callback(log, job.trajectories, settings, solved_at))
    if settings.stop_when_solved and not solved_at and all_copies_solved(log.success, settings.n_envs):
        solved_at.append(len(log.success))  # solved in the last round, which the budget ended before its update
    return RLCurve(job, tuple(log.completion[: job.trajectories]), tuple(log.success[: job.trajectories]),
                   int(ppo.num_timesteps), time.perf_counter() - start, solved_at[0] if solved_at else None,
                   dataclasses.asdict(settings))


@dataclass(frozen=True)
class CurveSummary:
    """Completion against trajectories over tasks: median and interquartile range at ``points``."""

    points: tuple[int, ...]
    median: tuple[float, ...]
    q25: tuple[float, ...]
    q75: tuple[float, ...]
    num_tasks: int


def smoothed(completion: tuple[float, ...] | list[float], points: tuple[int, ...], window: float = 0.1) -> list[float]:
    """Completion at each of ``points`` trajectories: the mean over the trajectories in
    ``(p - window * p, p]`` (at least the p-th alone), a learning curve read at a log scale."""
    c = np.asarray(completion, dtype=np.float64)
    out = []
    for p in points:
        lo = max(0, int(np.floor(p * (1 - window))))
        out.append(float(c[lo:p].mean()) if p <= len(c) and p > lo else float("nan"))
    return out


def summarize(curves: list[RLCurve], points: tuple[int, ...]) -> CurveSummary:
    """Median and interquartile range over the tasks of ``curves`` (one seed's, or all)."""
    table = np.array([smoothed(c.completion, points) for c in curves])
    return CurveSummary(points, tuple(np.nanmedian(table, 0)), tuple(np.nanpercentile(table, 25, 0)),
                        tuple(np.nanpercentile(table, 75, 0)), len(curves))


def log_points(budget: int, per_decade: int = 8) -> tuple[int, ...]:
    """About ``per_decade`` trajectory counts per power of ten from 1 to ``budget``."""
    raw = np.unique(np.round(np.logspace(0, np.log10(budget), int(per_decade * np.log10(max(budget, 10))) + 1)))
    return tuple(int(x) for x in raw if 1 <= x <= budget)

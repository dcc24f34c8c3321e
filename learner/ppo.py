"""The project's one PPO: stable-baselines3's (SB3), with its settings (``PPOSettings``) and one
subclass of it (``ppo_class``), built by ``make_sb3_ppo``.

Two users: the RL baselines of the sample-complexity figure (``gpl_dist.app.suite.rl.per_task``: the defaults, the
authors' expert PPO) and the learned relocation expert's PPO stage
(``learner.relocation_expert_training``: ``EXPERT_PPO``). Beyond SB3's own PPO the subclass does two
things, each off unless asked: its updates can be switched off while it keeps sampling
(``updating = False``; the RL jobs once every copy solved the task), and its value layers can keep
a learning rate of their own (``PPOSettings.value_learning_rate``; the expert stage).

SB3 is imported inside the functions (importing this module does not load it).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class PPOSettings:
    """SB3 PPO's settings, in SB3's names, and the few SB3 lacks (the value layers' own learning
    rate and width, whether the value reads the policy's trunk, the RL jobs' stop once solved).
    The defaults are the authors' expert PPO (their repository's ``ppo.py``,
    ``../shared/reference/original-code-facts.md`` section 4), which the paper says its RL
    baselines use: 20 copies of the task stepped together, one episode of each per update,
    Monte-Carlo returns, one Adam at 1e-3 for ``policy + value MSE - 0.001 entropy``."""

    n_envs: int = 20
    """Copies of the env stepped together (one batched policy forward for all of them)."""
    n_steps: int = 0
    """Env steps per copy between updates; 0: one episode (the caller's episode length)."""
    learning_rate: float = 1e-3
    """Adam's learning rate (of every parameter but the value layers' when ``value_learning_rate`` is set)."""
    value_learning_rate: float | None = None
    """Adam's learning rate of the value layers (a group of their own); None: ``learning_rate``, one group."""
    batch_size: int = 64
    """Minibatch size of an update (the authors: 64 in multi-room, 128 in relocation)."""
    n_epochs: int = 10
    """Passes over each rollout."""
    gamma: float = 0.99
    """Discount factor."""
    gae_lambda: float = 1.0
    """GAE's lambda (1: Monte-Carlo returns minus the value, as the authors)."""
    clip_range: float = 0.2
    """PPO's ratio clip."""
    ent_coef: float = 0.001
    """Entropy bonus."""
    vf_coef: float = 1.0
    """Weight of the value loss."""
    target_kl: float | None = None
    """SB3's early stop: an update's epochs end once the KL to the rollout policy passes 1.5 x this; None: never."""
    max_grad_norm: float = 0.5
    """Gradient clipping norm (SB3's default); ``inf``: none."""
    value_hidden: int = 64
    """Width of each hidden layer of the value head."""
    value_layers: int = 1
    """Hidden layers of the value head (each ``value_hidden`` wide)."""
    stop_when_solved: bool = True
    """RL jobs (``gpl_dist.app.suite.rl.per_task``): stop updating once every copy solved the task in one update's episodes,
    as the authors' expert PPO stopped; later trajectories are sampled from that policy. (Updating on:
    once all copies succeed the advantages are near-equal, normalising them amplifies noise, and the
    policy can collapse: measured on multi-room task 69, 0.99 completion to 0.0 within 100 trajectories.)"""
    share_trunk: bool = False
    """Whether the value head reads the policy's features extractor (SB3's ``share_features_extractor``).
    No (the authors' separate value network): the value has its own copy of the trunk, so returns in
    the hundreds do not pull the policy's features."""

    def value_arch(self) -> list[int]:
        """The value head's hidden layer widths (SB3's ``net_arch["vf"]``)."""
        return [self.value_hidden] * self.value_layers


def ppo_class():
    """SB3's PPO with two switches: ``updating = False`` skips its updates while it goes on sampling,
    and ``value_learning_rate`` (a constructor argument; None: off) gives the value layers an Adam
    group of their own at that rate (``value_parameters``), the rest the schedule's rate."""
    from stable_baselines3 import PPO

    class ProjectPPO(PPO):
        """SB3's PPO whose updates can be switched off and whose value layers can keep their own rate."""

        updating = True

        def __init__(self, *args, value_learning_rate: float | None = None, **kwargs):
            self.value_learning_rate = value_learning_rate
            self._value_ids: set[int] = set()
            super().__init__(*args, **kwargs)

        def _setup_model(self) -> None:
            super()._setup_model()
            if self.value_learning_rate is None:
                return
            value = value_parameters(self.policy)
            self._value_ids = {id(q) for q in value}
            others = [q for q in self.policy.parameters() if q.requires_grad and id(q) not in self._value_ids]
            groups: list[dict[str, Any]] = [{"params": others}, {"params": value, "lr": self.value_learning_rate}]
            optimizer_class: Any = self.policy.optimizer_class  # Adam, with SB3's eps 1e-5 in its kwargs
            self.policy.optimizer = optimizer_class(groups, lr=self.lr_schedule(1.0), **self.policy.optimizer_kwargs)

        def _update_learning_rate(self, optimizers) -> None:
            super()._update_learning_rate(optimizers)
            if self.value_learning_rate is None:
                return
            for group in self.policy.optimizer.param_groups:  # found by its parameters (a loaded state keeps them)
                if group["params"] and id(group["params"][0]) in self._value_ids:
                    group["lr"] = self.value_learning_rate

        def train(self) -> None:
            if self.updating:
                super().train()

    return ProjectPPO


def value_parameters(policy) -> list:
    """The parameters only the value reads in an SB3 ``ActorCriticPolicy``: its value MLP and output
    layer, and its own features extractor when it does not share the policy's."""
    modules = [policy.mlp_extractor.value_net, policy.value_net]
    if not policy.share_features_extractor:
        modules.insert(0, policy.vf_features_extractor)
    return [q for m in modules for q in m.parameters() if q.requires_grad]


def make_sb3_ppo(env, settings: PPOSettings, *, episode_steps: int, seed: int, pi: list[int], **policy_kwargs: Any):
    """``ppo_class()`` on SB3's vectorised ``env`` (``settings.n_envs`` copies) with every one of
    ``settings``, on the CPU, silent; ``n_steps`` 0 is ``episode_steps``. The policy MLP has hidden
    layers ``pi``, the value head ``settings.value_arch()``; ``policy_kwargs`` go to SB3's policy
    (the features extractor, the activation, ``ortho_init``, ...)."""
    with warnings.catch_warnings():  # a rollout need not be a multiple of the minibatch: SB3 warns, we know
        warnings.filterwarnings("ignore", message=".*mini-batch size.*")
        return ppo_class()(
            "MlpPolicy", env, learning_rate=settings.learning_rate, n_steps=settings.n_steps or episode_steps,
            batch_size=settings.batch_size, n_epochs=settings.n_epochs, gamma=settings.gamma,
            gae_lambda=settings.gae_lambda, clip_range=settings.clip_range, ent_coef=settings.ent_coef,
            vf_coef=settings.vf_coef, target_kl=settings.target_kl, max_grad_norm=settings.max_grad_norm,
            value_learning_rate=settings.value_learning_rate, seed=seed, device="cpu", verbose=0,
            policy_kwargs=dict(net_arch=dict(pi=list(pi), vf=settings.value_arch()),
                               share_features_extractor=settings.share_trunk, **policy_kwargs))

"""An attempt stepped again from its reset seed and actions: the one replay behind rendering
(``gpl_dist.app.rendering``), teaching (``gpl_dist.app.teaching``), the policy API
(``gpl_dist.app.policy``) and the Minari export (``gpl_dist.app.export``).

An attempt is a function of its task, reset seed and actions (``docs/design.md``, Determinism):
``step_through`` makes the task's env, resets it with the seed and steps it through the actions,
recording the completion, success and reward after each; a caller that draws, or reads the env's
state, does so in ``visit``, which sees the env at the start and after every action.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from gpl_dist.domains import get_domain
from gpl_dist.errors import UsageError
from gpl_dist.roles import DomainSpec


@dataclass(frozen=True)
class Course:
    """What ``step_through`` saw.

    Attributes:
        env: the env in the state after the last action.
        completion: float ``(T + 1,)`` the completion at the start and after each action.
        success: bool ``(T + 1,)`` whether the task is solved at the start and after each action.
        rewards: float ``(T,)`` the env's reward of each action.
        observations: ``(T + 1, ...)`` the observation at the start and after each action, when
            asked for (``keep_observations``); else None.
    """

    env: Any
    completion: np.ndarray
    success: np.ndarray
    rewards: np.ndarray
    observations: np.ndarray | None

    @property
    def solved_at(self) -> int | None:
        """The first step (actions taken) at which the task was solved; None if never."""
        hits = np.flatnonzero(self.success)
        return int(hits[0]) if hits.size else None


def step_through(domain: DomainSpec | str, task_id: int, actions: Sequence[int] | np.ndarray, reset_seed: int, *,
           render_mode: str | None = None, visit: Callable[[int, Any, dict], None] | None = None,
           keep_observations: bool = False) -> Course:
    """Step ``task_id``'s env of ``domain`` (a spec or a registered name), made with ``render_mode``
    (none when None) and reset with ``reset_seed``, through ``actions`` (the first
    ``steps_per_attempt`` of them). ``visit(t, env, info)`` is called after the reset (``t`` 0) and
    after each action (``t`` actions taken). ``UsageError`` (one line) for an action outside
    ``0..num_actions-1``, before it is taken."""
    spec = get_domain(domain) if isinstance(domain, str) else domain
    env: Any = spec.make_env(task_id, render_mode=render_mode) if render_mode else spec.make_env(task_id)
    first, info = env.reset(seed=reset_seed)
    observations = [np.asarray(first)] if keep_observations else None
    completion, success = [float(info.get("completion", 0.0))], [bool(info.get("success", False))]
    rewards: list[float] = []
    if visit is not None:
        visit(0, env, info)
    planned = np.asarray(actions).tolist()
    for t, a in enumerate(planned[: spec.steps_per_attempt]):
        if not 0 <= a < spec.num_actions:
            raise UsageError(f"action {a} at step {t} is outside 0..{spec.num_actions - 1}")
        obs, reward, _, _, info = env.step(a)
        if observations is not None:
            observations.append(np.asarray(obs))
        rewards.append(float(reward))
        completion.append(float(info.get("completion", 0.0)))
        success.append(bool(info.get("success", False)))
        if visit is not None:
            visit(t + 1, env, info)
    return Course(env, np.asarray(completion), np.asarray(success, dtype=bool), np.asarray(rewards, dtype=np.float64),
                  np.stack(observations) if observations is not None else None)

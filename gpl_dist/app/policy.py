"""The Python API: load a run's trained policy and make it attempt a task, corrected in words.

What stable-baselines3's ``PPO.load(path).predict(obs)`` is for a plain policy, this is for a GPL
policy, whose action depends on every earlier (attempt, correction) pair as well as the state::

    from gpl_dist.app.policy import load_policy

    policy = load_policy("runs/paper/multiroom-gpl/seed0")          # checkpoints/latest.pt
    attempts = policy.attempts(263, ["enter the grey room", "enter the red room"], seed=1)
    for a in attempts:                                              # gpl_dist.records.Attempt
        print(a.attempt_index, a.completion, a.success, policy.solved_at(a))
    frames = policy.frames(attempts[-1])                            # RGB arrays, start to end
    said = policy.oracle_correction(attempts[-1], seed=1)           # what the run's oracle says
    by_oracle = policy.attempts(263, seed=1, num_corrections=5)     # meta-test: the oracle corrects

Attempt ``k`` follows the instruction and the corrections ``0..k-1``; the policy stops at the
first attempt that solves the task, so fewer attempts than corrections + 1 can come back. Every
attempt is a function of (checkpoint, task, seed, corrections): the same call gives the same
attempts (``docs/design.md``, Determinism). Each ``Attempt`` carries the trajectory
(``observations``, ``actions``), its ``completion``, ``success``, reset ``seed`` and ``reward_sum``;
``correction`` is the one given *after* it (empty for the last), as in the buffer. A
``TrainedPolicy`` is not thread-safe: share it behind a lock (``gpl_dist.app.teaching`` does).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from gpl_dist.app.rendering import replay_attempt
from gpl_dist.app.replay import step_through
from gpl_dist.config import RunConfig
from gpl_dist.corrections import make_corrector
from gpl_dist.domains import get_domain
from gpl_dist.errors import UsageError
from gpl_dist.models.build import PolicyNetwork
from gpl_dist.records import Attempt, Correction
from gpl_dist.roles import DomainSpec
from gpl_dist.seeding import correction_rng
from learner.checkpoint import LATEST
from learner.evaluate import load_trained_policy, meta_test_rollout
from workers.rollout import Rollout

#: Kind recorded in ``Attempt.correction_kind`` for a correction given as text through this API.
GIVEN_KIND = "person"


@dataclass(frozen=True)
class TrainedPolicy:
    """A run's policy with one checkpoint's weights, in eval mode (``load_policy``).

    Attributes:
        run_dir: the run dir (absolute).
        checkpoint: the checkpoint file (absolute).
        cfg: the run's resolved config, as the checkpoint records it.
        model: the network (``gpl_dist.models.build.PolicyNetwork``).
        round_index: the DAgger round the checkpoint ends.
        domain: the domain's spec.
        greedy: act with the most likely action (else sample, as meta-test does).
    """

    run_dir: str
    checkpoint: str
    cfg: RunConfig
    model: PolicyNetwork
    round_index: int
    domain: DomainSpec
    greedy: bool = False

    def attempts(self, task_id: int, corrections: Sequence[str] | None = None, *, seed: int = 0,
                 num_corrections: int | None = None) -> tuple[Attempt, ...]:
        """Attempts at ``task_id``: the ``k``-th after ``corrections[k-1]`` (texts, as a person
        would type them), or, without ``corrections``, after the run's own oracle's, up to
        ``num_corrections`` (default the run's ``eval.num_corrections``) as at meta-test."""
        if not 0 <= int(task_id) < self.domain.num_tasks:
            raise UsageError(f"task {task_id} is outside 0..{self.domain.num_tasks - 1} of {self.domain.name}")
        if corrections is None:
            rollout = meta_test_rollout(self.cfg, self.model, greedy=self.greedy)
            k = self.cfg.eval.num_corrections if num_corrections is None else int(num_corrections)
        else:
            if num_corrections is not None:
                raise UsageError("give corrections or num_corrections (the oracle's), not both")
            texts = [str(c) for c in corrections]
            given = iter(texts)
            rollout = Rollout(self.domain, self.model, lambda env, rng: Correction(next(given), GIVEN_KIND),
                              greedy=self.greedy, end_aligned=self.cfg.model.trajectory_ends_at_last_state)
            k = len(texts)
        result = rollout.run([int(task_id)], k, int(seed), split="api")
        if result.failures:
            raise UsageError(str(result.failures[0]))
        return result.attempts

    def solved_at(self, attempt: Attempt) -> int | None:
        """The step (1-based: after that many actions) at which ``attempt`` first solved its task;
        None when it never did. The attempt runs on after it (the paper's protocol)."""
        return step_through(self.domain, attempt.task_id, attempt.actions, attempt.seed).solved_at

    def frames(self, attempt: Attempt) -> list[np.ndarray]:
        """RGB frames of ``attempt``: its start state and the state after each action."""
        return replay_attempt(self.domain.name, attempt.task_id, attempt.actions, attempt.seed).frames

    def oracle_correction(self, attempt: Attempt, seed: int = 0) -> str:
        """What the run's correction oracle says after ``attempt`` (made with ``seed``)."""
        env = step_through(self.domain, attempt.task_id, attempt.actions, attempt.seed).env
        oracle = make_corrector(self.domain.name, self.cfg.env.correction_kind)
        return oracle.correct(env, correction_rng(seed, attempt.task_id, attempt.attempt_index)).text


def load_policy(run_dir: str | Path, checkpoint: str | Path | None = None, greedy: bool = False, *,
                allow_foreign: bool = False) -> TrainedPolicy:
    """The policy of ``run_dir`` with ``checkpoint``'s weights (default ``RUN_DIR/checkpoints/latest.pt``,
    loaded with ``weights_only=True``). A checkpoint of another run, domain or model is refused
    (``CheckpointError``) unless ``allow_foreign``."""
    ckpt = Path(checkpoint).resolve() if checkpoint else Path(run_dir).resolve() / "checkpoints" / LATEST
    cfg, model, round_index = load_trained_policy(run_dir, str(ckpt), allow_foreign=allow_foreign)
    model.eval()
    return TrainedPolicy(str(Path(run_dir).resolve()), str(ckpt), cfg, model, round_index, get_domain(cfg.env.domain),
                         bool(greedy))

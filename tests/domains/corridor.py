"""A whole domain in one file outside the package: a seven-cell corridor with its env, expert,
correction oracle, vocabulary, model sizes and splits (``docs/adding-a-domain.md``).

A run names it with ``env.domain_module: tests/domains/corridor.py`` (or an installed package
declares it under the ``gpl_dist.domains`` entry points); the tests train it serially and on Ray
and run the env contract tests over it.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from gpl_dist.language import Vocabulary
from gpl_dist.models.sizes import Sizes
from gpl_dist.records import Correction
from gpl_dist.roles import DomainSpec

CELLS = 7
START = 3
STEPS = 8
# task t: the goal cell (never the start) and the colour the instruction names
GOALS = (0, 1, 2, 4, 5, 6, 0, 6)
COLOURS = ("red", "blue", "red", "blue", "red", "blue", "blue", "red")
VOCAB = Vocabulary(words=("go", "to", "the", "red", "blue", "cell", "left", "right", "you", "are", "done",
                          "goal", "is", "zero", "one", "two", "four", "five", "six"), max_tokens=8)
NUMBERS = {0: "zero", 1: "one", 2: "two", 4: "four", 5: "five", 6: "six"}


class Corridor(gym.Env):
    """Seven cells in a row; the agent starts in the middle and must stand on the task's goal cell.

    Observation: float32 ``(3,)``: the agent's cell / 6, the steps taken / 8, 1 once the goal was reached.
    Actions: 0 left, 1 right. ``info``: ``completion`` (1 once the goal was reached, else 0) and ``success``.
    """

    domain_name = "corridor"

    metadata = {"render_modes": ["ansi"]}

    def __init__(self, task_id: int, render_mode: str | None = None):
        if isinstance(task_id, bool) or not isinstance(task_id, (int, np.integer)) or not 0 <= task_id < len(GOALS):
            raise ValueError(f"task_id must be an int in 0..{len(GOALS) - 1}, got {task_id!r}")
        self.render_mode = render_mode
        self.task_id = int(task_id)
        self.goal = GOALS[task_id]
        self.instruction = f"go to the {COLOURS[task_id]} cell"
        self.observation_space = spaces.Box(0.0, 1.0, (3,), np.float32)
        self.action_space = spaces.Discrete(2)
        self.pos, self.t, self.reached = START, 0, False
        self.path = [START]

    def _obs(self) -> np.ndarray:
        return np.array([self.pos / 6, self.t / STEPS, float(self.reached)], np.float32)

    def _info(self) -> dict:
        return {"completion": float(self.reached), "success": self.reached}

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.pos, self.t, self.reached = START, 0, False
        self.path = [START]
        return self._obs(), self._info()

    def step(self, action):
        self.pos = int(np.clip(self.pos + (1 if action == 1 else -1), 0, CELLS - 1))
        self.t += 1
        self.reached = self.reached or self.pos == self.goal
        self.path.append(self.pos)
        return self._obs(), float(self.reached), False, self.t >= STEPS, self._info()


    def render(self) -> str:
        """``ansi``: the corridor with the goal (G), the cells visited (.) and the agent (A)."""
        cells = ["G" if c == self.goal else ("." if c in self.path else "_") for c in range(CELLS)]
        cells[self.pos] = "A"
        return "".join(cells) + f"  {self.t} steps"


class WalkToGoal:
    """The scripted expert: one step towards the goal."""

    soft_labels = False

    def act(self, env) -> int:
        e = env.unwrapped
        return 0 if e.goal < e.pos else 1

    def label(self, env) -> tuple[int, np.ndarray]:
        a = self.act(env)
        return a, np.eye(2, dtype=np.float32)[a]


class SayDirection:
    """The correction oracle: which way the goal lies, from where the attempt ended."""

    def __init__(self, kind: str = "default"):
        self.kind = kind

    def correct(self, env, rng) -> Correction:
        e = env.unwrapped
        if e.reached:
            return Correction("you are done", "direction")
        return Correction("go left" if e.goal < e.pos else "go right", "direction")

    def full_information(self, env) -> str:
        return f"the goal is cell {NUMBERS[env.unwrapped.goal]}"


def phrasings() -> tuple[str, ...]:
    """Every sentence the oracle says."""
    return ("you are done", "go left", "go right")


DOMAIN = DomainSpec(
    name="corridor",
    env_id="gpl-test/Corridor-v0",
    num_tasks=len(GOALS),
    obs_shape=(3,),
    obs_dtype="float32",
    num_actions=2,
    steps_per_attempt=STEPS,
    trajectory_stride=4,
    vocabulary=VOCAB,
    make_env=Corridor,
    split_names=("train", "test"),
    experts={"walker": WalkToGoal},  # no "scripted": the first expert is the default
    correction_kinds=("default",),
    make_corrector=SayDirection,
    model_sizes=Sizes(state_channels=(), state_mlp=(), traj_state_channels=(), traj_state_mlp=(), traj_conv=4,
                      traj_mlp=(8, 4), text_conv=4, correction_mlp=(8, 4), instruction_mlp=(8, 8), pair_mlp=(8, 8),
                      pair_final_relu=True, policy_mlp=(16, 16)),
    paper_completion={},
    splits={"train": (0, 1, 2, 3, 4, 5), "test": (6, 7)},
    correction_phrasings=phrasings,
)

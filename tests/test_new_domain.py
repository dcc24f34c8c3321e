"""A domain is added in one place: a ``DomainSpec`` given to ``register_domain``.

This file defines a whole domain (a seven-cell corridor with its env, expert, correction oracle,
vocabulary, model sizes and splits), registers it, and runs one serial DAgger round and a
meta-test on it, with no edit anywhere else: the steps of ``docs/adding-a-domain.md``.
"""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

from gpl_dist.config import ConfigError, config_from_dict
from gpl_dist.domains import domain_names, get_domain, register_domain, unregister_domain
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

    def __init__(self, task_id: int, render_mode: str | None = None):
        self.task_id = task_id
        self.goal = GOALS[task_id]
        self.instruction = f"go to the {COLOURS[task_id]} cell"
        self.observation_space = spaces.Box(0.0, 1.0, (3,), np.float32)
        self.action_space = spaces.Discrete(2)
        self.pos, self.t, self.reached = START, 0, False

    def _obs(self) -> np.ndarray:
        return np.array([self.pos / 6, self.t / STEPS, float(self.reached)], np.float32)

    def _info(self) -> dict:
        return {"completion": float(self.reached), "success": self.reached}

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.pos, self.t, self.reached = START, 0, False
        return self._obs(), self._info()

    def step(self, action):
        self.pos = int(np.clip(self.pos + (1 if action == 1 else -1), 0, CELLS - 1))
        self.t += 1
        self.reached = self.reached or self.pos == self.goal
        return self._obs(), float(self.reached), False, self.t >= STEPS, self._info()


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


CORRIDOR = DomainSpec(
    name="corridor",
    env_id="gpl-test/Corridor-v0",
    num_tasks=len(GOALS),
    obs_shape=(3,),
    obs_dtype="float32",
    num_actions=2,
    steps_per_attempt=STEPS,
    trajectory_stride=4,
    vocabulary=VOCAB,
    make_env=lambda task_id, **kw: Corridor(task_id, **kw),
    split_names=("train", "test"),
    experts={"scripted": WalkToGoal},
    correction_kinds=("default",),
    make_corrector=SayDirection,
    model_sizes=Sizes(state_channels=(), state_mlp=(), traj_state_channels=(), traj_state_mlp=(), traj_conv=4,
                      traj_mlp=(8, 4), text_conv=4, correction_mlp=(8, 4), instruction_mlp=(8, 8), pair_mlp=(8, 8),
                      pair_final_relu=True, policy_mlp=(16, 16)),
    paper_completion={},
    splits={"train": (0, 1, 2, 3, 4, 5), "test": (6, 7)},
)


@pytest.fixture
def corridor():
    register_domain(CORRIDOR)
    yield CORRIDOR
    unregister_domain("corridor")


def test_a_domain_defined_here_trains_one_dagger_round_and_evaluates(corridor, tmp_path, capsys):
    from gpl_dist.cli import main
    from storage import BufferReader

    assert "corridor" in domain_names() and get_domain("corridor") is corridor
    assert gym.make("gpl-test/Corridor-v0", task_id=2).reset(seed=0)[0].shape == (3,)
    with pytest.raises(ConfigError, match="env.correction_kind must be one of default for corridor"):
        config_from_dict({"env": {"domain": "corridor", "correction_kind": "subgoal"}})

    config = tmp_path / "corridor.yaml"
    config.write_text("env: {domain: corridor}\ncollection: {num_corrections: 2, tasks_per_unit: 4}\n"
                      "training: {num_rounds: 1, num_epochs_per_round: 2, batch_size: 16}\neval: {seeds: [0, 1]}\n")
    run = tmp_path / "run"
    assert main(["train", "--config", str(config), "--serial", "--run-dir", str(run), "--no-progress"]) == 0
    reader = BufferReader(run / "buffer")
    assert reader.committed_rounds() == [0]
    attempts = reader.read_table("attempts")
    assert sorted(set(attempts.column("task_id").to_pylist())) == [0, 1, 2, 3, 4, 5]
    assert set(attempts.column("correction").to_pylist()) <= {"", "go left", "go right"}
    tuples = reader.read_table("tuples")
    assert tuples.num_rows == STEPS * attempts.num_rows
    # every label is the expert's step towards the goal
    view = reader.load_training_view(trajectory_stride=corridor.trajectory_stride)
    cells = np.rint(view.observations[:, 0] * 6).astype(int)
    goals = np.array(GOALS)[view.task_id[view.attempt_rows]]
    assert np.array_equal(view.expert_actions, (goals >= cells).astype(np.int64))

    assert main(["eval", "--run-dir", str(run)]) == 0
    out = capsys.readouterr().out
    assert "meta-test on 2 tasks x 2 seeds" in out
    report = json.loads((run / "eval.json").read_text())
    assert report["domain"] == "corridor" and len(report["completion"]) == 6
    assert all(0.0 <= c <= 1.0 for c in report["completion"])


def test_a_spec_that_misses_a_required_part_is_refused():
    import dataclasses

    with pytest.raises(ValueError, match="correction_kinds must include 'default'"):
        register_domain(dataclasses.replace(CORRIDOR, name="corridor-bad", correction_kinds=("left",)))
    with pytest.raises(ValueError, match="a different domain named 'multiroom'"):
        register_domain(dataclasses.replace(get_domain("multiroom"), num_tasks=3))
    assert "corridor-bad" not in domain_names()

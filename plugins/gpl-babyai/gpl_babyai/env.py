"""The BabyAI env of one task; see :class:`BabyAIEnv`."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from minigrid.core.actions import Actions

from gpl_babyai import tasks as task_table
from gpl_babyai.domain import STEPS  # actions per attempt
from gpl_babyai.level import LevelCore
from gpl_babyai.plan import Progress, plan_of
from gpl_babyai.view import VIEW

NUM_ACTIONS = len(Actions)  # 7
#: Codes per observation channel: object type 0..10, colour 0..5, state 0..2 (minigrid's encoding).
OBS_CATEGORIES = (11, 6, 3)

_ARROWS = {0: ">", 1: "v", 2: "<", 3: "^"}
_COLOUR_CHAR = {"red": "r", "green": "g", "blue": "b", "purple": "p", "yellow": "y", "grey": "a"}
_TYPE_CHAR = {"wall": "#", "door": "D", "key": "K", "ball": "O", "box": "B", "goal": "G", "floor": "F", "lava": "V"}


class BabyAIEnv(gym.Env):
    """One BabyAI task: a level of minigrid's BabyAI suite, generated with one seed.

    ## Task
    ``task_id`` names a row of the task table (``gpl_babyai.tasks``): a BabyAI level (e.g.
    ``GoToLocal``) and a seed. ``reset`` generates that level with that seed, every time: every
    attempt of a task starts from the same layout, agent pose and mission. ``reset(seed=...)``
    seeds ``self.np_random`` only (nothing here draws from it).

    ## Instruction
    The level's own mission string, e.g. "put the yellow box next to the yellow ball",
    "pick up the green ball on your right", "go to a box and go to a ball, then open the red door"
    (its commas are not words: ``gpl_dist.language`` splits on letters).

    ## Observation
    BabyAI's egocentric view: ``Box(0, 255, (7, 7, 3), uint8)``, equal to minigrid's
    ``obs["image"]`` (``gpl_babyai.view``; tests check it bit for bit): ``obs[i, j]`` with ``i``
    across the view and ``j`` along it, the agent at ``[3, 6]`` facing ``j = 0``; channels: object
    type (0 unseen, 1 empty, 2 wall, 3 floor, 4 door, 5 key, 6 ball, 7 box, 8 goal, 9 lava,
    10 agent: 11 codes), colour (red, green, blue, purple, yellow, grey: 6 codes), state (doors:
    0 open, 1 closed, 2 locked: 3 codes). Walls and closed doors hide what lies behind them; the
    agent's own cell shows what it carries.

    ## Actions
    ``Discrete(7)``, minigrid's: 0 turn left, 1 turn right, 2 forward, 3 pick up, 4 drop,
    5 toggle (open/close a door, unlock a locked one when carrying its key; a box vanishes),
    6 done (no effect).

    ## Success
    BabyAI's own: the level's verifier (``instrs.verify``) says "success" at a step no later than
    the level's own time limit (``max_steps`` of the level: 64 for GoToLocal and PickupLoc, 128
    for PutNextLocal, 576 for the one-instruction 3x3 mazes...). Sticky: once solved the attempt
    stays solved. A verifier "failure" (strict levels only; none of this task set) ends any chance
    of success in that attempt. Steps past the level's time limit still move the agent but can
    neither succeed nor complete subgoals.

    ## Completion
    ``gpl_babyai.plan``: the task's plan is the list of ``n`` subgoals (open a door, pick up an
    object, go to an object, put an object next to another) the BabyAI bot achieves when it
    solves the task from its start knowing the whole map. ``k`` counts the subgoals the attempt
    achieved in order (subgoal ``i`` counts once its test on the state holds after subgoal
    ``i - 1`` counted; never decreases). ``info["completion"] = 1`` once the attempt succeeded,
    else ``min(k, n - 1) / n``: a fraction in [0, 1], 1 exactly when solved (the last subgoal's
    test can hold without BabyAI's verifier agreeing, e.g. the wrong one of two red balls).
    ``info["success"]``: the sticky success above.

    ## Reward
    BabyAI's: ``1 - 0.9 * step / max_steps`` (``max_steps`` the level's) on the step the task is
    first solved, else 0.

    ## Termination
    Never terminates (the paper's protocol runs every attempt its full length and reads the best
    completion); truncated from step ``STEPS`` (128) on, as the TimeLimit of
    ``gymnasium.make("gpl-babyai/BabyAI-v0", task_id=...)``.

    ## Rendering
    ``rgb_array``: minigrid's picture of the whole grid (32-pixel tiles, the view highlighted).
    ``ansi``: the grid as text, two characters a cell, the cells visited since reset marked.
    """

    metadata = {"render_modes": ["rgb_array", "ansi"], "render_fps": 10}
    domain_name = "babyai"
    #: what each point of ``picture_points()`` follows (the teaching page's legend)
    picture_point_names = ("the agent",)

    def __init__(self, task_id: int, render_mode: str | None = None):
        self.task_id = task_table.check_task_id(task_id)
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        self.render_mode = render_mode
        task = task_table.tasks()[self.task_id]
        self.level_name, self.level_seed = task.level, task.seed
        self.instruction: str = task.mission
        self.observation_space = spaces.Box(0, 255, (VIEW, VIEW, 3), np.uint8)
        self.action_space = spaces.Discrete(NUM_ACTIONS)
        self._core: LevelCore | None = None  # generated on the first reset
        self._plan = None
        self.expert_state: dict[str, Any] = {}  # the experts' per-episode state (their bots)

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        if self._core is None:
            self._core = LevelCore(self.level_name)
        self._core.generate(self.level_seed)
        if self._core.mission != self.instruction:
            raise RuntimeError(f"task {self.task_id} ({self.level_name} seed {self.level_seed}) generated the mission "
                               f"{self._core.mission!r}, the task table says {self.instruction!r}: another minigrid?")
        if self._plan is None:
            self._plan = plan_of(self.level_name, self.level_seed)
        self._steps = 0
        self._success = False
        self._failed = False
        self._progress = Progress(self._plan)
        self._progress.update(self._core.level)
        self.last_action: int | None = None
        self.expert_state = {}
        self._trail = [tuple(int(v) for v in self._core.level.agent_pos)] if self.render_mode == "ansi" else None
        return self._core.observe(), self._info()

    def step(self, action):
        a = int(action)
        if not 0 <= a < NUM_ACTIONS:
            raise ValueError(f"invalid action {action!r} (expected 0..{NUM_ACTIONS - 1})")
        core = self._core
        level = core.level
        carried = level.carrying
        status = core.step(a)
        self._steps += 1
        self.last_action = a
        reward = 0.0
        if self._steps <= level.max_steps and not self._success and not self._failed:
            dropped = carried if (a == Actions.drop and carried is not None and level.carrying is None) else None
            self._progress.update(level, a, dropped)
            if status == "success":
                self._success = True
                reward = 1.0 - 0.9 * (self._steps / level.max_steps)
            elif status == "failure":
                self._failed = True
        if self._trail is not None:
            self._trail.append(tuple(int(v) for v in level.agent_pos))
        return core.observe(), reward, False, self._steps >= STEPS, self._info()

    def _info(self) -> dict[str, Any]:
        return {"completion": self.completion, "success": self._success}

    # ------------------------------------------------------------------ state read by experts and oracles
    @property
    def level(self):
        """The minigrid level (privileged state: grid, agent pose, carried object, instructions)."""
        return self._core.level

    @property
    def core(self) -> LevelCore:
        return self._core

    @property
    def plan(self):
        """The task's subgoals (``gpl_babyai.plan.Subgoal``), from its start."""
        if self._plan is None:
            self._plan = plan_of(self.level_name, self.level_seed)
        return self._plan

    @property
    def subgoal_texts(self) -> tuple[str, ...]:
        return tuple(s.text for s in self.plan)

    @property
    def subgoals_done(self) -> int:
        """How many of the plan's subgoals the attempt achieved, in order."""
        return self._progress.done

    @property
    def steps(self) -> int:
        return self._steps

    @property
    def success(self) -> bool:
        return self._success

    @property
    def completion(self) -> float:
        if self._success:
            return 1.0
        n = len(self._plan)
        return min(self._progress.done, n - 1) / n if n else 0.0

    # ------------------------------------------------------------------ pictures
    def render(self):
        if self.render_mode == "rgb_array":
            return self._core.level.get_frame(highlight=True, tile_size=32)
        if self.render_mode == "ansi":
            return self._text_picture()
        return None

    def picture_points(self) -> tuple[tuple[float, float], ...]:
        """The agent's centre in the ``rgb_array`` picture, in pixels (what a drawn path follows)."""
        x, y = self._core.level.agent_pos
        return ((float(x) * 32 + 16, float(y) * 32 + 16),)

    def _text_picture(self) -> str:
        level = self._core.level
        grid = level.grid
        trail = set(self._trail or ())
        rows = []
        for y in range(grid.height):
            row = []
            for x in range(grid.width):
                if (x, y) == tuple(int(v) for v in level.agent_pos):
                    row.append(_ARROWS[level.agent_dir] * 2)
                    continue
                cell = grid.get(x, y)
                if cell is None:
                    row.append(". " if (x, y) in trail else "  ")
                elif cell.type == "wall":
                    row.append("##")
                elif cell.type == "door":
                    row.append(("_" if cell.is_open else "L" if cell.is_locked else "D") + _COLOUR_CHAR[cell.color])
                else:
                    row.append(_TYPE_CHAR.get(cell.type, "?") + _COLOUR_CHAR[cell.color])
            rows.append("".join(row))
        carrying = level.carrying
        held = f"{carrying.color} {carrying.type}" if carrying is not None else "nothing"
        rows.append(f"{self.instruction}")
        rows.append(f"{self._steps} steps, carrying {held}, subgoals {self._progress.done}/{len(self._plan)}, "
                    f"{'solved' if self._success else 'not solved'}")
        rows.append("legend: ## wall, D/L/_ closed/locked/open door, K key, O ball, B box, each then its colour: r red, "
                    "g green, b blue, p purple, y yellow, a grey; . visited; arrows the agent")
        return "\n".join(rows)


def make_env(task_id: int, **kwargs: Any) -> BabyAIEnv:
    """The unwrapped env of ``task_id`` (``kwargs``: ``render_mode``)."""
    return BabyAIEnv(task_id, **kwargs)

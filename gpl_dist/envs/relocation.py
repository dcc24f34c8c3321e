"""Robotic object relocation (Co-Reyes et al., ICLR 2019, section 6.1.2) as a plain gymnasium env.

The scene is ``gpl_dist/assets/relocation.xml`` (MuJoCo); tasks, instruction grammar and splits
live here, the correction oracle in ``gpl_dist.corrections.relocation`` and the scripted expert in
``gpl_dist.experts.relocation``. ``RelocationEnv``'s docstring is the domain's specification.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from typing import Any, Mapping

import gymnasium
import mujoco
import numpy as np
from gymnasium import spaces

from gpl_dist.envs.modes import check_modes
from gpl_dist.errors import UsageError
from gpl_dist.language import ParaphraseRule, Paraphrases, Vocabulary
from gpl_dist.models.sizes import Sizes
from gpl_dist.roles import DomainSpec, lazy

# --------------------------------------------------------------------------------------------
# Scene constants (they must agree with assets/relocation.xml).
# --------------------------------------------------------------------------------------------

#: Tasks 0..999 are the paper's 1000 (750 train / 250 test); 1000..1249 are drawn by the same
#: generator (``make_task``) as a valid split for design choices (split file version 2).
PAPER_TASKS = 1000
NUM_VALID_TASKS = 250
NUM_TASKS = PAPER_TASKS + NUM_VALID_TASKS
EPISODE_STEPS = 350
SUCCESS_RADIUS = 0.03
#: Force the chosen action puts on one slide joint of the gripper (motor range is +-2).
ACTION_FORCE = 1.3

MOVABLE_COLORS = ("red", "cyan", "yellow")
MOVABLE_START = np.array([[0.3, 0.2], [0.3, 0.0], [0.3, -0.2]])
FIXED_COLORS = ("purple", "grey", "white", "blue", "green")
FIXED_XY = np.array([[0.910, 0.207], [0.696, 0.777], [0.660, -0.786], [1.072, 0.694], [0.908, -0.487]])
BLOCK_HALF = 0.03
GRIPPER_START = np.array([0.0, 0.0, 0.0])
GRIPPER_POSE_NOISE = 0.05
GRIPPER_VEL_NOISE = 0.1
ARM_OFFSET = 0.02  # the "arm" site, in the gripper frame, used by the dense reward

#: Action table: (ctrl x, ctrl y) per discrete action.
ACTION_NAMES = ("+y (up)", "-y (down)", "+x (right)", "-x (left)")
_ACTION_CTRL = ((0.0, ACTION_FORCE), (0.0, -ACTION_FORCE), (ACTION_FORCE, 0.0), (-ACTION_FORCE, 0.0))

#: Index of each movable block's (x, y) in qpos (and in the observation).
BLOCK_QPOS = (3, 5, 7)

# Task sampling (facts file section 3).
_TASK_SEED = 20190506
P_CARDINAL = 0.51
TARGET_SPAN = 0.3
MIN_FIXED_CLEARANCE = 0.1
TARGET_X_RANGE = (0.5, 1.3)
TARGET_ABS_Y = 1.1
_CARDINAL_DIRS = np.array([[0.0, 1.0], [-1.0, 0.0], [0.0, -1.0], [1.0, 0.0]])  # up, left, down, right

# --------------------------------------------------------------------------------------------
# Language.
# --------------------------------------------------------------------------------------------

DIGIT_WORDS = ("zero", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine", "ten")
#: The eight direction phrases, indexed by octant of the angle (0 = right, counter-clockwise).
DIRECTION_PHRASES = ("right", "up right", "up", "up left", "left", "down left", "down", "down right")

VOCABULARY = Vocabulary(
    words=(
        # instruction
        "move", "close", "to",
        # corrections
        "touch", "the", "block", "a", "little", "lot", "of", "closer",
        "up", "down", "left", "right",
        # colours
        "red", "cyan", "yellow", "purple", "grey", "white", "blue", "green",
        # full information and reward texts
        "x", "y", "point", "minus", "reward",
        "zero", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine", "ten",
    ),
    max_tokens=24,
)

_DIR = "(?P<d>up right|up left|down right|down left|up|down|left|right)"
#: Five phrasings of the instruction and of every correction form, as in multi-room
#: (``gpl_dist.envs.multiroom.PARAPHRASES``): canonical, two for training, two held out.
PARAPHRASES = Paraphrases((
    ParaphraseRule(r"move (?P<b>\w+) close to (?P<o>\w+)", (
        "Move {b} close to {o}", "push the {b} block near the {o} block", "bring {b} next to {o}",
        "push the {b} block next to the {o} block", "bring the {b} block near {o}")),
    ParaphraseRule(r"touch the (?P<c>\w+) block", (
        "Touch the {c} block", "push the {c} block", "you should move the {c} block", "you should push the {c} block",
        "move the {c} block")),
    ParaphraseRule(r"move a (?P<amt>little|lot) " + _DIR, (
        "Move a {amt} {d}", "go a {amt} {d}", "push it a {amt} {d}", "push a {amt} {d}", "go {d} a {amt}")),
    ParaphraseRule(r"move closer to the (?P<c>\w+) block", (
        "Move closer to the {c} block", "go closer to the {c} block", "push it nearer to the {c} block",
        "push it closer to the {c} block", "go nearer to the {c} block")),
    ParaphraseRule(r"move " + _DIR + r" of the (?P<c>\w+) block", (
        "Move {d} of the {c} block", "go {d} of the {c} block", "push it to the {d} of the {c} block",
        "push it {d} of the {c} block", "go to the {d} of the {c} block")),
))

#: Correction oracle kinds (``gpl_dist.corrections.relocation``): ``default`` is the paper's mixed oracle.
CORRECTION_KINDS = ("default", "mixed", "directional", "relational", "touch", "reward")


def direction_phrase(dx: float, dy: float) -> str:
    """The one of eight directions with the smallest angle to ``(dx, dy)`` (``"up left"``, ...)."""
    octant = int(round(math.atan2(dy, dx) / (math.pi / 4))) % 8
    return DIRECTION_PHRASES[octant]


def spell_number(value: float) -> str:
    """``value`` rounded to two decimals, spelled digit by digit: -0.41 -> "minus zero point four one"."""
    hundredths = int(round(abs(value) * 100))
    whole, frac = divmod(hundredths, 100)
    words = ["minus"] if value < 0 and hundredths else []
    words += [DIGIT_WORDS[int(c)] for c in str(whole)]
    words += ["point", DIGIT_WORDS[frac // 10], DIGIT_WORDS[frac % 10]]
    return " ".join(words)


# --------------------------------------------------------------------------------------------
# Tasks.
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RelocationTask:
    """One of the 1000 tasks, a deterministic function of its id.

    Attributes:
        task_id: index in 0..999.
        block: index of the goal block among ``MOVABLE_COLORS``.
        block_color: its colour word.
        target: (x, y) the goal block must reach.
        target_kind: ``cardinal`` or ``close`` (how the target was sampled).
        anchor: index of the fixed block the target was sampled around.
        obstacle: index of the fixed block named in the instruction (nearest or second nearest
            fixed block to the target).
        obstacle_color: its colour word.
        initial_distance: distance from the goal block's start position to the target.
    """

    task_id: int
    block: int
    block_color: str
    target: tuple[float, float]
    target_kind: str
    anchor: int
    obstacle: int
    obstacle_color: str
    initial_distance: float

    @property
    def instruction(self) -> str:
        return f"Move {self.block_color} close to {self.obstacle_color}"


def _check_task_id(task_id: Any) -> int:
    if isinstance(task_id, bool) or not isinstance(task_id, (int, np.integer)):
        raise UsageError(f"relocation task_id must be an int in 0..{NUM_TASKS - 1}, got {task_id!r}")
    if not 0 <= int(task_id) < NUM_TASKS:
        raise UsageError(f"relocation task_id must be in 0..{NUM_TASKS - 1}, got {int(task_id)}")
    return int(task_id)


def _target_ok(p: np.ndarray) -> bool:
    return (TARGET_X_RANGE[0] < p[0] < TARGET_X_RANGE[1] and abs(p[1]) < TARGET_ABS_Y
            and bool(np.all(np.hypot(*(FIXED_XY - p).T) > MIN_FIXED_CLEARANCE)))


@lru_cache(maxsize=None)
def make_task(task_id: int) -> RelocationTask:
    """The task ``task_id`` (0..1249): goal block, target and instruction, from a per-task seed
    (each task's own stream, so adding tasks past the paper's 1000 changed none of them)."""
    task_id = _check_task_id(task_id)
    rng = np.random.default_rng(np.random.SeedSequence([_TASK_SEED, task_id]))
    block = int(rng.integers(3))
    kind = "cardinal" if rng.random() < P_CARDINAL else "close"
    while True:  # redraw the position (not the kind) until it meets the constraints
        anchor = int(rng.integers(len(FIXED_XY)))
        f = FIXED_XY[anchor]
        if kind == "cardinal":
            direction = _CARDINAL_DIRS[int(rng.integers(4))]
            target = f + rng.uniform(0.0, TARGET_SPAN) * direction
        else:
            angle = rng.uniform(0.0, 2.0 * math.pi)
            corner = f + TARGET_SPAN * np.array([math.cos(angle), math.sin(angle)])
            lo, hi = np.minimum(f, corner), np.maximum(f, corner)
            target = rng.uniform(lo, hi)
        if _target_ok(target):
            break
    order = np.argsort(np.hypot(*(FIXED_XY - target).T), kind="stable")
    obstacle = int(order[int(rng.integers(2))])
    target_t = (float(target[0]), float(target[1]))
    return RelocationTask(
        task_id=task_id, block=block, block_color=MOVABLE_COLORS[block], target=target_t,
        target_kind=kind, anchor=anchor, obstacle=obstacle, obstacle_color=FIXED_COLORS[obstacle],
        initial_distance=float(np.hypot(*(MOVABLE_START[block] - target))),
    )


#: The split file's version: 1 had train/test only; 2 adds ``valid`` (tasks beyond the paper's 1000).
SPLIT_VERSION = 2
SPLIT_NOTE = ("relocation, version 2: train (750) / test (250) = numpy default_rng(seed).permutation(1000), the "
              "paper's 1000 tasks, as in version 1; valid (250) = tasks 1000..1249, drawn by make_task's generator "
              "beyond the paper's 1000, for design choices")


def make_splits(seed: int = 0) -> dict[str, list[int]]:
    """The versioned split: ``train`` (750) / ``test`` (250), a seeded permutation of the paper's
    1000 tasks, and ``valid`` (250), the tasks drawn beyond them (see ``SPLIT_NOTE``)."""
    perm = np.random.default_rng(seed).permutation(PAPER_TASKS)
    return {"train": sorted(int(i) for i in perm[:750]), "test": sorted(int(i) for i in perm[750:]),
            "valid": list(range(PAPER_TASKS, NUM_TASKS))}


def write_relocation_splits(seed: int = 0):
    """Regenerate ``gpl_dist/splits/relocation.json`` (then commit it)."""
    from gpl_dist.splits import write_splits

    return write_splits("relocation", make_splits(seed), seed, SPLIT_NOTE, version=SPLIT_VERSION)


# --------------------------------------------------------------------------------------------
# The MuJoCo model, compiled once per process.
# --------------------------------------------------------------------------------------------

ASSET = "relocation.xml"


def asset_path() -> str:
    """Path of the MuJoCo scene file shipped with the package."""
    return str(resources.files("gpl_dist").joinpath("assets", ASSET))


@lru_cache(maxsize=1)
def load_model() -> mujoco.MjModel:
    """The compiled scene (shared read-only by every env of the process; each env has its MjData)."""
    return mujoco.MjModel.from_xml_path(asset_path())


# --------------------------------------------------------------------------------------------
# The env.
# --------------------------------------------------------------------------------------------


class RelocationEnv(gymnasium.Env):
    """Push one of three blocks to a target with a U-shaped gripper, guided by language.

    **Description.** A planar MuJoCo arena seen from above, zero gravity, timestep 0.01 s
    (Euler, 20 solver iterations, one ``mj_step`` per env step). A gripper (a U of capsules: a bar
    spanning y +-0.1 and two prongs to x = 0.1, free to rotate on an unactuated, damped hinge)
    slides in x and y. Three movable 0.06 x 0.06 blocks (red, cyan, yellow) start at (0.3, 0.2),
    (0.3, 0), (0.3, -0.2); five immovable blocks (purple, grey, white, blue, green) are the same in
    every task. The task is to push the goal block to a target (a non-colliding marker that is
    not observed). Contacts between the gripper and the blocks have friction 0.8; the table plane
    is frictionless for the blocks (with zero gravity it could not carry a normal load anyway).

    **Instruction grammar.** ``"Move <red|cyan|yellow> close to <purple|grey|white|blue|green>"``,
    the fixed block being the nearest or the second nearest to the target, chosen by the task's
    seed (so every task has one fixed instruction).

    **Corrections** (``gpl_dist.corrections.relocation``): ``"Touch the red block"``,
    ``"Move a little left"``, ``"Move a lot down right"``, ``"Move left of the white block"``,
    ``"Move closer to the purple block"``; full information ``"move red to x zero point nine
    three y minus zero point four one"``; reward ``"reward seven"``.

    **Observation** ``Box(-inf, inf, (28,), float32)``:

    ====== ======================================================================
    index  value
    ====== ======================================================================
    0-2    gripper x, y, orientation (hinge angle, rad)
    3-8    x, y of the movable blocks: red, cyan, yellow
    9-18   x, y of the fixed blocks: purple, grey, white, blue, green (constant)
    19-27  the 9 joint velocities, same order as 0-8 (gripper vx, vy, omega, then blocks)
    ====== ======================================================================

    Indices 0-18 are the paper's 19 values; 19-27 are the velocities the original code also
    observed (a Markov state needs them: the gripper's velocity time constant is about 9 steps).

    **Actions** ``Discrete(4)``, a force of 1.3 on one slide joint of the gripper:

    ====== =========== =========================
    action direction   control (x, y)
    ====== =========== =========================
    0      up (+y)     (0, +1.3)
    1      down (-y)   (0, -1.3)
    2      right (+x)  (+1.3, 0)
    3      left (-x)   (-1.3, 0)
    ====== =========== =========================

    A free gripper tends to 2.6 units/s; pushing a block, about 0.65.

    **Completion metric** (``info["completion"]``, every step): ``1 - min(d, d0) / d0`` with ``d``
    the goal block's current distance to the target and ``d0`` its distance at reset, so it lies
    in [0, 1]; read at the end of the episode it is the paper's completion rate.
    ``info["success"]`` is *not sticky*: the block is within 0.03 of the target now (the
    original's ``finished = d_final < 0.03``, consistent with a final-state completion);
    ``info["reached"]`` is the sticky version (within 0.03 at some step of the episode).
    ``info["distance"]`` is ``d``.

    **Reward.** ``reward_mode="dense"`` (the paper's PPO reward): ``-(|arm - block| + 5 |block -
    target|)``, ``arm`` being the gripper's ``arm`` site (0.02 ahead of the bar). ``"sparse"``:
    1.0 on the first step at which the block is within 0.03 of the target, 0.0 otherwise.

    **Termination.** Never terminates; the env itself truncates after 350 steps (the registered
    ``gpl/Relocation-v0`` adds an equivalent TimeLimit).

    **Reset.** Blocks at their start positions; gripper at the origin with U(+-0.05) noise on x, y
    and orientation, and N(0, 0.1) velocity on its three joints, drawn from ``self.np_random``.

    **Tasks and splits.** 1000 tasks, each a deterministic function of its id (``make_task``):
    goal block uniform over 3; target "cardinal" (p=0.51: uniform on the 0.3-long segment from a
    uniformly chosen fixed block up/left/down/right) or "close" (p=0.49: uniform in the box
    between a fixed block and a point 0.3 away at a random angle); the position (not the kind) is
    redrawn until it is more than 0.1 from every fixed block, x in (0.5, 1.3) and |y| < 1.1.
    Initial block-to-target distances span 0.32-1.40. ``make_splits(0)`` gives the committed ``train`` (750)
    and ``test`` (250) split, ``gpl_dist/splits/relocation.json``.

    **Rendering.** ``render_mode="rgb_array"``: a top-down picture (400x400x3 uint8);
    ``"ansi"``: the same view as text, with the paths of the gripper and the goal block since reset
    (``relocation_render.render_text``).

    **State access** (expert, corrections, tests): ``data`` (MjData; ``qpos`` layout as the
    observation's indices 0-8), ``block_xy(i)``, ``initial_blocks`` (3, 2) at reset,
    ``set_state(qpos, qvel)``.
    """

    metadata = {"render_modes": ["rgb_array", "ansi"], "render_fps": 100}
    domain_name = "relocation"

    def __init__(self, task_id: int, render_mode: str | None = None, reward_mode: str = "dense"):
        self.task: RelocationTask = make_task(task_id)
        self.task_id: int = self.task.task_id
        self.instruction: str = self.task.instruction
        self.render_mode, self.reward_mode = check_modes(render_mode, reward_mode)
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(28,), dtype=np.float32)
        self.action_space = spaces.Discrete(4)
        self.model = load_model()
        self.data = mujoco.MjData(self.model)
        self._setup()
        self.initial_blocks = MOVABLE_START.copy()
        self.initial_distance = self.task.initial_distance
        self.steps = 0
        self.reached = False
        self._reset_state(GRIPPER_START, np.zeros(3))

    # -- internals -----------------------------------------------------------------------------

    def _setup(self) -> None:
        """Per-env buffers and constants (also rebuilt on unpickling)."""
        self._obs = np.zeros(28, dtype=np.float32)
        self._obs[9:19] = FIXED_XY.reshape(-1)
        self._target = self.task.target
        self._bq = BLOCK_QPOS[self.task.block]
        self._dense = self.reward_mode == "dense"
        self.data.mocap_pos[0, :2] = self.task.target
        # views into self.data's arrays (reading data.qpos builds a new view each time, on every step)
        self._qpos, self._qvel, self._ctrl = self.data.qpos, self.data.qvel, self.data.ctrl

    def _reset_state(self, gripper_pose: np.ndarray, gripper_vel: np.ndarray) -> None:
        d = self.data
        mujoco.mj_resetData(self.model, d)
        d.qpos[0:3] = gripper_pose
        d.qpos[3:9] = MOVABLE_START.reshape(-1)
        d.qvel[0:3] = gripper_vel
        d.mocap_pos[0, :2] = self.task.target
        mujoco.mj_forward(self.model, d)
        self.initial_blocks = MOVABLE_START.copy()
        self.initial_distance = self.task.initial_distance
        self.steps = 0
        self.reached = self.distance() < SUCCESS_RADIUS
        # (gripper x, y, goal block x, y) since reset, kept only for the text picture (render_mode "ansi")
        self._trail: list[tuple[float, float, float, float]] | None = (
            [self._trail_point()] if self.render_mode == "ansi" else None)

    def _trail_point(self) -> tuple[float, float, float, float]:
        q = self.data.qpos
        return float(q[0]), float(q[1]), float(q[self._bq]), float(q[self._bq + 1])

    def _observe(self) -> np.ndarray:
        obs = self._obs
        obs[0:9] = self.data.qpos
        obs[19:28] = self.data.qvel
        return obs.copy()

    def _info(self, dist: float) -> dict:
        d0 = self.initial_distance
        return {"completion": 1.0 - min(dist, d0) / d0, "success": dist < SUCCESS_RADIUS,
                "reached": self.reached, "distance": dist}

    # -- state access ----------------------------------------------------------------------------

    @property
    def gripper_pose(self) -> np.ndarray:
        """(x, y, orientation) of the gripper (a copy)."""
        return self.data.qpos[0:3].copy()

    def block_xy(self, index: int) -> np.ndarray:
        """(x, y) of movable block ``index`` (0 red, 1 cyan, 2 yellow), a copy."""
        q = BLOCK_QPOS[index]
        return self.data.qpos[q:q + 2].copy()

    @property
    def target(self) -> np.ndarray:
        return np.array(self.task.target)

    def distance(self) -> float:
        """Current distance of the goal block to the target."""
        q = self.data.qpos
        return math.hypot(q[self._bq] - self._target[0], q[self._bq + 1] - self._target[1])

    def completion(self) -> float:
        d0 = self.initial_distance
        return 1.0 - min(self.distance(), d0) / d0

    def set_state(self, qpos: Any, qvel: Any | None = None) -> None:
        """Put the scene in ``qpos`` (9 values, observation layout) and ``qvel`` (zeros if None).

        Does not touch the episode's tracking (initial block positions, step count).
        """
        d = self.data
        d.qpos[:] = np.asarray(qpos, dtype=np.float64)
        d.qvel[:] = 0.0 if qvel is None else np.asarray(qvel, dtype=np.float64)
        mujoco.mj_forward(self.model, d)

    # -- gymnasium API -------------------------------------------------------------------------

    def reset(self, *, seed: int | None = None, options: Mapping[str, Any] | None = None):
        super().reset(seed=seed)
        rng = self.np_random
        pose = GRIPPER_START + rng.uniform(-GRIPPER_POSE_NOISE, GRIPPER_POSE_NOISE, size=3)
        vel = rng.normal(0.0, GRIPPER_VEL_NOISE, size=3)
        self._reset_state(pose, vel)
        return self._observe(), self._info(self.distance())

    def step(self, action):
        if not 0 <= action < 4:
            raise ValueError(f"action must be in 0..3, got {action!r}")
        cx, cy = _ACTION_CTRL[action]
        ctrl = self._ctrl
        ctrl[0] = cx
        ctrl[1] = cy
        mujoco.mj_step(self.model, self.data)
        self.steps += 1
        q = self._qpos
        bq = self._bq
        bx = q[bq]
        by = q[bq + 1]
        tx, ty = self._target
        dist = math.hypot(bx - tx, by - ty)
        if self._dense:
            th = q[2]
            reward = -(math.hypot(q[0] + ARM_OFFSET * math.cos(th) - bx, q[1] + ARM_OFFSET * math.sin(th) - by)
                       + 5.0 * dist)
        else:
            reward = 0.0
        if dist < SUCCESS_RADIUS:
            if not self.reached:
                self.reached = True
                if not self._dense:
                    reward = 1.0
        if self._trail is not None:
            self._trail.append(self._trail_point())
        obs = self._obs
        obs[0:9] = q
        obs[19:28] = self._qvel
        return obs.copy(), reward, False, self.steps >= EPISODE_STEPS, self._info(dist)

    def render(self):
        if self.render_mode == "ansi":
            from gpl_dist.envs.relocation_render import render_text

            return render_text(self, self._trail or [self._trail_point()])
        if self.render_mode != "rgb_array":
            return None
        from gpl_dist.envs.relocation_render import render_topdown

        return render_topdown(self)

    # -- pickling --------------------------------------------------------------------------------

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        for key in ("model", "data", "_obs", "_qpos", "_qvel", "_ctrl"):
            state.pop(key, None)
        d = self.data
        state["_mj"] = {"qpos": d.qpos.copy(), "qvel": d.qvel.copy(), "ctrl": d.ctrl.copy(),
                        "act": d.act.copy(), "time": float(d.time),
                        "qacc_warmstart": d.qacc_warmstart.copy()}
        return state

    def __setstate__(self, state: dict) -> None:
        mj = state.pop("_mj")
        self.__dict__.update(state)
        self.model = load_model()
        self.data = mujoco.MjData(self.model)
        self._setup()
        d = self.data
        d.qpos[:] = mj["qpos"]
        d.qvel[:] = mj["qvel"]
        d.ctrl[:] = mj["ctrl"]
        d.act[:] = mj["act"]
        d.time = mj["time"]
        mujoco.mj_forward(self.model, d)
        d.qacc_warmstart[:] = mj["qacc_warmstart"]


def make_env(task_id: int, **kwargs: Any) -> RelocationEnv:
    """The unwrapped env of ``task_id`` (``DomainSpec.make_env``)."""
    return RelocationEnv(task_id, **kwargs)


def full_information_values(task_id: int) -> np.ndarray:
    """The paper's relocation oracle input, as numbers: float32 ``(5,)`` = the goal block's one-hot
    over the 3 movable blocks, then the target's x and y."""
    task = make_task(task_id)
    return np.array([*(float(i == task.block) for i in range(len(MOVABLE_COLORS))), *task.target], dtype=np.float32)


DOMAIN = DomainSpec(
    name="relocation",
    env_id="gpl/Relocation-v0",
    num_tasks=NUM_TASKS,
    obs_shape=(28,),
    obs_dtype="float32",
    num_actions=4,
    steps_per_attempt=EPISODE_STEPS,
    trajectory_stride=70,
    vocabulary=VOCABULARY,
    make_env=make_env,
    split_names=("train", "test"),
    experts={"scripted": lazy("gpl_dist.experts.relocation:RelocationExpert"),
             "learned": lazy("gpl_dist.experts.relocation_learned:LearnedRelocationExpert")},
    correction_kinds=CORRECTION_KINDS,
    make_corrector=lazy("gpl_dist.corrections.relocation:make_relocation_corrector"),
    correction_phrasings=lazy("gpl_dist.corrections.relocation:phrasings"),
    paraphrases=PARAPHRASES,
    model_sizes=Sizes(
        state_channels=(), state_mlp=(),
        traj_state_channels=(), traj_state_mlp=(), traj_conv=8, traj_mlp=(16, 8),
        text_conv=4, correction_mlp=(16, 16), instruction_mlp=(16, 16),
        pair_mlp=(32, 32), pair_final_relu=False, policy_mlp=(256, 256, 256),
    ),
    # Table 1 (GPL, c0..c5) and Table 3 (c7, c10)
    paper_completion={0: 0.65, 1: 0.80, 2: 0.84, 3: 0.85, 4: 0.88, 5: 0.90, 7: 0.91, 10: 0.95},
    full_information_values=full_information_values,
)

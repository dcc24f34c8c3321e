"""Static data of the relocation domain: the scene's constants, the 1250 tasks, the instruction
grammar and the splits.

Everything here is a pure function of the task id (or of nothing), with no MuJoCo: the env
(``gpl_dist.envs.relocation``), its renderer, the oracle and the experts read it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from gpl_dist.errors import UsageError
from gpl_dist.language import ParaphraseRule, Paraphrases, Vocabulary

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
ACTION_CTRL = ((0.0, ACTION_FORCE), (0.0, -ACTION_FORCE), (ACTION_FORCE, 0.0), (-ACTION_FORCE, 0.0))

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
    ParaphraseRule(r"move the block", (  # the retry control's one sentence; no new words
        "move the block", "push the block", "move it", "push it", "go push it")),
))

#: Correction oracle kinds (``gpl_dist.corrections.relocation``): ``default`` is the paper's mixed oracle.
CORRECTION_KINDS = ("default", "mixed", "directional", "relational", "touch", "reward", "retry")


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


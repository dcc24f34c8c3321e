"""Robotic object relocation (Co-Reyes et al., ICLR 2019, section 6.1.2) as a plain gymnasium env.

The scene is ``gpl_dist/assets/relocation.xml`` (MuJoCo); tasks, instruction grammar and splits
live in ``gpl_dist.envs.relocation_core``, the correction oracle in ``gpl_dist.corrections.relocation`` and the scripted expert in
``gpl_dist.experts.relocation``. ``RelocationEnv``'s docstring is the domain's specification.
"""

from __future__ import annotations

import math
from functools import lru_cache
from importlib import resources
from typing import Any, Mapping, Sequence

import gymnasium
import mujoco
import numpy as np
from gymnasium import spaces

from gpl_dist.envs.modes import check_modes
from gpl_dist.envs.relocation_core import (
    ACTION_CTRL,
    ARM_OFFSET,
    BLOCK_QPOS,
    CORRECTION_KINDS,
    EPISODE_STEPS,
    FIXED_XY,
    GRIPPER_POSE_NOISE,
    GRIPPER_START,
    GRIPPER_VEL_NOISE,
    MOVABLE_COLORS,
    MOVABLE_START,
    NUM_TASKS,
    PARAPHRASES,
    SUCCESS_RADIUS,
    VOCABULARY,
    RelocationTask,
    make_task,
)
from gpl_dist.envs.relocation_render import render_text, render_topdown
from gpl_dist.models.sizes import Sizes
from gpl_dist.roles import DomainSpec, lazy

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
    ``info["distance"]`` is ``d``. ``info["instruction"]`` is the task's instruction (as minigrid's
    ``mission``) and ``info["instruction_ids"]`` its token ids (``VOCABULARY.encode``, a tuple of ints);
    the observation stays the 28 numbers the policy reads.

    **Reward.** ``reward_mode="dense"`` (the paper's PPO reward): ``-(|arm - block| + 5 |block -
    target|)``, ``arm`` being the gripper's ``arm`` site (0.02 ahead of the bar). ``"sparse"``:
    1.0 on the first step at which the block is within 0.03 of the target, 0.0 otherwise.

    **Termination.** By default never terminates (the paper's protocol: every attempt runs its 350
    steps and completion is read at the end; collection, evaluation and teaching use the default);
    ``terminate_on_success=True`` ends the episode (``terminated=True``) on the first step the
    block is within 0.03 of the target. The env itself truncates after 350 steps (the registered
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
    (``relocation_render.render_text``). ``picture_points()``: the gripper's and the goal block's
    pixels in the RGB picture (what drawn paths follow).

    **State access** (expert, corrections, tests): ``data`` (MjData; ``qpos`` layout as the
    observation's indices 0-8), ``block_xy(i)``, ``initial_blocks`` (3, 2) at reset,
    ``set_state(qpos, qvel)``.
    """

    metadata = {"render_modes": ["rgb_array", "ansi"], "render_fps": 100}
    domain_name = "relocation"
    #: what each point of ``picture_points()`` follows (the teaching page's legend)
    picture_point_names = ("the gripper", "the goal block")

    def __init__(self, task_id: int, render_mode: str | None = None, reward_mode: str = "dense",
                 terminate_on_success: bool = False):
        self.task: RelocationTask = make_task(task_id)
        self.task_id: int = self.task.task_id
        self.instruction: str = self.task.instruction
        self.instruction_ids: tuple[int, ...] = tuple(int(i) for i in VOCABULARY.encode(self.instruction))
        self.terminate_on_success = bool(terminate_on_success)
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
                "reached": self.reached, "distance": dist,
                "instruction": self.instruction, "instruction_ids": self.instruction_ids}

    # -- state access ----------------------------------------------------------------------------

    def picture_points(self) -> tuple[tuple[float, float], ...]:
        """Where the gripper and the goal block are in the ``rgb_array`` picture, in pixels (x, y):
        what drawn paths follow."""
        from gpl_dist.envs.relocation_render import picture_xy

        q = self.data.qpos
        return (picture_xy(float(q[0]), float(q[1])), picture_xy(float(q[self._bq]), float(q[self._bq + 1])))

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
        reward, dist = self._advance(action)
        obs = self._obs
        obs[0:9] = self._qpos
        obs[19:28] = self._qvel
        terminated = self.terminate_on_success and dist < SUCCESS_RADIUS
        return obs.copy(), reward, terminated, self.steps >= EPISODE_STEPS, self._info(dist)

    def _advance(self, action: int) -> tuple[float, float]:
        """One simulator step under ``action`` (checked by the caller) and the episode's
        bookkeeping; returns the step's reward and the goal block's distance to the target."""
        ctrl = self._ctrl
        ctrl[0], ctrl[1] = ACTION_CTRL[action]
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
        if dist < SUCCESS_RADIUS and not self.reached:
            self.reached = True
            if not self._dense:
                reward = 1.0
        if self._trail is not None:
            self._trail.append(self._trail_point())
        return reward, dist

    @classmethod
    def step_batch(cls, envs: Sequence["RelocationEnv"], actions: np.ndarray, out: np.ndarray,
                   with_info: bool) -> tuple[np.ndarray, list[dict] | None]:
        """``step`` of each of ``envs`` with its action, in one call (``gpl_dist.roles.BatchStepEnv``):
        the same simulation, observations, rewards and bookkeeping, bit for bit, without the per-env
        call, tuple and info dict of ``step``. Writes the observations into ``out`` ``(n, 28)`` and
        returns the float64 rewards ``(n,)`` and, with ``with_info``, each env's info (else None).
        Every action is checked before any env steps."""
        acts = np.asarray(actions)
        if acts.size and (int(acts.min()) < 0 or int(acts.max()) >= len(ACTION_CTRL)):
            bad = next(int(a) for a in acts.tolist() if not 0 <= a < len(ACTION_CTRL))
            raise ValueError(f"action must be in 0..3, got {bad!r}")
        rewards = np.empty(len(envs))
        infos: list[dict] | None = [] if with_info else None
        for j, (env, a) in enumerate(zip(envs, acts.tolist())):
            rewards[j], dist = env._advance(a)
            row = out[j]
            row[0:9] = env._qpos
            row[9:19] = env._obs[9:19]
            row[19:28] = env._qvel
            if infos is not None:
                infos.append(env._info(dist))
        return rewards, infos

    def render(self):
        if self.render_mode == "ansi":

            return render_text(self, self._trail or [self._trail_point()])
        if self.render_mode != "rgb_array":
            return None

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
    split_names=("train", "valid", "test"),
    valid_splits={"train": "valid"},
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

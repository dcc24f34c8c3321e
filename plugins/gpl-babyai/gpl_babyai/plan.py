"""The expert's plan of a task: its subgoals, in BabyAI's words, and when an attempt achieved them.

The plan is what the BabyAI bot (the domain's expert) does when it solves the task from its start,
read off as a list of subgoals, in the order the bot achieved them:

- ``open``: the bot opened a door (the doors it opens on its way and to explore, and the door of
  an "open" clause): "open the <colour> door";
- ``pickup``: the bot picked up the object a "pick up" clause names, the object it then moves
  for a "put ... next to" clause, or a key it then unlocked a door with: "pick up the <colour>
  <type>" (objects it only moves out of its way are not subgoals);
- ``goto``: a "go to" clause was verified: "go to the <colour> <type>" (the object it faced);
- ``putnext``: a "put ... next to" clause was verified: "put the <colour> <type> next to the
  <colour> <type>".

Each subgoal has a test on the env's state, checked after every step of an attempt:

- ``open (x, y)``: the door at (x, y) is open;
- ``pickup (t, c)``: the agent carries an object of type t and colour c;
- ``goto (t, c)``: the cell in front of the agent holds an object of type t and colour c;
- ``putnext (t1, c1, t2, c2)``: the step was a drop of a (t1, c1) object onto a cell next to
  (4-neighbourhood) an object of type t2 and colour c2.

``Progress`` counts the subgoals achieved in order: subgoal ``k`` counts once its test holds at
a step (or at reset) after subgoal ``k - 1`` counted. The count never decreases.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

from minigrid.core.actions import Actions
from minigrid.envs.babyai.core.verifier import (
    AfterInstr,
    AndInstr,
    BeforeInstr,
    GoToInstr,
    OpenInstr,
    PickupInstr,
    PutNextInstr,
)

from gpl_babyai.bot import FastBot
from gpl_babyai.level import LevelCore

#: Steps the bot may take to solve a task from its start.
PLAN_STEP_LIMIT = 1000


class PlanError(RuntimeError):
    """The bot did not solve the task from its start."""


@dataclass(frozen=True)
class Subgoal:
    """One subgoal: ``kind`` in open / pickup / goto / putnext and its arguments (module docstring)."""

    kind: str
    args: tuple

    @property
    def text(self) -> str:
        a = self.args
        if self.kind == "open":
            return f"open the {a[2]} door"
        if self.kind == "pickup":
            return f"pick up the {a[1]} {a[0]}"
        if self.kind == "goto":
            return f"go to the {a[1]} {a[0]}"
        return f"put the {a[1]} {a[0]} next to the {a[3]} {a[2]}"

    def holds(self, level, action: int | None, dropped) -> bool:
        """Whether the test holds in ``level``'s state after ``action`` (None at reset);
        ``dropped`` is the object the step dropped, if it dropped one."""
        kind, a = self.kind, self.args
        if kind == "open":
            cell = level.grid.get(a[0], a[1])
            return cell is not None and cell.type == "door" and cell.is_open
        if kind == "pickup":
            c = level.carrying
            return c is not None and c.type == a[0] and c.color == a[1]
        if kind == "goto":
            fx, fy = level.front_pos
            cell = level.grid.get(fx, fy)
            return cell is not None and cell.type == a[0] and cell.color == a[1]
        if dropped is None or dropped.type != a[0] or dropped.color != a[1]:
            return False
        x, y = dropped.cur_pos
        for nx, ny in ((x + 1, y), (x - 1, y), (x, y + 1), (x, y - 1)):
            cell = level.grid.get(nx, ny)
            if cell is not None and cell.type == a[2] and cell.color == a[3]:
                return True
        return False


class Progress:
    """How many of a plan's subgoals an attempt achieved, in order (module docstring)."""

    def __init__(self, plan: tuple[Subgoal, ...]):
        self.plan = plan
        self.done = 0

    def update(self, level, action: int | None = None, dropped=None) -> int:
        plan = self.plan
        while self.done < len(plan) and plan[self.done].holds(level, action, dropped):
            self.done += 1
        return self.done


def instruction_leaves(instr, done: bool = False, out: list | None = None) -> list:
    """``[(leaf, done)]`` of an instruction tree, depth first; a leaf is done once the sequencing
    node above it recorded its branch as a success (or ``done``: the whole tree succeeded)."""
    out = [] if out is None else out
    if isinstance(instr, (BeforeInstr, AfterInstr, AndInstr)):
        instruction_leaves(instr.instr_a, done or getattr(instr, "a_done", False) == "success", out)
        instruction_leaves(instr.instr_b, done or getattr(instr, "b_done", False) == "success", out)
    else:
        out.append((instr, done))
    return out


def _neighbour_in(pos, positions, level):
    x, y = int(pos[0]), int(pos[1])
    wanted = {(int(p[0]), int(p[1])) for p in positions}
    for n in ((x + 1, y), (x - 1, y), (x, y + 1), (x, y - 1)):
        if n in wanted and level.grid.get(*n) is not None:
            return level.grid.get(*n)
    return None


def compute_plan(level_name: str, seed: int, step_limit: int = PLAN_STEP_LIMIT) -> tuple[tuple[Subgoal, ...], int]:
    """``(subgoals, steps)``: the bot's plan of ``(level_name, seed)`` from its start,
    and how many steps it took; ``PlanError`` if it does not solve the task in ``step_limit``."""
    core = LevelCore(level_name)
    core.generate(seed)
    core.observe()
    level = core.level
    bot = FastBot(core.cache)
    events: list[tuple[Subgoal, object]] = []  # (subgoal, the object it concerns, for pickups)
    kept: set[int] = set()  # indices of pickup events that are subgoals
    last_pickup: dict[int, int] = {}  # id(object) -> index of its latest pickup event
    done_before = [d for _, d in instruction_leaves(level.instrs)]
    action = None
    for step in range(1, step_limit + 1):
        try:
            action = int(bot.replan(action))
        except Exception as err:  # noqa: BLE001 - e.g. bot.PlanLoop: minigrid's bot spins on a few tasks
            raise PlanError(f"{level_name} seed {seed}: the bot failed at step {step}: {type(err).__name__}: {err}") from err
        front = tuple(int(v) for v in level.front_pos)
        ahead = level.grid.get(*front)
        was_open = ahead is not None and ahead.type == "door" and ahead.is_open
        was_locked = ahead is not None and ahead.type == "door" and ahead.is_locked
        carried = level.carrying
        status = core.step(action)
        core.observe()
        if action == Actions.toggle and ahead is not None and ahead.type == "door" and not was_open and ahead.is_open:
            events.append((Subgoal("open", (front[0], front[1], ahead.color)), ahead))
            kept.add(len(events) - 1)
            if was_locked and carried is not None and id(carried) in last_pickup:
                kept.add(last_pickup[id(carried)])
        if action == Actions.pickup and carried is None and level.carrying is not None:
            obj = level.carrying
            last_pickup[id(obj)] = len(events)
            events.append((Subgoal("pickup", (obj.type, obj.color)), obj))
        leaves = instruction_leaves(level.instrs, status == "success")
        for (leaf, now), before in zip(leaves, done_before):
            if now and not before:
                if isinstance(leaf, GoToInstr):
                    target = level.grid.get(*(int(v) for v in level.front_pos))
                    if target is None:
                        raise PlanError(f"{level_name} seed {seed}: a 'go to' verified facing an empty cell")
                    events.append((Subgoal("goto", (target.type, target.color)), target))
                    kept.add(len(events) - 1)
                elif isinstance(leaf, PickupInstr) and id(level.carrying) in last_pickup:
                    kept.add(last_pickup[id(level.carrying)])
                elif isinstance(leaf, PutNextInstr) and carried is not None:
                    fixed = _neighbour_in(carried.cur_pos, leaf.desc_fixed.obj_poss, level)
                    if fixed is None:
                        raise PlanError(f"{level_name} seed {seed}: no fixed object next to the one put down")
                    events.append((Subgoal("putnext", (carried.type, carried.color, fixed.type, fixed.color)), carried))
                    kept.add(len(events) - 1)
                    if id(carried) in last_pickup:
                        kept.add(last_pickup[id(carried)])
                elif isinstance(leaf, OpenInstr):
                    pass  # the door's opening was recorded above
        done_before = [d for _, d in leaves]
        if status == "success":
            plan = tuple(e for i, (e, _) in enumerate(events) if i in kept)
            return plan, step
        if status == "failure":
            break
    raise PlanError(f"{level_name} seed {seed}: the bot did not solve it in {step_limit} steps")


@functools.lru_cache(maxsize=4096)
def plan_of(level_name: str, seed: int) -> tuple[Subgoal, ...]:
    """The plan of a task (cached in the process)."""
    return compute_plan(level_name, seed)[0]

"""The BabyAI bot as the DAgger expert: it labels any state the policy reaches.

minigrid's ``BabyAIBot`` keeps a plan (a stack of subgoals) and what it has seen; it is told the
action actually taken each step (``replan(action_taken)``) and repairs its plan around it (it
plans to pick a dropped object up again, to face a target it turned away from, and so on). So the
expert keeps one bot per env and episode, in ``env.expert_state``:

- at the first label of an episode (the reset state), a fresh bot, as BabyAI uses it;
- at each later step, the same bot told the policy's last action (``env.last_action``);
- when the bot cannot go on (it raises: e.g. ``DisappearedBoxError`` after the policy opened a
  box, an assertion on a state it never planned for; or ``bot.PlanLoop``), or when a label was
  skipped (the bot missed an action), a fresh bot takes over from the current state: it knows
  every cell the agent has seen since reset, and plans only the parts of a sequenced instruction
  not done yet; if it cannot plan with what the agent carries (BabyAIBot plans every pickup with
  empty hands and asserts them empty), another one first puts it down. If that one fails too,
  the label is ``done`` (no effect), counted in ``env.expert_state["fallbacks"]``;
- when every object a "pick up" or "put next to" clause still to do could mean is gone (the
  policy opened the box: boxes vanish when toggled), the task can no longer be solved (minigrid's
  bot then chases the box's old cell, or asserts "nothing left to explore"): from that takeover
  on, the label is ``done`` without asking a bot, and ``env.expert_state["target_gone"]`` is set;
- a state asked twice gets the same label.

Once the task is solved the label is ``done`` without asking the bot (minigrid's bot says ``done``
when its plan is empty). Past the level's own time limit (where nothing counts any more) the bot
goes on labelling as before it: those states look the same to the policy, and labels that turned
to ``done`` at a step count it cannot see would contradict the earlier ones.

One kind, ``bot``. Labels are one action (``soft_labels = False``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from minigrid.core.actions import Actions

from gpl_babyai.bot import FastBot

DONE = int(Actions.done)
NUM_ACTIONS = len(Actions)
_ONE_HOT = np.eye(NUM_ACTIONS, dtype=np.float32)


class BotExpert:
    """``act(env)`` / ``label(env)`` from minigrid's BabyAI bot (module docstring)."""

    soft_labels = False

    key = "bot"

    def act(self, env: Any) -> int:
        u = getattr(env, "unwrapped", env)
        state = u.expert_state
        if u.success or state.get("target_gone"):
            return DONE
        slot = state.get(self.key)
        if slot is not None and slot[1] == u.steps:
            return slot[2]
        action = None
        if slot is not None and slot[1] == u.steps - 1:
            bot = slot[0]
            try:
                action = int(bot.replan(u.last_action))
            except Exception:  # noqa: BLE001 - the bot gave up on this state: a fresh one takes over
                action = None
        if action is None and u.steps > 0 and target_gone(u.level):
            state["target_gone"] = True  # for good: a vanished object never comes back
            bot, action = None, DONE
        elif action is None:
            bot, action = _fresh_bot(u)
            if bot is not None and (slot is not None or u.steps > 0):
                state["takeovers"] = state.get("takeovers", 0) + 1
            if bot is None:
                action = DONE
                state["fallbacks"] = state.get("fallbacks", 0) + 1
        state[self.key] = (bot, u.steps, action)
        return action

    def label(self, env: Any) -> tuple[int, np.ndarray]:
        """``(act(env), its one-hot)``."""
        a = self.act(env)
        return a, _ONE_HOT[a]



def _fresh_bot(u) -> tuple[FastBot | None, int | None]:
    """A bot planned from the current state and its first action; ``(None, None)`` if none can plan."""
    for put_down_first in (False, True):
        if put_down_first and u.level.carrying is None:
            break
        try:
            bot = FastBot(u.core.cache)
            if put_down_first:
                bot.put_down_first()
            return bot, int(bot.replan(None))
        except Exception:  # noqa: BLE001 - the next way, or none
            continue
    return None, None


def target_gone(level) -> bool:
    """Whether every object a "pick up" or "put next to" clause of the mission could mean has left
    the grid (and is not carried): a box the policy opened (a box vanishes when toggled). ("go to"
    clauses are not asked: BabyAI's verifier accepts facing a vanished object's last cell.)"""
    from minigrid.envs.babyai.core.verifier import PickupInstr, PutNextInstr

    from gpl_babyai.plan import instruction_leaves

    carried, grid = level.carrying, level.grid

    def on_grid(obj) -> bool:
        pos = obj.cur_pos
        return (pos is not None and 0 <= pos[0] < grid.width and 0 <= pos[1] < grid.height
                and grid.get(int(pos[0]), int(pos[1])) is obj)

    for leaf, done in instruction_leaves(level.instrs):
        if done:
            continue
        if isinstance(leaf, PickupInstr):
            descs = (leaf.desc,)
        elif isinstance(leaf, PutNextInstr):
            descs = (leaf.desc_move, leaf.desc_fixed)
        else:
            continue
        for desc in descs:
            if not desc.obj_set:
                continue
            if all(obj is not carried and not on_grid(obj) for obj in desc.obj_set):
                return True
    return False

"""minigrid's BabyAI bot, fitted to labelling DAgger states.

``FastBot`` is ``minigrid.utils.baby_ai_bot.BabyAIBot`` with four changes, none to its plan:

- what the agent has seen (the bot's ``vis_mask``) is read from the env's ``GridCache``, which
  marks every view's visible cells as it computes the observation, instead of regenerating the
  view a second time (the same cells: ``tests/test_expert.py``);
- its breadth-first search pops from a deque instead of slicing a list (the same search, in the
  same order: same paths, same counters);
- a bot started mid-episode (a takeover after the policy's actions) plans only the parts of a
  sequenced instruction that are not done yet (``BeforeInstr``/``AfterInstr``/``AndInstr``
  keep which part succeeded); a fresh bot at reset plans exactly as BabyAIBot does;
- a replan that keeps pushing subgoals (more than ``MAX_PUSHES`` in one call) raises
  ``PlanLoop`` instead of spinning; ``BotExpert`` then starts a fresh bot;
- a matching object it has seen but cannot reach (a policy closed the door it was seen through)
  is passed over when it picks the nearest one, as one it has not seen: it then explores (opens
  doors) instead of failing the assertion that every seen object has a path. Where every seen
  object has a path, the choice is BabyAIBot's, with its distances and its tie-breaking.

(The bot cannot simply be handed the whole map: its searches never pass a closed door, so with
everything "seen" an object in a closed room is a target without a path, which it asserts never
happens. It explores, opening doors, as minigrid ships it.)
"""

from __future__ import annotations

from collections import deque

from minigrid.envs.babyai.core.verifier import AfterInstr, AndInstr, BeforeInstr
from minigrid.utils.baby_ai_bot import BabyAIBot, DropSubgoal, GoNextToSubgoal

#: Subgoals one ``replan`` call may push before the bot is declared stuck.
MAX_PUSHES = 500


class PlanLoop(RuntimeError):
    """A replan pushed more than ``MAX_PUSHES`` subgoals."""


class _Stack(list):
    """The bot's subgoal stack, counting pushes since ``arm()``."""

    pushes = 0

    def arm(self) -> None:
        self.pushes = 0

    def append(self, item) -> None:  # noqa: D102
        self.pushes += 1
        if self.pushes > MAX_PUSHES:
            raise PlanLoop(f"more than {MAX_PUSHES} subgoals pushed in one replan")
        super().append(item)


def _done(flag) -> bool:
    return flag == "success"


class FastBot(BabyAIBot):
    """BabyAIBot over a ``GridCache`` (see the module docstring).

    Args:
        cache: the env's ``GridCache`` (its ``level`` is the BabyAI level the bot plays); the
            env must have computed the current observation (``cache.observe()``).
    """

    def __init__(self, cache):
        self._cache = cache
        super().__init__(cache.level)
        self.stack = _Stack(self.stack)
        self.vis_mask = cache.seen_grid()

    def put_down_first(self) -> None:
        """Plan to put down what the agent carries before anything else (a bot taking over from a
        policy that picked something up: BabyAIBot plans every pickup with empty hands)."""
        if self.mission.unwrapped.carrying is None:
            return
        spot = self._find_drop_pos()
        if spot is None:
            return
        self.stack.append(DropSubgoal(self))
        self.stack.append(GoNextToSubgoal(self, spot))

    def replan(self, action_taken=None):
        self.stack.arm()
        return super().replan(action_taken)

    def _process_obs(self):
        # The env's cache marked the current view's visible cells when it computed the
        # observation; point at it again (an unpickled env holds a copy of it, not a view).
        self.vis_mask = self._cache.seen_grid()

    def _process_instr(self, instr):
        if isinstance(instr, (BeforeInstr, AndInstr)):
            if not _done(getattr(instr, "b_done", False)):
                self._process_instr(instr.instr_b)
            if not _done(getattr(instr, "a_done", False)):
                self._process_instr(instr.instr_a)
            return
        if isinstance(instr, AfterInstr):
            if not _done(getattr(instr, "a_done", False)):
                self._process_instr(instr.instr_a)
            if not _done(getattr(instr, "b_done", False)):
                self._process_instr(instr.instr_b)
            return
        super()._process_instr(instr)

    def _find_obj_pos(self, obj_desc, adjacent=False):
        carried = self.mission.unwrapped.carrying
        best, best_obj, best_pos = None, None, None
        for i, obj in enumerate(obj_desc.obj_set):
            if obj.type == "wall" or obj == carried or i >= len(obj_desc.obj_poss):
                continue
            pos = obj_desc.obj_poss[i]
            if not self.vis_mask[pos]:
                continue
            path, _, blocked = self._shortest_path(lambda p, cell, pos=pos: p == pos, try_with_blockers=True)
            if path is None:
                continue  # seen, out of reach now: look elsewhere (BabyAIBot asserts)
            # BabyAIBot's costs: blockers cost at least 4 more steps to clear (7 with full hands);
            # standing on the target (a door) is 2 steps from facing it (3 when a cell next to it
            # is wanted), and next to it, when a cell next to it is wanted, counts as 3.
            cost = len(path) + ((7 if carried else 4) if blocked else 0)
            if cost == 0:
                cost = 3 if adjacent else 2
            if adjacent and cost == 1:
                cost = 3
            if best is None or cost < best:
                best, best_obj, best_pos = cost, obj, pos
        return best_obj, best_pos

    def _breadth_first_search(self, initial_states, accept_fn, ignore_blockers):
        self.bfs_counter += 1
        grid = self.mission.unwrapped.grid
        cells, width = grid.grid, grid.width
        known = self.vis_mask
        came_from: dict = {}
        frontier = deque((state, None) for state in initial_states)
        while frontier:
            (x, y, dx, dy), parent = frontier.popleft()
            here = (x, y)
            if here in came_from:
                continue
            self.bfs_step_counter += 1
            cell = cells[y * width + x]
            came_from[here] = parent
            if accept_fn(here, cell):
                path = []
                node = here
                while node is not None:
                    path.append(node)
                    node = came_from[node]
                return path, here, came_from
            if not known[x, y]:
                continue
            if cell is not None:
                kind = cell.type
                if kind == "wall":
                    continue
                if kind == "door":
                    if not cell.is_open:
                        continue
                elif not ignore_blockers:
                    continue
            # straight on first, then the two sides, then back (BabyAIBot's order)
            for ox, oy in ((dx, dy), (dy, dx), (-dy, -dx), (-dx, -dy)):
                frontier.append(((x + ox, y + oy, ox, oy), here))
        return None, None, came_from

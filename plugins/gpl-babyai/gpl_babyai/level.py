"""One BabyAI level instance, stepped without minigrid's own observation.

``LevelCore`` builds a minigrid BabyAI level by its registered name (``BabyAI-<name>-v0``),
generates it with a seed (the level generators' "Sampling rejected: ..." prints silenced), and
steps it as ``RoomGridLevel.step`` does (minigrid's step, object positions refreshed after a drop,
the instruction verified), keeping a ``GridCache`` of the grid for the fast view.

Generating a level runs its rejection sampling again (1-12 ms); every attempt of a task starts
from the same generated level, so the first generation is kept as a pickle and later ones of the
same seed unpickle it (0.5-1 ms): the same objects, bit for bit (``tests/test_env.py``).
"""

from __future__ import annotations

import contextlib
import functools
import io
import pickle

import gymnasium
import minigrid  # noqa: F401  (registers the BabyAI levels)
from gymnasium.envs.registration import load_env_creator
from minigrid.core.actions import Actions
from minigrid.minigrid_env import MiniGridEnv

from gpl_babyai.view import GridCache

ACTIONS = Actions
ACTION_NAMES = tuple(a.name for a in Actions)  # left, right, forward, pickup, drop, toggle, done
CHANGES_FRONT_CELL = (int(Actions.pickup), int(Actions.drop), int(Actions.toggle))


def _no_observation():
    """Stands in for the level's ``gen_obs``: ``LevelCore`` computes the view itself."""
    return None


def level_id(name: str) -> str:
    """The gymnasium id of BabyAI level ``name`` (``GoTo`` -> ``BabyAI-GoTo-v0``; a full id as it is)."""
    return name if name.startswith("BabyAI-") else f"BabyAI-{name}-v0"


def babyai_level_ids() -> tuple[str, ...]:
    """Every BabyAI level minigrid registers (its newest version of each)."""
    newest: dict[str, str] = {}
    for env_id in sorted(gymnasium.registry):
        if env_id.startswith("BabyAI-"):
            newest[env_id.rsplit("-v", 1)[0]] = env_id
    return tuple(sorted(newest.values()))


@functools.cache
def _level_factory(name: str):
    spec = gymnasium.spec(level_id(name))
    return load_env_creator(spec.entry_point), dict(spec.kwargs)


def make_level(name: str):
    """A fresh (not yet generated) minigrid level of BabyAI level ``name`` (or a full gymnasium id)."""
    creator, kwargs = _level_factory(name)
    level = creator(**kwargs)
    level.gen_obs = _no_observation
    return level


class _Silence(io.TextIOBase):
    def write(self, s: str) -> int:
        return len(s)


class LevelCore:
    """A BabyAI level of one name, generated with one seed at a time.

    Attributes:
        level: the minigrid level (``RoomGridLevel``); its ``instrs`` verify the mission.
        cache: the ``GridCache`` of its grid (the view, and what the agent has seen).
        status: the verifier's last answer (``continue``, ``success`` or ``failure``).
    """

    def __init__(self, name: str):
        self.name = name
        self.level = make_level(name)
        self.cache: GridCache | None = None
        self.status = "continue"
        self._snapshot: tuple[int, bytes, tuple] | None = None  # (seed, pickled level, cache arrays)

    def generate(self, seed: int) -> None:
        """Generate the level with ``seed`` (the same layout and mission for the same seed)."""
        seed = int(seed)
        if self._snapshot is not None and self._snapshot[0] == seed:
            self.level = pickle.loads(self._snapshot[1])
            self.cache.level = self.level
            self.cache.restore(self._snapshot[2])
        else:
            with contextlib.redirect_stdout(_Silence()):
                self.level.reset(seed=seed)
            if self.cache is None:
                self.cache = GridCache(self.level)
            else:
                self.cache.level = self.level
                self.cache.rebuild()
            self._snapshot = (seed, pickle.dumps(self.level, protocol=pickle.HIGHEST_PROTOCOL), self.cache.arrays())
        self.status = "continue"

    @property
    def mission(self) -> str:
        return self.level.mission

    def step(self, action: int) -> str:
        """One action, as ``RoomGridLevel.step``; returns the verifier's status."""
        level = self.level
        front = level.front_pos
        MiniGridEnv.step(level, action)
        if action == Actions.drop:
            level.update_objs_poss()
        self.status = level.instrs.verify(action)
        if action in CHANGES_FRONT_CELL:
            self.cache.refresh(int(front[0]), int(front[1]))
        return self.status

    def observe(self):
        return self.cache.observe()

"""Gymnasium registration of the two domains.

``gymnasium.make("gpl/MultiRoom-v0", task_id=17)`` and ``gymnasium.make("gpl/Relocation-v0",
task_id=3)`` build one task's env; the TimeLimit wrapper applies the paper's episode lengths.
"""

from gymnasium.envs.registration import register, registry

_ENVS = {
    "gpl/MultiRoom-v0": ("gpl_dist.envs.multiroom:MultiRoomEnv", 100),
    "gpl/Relocation-v0": ("gpl_dist.envs.relocation:RelocationEnv", 350),
}

for _env_id, (_entry_point, _max_steps) in _ENVS.items():
    if _env_id not in registry:
        register(id=_env_id, entry_point=_entry_point, max_episode_steps=_max_steps)

ENV_IDS = tuple(_ENVS)

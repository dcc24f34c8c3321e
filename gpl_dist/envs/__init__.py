"""Gymnasium registration of the built-in domains.

``import gpl_dist.envs`` registers every built-in domain (``gpl_dist.domains``), so that
``gymnasium.make("gpl/MultiRoom-v0", task_id=17)`` and ``gymnasium.make("gpl/Relocation-v0",
task_id=3)`` build one task's env; the TimeLimit wrapper applies each domain's episode length.
"""

from gpl_dist.domains import BUILTIN_DOMAINS, get_domain

ENV_IDS = tuple(get_domain(name).env_id for name in BUILTIN_DOMAINS)

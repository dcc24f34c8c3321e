"""gpl-dist: Guiding Policies with Language via Meta-Learning, as a distributed DAgger system.

Importing the package registers the gymnasium envs ``gpl/MultiRoom-v0`` and ``gpl/Relocation-v0``.
"""

from gpl_dist import envs as _envs  # noqa: F401  (registration side effect)

__version__ = "0.1.0"

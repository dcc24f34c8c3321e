"""The application layer: what people run, over the core package and the system below it.

The suite (spec and runner, its Ray runner, RL jobs, report, archive, cost), teaching (session,
terminal, web page) and rendering. This is the only part of ``gpl_dist`` that imports ``learner``,
``workers`` or ``storage``; ``gpl_dist.cli`` sits over it. The floors are checked by
``lint-imports`` (contracts in ``pyproject.toml``; ``docs/design.md``).
"""

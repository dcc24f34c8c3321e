"""Expected failures: what a user can cause and fix (a bad config, a corrupt file, a busy run dir).

Every such error derives from ``UserError``. The CLI prints its message as one line and exits with
status 2; any other exception is a bug and keeps its traceback.
"""

from __future__ import annotations


class UserError(Exception):
    """An expected failure whose message, one line, names the problem and the file or key at fault."""


class CheckpointError(UserError):
    """A checkpoint file is missing, unreadable, or does not fit the run's model."""


class RunDirError(UserError):
    """A run directory or buffer is not what the command needs: not a run, already a run, or in use."""


class UsageError(UserError, ValueError):
    """An argument is out of range or malformed, or names something that does not exist (a domain,
    split, task, expert or correction kind). Also a ``ValueError``, for callers of the library."""


class ContractError(UserError):
    """A domain broke the env contract while a run used it (``docs/adding-a-domain.md``; ``gpl-dist
    check-domain`` checks a domain before any run): the message names the task and the value."""


class SuiteError(UserError):
    """Suite runs failed on a cluster (each named; running the suite again resumes them)."""

"""Errors raised by the buffer."""

from __future__ import annotations

from gpl_dist.errors import UserError


class BufferIntegrityError(UserError, RuntimeError):
    """A committed file is missing, has the wrong size or checksum, or disagrees with its manifest.

    The message always names the offending file (its path relative to the run root and the root).
    """

    def __init__(self, message: str, path: str | None = None) -> None:
        super().__init__(message)
        self.path = path


class LinkError(BufferIntegrityError):
    """A path inside a run passes through a symbolic link: refused, never followed (the message
    names the link and its target)."""

"""SIGTERM ends a command as Ctrl-C does: ``KeyboardInterrupt`` unwinds it (leases released, Ray
shut down, nothing half written: every file is written under a temporary name and renamed), and
the CLI prints one line saying how to resume.

Ray's core worker installs a C++ failure handler for SIGTERM when it starts in this process (it
prints a stack dump and aborts); ``reclaim_sigterm`` puts ours back after ``ray.init``.
"""

from __future__ import annotations

import signal
import threading

#: Exit status of a command ended by SIGTERM (128 + 15, as a shell reports it).
SIGTERM_STATUS = 128 + signal.SIGTERM


class Terminated(KeyboardInterrupt):
    """The process received SIGTERM."""


_active = False
_received = False


def _on_sigterm(signum: int, frame: object) -> None:
    global _received
    _received = True
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # a second SIGTERM lets the first's clean-up finish
    raise Terminated()


def received_sigterm() -> bool:
    """Whether SIGTERM arrived: the ``KeyboardInterrupt`` that unwinds may be a plain one (Ray
    turns an exception raised by a handler during its blocking calls into one)."""
    return _received


def end_on_sigterm() -> None:
    """From now on SIGTERM raises ``Terminated`` in the main thread (the CLI calls it once)."""
    global _active
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _on_sigterm)
        _active = True


def reclaim_sigterm() -> None:
    """Install the handler again if ``end_on_sigterm`` did and a library replaced it since."""
    if _active and threading.current_thread() is threading.main_thread() \
            and signal.getsignal(signal.SIGTERM) not in (_on_sigterm, signal.SIG_IGN):
        signal.signal(signal.SIGTERM, _on_sigterm)

"""Fault injection: named points where a test can stop a process in the middle of its work.

Product code calls ``fault_point(name, **context)`` at the few places where a crash matters most:

- ``worker.unit_collected`` (round, unit): a rollout worker has collected a unit and not yet written
  its shard (in the driver with ``--serial``, else in a Ray actor);
- ``writer.before_publish``: a shard writer has written its try under ``_tmp-`` and not yet renamed it;
- ``commit.between_moves``: the driver has moved the first file of a round's commit, not the rest;
- ``verify.between_listings``: ``verify_buffer`` has read the manifests and journals, not yet ``data/``.

Nothing happens at a point unless a hook is installed. A test installs one in its own process with
``install(hook)``; for the processes it starts (``gpl-dist train``, Ray actors, which inherit the
environment) it sets ``GPL_DIST_FAULT`` to a ``PauseAt`` spec. ``PauseAt`` is the one hook the
tests need: at the named point (and matching context), the first process to get there writes its
pid to a signal file and sleeps until the test kills it; any later try goes through, so a retried
unit or a resumed run completes.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

#: Environment variable holding a ``PauseAt`` spec for the processes a test starts.
FAULT_ENV = "GPL_DIST_FAULT"

FaultHook = Callable[[str, Mapping[str, Any]], None]

_installed: FaultHook | None = None
_from_env: tuple[str, FaultHook | None] = ("", None)


def install(hook: FaultHook | None) -> None:
    """Use ``hook`` at every fault point of this process (None removes it)."""
    global _installed
    _installed = hook


def fault_point(name: str, **context: Any) -> None:
    """A named point where an installed hook (or one given by ``GPL_DIST_FAULT``) may act."""
    hook = _installed or _env_hook()
    if hook is not None:
        hook(name, context)


def _env_hook() -> FaultHook | None:
    global _from_env
    spec = os.environ.get(FAULT_ENV, "")
    if spec != _from_env[0]:
        _from_env = (spec, PauseAt.parse(spec) if spec else None)
    return _from_env[1]


@dataclass(frozen=True)
class PauseAt:
    """Pause the first process that reaches ``point`` with ``context`` matching ``where``.

    Attributes:
        point: a fault point's name.
        signal_file: where the paused process writes its pid (created once, atomically).
        where: context values that must match (compared as strings), e.g. ``{"round": "0", "unit": "1"}``.
    """

    point: str
    signal_file: str
    where: Mapping[str, str] = field(default_factory=dict)

    def spec(self) -> str:
        """The ``GPL_DIST_FAULT`` value of this hook: ``point;signal_file;key=value,...``."""
        return ";".join([self.point, self.signal_file, ",".join(f"{k}={v}" for k, v in self.where.items())])

    @classmethod
    def parse(cls, spec: str) -> "PauseAt":
        """The hook a ``spec()`` string describes."""
        point, signal_file, where = (spec.split(";") + ["", ""])[:3]
        pairs = dict(kv.split("=", 1) for kv in where.split(",") if kv)
        return cls(point, signal_file, pairs)

    def __call__(self, name: str, context: Mapping[str, Any]) -> None:
        if name != self.point or any(str(context.get(k)) != v for k, v in self.where.items()):
            return
        tmp = f"{self.signal_file}.tmp-{os.getpid()}"
        with open(tmp, "w") as fh:
            fh.write(str(os.getpid()))
        try:
            os.link(tmp, self.signal_file)  # atomic, and fails when a first try already paused here
        except FileExistsError:
            return
        finally:
            os.unlink(tmp)
        while True:  # wait to be killed
            time.sleep(0.05)

"""``Lease``: one process at a time holds a run directory or buffer root for writing.

The driver holds its run directory and its buffer root for the whole run; ``clean`` and
``verify --quarantine`` hold the buffer root while they change it. A second holder is refused
with one line naming the first (command, pid, host, since when).

Two mechanisms behind one interface, because object stores have no locks:

* **Local roots** take an exclusive ``flock`` on ``ROOT/_lease.lock``. The kernel drops it when the
  holder dies, however it dies, so a local lease is never stale.
* **Remote roots** (``s3://...``, any fsspec URL) write ``ROOT/_lease.json`` and refresh its
  heartbeat every ``HEARTBEAT_S`` seconds from a daemon thread. A lease whose heartbeat is older
  than ``TTL_S`` (a killed driver), or whose holder on this very host is no longer running, is
  taken over. Two processes that start within a moment of each other on a remote root can both
  win; the lease guards against the common mistakes (a second driver, a clean during a run), not
  against that race.

Both names start with ``_``, so pyarrow datasets and ``clean`` ignore them.
"""

from __future__ import annotations

import json
import logging
import os
import socket
import threading
import time
from dataclasses import asdict, dataclass
from datetime import datetime, timezone

from gpl_dist.errors import RunDirError
from storage.fs import Location, resolve

LEASE_FILE = "_lease.json"
LOCK_FILE = "_lease.lock"
#: Tries (50 ms apart) to take a local lock before reporting it held.
LOCK_TRIES = 5

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LeaseHolder:
    """Who holds a lease: ``command`` (e.g. ``gpl-dist train``) as process ``pid`` on ``host``,
    since ``started`` (ISO time, UTC); ``heartbeat`` is the holder's last refresh (Unix seconds)."""

    command: str
    pid: int
    host: str
    started: str
    heartbeat: float

    def describe(self) -> str:
        return f"{self.command} (pid {self.pid} on {self.host}, since {self.started})"


def _pid_running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _read_holder(loc: Location) -> LeaseHolder | None:
    try:
        raw = json.loads(loc.read_bytes(LEASE_FILE).decode())
        return LeaseHolder(**raw)
    except (FileNotFoundError, ValueError, TypeError):
        return None


class Lease:
    """Exclusive hold of ``root`` by this process; use as a context manager or acquire/release."""

    #: Seconds between heartbeats of a remote lease.
    HEARTBEAT_S = 30.0
    #: Seconds after its last heartbeat that a remote lease counts as abandoned.
    TTL_S = 120.0

    def __init__(self, root: "str | os.PathLike[str] | Location", command: str) -> None:
        self.location = resolve(root)
        self.command = command
        self._fd: int | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._holder: LeaseHolder | None = None

    @property
    def held(self) -> bool:
        return self._holder is not None

    def acquire(self) -> "Lease":
        """Take the lease, or raise ``RunDirError`` naming the process that holds it."""
        if self.held:
            return self
        loc = self.location
        loc.makedirs("")
        if loc.is_local:
            self._lock_local()
        else:
            other = lease_holder(loc)
            if other is not None:
                raise RunDirError(f"{loc.url} is in use by {other.describe()}")
        self._holder = LeaseHolder(self.command, os.getpid(), socket.gethostname(),
                                   datetime.now(timezone.utc).isoformat(timespec="seconds"), time.time())
        try:
            self._write_holder()
        except BaseException:
            self._holder = None
            self._unlock()
            raise
        if not loc.is_local:
            self._thread = threading.Thread(target=self._beat, name="lease-heartbeat", daemon=True)
            self._thread.start()
        return self

    def release(self) -> None:
        if not self.held:
            return
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        try:
            self.location.remove(LEASE_FILE)
        finally:
            self._unlock()
            self._holder = None

    def _unlock(self) -> None:
        if self._fd is not None:
            import fcntl

            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> "Lease":
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()

    def _lock_local(self) -> None:
        import fcntl

        fd = os.open(self.location.path(LOCK_FILE), os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o644)
        for attempt in range(LOCK_TRIES):  # a `lease_holder` probe holds the lock for an instant
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if attempt == LOCK_TRIES - 1:
                    os.close(fd)
                    other = _read_holder(self.location)
                    who = other.describe() if other else "another process"
                    raise RunDirError(f"{self.location.url} is in use by {who}") from None
                time.sleep(0.05)
        self._fd = fd

    def _write_holder(self) -> None:
        assert self._holder is not None
        self.location.write_bytes_atomic(LEASE_FILE, json.dumps(asdict(self._holder)).encode())

    def _beat(self) -> None:
        while not self._stop.wait(self.HEARTBEAT_S):
            if self._holder is None:
                continue
            self._holder = LeaseHolder(**{**asdict(self._holder), "heartbeat": time.time()})
            try:
                self._write_holder()
            except Exception as err:  # noqa: BLE001 - a store's hiccup must not end the heartbeat
                log.warning("lease heartbeat of %s failed (%s); retrying", self.location.url, err)


def lease_holder(root: "str | os.PathLike[str] | Location") -> LeaseHolder | None:
    """The live holder of ``root``'s lease, or None when nobody holds it."""
    loc = resolve(root)
    if loc.is_local:
        import fcntl

        path = loc.path(LOCK_FILE)
        if not os.path.exists(path):
            return None
        fd = os.open(path, os.O_RDWR | os.O_NOFOLLOW)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return _read_holder(loc) or LeaseHolder("another process", -1, "?", "?", 0.0)
        finally:
            os.close(fd)  # closing drops a lock this call took
        return None
    holder = _read_holder(loc)
    if holder is None:
        return None
    if time.time() - holder.heartbeat > Lease.TTL_S:
        return None
    if holder.host == socket.gethostname() and not _pid_running(holder.pid):
        return None
    return holder

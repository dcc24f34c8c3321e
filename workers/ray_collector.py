"""Ray wiring: rollout actors, dynamic hand-out of work units, weight broadcast, fault handling.

This is the only module that imports Ray. Per round the driver puts the weights into the object
store once (``ray.put``, with a version number); actors fetch them only when the version changes.
Units are handed out one at a time to whichever actor is idle (``ray.wait``), so a slow actor does
not stall the round. Actors are placed with the ``SPREAD`` strategy, so on a multi-node cluster they
land on as many nodes as there are free CPUs rather than packing the first node.

Faults. An actor that dies (its process killed, its node lost) is restarted by Ray
(``max_restarts=-1``) and its unit is handed out again; because a shard's name is a function of
(round, unit) the retry replaces any partial try, and only the driver commits the round's manifest.
A dead actor is not handed another unit until a cheap probe call (``node_id``) has come back: an
actor whose node is gone may stay pending for a long time (no free CPU anywhere), and a unit queued
behind it would stall the round, so the remaining actors take over its work meanwhile. A probe that
fails (the actor died for good, e.g. its constructor raised) replaces the actor with a fresh one.
A unit out for longer than its timeout without a result (its actor hung, or the call or its reply
was lost while the actor looks alive) counts as a failed try: its actor is replaced and the unit
handed out again, so a hung actor costs the round minutes, and a stuck round fails in one line
instead of waiting without end. The timeout adapts to the run (``unit_timeout``):
``collection.unit_timeout_multiple`` (10) times the median time of the units that have come back
so far in this driver's run, at least ``collection.unit_timeout_floor_s`` (60 s), at most
``collection.unit_timeout_s`` (1800 s), which alone applies until a first unit has come back. A
unit's clock starts when it is handed to an actor that has answered a probe, so an actor's start
(seconds to a minute on loaded cores) is never part of a unit's time. While a unit is late (out for
more than a quarter of its timeout) a line says so every quarter of its timeout (``stall_line``),
so a stall is seen while it lasts, not only when it ends.
A round fails (``RoundFailed``) when a unit failed more than ``max_unit_retries`` times, or when no
actor has been usable for ``ACTOR_WAIT_S`` seconds.
"""

from __future__ import annotations

import logging
import os
import re
import socket
import statistics
import time
from collections import deque
from collections.abc import Callable, Sequence
from contextlib import contextmanager

import ray
from ray.exceptions import RayActorError, RayTaskError

from gpl_dist.errors import UsageError, UserError
from gpl_dist.records import WorkUnit
from gpl_dist.signals import reclaim_sigterm
from workers.collector import UnitResult, make_worker, run_unit
from workers.worker import RolloutSettings

log = logging.getLogger(__name__)


class RoundFailed(UserError, RuntimeError):
    """A work unit failed more often than ``max_unit_retries``, or no rollout actor was usable."""


@ray.remote(num_cpus=1, max_restarts=-1, max_task_retries=0)
class RolloutActor:
    """A ``RolloutWorker`` inside a Ray actor."""

    def __init__(self, domain_name: str, settings: RolloutSettings, buffer_root: str, run_id: str, worker_id: str):
        # One torch thread per actor: actors already use one core each.
        self.worker = make_worker(domain_name, settings, buffer_root, run_id, worker_id, num_threads=1)

    def run_unit(self, unit: WorkUnit, weights_box: list) -> tuple[UnitResult, str]:
        """The unit's result and the id of the node that collected it."""
        if self.worker.policy_version != unit.policy_version:
            # The ref sits inside a list so Ray does not resolve it for every call.
            self.worker.set_weights(ray.get(weights_box[0]), unit.policy_version)
        return run_unit(self.worker, unit), self.node_id()

    def node_id(self) -> str:
        return ray.get_runtime_context().get_node_id()

    def pid(self) -> int:
        return os.getpid()


#: Ray's switch for single-machine clusters. Off, every process of a local cluster advertises and
#: binds the loopback address (Ray resolves an explicit ``_node_ip_address="127.0.0.1"`` to the
#: machine's address and then listens on every interface).
_LOCAL_ONLY_ENV = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"


@contextmanager
def _loopback_only():
    """Start Ray's processes with the single-machine switch off, then restore it.

    Ray's children (GCS, raylet, and through the raylet every worker) inherit the environment; the
    driver read the switch when it imported Ray, so its constant is set too. Both are restored so
    that a later ``ray.init(address=...)`` in this process, or a ``ray start`` it spawns, can join
    a multi-node cluster.
    """
    from ray._private import ray_constants

    before_env, before_const = os.environ.get(_LOCAL_ONLY_ENV), ray_constants.ENABLE_RAY_CLUSTER
    os.environ[_LOCAL_ONLY_ENV] = "0"
    ray_constants.ENABLE_RAY_CLUSTER = False
    try:
        yield
    finally:
        ray_constants.ENABLE_RAY_CLUSTER = before_const
        if before_env is None:
            os.environ.pop(_LOCAL_ONLY_ENV, None)
        else:
            os.environ[_LOCAL_ONLY_ENV] = before_env


#: The logger of Ray's notice that a new local cluster turned token authentication on.
_AUTH_LOGGER = "ray._private.authentication.authentication_token_setup"


class _DropAuthEnabledNotice(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return not record.getMessage().startswith("Token authentication is enabled for this Ray cluster")


@contextmanager
def _quiet_local_auth_notice():
    """Drop Ray's "Token authentication is enabled" notice while a local cluster starts: it is
    printed on every run and asks nothing of the user (the cluster listens on loopback only, and
    authentication stays on as Ray sets it). Its warning that authentication is *disabled*, and
    everything about a cluster joined with ``--address``, still shows."""
    logger, notice = logging.getLogger(_AUTH_LOGGER), _DropAuthEnabledNotice()
    logger.addFilter(notice)
    try:
        yield
    finally:
        logger.removeFilter(notice)


_ANSI = re.compile(r"\x1b\[[0-9;?]*[ -/]*[@-~]")
#: Characters of a root cause kept in an error line.
CAUSE_CHARS = 300


def root_cause(err: BaseException) -> str:
    """``Type: message`` of the exception at the bottom of ``err``: the one a unit raised inside
    its actor (``RayTaskError.cause``), followed through its explicit causes; one line, without
    Ray's ANSI colour codes, cut at ``CAUSE_CHARS``."""
    seen = {id(err)}
    while True:
        inner = getattr(err, "cause", None) if isinstance(err, RayTaskError) else None
        inner = inner if isinstance(inner, BaseException) else err.__cause__
        if inner is None or id(inner) in seen:
            break
        seen.add(id(inner))
        err = inner
    text = " ".join(_ANSI.sub("", str(err)).split())
    if isinstance(err, RayTaskError | RayActorError):  # no cause to unwrap: Ray's own first line
        text = _ANSI.sub("", str(err)).strip().splitlines()[0] if str(err).strip() else ""
    text = text[:CAUSE_CHARS] + (" [...]" if len(text) > CAUSE_CHARS else "")
    return f"{type(err).__name__}: {text}" if text else type(err).__name__


#: Seconds to wait for a TCP connection to a cluster's GCS before giving up.
CONNECT_TIMEOUT_S = 10.0


def check_reachable(address: str) -> None:
    """Fail in one line, at once, when ``--address host:port`` cannot be reached: Ray itself
    retries an unreachable GCS for minutes. ``auto`` and ``ray://`` addresses are left to Ray."""
    host, sep, port = address.rpartition(":")
    if not sep or address == "auto" or "://" in address or not port.isdigit():
        return
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=CONNECT_TIMEOUT_S).close()
    except OSError as err:
        raise UsageError(f"cannot reach a Ray cluster at {address} ({err.strerror or err})") from None


def init_ray(address: str | None, num_workers: int, temp_dir: str | None = None, **kwargs) -> bool:
    """Start or join Ray; returns True when this call started a local cluster (and owns it).

    A local cluster listens on loopback only (every GCS, raylet, object manager, worker and agent
    socket; ``tests/test_fault_tolerance.py`` reads them). ``kwargs`` go to ``ray.init``.
    """
    if ray.is_initialized():
        return False
    try:
        if address:
            check_reachable(address)
            ray.init(address=address, **{"log_to_driver": True, **kwargs})
            return False
        with _loopback_only(), _quiet_local_auth_notice():
            ray.init(num_cpus=max(num_workers, os.cpu_count() or 1), include_dashboard=False, _temp_dir=temp_dir,
                     **{"log_to_driver": True, **kwargs})
        return True
    finally:
        reclaim_sigterm()  # Ray's core worker replaced it with a handler that dumps a C++ stack and aborts


def unit_timeout(durations: Sequence[float], floor_s: float, multiple: float, ceiling_s: float) -> float:
    """Seconds a unit may be out without a result: ``multiple`` times the median of ``durations``
    (the seconds of the units that came back so far), at least ``floor_s``, at most ``ceiling_s``;
    ``ceiling_s`` while nothing came back (nothing says how long a unit takes yet)."""
    if not durations:
        return ceiling_s
    return min(ceiling_s, max(floor_s, multiple * statistics.median(durations)))


def stall_line(unit: WorkUnit, actor: int, waited_s: float, timeout_s: float) -> str:
    """The line printed while a unit is late (see the module docstring)."""
    return (f"unit {unit.unit_index} of round {unit.round_index} on actor {actor}: no result for {waited_s:.0f} s "
            f"(timeout {timeout_s:.0f} s)")


class RayCollector:
    """Runs ``num_workers`` rollout actors and hands each round's units out dynamically.

    Attributes (for logs and tests):
        unit_tries: failed tries per ``(round, unit)``.
        unit_nodes: node id of the actor whose try of ``(round, unit)`` was returned.
        replaced_actors: actors replaced after a failed liveness probe or a timeout.
        unit_seconds: seconds each unit that came back was out, in the order they came back
            (the adaptive timeout's record).
    """

    #: Seconds a round waits with no unit in flight and no live actor before it fails.
    ACTOR_WAIT_S = 600.0
    #: ray.wait timeout: how often the collector checks whether it is stuck.
    POLL_S = 5.0

    def __init__(self, domain_name: str, settings: RolloutSettings, buffer_root: str, run_id: str,
                 num_workers: int, address: str | None = None, max_unit_retries: int = 3,
                 unit_timeout_s: float = 1800.0, unit_timeout_floor_s: float = 60.0,
                 unit_timeout_multiple: float = 10.0):
        self._owns_ray = init_ray(address, num_workers)
        self.max_unit_retries = max_unit_retries
        self.unit_timeout_s = unit_timeout_s
        self.unit_timeout_floor_s = unit_timeout_floor_s
        self.unit_timeout_multiple = unit_timeout_multiple
        self._actor_args = (domain_name, settings, buffer_root, run_id)
        self.unit_tries: dict[tuple[int, int], int] = {}
        self.unit_nodes: dict[tuple[int, int], str] = {}
        self.unit_seconds: list[float] = []
        self._timeout_s = unit_timeout_s  # unit_timeout() of unit_seconds, kept up to date
        self.replaced_actors = 0
        # liveness probes: probe ref -> actor index (carried across rounds); every actor answers
        # one before its first unit, so that no unit's clock includes the actor's start
        self._probes: dict = {}
        self.actors = [self._new_actor(i) for i in range(num_workers)]
        for i in range(num_workers):
            self._probe(i)

    def _new_actor(self, i: int):
        # ray.remote made the class an ActorClass, which type checkers do not see
        return RolloutActor.options(scheduling_strategy="SPREAD").remote(*self._actor_args, f"actor-{i}")  # type: ignore[attr-defined]

    def _probe(self, i: int) -> None:
        """Hand actor ``i`` no unit until a cheap call shows it is alive (restarted) again."""
        self._probes[self.actors[i].node_id.remote()] = i

    def _replace(self, i: int, err: BaseException, why: str = "is gone for good") -> None:
        self.replaced_actors += 1
        if self.replaced_actors > self.max_unit_retries + len(self.actors):
            raise RoundFailed(f"replaced {self.replaced_actors} rollout actors; last error: {root_cause(err)}") from err
        log.warning("rollout actor-%d %s (%s); starting a replacement", i, why, type(err).__name__)
        ray.kill(self.actors[i], no_restart=True)
        self.actors[i] = self._new_actor(i)
        self._probe(i)

    def collect_round(self, units: Sequence[WorkUnit], weights: dict, policy_version: int,
                      on_result: Callable[[UnitResult], None] | None = None) -> list[UnitResult]:
        weights_ref = ray.put(weights)
        queue = deque(units)
        probing = set(self._probes.values())
        idle = [i for i in reversed(range(len(self.actors))) if i not in probing]
        inflight: dict = {}
        results: dict[tuple[int, int], UnitResult] = {}
        last_progress = time.monotonic()
        while queue or inflight:
            while queue and idle:
                i, unit = idle.pop(), queue.popleft()
                inflight[self.actors[i].run_unit.remote(unit, [weights_ref])] = (i, unit, time.monotonic(), [0])
            done, _ = ray.wait(list(inflight) + list(self._probes), num_returns=1, timeout=self.POLL_S)
            self._hand_out_overdue_again(inflight, queue)
            if not done:
                if not inflight and time.monotonic() - last_progress > self.ACTOR_WAIT_S:
                    raise RoundFailed(f"no rollout actor was usable for {self.ACTOR_WAIT_S:.0f}s with "
                                      f"{len(queue)} units left (is there a node with a free CPU?)")
                continue
            for ref in done:
                if ref in self._probes:
                    i = self._probes.pop(ref)
                    try:
                        ray.get(ref)
                    except RayActorError as err:
                        self._replace(i, err)
                        continue
                    log.info("rollout actor-%d is back", i)
                    idle.append(i)
                    last_progress = time.monotonic()
                    continue
                if ref not in inflight:
                    continue  # overdue: handed out again above
                i, unit, sent_s, _ = inflight.pop(ref)
                key = (unit.round_index, unit.unit_index)
                try:
                    result, node = ray.get(ref)
                except (RayActorError, RayTaskError) as err:
                    self._count_failed_try(key, err)
                    log.warning("unit %s failed on actor-%d (%s); handing it out again", key, i, root_cause(err))
                    queue.appendleft(unit)
                    if isinstance(err, RayActorError):
                        self._probe(i)  # dead: Ray restarts it (maybe on another node, maybe much later)
                    else:
                        idle.append(i)  # the unit raised; the actor itself is fine
                    continue
                results[key] = result
                self.unit_nodes[key] = node
                self._record_unit_time(time.monotonic() - sent_s)
                last_progress = time.monotonic()
                idle.append(i)
                if on_result is not None:
                    on_result(result)
        return [results[(u.round_index, u.unit_index)] for u in units]

    def _count_failed_try(self, key: tuple[int, int], err: BaseException) -> None:
        """Count a failed try of unit ``key``; the round fails once it failed too often."""
        self.unit_tries[key] = self.unit_tries.get(key, 0) + 1
        if self.unit_tries[key] > self.max_unit_retries:
            raise RoundFailed(f"unit {key} failed {self.unit_tries[key]} times; last error: {root_cause(err)}") from err

    def _record_unit_time(self, seconds: float) -> None:
        self.unit_seconds.append(seconds)
        self._timeout_s = unit_timeout(self.unit_seconds, self.unit_timeout_floor_s, self.unit_timeout_multiple,
                                       self.unit_timeout_s)

    @property
    def timeout_s(self) -> float:
        """Seconds a unit may be out now without a result (``unit_timeout`` of the run's unit times)."""
        return self._timeout_s

    def _why_timeout(self) -> str:
        if not self.unit_seconds:
            return f"collection.unit_timeout_s={self.unit_timeout_s:g}s: no unit has come back yet to time units by"
        median = statistics.median(self.unit_seconds)
        return (f"{self.unit_timeout_multiple:g} x the median unit time {median:.1f}s of {len(self.unit_seconds)} units, "
                f"at least collection.unit_timeout_floor_s={self.unit_timeout_floor_s:g}s, at most "
                f"collection.unit_timeout_s={self.unit_timeout_s:g}s")

    def _hand_out_overdue_again(self, inflight: dict, queue: deque) -> None:
        """Units out longer than the timeout (``timeout_s``): each is a failed try; its actor is
        replaced (a hung actor would hold its CPU for good) and the unit goes to the front of the
        queue. A late reply of the old call is ignored: its ref is no longer in flight. A unit late
        but not yet overdue gets a ``stall_line`` every quarter of the timeout."""
        now = time.monotonic()
        timeout = self.timeout_s
        for ref, (i, unit, sent_s, lines) in list(inflight.items()):
            waited = now - sent_s
            if waited <= timeout:
                if waited >= (lines[0] + 1) * timeout / 4:
                    lines[0] = int(waited // (timeout / 4))
                    print(stall_line(unit, i, waited, timeout), flush=True)
                continue
            del inflight[ref]
            key = (unit.round_index, unit.unit_index)
            err = TimeoutError(f"unit {key} got no result from actor-{i} within {timeout:.0f}s ({self._why_timeout()}; "
                               "a hung actor or a lost call)")
            self._count_failed_try(key, err)
            log.warning("%s; handing it out again", err)
            queue.appendleft(unit)
            self._replace(i, err, why="returned nothing in time")

    def close(self) -> None:
        for actor in self.actors:
            ray.kill(actor, no_restart=True)
        self.actors = []
        self._probes = {}
        if self._owns_ray:
            ray.shutdown()

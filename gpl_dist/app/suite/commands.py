"""The ``gpl-dist suite`` subcommands: each runs its part of the suite package and returns what
the command prints (``Done``); the CLI parses the arguments, calls one of these and prints.
"""

from __future__ import annotations

from dataclasses import dataclass

from gpl_dist.app.suite.archive import restore_runs
from gpl_dist.app.suite.curves import compute_curves
from gpl_dist.app.suite.every_run import run_suite
from gpl_dist.app.suite.records import CURVE_FILE, SWAP_FILE
from gpl_dist.app.suite.report import write_report
from gpl_dist.app.suite.rl.jobs import run_rl_plan
from gpl_dist.app.suite.spec import keep_copy, load_suite
from gpl_dist.app.suite.status import suite_status
from gpl_dist.app.suite.swap import compute_swaps
from gpl_dist.errors import UsageError


@dataclass(frozen=True)
class Done:
    """What a subcommand prints: its lines, and an error line (the command then exits 2) or None."""

    lines: tuple[str, ...]
    error: str | None = None


def _one_of(serial: bool, address: str | None) -> None:
    if serial and address:
        raise UsageError("--serial runs without Ray and --address runs on a Ray cluster: give one of them")


def run(suite_file: str, out: str, only: tuple[str, ...] = (), seeds: tuple[int, ...] = (), *,
        address: str | None = None, serial: bool = False, one_at_a_time: bool = False, progress: bool = True) -> Done:
    """``suite run``: train and evaluate every unfinished run of the suite file (resumable;
    ``every_run.run_suite``), as many at once as keep this machine busy unless ``serial`` or
    ``one_at_a_time``, or on the Ray cluster at ``address``."""
    _one_of(serial, address)
    run_suite(load_suite(suite_file), out, only=only, seeds=seeds, address=address, serial=serial, progress=progress,
              at_once=not (serial or one_at_a_time))
    return Done((f"suite {suite_file}: every selected run is done; report with: gpl-dist suite report {out}",))


def status(suite_file: str, out: str, only: tuple[str, ...] = (), seeds: tuple[int, ...] = (),
           costs_from: str | None = None) -> Done:
    """``suite status``: each run's state and the wall time left (``status.suite_status``), reading
    the suite file without importing a plug-in."""
    found = suite_status(load_suite(suite_file, plugins="none"), suite_file, out, only, seeds, costs_from)
    return Done(found.lines, found.error)


def rl(suite_file: str, out: str, domains: tuple[str, ...] = (), *, address: str | None = None,
       serial: bool = False) -> Done:
    """``suite rl``: every job of the suite file's ``rl`` section not done yet (``rl.jobs.run_rl_plan``),
    its plan first copied to ``out`` (the report reads the results of that plan)."""
    _one_of(serial, address)
    suite = load_suite(suite_file)
    if suite.rl is None:
        raise UsageError(f"{suite_file} has no 'rl' section")
    keep_copy(suite, out)
    ran = run_rl_plan(suite.rl, out, address=address, serial=serial, domains=domains)
    return Done((f"suite {suite_file}: {ran} RL job(s) ran; every selected one is done; report with: "
                 f"gpl-dist suite report {out}",))


def report(suite_out: str, out: str) -> Done:
    """``suite report``: archive the runs, then write the report from the archive (``report.write_report``)."""
    md, html = write_report(suite_out, out)
    return Done((f"wrote {md} and {html}",))


def curves(suite_out: str, only: tuple[str, ...] = (), seeds: tuple[int, ...] = ()) -> Done:
    """``suite curves``: each trained run's valid curve (``curves.compute_curves``; all runs when
    ``only`` and ``seeds`` are empty)."""
    written = compute_curves(suite_out, set(only) or None, set(seeds) or None)
    return Done((f"{len(written)} run(s) have their valid curve ({CURVE_FILE}); the report draws them",))


def swap(suite_out: str, only: tuple[str, ...] = (), seeds: tuple[int, ...] = ()) -> Done:
    """``suite swap``: each trained run's instruction-swap control (``swap.compute_swaps``)."""
    written = compute_swaps(suite_out, set(only) or None, set(seeds) or None)
    return Done((f"{len(written)} run(s) have their instruction-swap control ({SWAP_FILE}); the report tabulates them",))


def restore(archive: str, out: str) -> Done:
    """``suite restore``: copy the archived runs that ``out`` lacks into it (``archive.restore_runs``)."""
    restored = restore_runs(archive, out)
    return Done((f"restored {len(restored)} run(s) into {out}" + "".join(f"\n  {p}" for p in restored),))


"""A run dir's upkeep, for ``gpl-dist inspect``, ``verify`` and ``clean``: where its buffer is, its
checks beyond the buffer (identity, checkpoints), the buffer's verification and quarantine, and the
leftovers of dead writers. Each command's lines are made here; the CLI prints them.

Nothing here imports a run's plug-in (its config is read with ``plugins="none"``) or follows a
symbolic link out of the run: the buffer's own walks refuse links (``storage.fs``), and a linked
``checkpoints/`` folder is refused before anything is listed or removed.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from gpl_dist.config import load_config
from gpl_dist.errors import RunDirError, UsageError
from learner.identity import refuse_linked_folders
from storage import clean_leftovers, format_inspection
from storage.lease import Lease
from storage.manifest import is_buffer
from storage.verify import VerifyReport, quarantine_round, verify_buffer


def buffer_root(path: str) -> str:
    """A run dir's buffer root (its config may point elsewhere), or ``path`` itself when it is a
    buffer; ``RunDirError`` when ``path`` holds neither."""
    p = Path(path)
    if (p / "config.yaml").is_file():
        refuse_linked_folders(p)
        location = load_config(p / "config.yaml", plugins="none").buffer.location
        return location or str(p / "buffer")
    if "://" not in path and not p.exists():
        raise RunDirError(f"no run directory or buffer at {path}")
    for candidate in ([path] if "://" in path else [str(p / "buffer"), path]):
        if is_buffer(candidate):
            return candidate
    raise RunDirError(f"{path} holds no gpl-dist run or buffer (no config.yaml, manifests/ or _gpl-dist-buffer.json)")


def no_buffer_note(run_dir: str, root: str) -> str | None:
    """For a run dir without a buffer (a run put back by ``suite restore`` has none), what it holds
    instead; None when it has one (or is no run dir)."""
    if "://" in root or Path(root).exists() or not (Path(run_dir) / "config.yaml").is_file():
        return None
    restored = (Path(run_dir) / "suite-run.json").is_file()
    return (f"{run_dir} has no buffer (no {root}): "
            + ("runs restored by 'gpl-dist suite restore' carry no buffer, only " if restored else "it holds only ")
            + "the config, metrics.jsonl, eval files and checkpoints. Teach or evaluate it (gpl-dist teach/serve/eval "
            f"--run-dir {run_dir}); a buffer comes only from training (gpl-dist train --config {run_dir}/config.yaml "
            "--run-dir NEW_DIR)")


def report_lines(report: VerifyReport) -> list[str]:
    """What ``verify`` prints of a buffer's report: each problem, the totals, commits in progress."""
    lines = [f"BAD  {p.path}: {p.message}" for p in report.problems]
    quarantined = f", quarantined rounds {list(report.quarantined)}" if report.quarantined else ""
    lines.append(f"checked {report.num_files} committed files ({report.num_bytes / 2**20:.1f} MiB) of rounds "
                 f"{list(report.rounds)}{quarantined}: {len(report.problems)} problem(s)")
    lines += [f"round {r}: a commit in progress (a driver stopped mid-commit); train --resume or clean finishes it"
              for r in report.in_progress]
    return lines


@dataclass(frozen=True)
class RunChecks:
    """A run dir's checks beyond its buffer: the run id its buffer must carry (None for a bare
    buffer), a note naming the id it is checked as when that id is inferred (no ``run.json``:
    ``learner.identity.resolve_identity``), and a ``path: what`` line per problem: a
    ``config.yaml`` edited after the run wrote it, a checkpoint unreadable or of another run."""

    run_id: str | None
    note: str | None
    problems: tuple[str, ...]


def run_checks(path: str, root: str) -> RunChecks:
    """``RunChecks`` of the run dir ``path`` whose buffer is at ``root`` (``learner.identity``)."""
    if not (Path(path) / "config.yaml").is_file():
        return RunChecks(None, None, ())
    from learner.identity import checkpoint_problems, config_problems, resolve_identity

    identity = resolve_identity(path, root)
    note = (f"note: {path} has no run.json: checked as run {identity.run_id[:64]} (its buffer's marker id, else its "
            "dir's name)" if identity.inferred else None)
    problems = config_problems(path) + checkpoint_problems(path, identity.run_id)
    return RunChecks(identity.run_id, note, tuple(f"{p}: {what}" for p, what in problems))


def inspect_run(run_dir: str, show_tasks: bool = False, checksums: bool = True, log=print) -> None:
    """``gpl-dist inspect``: verify the buffer of ``run_dir`` (``checksums``: sha256, else sizes
    only), then log its summary (``storage.format_inspection``; ``show_tasks``: a per-task table).
    A run dir without a buffer logs what it holds instead; a bad buffer logs each problem, then
    fails in one line."""
    root = buffer_root(run_dir)
    note = no_buffer_note(run_dir, root)
    if note:
        log(note)
        return
    report = verify_buffer(root, checksums=checksums)
    for p in report.problems:
        log(f"BAD  {p.path}: {p.message}")
    report.raise_if_bad(f"run gpl-dist verify {run_dir} for the list and docs/buffer.md (Recovering)")
    log(format_inspection(root, show_tasks=show_tasks))


def verify_run(run_dir: str, quarantine: bool = False, log=print) -> tuple[str, ...]:
    """``gpl-dist verify``: check the run's config, checkpoints and identity (``run_checks``) and
    every committed file of its buffer, logging each problem and the totals (``report_lines``);
    with ``quarantine``, under the buffer's lease, move its bad rounds under ``quarantine/``
    (never past a link, never a whole buffer of another run: ``UsageError``) and verify again.
    Returns the error lines (none when every check held)."""
    root = buffer_root(run_dir)
    checks = run_checks(run_dir, root)
    for line in ([checks.note] if checks.note else []) + [f"BAD  {line}" for line in checks.problems]:
        log(line)
    errors = [f"{len(checks.problems)} problem(s) with {run_dir}'s config.yaml or checkpoints (named above; verify "
              "never moves them)"] if checks.problems else []
    if not quarantine:
        report = verify_buffer(root, run_id=checks.run_id)
        log("\n".join(report_lines(report)))
    else:
        with Lease(root, "gpl-dist verify --quarantine"):  # before verifying: no run may change it meanwhile
            report = verify_buffer(root, run_id=checks.run_id)
            log("\n".join(report_lines(report)))
            refuse = [p for p in report.problems if p.kind == "link" or (p.kind == "foreign" and p.round_index is None)]
            if refuse:  # a link, or a whole buffer of another run: setting rounds aside would move what is not ours
                raise UsageError(f"--quarantine moves nothing here: {refuse[0].path}: {refuse[0].message} "
                                 "(remove the link, or verify the run the buffer belongs to)")
            for r in report.bad_rounds:
                moved = quarantine_round(root, r)
                what = f"moved {', '.join(moved)}" if moved else "nothing was left of it; recorded it as missing"
                log(f"quarantined round {r}: {what} under quarantine/")
            if report.bad_rounds:
                report = verify_buffer(root, run_id=checks.run_id)
                log("\n".join(report_lines(report)))
        if report.ok and not checks.problems:
            log(f"resume with: gpl-dist train --run-dir {run_dir} --resume "
                "(rounds after the last checkpoint are collected again)")
    if not report.ok:
        errors.append(f"{len(report.problems)} problem(s) in {report.root}; bad rounds {list(report.bad_rounds)} "
                      "(set them aside with --quarantine; see docs/buffer.md, Recovering)")
    return tuple(errors)


@dataclass(frozen=True)
class Cleaned:
    """What ``clean`` removed (or would, with ``dry_run``), relative to the buffer root or as paths,
    and how many paths under ``data/`` no manifest lists (kept: committed data is never removed)."""

    removed: tuple[str, ...]
    unlisted: int
    dry_run: bool = False

    def lines(self, run_dir: str) -> list[str]:
        """What ``gpl-dist clean`` prints of it: each path, the count, and the unlisted paths kept."""
        verb = "would remove" if self.dry_run else "removed"
        lines = [f"{verb} {path}" for path in self.removed] + [f"{verb} {len(self.removed)} leftover(s)"]
        if self.unlisted:
            lines.append(f"kept {self.unlisted} path(s) under data/ that no manifest lists (clean never removes committed "
                         f"data); see gpl-dist verify {run_dir}")
        return lines


def clean_run(run_dir: str, dry_run: bool = False) -> Cleaned:
    """Remove the leftovers of dead writers: the buffer's (``storage.clean_leftovers``), the run
    dir's own temporaries (``learner.checkpoint.dead_temporaries``) and its teaching logs' and
    GIFs' (``gpl_dist.app.teaching.teaching_leftovers``), under the leases and the teaching
    folder's lock. A symbolic link where it would look (a linked ``buffer``, ``checkpoints`` or
    ``teaching``: ``buffer_root``; one inside them) is refused before anything is removed, and so is
    a buffer of another run than the run dir's."""
    from gpl_dist.app.teaching import teaching_leftovers
    from learner.identity import read_identity
    from storage.manifest import buffer_run_id

    root = buffer_root(run_dir)  # refuses a linked folder of the run dir first
    identity = read_identity(run_dir) if (Path(run_dir) / "config.yaml").is_file() else None
    marked = buffer_run_id(root) if identity is not None else None
    if identity is not None and marked is not None and marked != identity.run_id:
        raise RunDirError(f"the buffer at {root} belongs to run {marked[:64]}, not to {run_dir}'s run "
                          f"{identity.run_id[:64]}: nothing removed (clean that run's own dir)")
    teaching = Path(run_dir) / "teaching"
    teaching_leftovers(teaching, dry_run=True)  # a link inside it is refused here, before anything is removed
    removed = clean_leftovers(root, dry_run=dry_run) + _run_dir_temporaries(run_dir, dry_run)
    removed += teaching_leftovers(teaching, dry_run=dry_run)
    unlisted = sum(p.kind == "unlisted" for p in verify_buffer(root, checksums=False).problems)
    return Cleaned(tuple(removed), unlisted, dry_run)


def _run_dir_temporaries(path: str, dry_run: bool) -> list[str]:
    """Temporary files of dead writers in a run dir and its checkpoints, removed under the run dir's
    lease (no driver can be writing them meanwhile); [] for a bare buffer."""
    if not (Path(path) / "config.yaml").is_file():
        return []
    from learner.checkpoint import dead_temporaries

    with Lease(path, "gpl-dist clean"):
        found = [p for p in dead_temporaries(path) if not p.is_symlink()]
        if not dry_run:
            for p in found:
                p.unlink(missing_ok=True)
    return [str(p) for p in found]

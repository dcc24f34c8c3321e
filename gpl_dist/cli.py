"""The ``gpl-dist`` command: train, eval, suite, render, inspect, verify, clean.

Heavy imports (torch, Ray, storage) happen inside each subcommand so ``gpl-dist --help`` is fast.
One error path: every expected failure (``gpl_dist.errors.UserError``: config, storage integrity,
checkpoint, device, run dir, usage; and an ``OSError`` of the user's paths and permissions) prints
one line naming the problem and exits with status 2 (``-v`` adds its traceback). Anything else is a
bug and prints its traceback.
"""

from __future__ import annotations

import argparse
import logging
import sys
import textwrap
import traceback
from pathlib import Path

from gpl_dist import __version__
from gpl_dist.errors import UsageError
from gpl_dist.language import PHRASINGS
from gpl_dist.metrics import ROUND_LINE_LEGEND

#: An error line is cut here (a value given on the command line can be arbitrarily long).
MAX_MESSAGE_CHARS = 600


def parse_overrides(pairs: list[str]) -> dict[str, str]:
    """``--set KEY=VALUE`` arguments as the dotted-key mapping ``load_config`` applies."""
    out = {}
    for pair in pairs:
        if "=" not in pair:
            raise UsageError(f"--set takes KEY=VALUE (e.g. training.num_rounds=3), got '{pair[:80]}'")
        key, value = pair.split("=", 1)
        out[key.strip()] = value
    return out


def _buffer_root(path: str) -> str:
    """A run dir's buffer root (its config may point elsewhere), or ``path`` itself when it is a
    buffer; ``RunDirError`` when ``path`` holds neither."""
    from gpl_dist.errors import RunDirError
    from storage.manifest import is_buffer

    p = Path(path)
    if (p / "config.yaml").is_file():
        from gpl_dist.config import load_config
        location = load_config(p / "config.yaml").buffer.location
        return location or str(p / "buffer")
    if "://" not in path and not p.exists():
        raise RunDirError(f"no run directory or buffer at {path}")
    for candidate in ([path] if "://" in path else [str(p / "buffer"), path]):
        if is_buffer(candidate):
            return candidate
    raise RunDirError(f"{path} holds no gpl-dist run or buffer (no config.yaml, manifests/ or _gpl-dist-buffer.json)")


def cmd_train(args: argparse.Namespace) -> int:
    """``gpl-dist train``: meta-train a run (Algorithm 1), fresh or ``--resume``."""
    from gpl_dist.config import load_config
    from learner.driver import run_training

    overrides = parse_overrides(args.set)
    if args.num_workers is not None:
        overrides["collection.num_workers"] = str(args.num_workers)
    config_path = args.config
    if config_path is None:
        if not args.resume:
            raise UsageError("--config is required (unless --resume, which reuses RUN_DIR/config.yaml)")
        config_path = Path(args.run_dir) / "config.yaml"
    cfg = load_config(config_path, overrides)
    result = run_training(cfg, args.run_dir, serial=args.serial, address=args.address, resume=args.resume,
                          progress=not args.no_progress)
    if result.history:
        last = result.history[-1]
        print("\nfinal round, training tasks: cK is the mean completion (fraction of the task done) after K "
              "corrections; c0 follows the instruction alone:")
        for k, v in enumerate(last.completion_by_corrections):
            print(f"  c{k}: {v:.3f}")
        print(f"run saved to {result.run_dir}; evaluate with: gpl-dist eval --run-dir {result.run_dir}")
    return 0


def _parse_seeds(text: str | None) -> tuple[int, ...] | None:

    if text is None:
        return None
    try:
        seeds = tuple(int(s) for s in text.split(","))
    except ValueError:
        raise UsageError(f"--seeds takes comma-separated integers (e.g. 0,1,2), got '{text[:80]}'") from None
    if len(set(seeds)) != len(seeds):
        raise UsageError(f"--seeds repeats a seed: {text[:80]}")
    return seeds


def cmd_eval(args: argparse.Namespace) -> int:
    """``gpl-dist eval``: meta-test a run's checkpoint on held-out tasks (Algorithm 2)."""
    from learner.evaluate import evaluate_run, format_table

    seeds = _parse_seeds(args.seeds)
    result, path = evaluate_run(args.run_dir, num_corrections=args.corrections, seeds=seeds, split=args.split,
                                max_tasks=args.max_tasks, checkpoint=args.checkpoint, greedy=args.greedy,
                                phrasings=args.phrasings, foreign_checkpoint=args.foreign_checkpoint, out_dir=args.out,
                                swap_instructions=args.swap_instructions)
    import json
    report = json.loads(path.read_text())
    print(f"meta-test on {result.num_tasks} tasks x {len(result.per_seed)} seeds ({result.seconds:.1f}s):")
    print(format_table(report["domain"], result,
                       with_paper=report["reduced_scale"] is None and report["instructions"] == "own"))
    if report["reduced_scale"]:
        print(f"note: {report['reduced_scale']}")
    print(f"wrote {path} and {path.with_suffix('.png')}")
    return 0


def _names(text: str | None) -> tuple[str, ...]:
    return tuple(n.strip() for n in (text or "").split(",") if n.strip())


def cmd_suite_run(args: argparse.Namespace) -> int:
    """``gpl-dist suite run``: train and evaluate every unfinished run of a suite (resumable)."""
    from gpl_dist.app.suite.runner import run_suite
    from gpl_dist.app.suite.spec import load_suite

    if args.serial and args.address:
        raise UsageError("--serial runs without Ray and --address runs on a Ray cluster: give one of them")
    suite = load_suite(args.suite)
    run_suite(suite, args.out, only=_names(args.only), seeds=_parse_seeds(args.seeds) or (), address=args.address,
              serial=args.serial, progress=not args.no_progress)
    print(f"suite {args.suite}: every selected run is done; report with: gpl-dist suite report {args.out}")
    return 0


def cmd_suite_status(args: argparse.Namespace) -> int:
    """``gpl-dist suite status``: each run's state (done, evaluate, resume, new, or running with
    its driver), read from its files, and the predicted wall time of what is left
    (``gpl_dist.app.suite.cost``)."""
    from gpl_dist.app.suite.cost import hours, predict
    from gpl_dist.app.suite.evidence import EvidenceError
    from gpl_dist.app.suite.runs import machine_numerics, run_state, trained_as_here
    from gpl_dist.app.suite.spec import load_suite, plan
    from learner.cpu import machine_summary
    from storage.lease import lease_holder

    suite = load_suite(args.suite)
    runs = plan(suite, args.out, _names(args.only), _parse_seeds(args.seeds) or ())
    states, lines = {}, []
    refused = 0
    numerics = {True: 0, False: 0, None: 0}  # trained runs: under this machine's fingerprint, another, none recorded
    here: set[str] = set()  # this machine's fingerprint for each run (its thread count), once per run
    for run in runs:
        holder = lease_holder(run.run_dir) if run.run_dir.is_dir() else None
        try:
            states[run.run_dir] = state = "running" if holder else run_state(run, suite)
        except EvidenceError as err:  # not counted: named in its line, and the status exits 2
            states[run.run_dir], state, refused = "refused", "refused", refused + 1
            lines.append((run, f"{state:8s} {run.entry.name} seed {run.seed}  ({' '.join(str(err).split())[:400]})"))
            continue
        held = f"; {holder.describe()}" if holder else ""
        mine = machine_numerics(run, suite)
        here.add(mine)
        if state in ("done", "evaluate"):
            same = trained_as_here(run, mine)
            numerics[same] += 1
            held += "; numerics as here" if same else ""
        lines.append((run, f"{state:8s} {run.entry.name} seed {run.seed}  ({run.run_dir}{held})"))
    rl_left: list = []
    if suite.rl is not None:
        from gpl_dist.app.suite.rl_jobs import NotTrainedYet, attempts_current, is_current, trained_fingerprint
        from gpl_dist.app.suite.rl_plan import attempts_jobs, rl_jobs

        rl_plan, jobs, points = suite.rl, rl_jobs(suite.rl), attempts_jobs(suite.rl)

        fingerprints: dict[str, str] = {}  # one checkpoint read per pretrained entry, not per job

        def start(job) -> str | None:  # the fingerprint of the policy rl-finetune starts from, as trained now
            if job.method != "rl-finetune":
                return None
            if job.pretrained not in fingerprints:
                try:
                    fingerprints[job.pretrained] = trained_fingerprint(args.out, job.pretrained)
                except NotTrainedYet:
                    fingerprints[job.pretrained] = "not trained"
            return fingerprints[job.pretrained]
        rl_left = [j for j in jobs if not is_current(args.out, j, rl_plan.settings(j.domain), start(j))]
    cost = predict(suite, args.out, states, tuple(rl_left), measured_in=args.costs_from)
    predicted = {c.run.run_dir: c for c in cost.runs}
    for run, line in lines:
        c = predicted.get(run.run_dir)
        print(line if c is None else f"{line}  ~{hours(c.seconds)}{'' if c.source == 'entry' else f' ({c.source})'}")
    if suite.rl is not None:
        counts = (("RL jobs", len(jobs) - len(rl_left), len(jobs)),
                  ("GPL/GPR attempt sets", sum(attempts_current(args.out, j, rl_plan) for j in points), len(points)))
        for what, done, total in counts:  # made with other PPO settings or from another policy: not done
            print(f"rl: {done} of {total} {what} done (gpl-dist suite rl {args.suite} --out {args.out})")
    todo = len(cost.runs)
    bound = "" if cost.complete else "at least "
    print(f"predicted: {todo} run(s) and {cost.rl_jobs} RL job(s) left, {bound}{hours(cost.total_seconds)} on this machine "
          f"(RL {hours(cost.rl_seconds)}), from this suite's finished work"
          + (f" under {args.costs_from}" if args.costs_from else "")
          + (f" at commit(s) {', '.join(cost.commits)}" if cost.commits else " (none finished yet: no estimate)")
          + ("" if cost.complete else f"; {sum(c.seconds is None for c in cost.runs) + cost.rl_unknown} without an estimate"))
    if here:
        print(f"numerics: this machine's {', '.join(sorted(here))} ({machine_summary()}); of the {sum(numerics.values())} "
              f"trained runs, {numerics[True]} were trained under it ('numerics as here': trained again here they give "
              f"the same files, bit for bit), {numerics[False]} under another (trained again here they land elsewhere "
              f"in their entry's seed spread), {numerics[None]} before fingerprints were recorded")
    if refused:
        print(f"gpl-dist: error: {refused} run(s) refused: their evidence fails its checksums or its own consistency "
              "(named above); restore them again from the archive, or remove them to train them anew", file=sys.stderr)
        return 2
    return 0


def cmd_suite_rl(args: argparse.Namespace) -> int:
    """``gpl-dist suite rl``: RL per test task against GPL and GPR (the suite file's ``rl`` section)."""
    from gpl_dist.app.suite.rl_jobs import run_rl_plan
    from gpl_dist.app.suite.spec import keep_copy, load_suite

    if args.serial and args.address:
        raise UsageError("--serial runs without Ray and --address runs on a Ray cluster: give one of them")
    suite = load_suite(args.suite)
    if suite.rl is None:
        raise UsageError(f"{args.suite} has no 'rl' section")
    keep_copy(suite, args.out)  # the report reads the RL results of this plan
    ran = run_rl_plan(suite.rl, args.out, address=args.address, serial=args.serial, domains=_names(args.domains))
    print(f"suite {args.suite}: {ran} RL job(s) ran; every selected one is done; report with: gpl-dist suite report {args.out}")
    return 0


def cmd_suite_report(args: argparse.Namespace) -> int:
    """``gpl-dist suite report``: the paper's tables from a suite's eval files, as Markdown and HTML."""
    from gpl_dist.app.suite.report import write_report

    md, html = write_report(args.suite_out, args.out)
    print(f"wrote {md} and {html}")
    return 0


def cmd_suite_curves(args: argparse.Namespace) -> int:
    """``gpl-dist suite curves``: each trained run's valid-split completion after every DAgger round."""
    from gpl_dist.app.suite.curves import compute_curves

    seeds = {int(s) for s in _names(args.seeds)} if args.seeds else None
    written = compute_curves(args.suite_out, set(_names(args.only)) if args.only else None, seeds)
    print(f"{len(written)} run(s) have their valid curve (curve-valid.json); the report draws them")
    return 0


def cmd_suite_swap(args: argparse.Namespace) -> int:
    """``gpl-dist suite swap``: each trained run's valid completion told other tasks' instructions."""
    from gpl_dist.app.suite.swap import compute_swaps

    seeds = {int(s) for s in _names(args.seeds)} if args.seeds else None
    written = compute_swaps(args.suite_out, set(_names(args.only)) if args.only else None, seeds)
    print(f"{len(written)} run(s) have their instruction-swap control (instruction-swap-valid.json); the report tabulates them")
    return 0


def cmd_suite_restore(args: argparse.Namespace) -> int:
    """``gpl-dist suite restore``: copy a report's archived runs into a suite output that lacks them."""
    from gpl_dist.app.suite.archive import restore_runs

    restored = restore_runs(args.archive, args.out)
    print(f"restored {len(restored)} run(s) into {args.out}" + "".join(f"\n  {p}" for p in restored))
    return 0


def cmd_render(args: argparse.Namespace) -> int:
    """``gpl-dist render``: a task's start state as PNG, an attempt as GIF, or a trained policy's
    successive attempts with the corrections between them (``--run-dir``)."""
    from gpl_dist.app.rendering import attempt_frames, parse_actions, policy_attempt_frames, write_picture

    if args.seed < 0:
        raise UsageError(f"--seed must be >= 0, got {args.seed}")
    if args.run_dir:
        if args.env or args.actions or args.expert:
            raise UsageError("--run-dir draws the run's policy on its own domain: leave out --env, --actions and --expert")
        frames = policy_attempt_frames(args.run_dir, args.task, args.attempts, seed=args.seed, checkpoint=args.checkpoint,
                                       foreign_checkpoint=args.foreign_checkpoint)
        out = write_picture(frames, args.out)
        print(f"wrote {out} ({len(frames)} frames)")
        return 0
    if not args.env:
        raise UsageError("--env is required (or --run-dir, to draw a trained policy's attempts)")
    actions = parse_actions(args.actions) if args.actions else None
    frames = attempt_frames(args.env, args.task, actions, expert=args.expert, seed=args.seed)
    out = write_picture(frames, args.out)
    print(f"wrote {out} ({len(frames)} frame{'s' if len(frames) != 1 else ''})")
    return 0


def _teacher(args: argparse.Namespace):
    from gpl_dist.app.teaching import Teacher

    if args.foreign_checkpoint and not args.out:
        raise UsageError(f"--foreign-checkpoint writes nothing into {args.run_dir}: give --out DIR for the teaching log")
    if args.foreign_checkpoint and Path(args.out).resolve().is_relative_to(Path(args.run_dir).resolve()):
        raise UsageError(f"--out {args.out} is inside {args.run_dir}: a foreign checkpoint's teaching log goes elsewhere")
    return Teacher(args.run_dir, args.checkpoint, max_corrections=args.max_corrections, greedy=args.greedy,
                   allow_foreign=args.foreign_checkpoint)


def cmd_teach(args: argparse.Namespace) -> int:
    """``gpl-dist teach``: correct a trained policy by typing, attempt after attempt."""
    from gpl_dist.app.teach_terminal import teach_in_terminal
    from gpl_dist.splits import split_tasks

    if args.task is not None and args.instruction is not None:
        raise UsageError("give --task or --instruction, not both")
    teacher = _teacher(args)
    task_id = teacher.resolve_task(args.task, args.instruction, args.seed, args.split)
    if args.task is not None and task_id not in split_tasks(teacher.domain.name, args.split):
        print(f"note: task {task_id} is not in the {args.split} split")
    out = Path(args.out) if args.out else Path(args.run_dir) / "teaching"
    teach_in_terminal(teacher.episode(task_id, args.seed, "terminal"), out, always_hint=args.hint)
    return 0


def cmd_serve(args: argparse.Namespace) -> int:
    """``gpl-dist serve``: the teaching loop in a web page."""
    from gpl_dist.app.teach_web import serve

    teacher = _teacher(args)
    out = Path(args.out) if args.out else Path(args.run_dir) / "teaching"
    serve(teacher, out, host=args.host, port=args.port, split=args.split)
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    """``gpl-dist export``: a run's committed buffer, or a folder of teaching logs, as a Minari
    dataset (``gpl_dist.app.export``)."""
    from gpl_dist.app.export import export_minari, export_teaching_minari, is_teaching_log

    if is_teaching_log(args.run_dir):
        dataset_id, n = export_teaching_minari(args.run_dir, args.out, args.dataset_id, run_dir=args.teaching_run_dir)
    else:
        if args.teaching_run_dir:
            raise UsageError(f"--teaching-run-dir is for a folder of teaching logs; {args.run_dir} is not one")
        dataset_id, n = export_minari(args.run_dir, _buffer_root(args.run_dir), args.out, args.dataset_id)
    print(f"wrote Minari dataset {dataset_id} ({n} episodes, one per attempt) under {args.out}; read it with "
          f"MINARI_DATASETS_PATH={args.out} python -c \"import minari; print(minari.load_dataset('{dataset_id}'))\"")
    return 0


def _print_problems(report) -> None:
    for p in report.problems:
        print(f"BAD  {p.path}: {p.message}")


def _says_no_buffer(run_dir: str, root: str) -> bool:
    """Print, for a run dir without a buffer (a run put back by ``suite restore`` has none), what it
    holds instead; returns whether it did."""
    if "://" in root or Path(root).exists() or not (Path(run_dir) / "config.yaml").is_file():
        return False
    restored = (Path(run_dir) / "suite-run.json").is_file()
    print(f"{run_dir} has no buffer (no {root}): "
          + ("runs restored by 'gpl-dist suite restore' carry no buffer, only " if restored else "it holds only ")
          + "the config, metrics.jsonl, eval files and checkpoints. Teach or evaluate it (gpl-dist teach/serve/eval "
          f"--run-dir {run_dir}); a buffer comes only from training (gpl-dist train --config {run_dir}/config.yaml "
          "--run-dir NEW_DIR)")
    return True


def cmd_inspect(args: argparse.Namespace) -> int:
    """``gpl-dist inspect``: verify a run's buffer, then summarise it."""
    from storage import format_inspection
    from storage.verify import verify_buffer

    root = _buffer_root(args.run_dir)
    if _says_no_buffer(args.run_dir, root):
        return 0
    report = verify_buffer(root, checksums=not args.no_verify)
    _print_problems(report)
    report.raise_if_bad(f"run gpl-dist verify {args.run_dir} for the list and docs/buffer.md (Recovering)")
    print(format_inspection(root, show_tasks=args.tasks))
    return 0


def _print_report(report) -> None:
    _print_problems(report)
    quarantined = f", quarantined rounds {list(report.quarantined)}" if report.quarantined else ""
    print(f"checked {report.num_files} committed files ({report.num_bytes / 2**20:.1f} MiB) of rounds "
          f"{list(report.rounds)}{quarantined}: {len(report.problems)} problem(s)")
    for r in report.in_progress:
        print(f"round {r}: a commit in progress (a driver stopped mid-commit); train --resume or clean finishes it")


def _run_checks(path: str, root: str) -> tuple[str | None, list[str]]:
    """For a run dir (not a bare buffer): its identity, and a ``path: what`` line for each of its
    checkpoints that is unreadable or of another run (``learner.identity``)."""
    if not (Path(path) / "config.yaml").is_file():
        return None, []
    from learner.identity import checkpoint_problems, resolve_identity

    identity = resolve_identity(path, root)
    if identity.legacy:
        print(f"note: {path} has no run.json (made before run identities): checked as run {identity.run_id[:64]}")
    return identity.run_id, [f"{p}: {what}" for p, what in checkpoint_problems(path, identity.run_id)]


def cmd_verify(args: argparse.Namespace) -> int:
    """``gpl-dist verify``: check every committed file and checkpoint; ``--quarantine`` sets bad rounds aside."""
    from storage.lease import Lease
    from storage.verify import quarantine_round, verify_buffer

    root = _buffer_root(args.run_dir)
    run_id, bad_checkpoints = _run_checks(args.run_dir, root)
    for line in bad_checkpoints:
        print(f"BAD  {line}")
    if bad_checkpoints:
        print(f"gpl-dist: error: {len(bad_checkpoints)} checkpoint(s) of {args.run_dir} are unreadable or of another "
              "run (set them aside by hand: verify never moves checkpoints)", file=sys.stderr)
    if not args.quarantine:
        report = verify_buffer(root, run_id=run_id)
        _print_report(report)
    else:
        with Lease(root, "gpl-dist verify --quarantine"):  # before verifying: no run may change it meanwhile
            report = verify_buffer(root, run_id=run_id)
            _print_report(report)
            for r in report.bad_rounds:
                moved = quarantine_round(root, r)
                what = f"moved {', '.join(moved)}" if moved else "nothing was left of it; recorded it as missing"
                print(f"quarantined round {r}: {what} under quarantine/")
            if report.bad_rounds:
                report = verify_buffer(root, run_id=run_id)
                _print_report(report)
        if report.ok and not bad_checkpoints:
            print(f"resume with: gpl-dist train --run-dir {args.run_dir} --resume "
                  "(rounds after the last checkpoint are collected again)")
    if report.ok:
        return 2 if bad_checkpoints else 0
    print(f"gpl-dist: error: {len(report.problems)} problem(s) in {report.root}; bad rounds {list(report.bad_rounds)} "
          "(set them aside with --quarantine; see docs/buffer.md, Recovering)", file=sys.stderr)
    return 2


def _clean_run_dir(path: str, dry_run: bool) -> list[str]:
    """Temporary files of dead writers in a run dir and its checkpoints (``learner.checkpoint.dead_temporaries``),
    removed under the run dir's lease (no driver can be writing them meanwhile); [] for a bare buffer."""
    if not (Path(path) / "config.yaml").is_file():
        return []
    from learner.checkpoint import dead_temporaries
    from storage.lease import Lease

    with Lease(path, "gpl-dist clean"):
        found = dead_temporaries(path)
        if not dry_run:
            for p in found:
                p.unlink(missing_ok=True)
    return [str(p) for p in found]


def cmd_clean(args: argparse.Namespace) -> int:
    """``gpl-dist clean``: remove dead writers' leftovers from a buffer no run holds."""
    from storage import clean_leftovers
    from storage.verify import verify_buffer

    root = _buffer_root(args.run_dir)
    removed = clean_leftovers(root, dry_run=args.dry_run) + _clean_run_dir(args.run_dir, args.dry_run)
    verb = "would remove" if args.dry_run else "removed"
    for path in removed:
        print(f"{verb} {path}")
    print(f"{verb} {len(removed)} leftover(s)")
    unlisted = [p for p in verify_buffer(root, checksums=False).problems if p.kind == "unlisted"]
    if unlisted:
        print(f"kept {len(unlisted)} path(s) under data/ that no manifest lists (clean never removes committed "
              f"data); see gpl-dist verify {args.run_dir}")
    return 0


def _add_version(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--version", action="version", version=f"gpl-dist {__version__}",
                        help="print the version and exit")


def _add_foreign_checkpoint(p: argparse.ArgumentParser) -> None:
    p.add_argument("--foreign-checkpoint", action="store_true",
                   help="use a --checkpoint of another run, domain or model (refused otherwise); nothing is then "
                        "written into RUN_DIR")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every subcommand."""
    from gpl_dist.domains import domain_names

    parser = argparse.ArgumentParser(prog="gpl-dist",
                                     description="Guiding Policies with Language: distributed DAgger meta-training.")
    parser.add_argument("-v", "--verbose", action="store_true", help="log at INFO level")
    _add_version(parser)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("train", help="meta-train a GPL policy (Algorithm 1)",
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog=textwrap.fill(ROUND_LINE_LEGEND[0].upper() + ROUND_LINE_LEGEND[1:] + ".", 80,
                                            break_on_hyphens=False))
    p.add_argument("--config", help="YAML config (see configs/)")
    p.add_argument("--run-dir", required=True, help="where the buffer, checkpoints and metrics go")
    p.add_argument("--num-workers", type=int, help="rollout actors (overrides collection.num_workers)")
    p.add_argument("--address", help="join an existing Ray cluster (e.g. 'auto') instead of starting a local one")
    p.add_argument("--serial", action="store_true", help="run one worker in this process, without Ray")
    p.add_argument("--resume", action="store_true", help="continue from the run dir's last checkpoint")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a config value")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("eval", help="meta-test a trained run on held-out tasks (Algorithm 2)",
                       description="Meta-test a trained run. Writes RUN_DIR/eval.json and eval.png with the run's "
                                   "own eval settings; other settings write eval-<what differs>.json/.png "
                                   "(eval-greedy.json, eval-c10.json, ...), leaving eval.json as it was.")
    p.add_argument("--run-dir", required=True, help="a trained run (its checkpoints/latest.pt and config.yaml)")
    p.add_argument("--corrections", type=int, help="corrections to give (default: eval.num_corrections)")
    p.add_argument("--seeds", help="comma-separated seeds (default: eval.seeds)")
    p.add_argument("--split", help="task split (default: eval.split)")
    p.add_argument("--max-tasks", type=int, help="evaluate only the first N tasks")
    p.add_argument("--phrasings", choices=PHRASINGS,
                   help="say instructions and corrections as the oracle does (canonical) or as train/heldout paraphrases")
    p.add_argument("--swap-instructions", action="store_true",
                   help="a control: tell each task another task's instruction (a policy blind to its "
                        "instruction scores the same as without this); on the run's valid split (valid, or "
                        "heldout4_valid for a run trained on heldout4_train) unless --split; "
                        "writes eval-<split>-...-swapped-instructions.json")
    p.add_argument("--checkpoint", help="checkpoint file (default: RUN_DIR/checkpoints/latest.pt)")
    _add_foreign_checkpoint(p)
    p.add_argument("--out", help="folder for the evaluation's files (default RUN_DIR; required with --foreign-checkpoint)")
    acting = p.add_mutually_exclusive_group()
    acting.add_argument("--greedy", dest="greedy", action="store_true", default=None, help="act with the most likely action")
    acting.add_argument("--sample", dest="greedy", action="store_false", help="sample actions from the policy (default)")
    p.set_defaults(func=cmd_eval)

    p = sub.add_parser("suite", help="run the paper's experiments (a suite file) and report them")
    suite_sub = p.add_subparsers(dest="suite_command", required=True)
    for name, func, text in (("run", cmd_suite_run, "train and evaluate every unfinished run; resumes a killed suite"),
                             ("status", cmd_suite_status, "each run's state, read from its files, and the predicted "
                                                          "wall time of what is left")):
        q = suite_sub.add_parser(name, help=text)
        q.add_argument("suite", help="suite file (e.g. configs/suites/paper.yaml)")
        q.add_argument("--out", required=True, help="the suite's folder of run dirs (OUT/<entry>/seed<k>)")
        q.add_argument("--only", help="comma-separated entry names")
        q.add_argument("--seeds", help="comma-separated training seeds")
        if name == "run":
            q.add_argument("--address", help="a Ray cluster: run the entries at once, each as a Ray task")
            q.add_argument("--serial", action="store_true", help="each run with one worker in this process, without Ray")
            q.add_argument("--no-progress", action="store_true", help="no progress bars")
        else:
            q.add_argument("--costs-from", help="predict from the finished runs and RL results of this suite folder "
                                                "(default: --out's own)")
        q.set_defaults(func=func)
    q = suite_sub.add_parser("rl", help="RL per test task (stable-baselines3 PPO) against GPL and GPR: the suite's rl section")
    q.add_argument("suite", help="suite file with an 'rl' section (e.g. configs/suites/paper.yaml)")
    q.add_argument("--out", required=True, help="the suite's folder of run dirs; results go to OUT/rl/")
    q.add_argument("--domains", help="comma-separated domains (default: every domain of the rl section)")
    q.add_argument("--address", help="a Ray cluster (default: local Ray with every core)")
    q.add_argument("--serial", action="store_true", help="one job after another in this process, without Ray")
    q.set_defaults(func=cmd_suite_rl)
    q = suite_sub.add_parser("report", help="the paper's tables from a suite's runs (Markdown and HTML)")
    q.add_argument("suite_out", help="the suite's folder of run dirs")
    q.add_argument("--out", required=True, help="folder for report.md, report.html and the plots")
    q.set_defaults(func=cmd_suite_report)
    for name, text, func in (
            ("curves", "each trained run's valid-split completion after every round (its per-round weights; "
             "resumes, skips finished curves)", cmd_suite_curves),
            ("swap", "each trained run's valid-split completion with its tasks' own instructions and told another "
             "task's: does it read its instruction? (skips finished runs)", cmd_suite_swap)):
        q = suite_sub.add_parser(name, help=text)
        q.add_argument("suite_out", help="the suite's folder of run dirs")
        q.add_argument("--only", help="comma-separated entry names")
        q.add_argument("--seeds", help="comma-separated training seeds")
        q.set_defaults(func=func)
    q = suite_sub.add_parser("restore", help="copy a report's archived runs (REPORT/runs) into a suite output, "
                             "where 'suite run' then skips them")
    q.add_argument("archive", help="the archive of runs (e.g. docs/paper-report/runs)")
    q.add_argument("--out", required=True, help="the suite's folder of run dirs; run dirs already there are kept")
    q.set_defaults(func=cmd_suite_restore)

    p = sub.add_parser("render", help="draw a task (PNG), an attempt (GIF), or a trained policy's attempts (GIF)")
    p.add_argument("--env", choices=domain_names(), help="the domain of the task to draw (not with --run-dir)")
    p.add_argument("--run-dir", help="draw this run's trained policy: its successive attempts and the corrections between")
    p.add_argument("--attempts", type=int, default=5, help="with --run-dir: attempts to draw (corrections + 1)")
    p.add_argument("--checkpoint", help="with --run-dir: checkpoint file (default: RUN_DIR/checkpoints/latest.pt)")
    _add_foreign_checkpoint(p)
    p.add_argument("--task", required=True, type=int, help="task id (multiroom 0..3239, relocation 0..999)")
    p.add_argument("--out", required=True, help="output .png (start state) or .gif (attempt)")
    drawn = p.add_mutually_exclusive_group()
    drawn.add_argument("--actions", help="actions of the attempt: '0,1,3,...' or a file holding them")
    drawn.add_argument("--expert", action="store_true", help="draw the expert's attempt")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the env's reset and, with --run-dir, of the policy's actions and the oracle (default 0)")
    p.set_defaults(func=cmd_render)

    for name, func, text in (("teach", cmd_teach, "correct a trained policy yourself, in the terminal"),
                             ("serve", cmd_serve, "correct a trained policy yourself, in a web page")):
        p = sub.add_parser(name, help=text, epilog=(
            "after each attempt, type a correction, or one of the commands ':hint' (what the run's oracle would say), "
            "':undo' (take the last correction back), ':quit'" if name == "teach" else None))
        p.add_argument("--run-dir", required=True, help="a trained run (its checkpoints/latest.pt)")
        p.add_argument("--checkpoint", help="checkpoint file (default: RUN_DIR/checkpoints/latest.pt)")
        _add_foreign_checkpoint(p)
        p.add_argument("--split", default="test", help="split of the tasks drawn or matched (default test: held out)")
        p.add_argument("--max-corrections", type=int, default=10, help="corrections an episode may take")
        p.add_argument("--out", help="folder of the teaching log (OUT/log/*.parquet)" + (" and GIFs (OUT/gifs)" if name == "teach"
                       else "") + " (default RUN_DIR/teaching)")
        p.add_argument("--greedy", action="store_true", help="take the most likely action (default: sample, as eval)")
        if name == "teach":
            p.add_argument("--task", type=int, help="task id (default: one of --split drawn with --seed)")
            p.add_argument("--instruction", help="a task of --split with this instruction")
            p.add_argument("--seed", type=int, default=0, help="seed of the task draw and of the policy's actions")
            p.add_argument("--hint", action="store_true", help="show what the run's oracle would say after each attempt")
        else:
            p.add_argument("--host", default="127.0.0.1", help="address to listen on (default loopback only)")
            p.add_argument("--port", type=int, default=8000, help="port to listen on (default 8000)")
        p.set_defaults(func=func)

    p = sub.add_parser("export", help="write a run's buffer, or teaching logs, as a Minari dataset (each attempt an episode)")
    p.add_argument("run_dir", metavar="PATH", help="a run dir with a buffer, or a folder of teaching logs "
                                                   "(RUN_DIR/teaching/log: every attempt replayed from its seed)")
    p.add_argument("--format", choices=("minari",), default="minari", help="dataset format (Minari's arrow storage)")
    p.add_argument("--out", required=True, help="the Minari datasets folder (MINARI_DATASETS_PATH) to write into")
    p.add_argument("--dataset-id", help="dataset id (default gpl-dist/<domain>-<folder name>-v0)")
    p.add_argument("--teaching-run-dir", help="teaching logs only: the run dir to replay with, in place of the one "
                                              "the logs name (logs copied from another machine)")
    p.set_defaults(func=cmd_export)

    p = sub.add_parser("inspect", help="summarise a run's committed buffer (after verifying it)")
    p.add_argument("run_dir", help="a run dir, or a buffer root")
    p.add_argument("--tasks", action="store_true", help="add a per-task table")
    p.add_argument("--no-verify", action="store_true", help="compare file sizes only, not sha256 checksums")
    p.set_defaults(func=cmd_inspect)

    p = sub.add_parser("verify", help="check every committed file against its manifest; name each bad one")
    p.add_argument("run_dir", help="a run dir, or a buffer root")
    p.add_argument("--quarantine", action="store_true",
                   help="move bad rounds under quarantine/ (nothing deleted) so that --resume can collect them again")
    p.set_defaults(func=cmd_verify)

    p = sub.add_parser("clean", help="remove leftovers of dead writers (never committed data; never during a run)")
    p.add_argument("run_dir", help="a run dir, or a buffer root")
    p.add_argument("--dry-run", action="store_true", help="list what would be removed, remove nothing")
    p.set_defaults(func=cmd_clean)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command line ``argv``; returns the exit status (2 for every expected failure)."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    from gpl_dist.errors import UserError
    from gpl_dist.signals import SIGTERM_STATUS, end_on_sigterm, received_sigterm

    end_on_sigterm()
    try:
        return args.func(args)
    except (UserError, OSError) as err:  # OSError: the user's paths, permissions, names too long
        if args.verbose:
            traceback.print_exc()
        message = " ".join(str(err).split())  # one line, whatever the message held
        if len(message) > MAX_MESSAGE_CHARS:
            message = message[:MAX_MESSAGE_CHARS] + " [...]"
        print(f"gpl-dist: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # Ctrl-C, or SIGTERM (gpl_dist.signals)
        terminated = received_sigterm()
        print(f"gpl-dist: {'terminated (SIGTERM)' if terminated else 'interrupted'}{_resume_hint(args)}", file=sys.stderr)
        return SIGTERM_STATUS if terminated else 130


def _resume_hint(args: argparse.Namespace) -> str:
    """How to go on after a stopped ``train`` or ``suite run`` ("" for other commands)."""
    if args.command == "train":
        return f"; resume with: gpl-dist train --run-dir {args.run_dir} --resume"
    if args.command == "suite" and args.suite_command == "run":
        chosen = "".join(f" --{k} {v}" for k, v in (("only", args.only), ("seeds", args.seeds)) if v)
        return f"; resume with: gpl-dist suite run {args.suite} --out {args.out}{chosen}"
    return ""


if __name__ == "__main__":
    sys.exit(main())

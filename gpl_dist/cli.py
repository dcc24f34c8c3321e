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


def cmd_train(args: argparse.Namespace) -> int:
    """``gpl-dist train``: meta-train a run (Algorithm 1), fresh or ``--resume``."""
    from gpl_dist.config import load_config
    from learner.driver import resume_config, run_training

    overrides = parse_overrides(args.set)
    if args.num_workers is not None:
        overrides["collection.num_workers"] = str(args.num_workers)
    if args.seeds is not None:
        return _train_seeds(args, overrides)
    if args.config is None and not args.resume:
        raise UsageError("--config is required (unless --resume, which goes on with the run's latest checkpoint's config)")
    # the user's own --config is imported as asked; a run's config only as gpl_dist.domains.domain_module_allowed says
    cfg = (load_config(args.config, overrides, plugins="own") if args.config
           else resume_config(args.run_dir, overrides))
    result = run_training(cfg, args.run_dir, serial=args.serial, address=args.address, resume=args.resume,
                          progress=not args.no_progress and sys.stderr.isatty())  # no bars in piped logs
    if result.history:
        last = result.history[-1]
        print("\nfinal round, training tasks: cK is the mean completion (fraction of the task done) after K "
              "corrections; c0 follows the instruction alone:")
        for k, v in enumerate(last.completion_by_corrections):
            print(f"  c{k}: {v:.3f}")
        print(f"run saved to {result.run_dir}; evaluate with: gpl-dist eval --run-dir {result.run_dir}")
    return 0


def cmd_config(args: argparse.Namespace) -> int:
    """``gpl-dist config``: every config key with its default and its one-line doc."""
    from gpl_dist.config import describe_keys
    from gpl_dist.domains import load_domain_module

    if args.domain_module:  # named on the command line: imported as asked
        load_domain_module(args.domain_module)
    keys = describe_keys(args.section, args.domain)
    width = max(len(k.key) for k in keys)
    for k in keys:
        default = "null (the domain's)" if k.default is None else (list(k.default) if isinstance(k.default, tuple)
                                                                    else k.default)
        print(f"{k.key:<{width}}  {k.type}, default {default!r}\n{'':<{width}}  {k.doc}")
    print(f"\n{len(keys)} key(s); set them in a YAML config (section: {{key: value}}) or with --set section.key=value")
    return 0


def cmd_check_domain(args: argparse.Namespace) -> int:
    """``gpl-dist check-domain``: the env contract on a domain, each check in a line."""
    from gpl_dist.app.contract import check_domain
    from gpl_dist.domains import domain_names, get_domain, load_domain_module

    ref = args.domain
    names = (ref,) if ref in domain_names() else load_domain_module(ref)  # named here: imported as asked
    failed = 0
    for name in names:
        spec = get_domain(name)
        print(f"domain {name} ({spec.env_id}, {spec.num_tasks} tasks):")
        for finding in check_domain(spec, per_split=args.tasks_per_split):
            print(f"  {finding.line()}")
            failed += not finding.ok
    if failed:
        raise UsageError(f"{ref}: {failed} check(s) of the env contract failed (named above; docs/adding-a-domain.md)")
    print("every check held")
    return 0


def _train_seeds(args: argparse.Namespace, overrides: dict[str, str]) -> int:
    """``train --seeds``: one run per training seed, ``RUN_DIR/seed<k>``, as many at once as this
    machine's cores keep busy (``gpl_dist.app.suite.cluster.train_at_once``)."""
    from gpl_dist.app.suite.cluster import train_at_once
    from gpl_dist.config import load_config
    from learner.driver import resume_config

    seeds = _parse_seeds(args.seeds) or ()
    if args.serial or args.address:
        raise UsageError("--seeds runs its runs at once on this machine's own Ray: leave out --serial and --address")
    if not args.config and not args.resume:
        raise UsageError("--config is required (unless --resume, which goes on with each run's latest checkpoint's config)")
    runs = []
    for seed in seeds:
        run_dir = Path(args.run_dir) / f"seed{seed}"
        runs.append((load_config(args.config, {**overrides, "seed": str(seed)}, plugins="own") if args.config
                     else resume_config(str(run_dir), overrides), str(run_dir)))
    train_at_once(runs, resume=args.resume)
    print(f"trained {len(runs)} run(s) under {args.run_dir} (seed{seeds[0]} .. seed{seeds[-1]}); evaluate each with: "
          f"gpl-dist eval --run-dir {args.run_dir}/seed<k>")
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
              serial=args.serial, progress=not args.no_progress and sys.stderr.isatty(),
              at_once=not (args.serial or args.one_at_a_time))
    print(f"suite {args.suite}: every selected run is done; report with: gpl-dist suite report {args.out}")
    return 0


def cmd_suite_status(args: argparse.Namespace) -> int:
    """``gpl-dist suite status``: each run's state, read from its files, and the predicted wall time
    of what is left (``gpl_dist.app.suite.status``)."""
    from gpl_dist.app.suite.spec import load_suite
    from gpl_dist.app.suite.status import suite_status

    suite = load_suite(args.suite, plugins="none")
    status = suite_status(suite, args.suite, args.out, _names(args.only), _parse_seeds(args.seeds) or (), args.costs_from)
    for line in status.lines:
        print(line)
    if status.refused:
        print(f"gpl-dist: error: {status.refused} run(s) refused: their evidence fails its checksums or its own "
              "consistency (named above); restore them again from the archive, or remove them to train them anew",
              file=sys.stderr)
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
    """``gpl-dist suite report``: a suite's runs as a report (its own comparison, or the paper's
    tables for the paper's suite), Markdown and HTML, with their evidence archived beside it."""
    from gpl_dist.app.suite.archive import archive_runs
    from gpl_dist.app.suite.report import ARCHIVE_DIR, build_report
    from gpl_dist.errors import RunDirError

    suite_out, out = Path(args.suite_out), Path(args.out)
    if not suite_out.is_dir():
        raise RunDirError(f"no suite output at {suite_out}")
    archive = out / ARCHIVE_DIR
    if archive.is_symlink():
        raise RunDirError(f"{archive} is a symbolic link: the report's archive is written in place, never through one")
    archive.mkdir(parents=True, exist_ok=True)
    archive_runs(suite_out, archive)  # the evidence first: the report is computed from it
    md, html = build_report(archive, out, source=suite_out)
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
    from gpl_dist.domains import get_domain, load_domain_module

    if args.domain_module:  # named on the command line: imported as asked
        load_domain_module(args.domain_module)
    get_domain(args.env)  # an unknown name fails in one line naming the known ones
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
    from gpl_dist.app.rundir import buffer_root

    if is_teaching_log(args.run_dir):
        dataset_id, n = export_teaching_minari(args.run_dir, args.out, args.dataset_id, run_dir=args.teaching_run_dir)
    else:
        if args.teaching_run_dir:
            raise UsageError(f"--teaching-run-dir is for a folder of teaching logs; {args.run_dir} is not one")
        dataset_id, n = export_minari(args.run_dir, buffer_root(args.run_dir), args.out, args.dataset_id)
    print(f"wrote Minari dataset {dataset_id} ({n} episodes, one per attempt) under {args.out}; read it with "
          f"MINARI_DATASETS_PATH={args.out} python -c \"import minari; print(minari.load_dataset('{dataset_id}'))\"")
    return 0


def cmd_inspect(args: argparse.Namespace) -> int:
    """``gpl-dist inspect``: verify a run's buffer, then summarise it."""
    from gpl_dist.app.rundir import buffer_root, no_buffer_note
    from storage import format_inspection
    from storage.verify import verify_buffer

    root = buffer_root(args.run_dir)
    note = no_buffer_note(args.run_dir, root)
    if note:
        print(note)
        return 0
    report = verify_buffer(root, checksums=not args.no_verify)
    for p in report.problems:
        print(f"BAD  {p.path}: {p.message}")
    report.raise_if_bad(f"run gpl-dist verify {args.run_dir} for the list and docs/buffer.md (Recovering)")
    print(format_inspection(root, show_tasks=args.tasks))
    return 0


def cmd_verify(args: argparse.Namespace) -> int:
    """``gpl-dist verify``: check every committed file and checkpoint; ``--quarantine`` sets bad rounds aside."""
    from gpl_dist.app.rundir import buffer_root, report_lines, run_checks
    from storage.lease import Lease
    from storage.verify import quarantine_round, verify_buffer

    root = buffer_root(args.run_dir)
    checks = run_checks(args.run_dir, root)
    for line in ([checks.note] if checks.note else []) + [f"BAD  {line}" for line in checks.problems]:
        print(line)
    if checks.problems:
        print(f"gpl-dist: error: {len(checks.problems)} problem(s) with {args.run_dir}'s config.yaml or checkpoints "
              "(named above; verify never moves them)", file=sys.stderr)
    if not args.quarantine:
        report = verify_buffer(root, run_id=checks.run_id)
        print("\n".join(report_lines(report)))
    else:
        with Lease(root, "gpl-dist verify --quarantine"):  # before verifying: no run may change it meanwhile
            report = verify_buffer(root, run_id=checks.run_id)
            print("\n".join(report_lines(report)))
            refuse = [p for p in report.problems if p.kind == "link" or (p.kind == "foreign" and p.round_index is None)]
            if refuse:  # a link, or a whole buffer of another run: setting rounds aside would move what is not ours
                raise UsageError(f"--quarantine moves nothing here: {refuse[0].path}: {refuse[0].message} "
                                 "(remove the link, or verify the run the buffer belongs to)")
            for r in report.bad_rounds:
                moved = quarantine_round(root, r)
                what = f"moved {', '.join(moved)}" if moved else "nothing was left of it; recorded it as missing"
                print(f"quarantined round {r}: {what} under quarantine/")
            if report.bad_rounds:
                report = verify_buffer(root, run_id=checks.run_id)
                print("\n".join(report_lines(report)))
        if report.ok and not checks.problems:
            print(f"resume with: gpl-dist train --run-dir {args.run_dir} --resume "
                  "(rounds after the last checkpoint are collected again)")
    if report.ok:
        return 2 if checks.problems else 0
    print(f"gpl-dist: error: {len(report.problems)} problem(s) in {report.root}; bad rounds {list(report.bad_rounds)} "
          "(set them aside with --quarantine; see docs/buffer.md, Recovering)", file=sys.stderr)
    return 2


def cmd_clean(args: argparse.Namespace) -> int:
    """``gpl-dist clean``: remove dead writers' leftovers from a run no process holds."""
    from gpl_dist.app.rundir import clean_run

    cleaned = clean_run(args.run_dir, dry_run=args.dry_run)
    verb = "would remove" if args.dry_run else "removed"
    for path in cleaned.removed:
        print(f"{verb} {path}")
    print(f"{verb} {len(cleaned.removed)} leftover(s)")
    if cleaned.unlisted:
        print(f"kept {cleaned.unlisted} path(s) under data/ that no manifest lists (clean never removes committed "
              f"data); see gpl-dist verify {args.run_dir}")
    return 0


def _add_version(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--version", action="version", version=f"gpl-dist {__version__}",
                        help="print the version and exit")


def _add_foreign_checkpoint(p: argparse.ArgumentParser) -> None:
    p.add_argument("--foreign-checkpoint", action="store_true",
                   help="use a --checkpoint of another run, domain or model (refused otherwise); nothing is then "
                        "written into RUN_DIR")


def _add_trust(p: argparse.ArgumentParser) -> None:
    p.add_argument("--trust-domain-module", action="store_true",
                   help="import the domain module (a .py file or a module) that a run's config names, though no run "
                        "of this machine was started from it and no installed package declares it (it runs its code)")


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
                                            break_on_hyphens=False)
                       + "\n\nEvery config key with its default and doc: gpl-dist config [SECTION] [--domain NAME].")
    p.add_argument("--config", help="YAML config (see configs/; every key, its default and doc: gpl-dist config)")
    p.add_argument("--run-dir", required=True, help="where the buffer, checkpoints and metrics go")
    p.add_argument("--num-workers", type=int, help="rollout actors (overrides collection.num_workers)")
    p.add_argument("--address", help="join an existing Ray cluster (e.g. 'auto') instead of starting a local one")
    p.add_argument("--serial", action="store_true", help="run one worker in this process, without Ray")
    p.add_argument("--resume", action="store_true", help="continue from the run dir's last checkpoint")
    p.add_argument("--seeds", help="train one run per seed (comma-separated) in RUN_DIR/seed<k>, as many at once as keep "
                   "this machine's cores busy; each run's files are what it gives alone")
    _add_trust(p)
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a config value")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("check-domain", help="hold a domain (a .py file, a module, or a registered name) to the env "
                       "contract: each check in a line")
    p.add_argument("domain", metavar="FILE_OR_MODULE", help="a .py file or module defining DOMAIN (imported: its code "
                   "runs), or a registered domain's name")
    p.add_argument("--tasks-per-split", type=int, default=3, help="tasks of each split the sampling checks use")
    p.set_defaults(func=cmd_check_domain)

    p = sub.add_parser("config", help="every config key with its default and its one-line doc")
    p.add_argument("section", nargs="?", help="one section only (env, collection, buffer, model, training, eval)")
    p.add_argument("--domain", help="fill in the defaults this domain gives (its expert, splits and layer sizes)")
    p.add_argument("--domain-module", help="with --domain: the module or .py file that defines it (imported: its code runs)")
    p.set_defaults(func=cmd_config)

    p = sub.add_parser("eval", help="meta-test a trained run on held-out tasks (Algorithm 2)",
                       description="Meta-test a trained run. Writes RUN_DIR/eval.json and eval.png with the run's "
                                   "own eval settings; other settings write eval-<what differs>.json/.png "
                                   "(eval-greedy.json, eval-c10.json, ...), leaving eval.json as it was.")
    p.add_argument("--run-dir", required=True, help="a trained run (its checkpoints/latest.pt and config.yaml)")
    _add_trust(p)
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
            q.add_argument("--one-at-a-time", action="store_true", help="one run after another, each with its config's "
                           "workers (default: as many runs at once as keep this machine's cores busy)")
            q.add_argument("--no-progress", action="store_true", help="no progress bars")
            _add_trust(q)
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
    _add_trust(q)
    q.set_defaults(func=cmd_suite_rl)
    q = suite_sub.add_parser("report", help="a suite's runs as a report (its own comparison against its reference "
                             "entry, or the paper's tables for the paper's suite), Markdown and HTML")
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
        _add_trust(q)
        q.set_defaults(func=func)
    q = suite_sub.add_parser("restore", help="copy a report's archived runs (REPORT/runs) into a suite output, "
                             "where 'suite run' then skips them")
    q.add_argument("archive", help="the archive of runs (e.g. docs/paper-report/runs)")
    q.add_argument("--out", required=True, help="the suite's folder of run dirs; run dirs already there are kept")
    q.set_defaults(func=cmd_suite_restore)

    p = sub.add_parser("render", help="draw a task (PNG), an attempt (GIF), or a trained policy's attempts (GIF)")
    p.add_argument("--env", metavar="DOMAIN", help=f"the domain of the task to draw ({', '.join(domain_names())} or a "
                   "plug-in's; not with --run-dir)")
    p.add_argument("--domain-module", help="with --env: the module or .py file that defines a plug-in domain (imported: "
                   "its code runs)")
    p.add_argument("--run-dir", help="draw this run's trained policy: its successive attempts and the corrections between")
    _add_trust(p)
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
        _add_trust(p)
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
    _add_trust(p)
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
    from gpl_dist.domains import trust_all_domain_modules
    from gpl_dist.errors import UserError
    from gpl_dist.signals import SIGTERM_STATUS, end_on_sigterm, received_sigterm

    trust_all_domain_modules(bool(getattr(args, "trust_domain_module", False)))
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

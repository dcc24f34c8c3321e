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
import os
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
    """``gpl-dist train``: meta-train a run (Algorithm 1), fresh or ``--resume``; with ``--seeds``, one
    run per training seed in ``RUN_DIR/seed<k>``, as many at once as this machine's cores keep busy."""
    from gpl_dist.app.suite.cluster import train_seeds
    from gpl_dist.config import load_config
    from learner.driver import resume_config, run_training

    overrides = parse_overrides(args.set)
    if args.num_workers is not None:
        overrides["collection.num_workers"] = str(args.num_workers)
    if args.config is None and not args.resume:
        raise UsageError("--config is required (unless --resume, which goes on with the latest checkpoint's config)")
    if args.seeds is not None:
        if args.serial or args.address:
            raise UsageError("--seeds runs its runs at once on this machine's own Ray: leave out --serial and --address")
        train_seeds(args.config, args.run_dir, _parse_seeds(args.seeds) or (), overrides, resume=args.resume)
        return 0
    # the user's own --config is imported as asked; a run's config only as gpl_dist.domains.domain_module_allowed says
    cfg = load_config(args.config, overrides, plugins="own") if args.config else resume_config(args.run_dir, overrides)
    result = run_training(cfg, args.run_dir, serial=args.serial, address=args.address, resume=args.resume,
                          progress=not args.no_progress and sys.stderr.isatty())  # no bars in piped logs
    if result.history:
        print("\nfinal round, training tasks: cK is the mean completion (fraction of the task done) after K "
              "corrections; c0 follows the instruction alone:")
        print("\n".join(f"  c{k}: {v:.3f}" for k, v in enumerate(result.history[-1].completion_by_corrections)))
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
        default = list(k.default) if isinstance(k.default, tuple) else "null (the domain's)" if k.default is None else k.default
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
    """``gpl-dist eval``: meta-test a run's checkpoint on held-out tasks (Algorithm 2); writes its
    record (``learner.evaluate.EvalRecord``) and its plot, and prints its table."""
    from learner.evaluate import evaluate_run, format_table, plot

    _check_eval_arguments(args)
    record, path = evaluate_run(args.run_dir, num_corrections=args.corrections, seeds=_parse_seeds(args.seeds), split=args.split,
                                max_tasks=args.max_tasks, checkpoint=args.checkpoint, greedy=args.greedy,
                                phrasings=args.phrasings, foreign_checkpoint=args.foreign_checkpoint, out_dir=args.out,
                                swap_instructions=args.swap_instructions)
    plot(record, path.with_suffix(".png"))
    print(f"meta-test on {record.num_tasks} tasks x {len(record.per_seed)} seeds ({record.seconds:.1f}s):")
    print(format_table(record.domain, record, with_paper=record.with_paper))
    if record.reduced_scale:
        print(f"note: {record.reduced_scale}")
    print(f"wrote {path} and {path.with_suffix('.png')}")
    return 0


def _check_eval_arguments(args: argparse.Namespace) -> None:
    """``eval``'s arguments, before anything is loaded: counts in range, a foreign checkpoint's files
    outside the run dir, and a folder to write into (made when ``--out`` names a new one)."""
    from gpl_dist.config import MAX_CORRECTIONS

    target = Path(args.out) if args.out is not None else Path(args.run_dir)
    _check_foreign_out(args, "evaluation")
    for name, value in (("corrections", args.corrections), ("max_tasks", args.max_tasks)):
        if value is not None and value < 0:
            raise UsageError(f"{name} must be >= 0, got {value}")
    if args.corrections is not None and args.corrections > MAX_CORRECTIONS:
        raise UsageError(f"corrections must be at most {MAX_CORRECTIONS}, got {args.corrections}")
    if args.out is not None:
        target.mkdir(parents=True, exist_ok=True)
    if target.is_dir() and not os.access(target, os.W_OK):
        raise UsageError(f"cannot write the report into {target} (no write permission)")


def _check_foreign_out(args: argparse.Namespace, what: str) -> None:
    if args.foreign_checkpoint and not args.out:
        raise UsageError(f"--foreign-checkpoint writes nothing into {args.run_dir}: give --out DIR for the {what}")
    if args.foreign_checkpoint and Path(args.out).resolve().is_relative_to(Path(args.run_dir).resolve()):
        raise UsageError(f"--out {args.out} is inside {args.run_dir}: a foreign checkpoint's {what} goes elsewhere")


def _names(text: str | None) -> tuple[str, ...]:
    return tuple(n.strip() for n in (text or "").split(",") if n.strip())


def cmd_suite(args: argparse.Namespace) -> int:
    """``gpl-dist suite SUBCOMMAND``: calls the subcommand (``gpl_dist.app.suite.commands``) with the
    parsed arguments and prints its lines; its error line, where it has one, goes to stderr (exit 2)."""
    from gpl_dist.app.suite import commands

    only, seeds = _names(getattr(args, "only", None)), _parse_seeds(getattr(args, "seeds", None)) or ()
    calls = {
        "run": lambda: commands.run(args.suite, args.out, only, seeds, address=args.address, serial=args.serial,
                                    one_at_a_time=args.one_at_a_time, progress=not args.no_progress and sys.stderr.isatty()),
        "status": lambda: commands.status(args.suite, args.out, only, seeds, args.costs_from),
        "rl": lambda: commands.rl(args.suite, args.out, _names(args.domains), address=args.address, serial=args.serial),
        "report": lambda: commands.report(args.suite_out, args.out),
        "curves": lambda: commands.curves(args.suite_out, only, seeds),
        "swap": lambda: commands.swap(args.suite_out, only, seeds),
        "restore": lambda: commands.restore(args.archive, args.out)}
    done = calls[args.suite_command]()
    print("\n".join(done.lines))
    if done.error:
        print(f"gpl-dist: error: {done.error}", file=sys.stderr)
    return 2 if done.error else 0


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
    else:
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


def cmd_teach(args: argparse.Namespace) -> int:
    """``gpl-dist teach`` (correct a trained policy by typing, attempt after attempt) and ``gpl-dist
    serve`` (the same in a web page)."""
    from gpl_dist.app.teaching import Teacher

    if getattr(args, "task", None) is not None and args.instruction is not None:
        raise UsageError("give --task or --instruction, not both")
    _check_foreign_out(args, "teaching log")
    teacher = Teacher(args.run_dir, args.checkpoint, max_corrections=args.max_corrections, greedy=args.greedy,
                      allow_foreign=args.foreign_checkpoint)
    out = Path(args.out) if args.out else Path(args.run_dir) / "teaching"
    if args.command == "serve":
        from gpl_dist.app.teach_web import serve

        serve(teacher, out, host=args.host, port=args.port, split=args.split)
        return 0
    from gpl_dist.app.teach_terminal import teach_in_terminal
    from gpl_dist.splits import split_tasks

    task_id = teacher.resolve_task(args.task, args.instruction, args.seed, args.split)
    if args.task is not None and task_id not in split_tasks(teacher.domain.name, args.split):
        print(f"note: task {task_id} is not in the {args.split} split")
    teach_in_terminal(teacher.episode(task_id, args.seed, "terminal"), out, always_hint=args.hint)
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    """``gpl-dist export``: a run's committed buffer, or a folder of teaching logs, as a Minari
    dataset (``gpl_dist.app.export``)."""
    from gpl_dist.app.export import export_minari, export_teaching_minari, is_teaching_log
    from gpl_dist.app.rundir import buffer_root

    teaching = is_teaching_log(args.run_dir)
    if args.teaching_run_dir and not teaching:
        raise UsageError(f"--teaching-run-dir is for a folder of teaching logs; {args.run_dir} is not one")
    dataset_id, n = (export_teaching_minari(args.run_dir, args.out, args.dataset_id, run_dir=args.teaching_run_dir)
                     if teaching else export_minari(args.run_dir, buffer_root(args.run_dir), args.out, args.dataset_id))
    print(f"wrote Minari dataset {dataset_id} ({n} episodes, one per attempt) under {args.out}; read it with "
          f"MINARI_DATASETS_PATH={args.out} python -c \"import minari; print(minari.load_dataset('{dataset_id}'))\"")
    return 0


def cmd_run_dir(args: argparse.Namespace) -> int:
    """``gpl-dist inspect`` (verify a run's buffer, then summarise it), ``verify`` (check every
    committed file and checkpoint; ``--quarantine`` sets bad rounds aside) and ``clean`` (remove dead
    writers' leftovers from a run no process holds): ``gpl_dist.app.rundir``."""
    from gpl_dist.app import rundir

    if args.command == "inspect":
        rundir.inspect_run(args.run_dir, show_tasks=args.tasks, checksums=not args.no_verify)
    elif args.command == "clean":
        print("\n".join(rundir.clean_run(args.run_dir, dry_run=args.dry_run).lines(args.run_dir)))
    else:
        errors = rundir.verify_run(args.run_dir, quarantine=args.quarantine)
        for line in errors:
            print(f"gpl-dist: error: {line}", file=sys.stderr)
        return 2 if errors else 0
    return 0


def _add_checkpoint(p: argparse.ArgumentParser, prefix: str = "") -> None:
    p.add_argument("--checkpoint", help=f"{prefix}checkpoint file (default: RUN_DIR/checkpoints/latest.pt)")
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
    parser.add_argument("--version", action="version", version=f"gpl-dist {__version__}", help="print the version and exit")
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
                       description="Meta-test a trained run. Writes RUN_DIR/eval.json and eval.png with the run's own eval "
                       "settings; others write eval-<what differs>.json/.png (eval-greedy.json, eval-c10.json, ...).")
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
    _add_checkpoint(p)
    p.add_argument("--out", help="folder for the evaluation's files (default RUN_DIR; required with --foreign-checkpoint)")
    acting = p.add_mutually_exclusive_group()
    acting.add_argument("--greedy", dest="greedy", action="store_true", default=None, help="act with the most likely action")
    acting.add_argument("--sample", dest="greedy", action="store_false", help="sample actions from the policy (default)")
    p.set_defaults(func=cmd_eval)

    p = sub.add_parser("suite", help="run the paper's experiments (a suite file) and report them")
    p.set_defaults(func=cmd_suite)  # each subcommand: gpl_dist.app.suite.commands
    suite_sub = p.add_subparsers(dest="suite_command", required=True)
    q = {name: suite_sub.add_parser(name, help=text) for name, text in (
        ("run", "train and evaluate every unfinished run; resumes a killed suite"),
        ("status", "each run's state, read from its files, and the predicted wall time of what is left"),
        ("rl", "RL per test task (stable-baselines3 PPO) against GPL and GPR: the suite's rl section"),
        ("report", "a suite's runs as a report (its own comparison against its reference entry, or the paper's tables "
                   "for the paper's suite), Markdown and HTML"),
        ("curves", "each trained run's valid-split completion after every round (its per-round weights; resumes, skips "
                   "finished curves)"),
        ("swap", "each trained run's valid-split completion with its tasks' own instructions and told another task's: "
                 "does it read its instruction? (skips finished runs)"),
        ("restore", "copy a report's archived runs (REPORT/runs) into a suite output, where 'suite run' then skips them"))}
    for name in ("run", "status", "rl"):
        q[name].add_argument("suite", help="suite file" + (" with an 'rl' section" if name == "rl" else "")
                             + " (e.g. configs/suites/paper.yaml)")
        q[name].add_argument("--out", required=True, help="the suite's folder of run dirs (OUT/<entry>/seed<k>)"
                             + ("; results go to OUT/rl/" if name == "rl" else ""))
    for name in ("report", "curves", "swap"):
        q[name].add_argument("suite_out", help="the suite's folder of run dirs")
    for name in ("run", "status", "curves", "swap"):
        q[name].add_argument("--only", help="comma-separated entry names")
        q[name].add_argument("--seeds", help="comma-separated training seeds")
    for name in ("run", "rl", "curves", "swap"):
        _add_trust(q[name])
    q["run"].add_argument("--address", help="a Ray cluster: run the entries at once, each as a Ray task")
    q["run"].add_argument("--serial", action="store_true", help="each run with one worker in this process, without Ray")
    q["run"].add_argument("--one-at-a-time", action="store_true", help="one run after another, each with its config's "
                          "workers (default: as many runs at once as keep this machine's cores busy)")
    q["run"].add_argument("--no-progress", action="store_true", help="no progress bars")
    q["status"].add_argument("--costs-from", help="predict from the finished runs and RL results of this suite folder "
                             "(default: --out's own)")
    q["rl"].add_argument("--domains", help="comma-separated domains (default: every domain of the rl section)")
    q["rl"].add_argument("--address", help="a Ray cluster (default: local Ray with every core)")
    q["rl"].add_argument("--serial", action="store_true", help="one job after another in this process, without Ray")
    q["report"].add_argument("--out", required=True, help="folder for report.md, report.html and the plots")
    q["restore"].add_argument("archive", help="the archive of runs (e.g. docs/paper-report/runs)")
    q["restore"].add_argument("--out", required=True, help="the suite's folder of run dirs; run dirs already there are kept")

    p = sub.add_parser("render", help="draw a task (PNG), an attempt (GIF), or a trained policy's attempts (GIF)")
    p.add_argument("--env", metavar="DOMAIN", help=f"the domain of the task to draw ({', '.join(domain_names())} or a "
                   "plug-in's; not with --run-dir)")
    p.add_argument("--domain-module", help="with --env: the module or .py file that defines a plug-in domain (imported: "
                   "its code runs)")
    p.add_argument("--run-dir", help="draw this run's trained policy: its successive attempts and the corrections between")
    _add_trust(p)
    p.add_argument("--attempts", type=int, default=5, help="with --run-dir: attempts to draw (corrections + 1)")
    _add_checkpoint(p, "with --run-dir: ")
    p.add_argument("--task", required=True, type=int, help="task id (multiroom 0..3239, relocation 0..999)")
    p.add_argument("--out", required=True, help="output .png (start state) or .gif (attempt)")
    drawn = p.add_mutually_exclusive_group()
    drawn.add_argument("--actions", help="actions of the attempt: '0,1,3,...' or a file holding them")
    drawn.add_argument("--expert", action="store_true", help="draw the expert's attempt")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the env's reset and, with --run-dir, of the policy's actions and the oracle (default 0)")
    p.set_defaults(func=cmd_render)

    for name, text in (("teach", "correct a trained policy yourself, in the terminal"),
                       ("serve", "correct a trained policy yourself, in a web page")):
        p = sub.add_parser(name, help=text, epilog=(
            "after each attempt, type a correction, or one of the commands ':hint' (what the run's oracle would say), "
            "':undo' (take the last correction back), ':quit'" if name == "teach" else None))
        p.add_argument("--run-dir", required=True, help="a trained run (its checkpoints/latest.pt)")
        _add_trust(p)
        _add_checkpoint(p)
        p.add_argument("--split", default="test", help="split of the tasks drawn or matched (default test: held out)")
        p.add_argument("--max-corrections", type=int, default=10, help="corrections an episode may take")
        gifs = " and GIFs (OUT/gifs)" if name == "teach" else ""
        p.add_argument("--out", help=f"folder of the teaching log (OUT/log/*.parquet){gifs} (default RUN_DIR/teaching)")
        p.add_argument("--greedy", action="store_true", help="take the most likely action (default: sample, as eval)")
        if name == "teach":
            p.add_argument("--task", type=int, help="task id (default: one of --split drawn with --seed)")
            p.add_argument("--instruction", help="a task of --split with this instruction")
            p.add_argument("--seed", type=int, default=0, help="seed of the task draw and of the policy's actions")
            p.add_argument("--hint", action="store_true", help="show what the run's oracle would say after each attempt")
        else:
            p.add_argument("--host", default="127.0.0.1", help="address to listen on (default loopback only)")
            p.add_argument("--port", type=int, default=8000, help="port to listen on (default 8000)")
        p.set_defaults(func=cmd_teach)

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
    p.set_defaults(func=cmd_run_dir)

    p = sub.add_parser("verify", help="check every committed file against its manifest; name each bad one")
    p.add_argument("run_dir", help="a run dir, or a buffer root")
    p.add_argument("--quarantine", action="store_true",
                   help="move bad rounds under quarantine/ (nothing deleted) so that --resume can collect them again")
    p.set_defaults(func=cmd_run_dir)

    p = sub.add_parser("clean", help="remove leftovers of dead writers (never committed data; never during a run)")
    p.add_argument("run_dir", help="a run dir, or a buffer root")
    p.add_argument("--dry-run", action="store_true", help="list what would be removed, remove nothing")
    p.set_defaults(func=cmd_run_dir)
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

"""One run of a suite: its record (``suite-run.json``), its state read from its files, and its
execution (train, or resume, then evaluate), the same serially and inside a Ray task.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from pathlib import Path

from gpl_dist.app.suite.curves import compute_curve
from gpl_dist.app.suite.evidence import CHECKSUMS, check_run
from gpl_dist.app.suite.provenance import code_commit
from gpl_dist.app.suite.records import CURVE_TASKS, CurveSettings
from gpl_dist.app.suite.spec import EVAL_DEFAULTS, Suite, SuiteRun
from gpl_dist.config import DOMAIN_FILLED, ConfigError, RunConfig, load_config, results_dict
from gpl_dist.errors import RunDirError
from learner.checkpoint import rounds_trained
from learner.cpu import numerics_fingerprint
from learner.driver import run_training
from learner.evaluate import evaluate_run, plot
from learner.trainer import resolve_device, threads_per_learner
from storage.lease import Lease

#: What ``suite-run.json`` and the report agree on; raise it when the record's meaning changes.
RECORD_VERSION = 1


def read_record(run_dir: Path) -> dict | None:
    """A run's ``suite-run.json`` in the current shape, or None; a damaged one fails in one line
    naming it. The one place a record of an older shape is read; the shapes (all ``RECORD_VERSION``):

    - an evaluation's ``settings`` without ``max_tasks`` and ``phrasings`` (recorded before those
      settings existed): they read as the values it was made with (``spec.EVAL_DEFAULTS``);
    - no ``numerics`` (trained before fingerprints were recorded): reads as none, ``[]``;
    - the current: both.
    """
    p = run_dir / "suite-run.json"
    if not p.is_file():
        return None
    try:
        record = json.loads(p.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise RunDirError(f"{p} is damaged ({err}): delete it to let the suite rebuild it from the run's files") from None
    if not isinstance(record, dict):
        raise RunDirError(f"{p} does not hold a JSON object: delete it to let the suite rebuild it")
    evaluations = record.get("evaluations")
    for ev in evaluations.values() if isinstance(evaluations, dict) else ():
        if isinstance(ev, dict) and isinstance(ev.get("settings"), dict):
            ev["settings"] = {**EVAL_DEFAULTS, **ev["settings"]}
    return {**record, "numerics": record.get("numerics", [])}


def _write_record(run_dir: Path, record: dict) -> None:
    tmp = run_dir / f".suite-run.json.tmp-{os.getpid()}"
    tmp.write_text(json.dumps(record, indent=1) + "\n")
    tmp.replace(run_dir / "suite-run.json")


def _started(run_dir: Path, record: dict, commit: str, numerics: str) -> None:
    """Record the code's commit and this machine's numerics fingerprint
    (``learner.cpu.numerics_fingerprint``) before it trains: a run killed and resumed lists every
    commit and every fingerprint that trained a round of it."""
    record["commits"] = sorted(set(record["commits"]) | {commit})
    record["numerics"] = sorted(set(record["numerics"]) | {numerics})
    run_dir.mkdir(parents=True, exist_ok=True)
    _write_record(run_dir, record)


#: What a run records instead of a fingerprint where bitwise reproduction is not on offer.
NOT_BITWISE = ("gpu", "threads>1", "cluster")


def machine_numerics(run: SuiteRun, suite: Suite, address: str | None = None) -> str:
    """This machine's numerics fingerprint for ``run`` (at its learner's thread count), or why
    there is none to compare: ``gpu`` (its learner trains on a GPU: not bitwise reproducible at
    all), ``threads>1`` (more than one intra-op thread sums in a varying order) or ``cluster``
    (``address``: its actors and learners may run on other machines than this one)."""
    training = run.config(suite).training
    if address is not None:
        return "cluster"
    if resolve_device(training.device).type != "cpu":
        return "gpu"
    threads = threads_per_learner(training)
    return "threads>1" if threads > 1 else numerics_fingerprint(threads)


def trained_as_here(run: SuiteRun, here: str) -> bool | None:
    """Whether every round of ``run`` was trained under ``here`` (this machine's
    ``machine_numerics`` for it), so that training it again here gives the same files, bit for bit;
    None where its record names no fingerprint (trained before they were recorded)."""
    recorded = (read_record(run.run_dir) or {"numerics": []})["numerics"]
    if not recorded:
        return None
    return here not in NOT_BITWISE and recorded == [here]


def _check_unchanged(run: SuiteRun, cfg: RunConfig) -> None:
    """A run dir trained by another version of its entry is refused: its results would be mixed. A
    field the entry leaves to a domain that is not loaded here (``gpl_dist.config.DOMAIN_FILLED``) is not the
    entry's to decide, so the run's own value stands for it. The ``eval`` section is not compared:
    it does not touch training, and a suite evaluates each run under its named evaluations' own
    settings (recorded with each evaluation), so another suite may evaluate a run it did not train
    (``configs/suites/speed-valid.yaml`` reads the paper suite's archived runs on the valid split)."""
    saved_path = run.run_dir / "config.yaml"
    if not saved_path.is_file():
        return
    saved = load_config(saved_path, plugins="none")
    for section, key in DOMAIN_FILLED:
        if getattr(getattr(cfg, section), key) == "":
            part = dataclasses.replace(getattr(cfg, section), **{key: getattr(getattr(saved, section), key)})
            cfg = dataclasses.replace(cfg, **{section: part})
    if _training(saved) != _training(cfg):
        raise ConfigError(f"{run.run_dir} was trained with another config than entry '{run.entry.name}' gives now "
                          "(the suite file or the base config changed): use another --out, or remove that run dir")


def _training(cfg: RunConfig) -> dict:
    """What a run's trained files depend on: ``results_dict`` without the ``eval`` section."""
    out = results_dict(cfg)
    out.pop("eval", None)
    return out


def run_state(run: SuiteRun, suite: Suite) -> str:
    """``done``, ``evaluate`` (trained), ``resume`` (started) or ``new``, read from the run's files."""

    cfg = run.config(suite)
    _check_unchanged(run, cfg)
    if not any((run.run_dir / name).exists() for name in ("config.yaml", "checkpoints", "buffer", "metrics.jsonl")):
        return "new"  # nothing but lease files: a driver stopped before writing anything
    if rounds_trained(run.run_dir) < cfg.training.num_rounds:
        return "resume"
    record = read_record(run.run_dir) or {}
    done = record.get("evaluations", {})
    if done:  # what counts must check itself: each eval file, and a restored run's checksums
        check_run(run.run_dir)
    for name, ev in done.items():
        now = suite.evaluations[name].settings() if name in suite.evaluations else None
        recorded = ev.get("settings") or {}
        if now is not None and recorded != now:  # compared as recorded: JSON lists, not tuples
            raise ConfigError(f"{run.run_dir}: evaluation '{name}' was made with other settings than the suite "
                              f"gives now ({ev.get('settings')}): use another --out, or delete {ev.get('file')} and "
                              f"its entry in suite-run.json to evaluate it again")
    return "done" if set(run.entry.evaluations) <= set(done) else "evaluate"


def execute(run: SuiteRun, suite: Suite, *, address: str | None = None, serial: bool = False, progress: bool = True,
            log=print, commit: str | None = None, workers: int | None = None, on_this_machine: bool = False) -> dict:
    """Bring one run to ``done``: train (fresh or resumed), then every evaluation not yet written.
    ``commit`` names the code in the records (default: this process's ``code_commit()``);
    ``workers``: its rollout actors in place of the config's (how fast it collects, never what);
    ``on_this_machine``: ``address`` is a local cluster of this machine (its numerics are this machine's)."""

    commit = commit or code_commit()
    state = run_state(run, suite)
    if state != "done":  # the suite changes the run: it is no longer an archive's copy (checked just above)
        (run.run_dir / CHECKSUMS).unlink(missing_ok=True)
    record = read_record(run.run_dir) or {"version": RECORD_VERSION, "suite": str(suite.path), "entry": run.entry.name,
                                          "seed": run.seed, "evaluations": {}, "train_seconds": 0.0, "commits": [],
                                          "numerics": []}
    if state in ("new", "resume"):
        log(f"[{run.entry.name} seed {run.seed}] {'training' if state == 'new' else 'resuming'} into {run.run_dir}")
        _started(run.run_dir, record, commit, machine_numerics(run, suite, None if on_this_machine else address))
        t0 = time.perf_counter()
        cfg = run.config(suite)
        if workers is not None:
            cfg = dataclasses.replace(cfg, collection=dataclasses.replace(cfg.collection, num_workers=workers))
        run_training(cfg, run.run_dir, address=address, serial=serial, resume=state == "resume", progress=progress)
        record["train_seconds"] += time.perf_counter() - t0
        _write_record(run.run_dir, record)
    todo = [name for name in run.entry.evaluations if name not in record["evaluations"]]
    if todo:
        with Lease(run.run_dir, "gpl-dist suite run (evaluating)"):  # a second suite run is refused, naming this one
            record = _evaluate(run, suite, todo, log, commit, record)
    _valid_curve(run, suite, log)  # resumes a partial curve; a curve done is not recomputed
    return record


def _evaluate(run: SuiteRun, suite: Suite, names: list[str], log, commit: str, record: dict) -> dict:
    """Write each of ``names`` (the run's evaluations not yet done), its file and its plot, and record
    it; read the record again first (under the lease): another suite run may have written some meanwhile."""
    record = read_record(run.run_dir) or record
    for name in names:
        if name in record["evaluations"]:
            continue
        evaluation = suite.evaluations[name]
        ev = evaluation.config
        log(f"[{run.entry.name} seed {run.seed}] evaluation '{name}'")
        t0 = time.perf_counter()
        evaluated, path = evaluate_run(run.run_dir, num_corrections=ev.num_corrections, seeds=ev.seeds, split=ev.split,
                                       max_tasks=ev.max_tasks, greedy=ev.greedy_actions, phrasings=ev.phrasings)
        plot(evaluated, path.with_suffix(".png"))
        record["evaluations"][name] = {"file": path.name, "seconds": time.perf_counter() - t0,
                                       "commit": commit, "settings": evaluation.settings()}
        _write_record(run.run_dir, record)
    return record


def _valid_curve(run: SuiteRun, suite: Suite, log) -> None:
    """The run's valid learning curve (``gpl_dist.app.suite.curves``), while its per-round weights are
    there: a training split without a valid split has none; an entry whose first evaluation caps
    its tasks (a quick suite) caps the curve's too. A curve of other settings (made by the suite
    that trained the run, when another suite evaluates it) is kept: ``gpl-dist suite curves``
    measures it again when asked."""
    cap = suite.evaluations[run.entry.evaluations[0]].config.max_tasks
    settings = CurveSettings(tasks=min(CURVE_TASKS, cap) if cap else CURVE_TASKS)
    compute_curve(run.run_dir, settings, log=lambda line: log(f"[{run.entry.name} seed {run.seed}] {line}"),
                  replace_other=False)

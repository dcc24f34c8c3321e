"""The paper's sample-complexity comparison: RL per test task (``gpl_dist.app.suite.rl.per_task``) against GPL and GPR,
which solve a new task within a handful of attempts.

A suite file's ``rl`` section names the test tasks of each domain (the same for every method),
the seeds, the budget of trajectories per task, the instruction-only entry each domain's
``rl-finetune`` starts from, and the entries (GPL, GPR) drawn as points. ``gpl-dist suite rl``
runs every (method, domain, task, seed) not yet done, one after another or as Ray tasks
(``gpl_dist.app.suite.rl.cluster.run_rl_on_ray``), and writes each result as it finishes:

- ``OUT/rl/<method>/<domain>/task<t>-seed<s>.json``: an ``RLCurve`` (every trajectory's completion);
- ``OUT/rl/attempts/<entry>-seed<s>.json``: each RL task's completion after attempts 1..6 of the
  entry's trained policy (its training seed 0), corrected by the run's oracle with evaluation seed ``s``.

A result made from a trained policy (``rl-finetune``'s start, the attempts) records that policy's
``policy_fingerprint``; once the entry is trained again, its results are redone. A killed run loses
only the jobs in flight; running it again does the rest. The report
(``gpl_dist.app.suite.rl.report``) draws the figure from these files, from those of the suite's ``rl``
section as it stands only (``load_results``): results of an earlier task list, budget or PPO
settings stay on disk, are counted as left out and never mix into the medians.
"""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

from gpl_dist.app.suite.provenance import code_commit
from gpl_dist.app.suite.rl.per_task import RLCurve, RLJob, made_with, run_rl_job
from gpl_dist.app.suite.rl.plan import ATTEMPTS, AttemptsJob, RLPlan, attempts_jobs, parse_rl_plan, rl_jobs
from gpl_dist.config import ConfigError, ModelConfig, load_config, load_yaml_text
from gpl_dist.metrics import completion_by_attempt
from gpl_dist.models.build import state_dict_to_numpy
from learner.checkpoint import rounds_trained
from learner.evaluate import load_trained_policy, meta_test_rollout
from learner.ppo import PPOSettings


def result_path(out: str | Path, key: str) -> Path:
    """Where a job's result lives: ``OUT/rl/<key>.json``."""
    return Path(out) / "rl" / f"{key}.json"


#: ``PPOSettings`` fields that a curve result's settings lack when it was written before they existed:
#: every such job ran with their defaults (SB3's own, one learning rate, one value layer).
_FIELDS_ADDED_LATER = ("value_learning_rate", "target_kl", "max_grad_norm", "value_layers")


def read_result(path: Path) -> dict:
    """An RL result file (a curve's, ``RLCurve.to_json``, or an attempts set's), in the current
    shape: the one place a result of an older shape is read. A curve's ``settings`` of the
    results written before ``_FIELDS_ADDED_LATER`` existed lack them and read as their defaults;
    the current ones hold every ``PPOSettings`` field. Raises what ``json.loads`` raises."""
    data = json.loads(path.read_text())
    settings = data.get("settings") if isinstance(data, dict) else None
    if isinstance(settings, dict):
        defaults = dataclasses.asdict(PPOSettings())
        data["settings"] = {**{k: defaults[k] for k in _FIELDS_ADDED_LATER}, **settings}
    return data


def is_current(out: str | Path, job, settings, policy: str | None = None) -> bool:
    """Whether ``job``'s result is written for this very job (its budget is not in the file's
    name), made with ``settings`` (``learner.ppo.PPOSettings``) and, for a job that starts from a
    trained policy, from the one of fingerprint ``policy``."""

    path = result_path(out, job.key)
    if not path.is_file():
        return False
    data = read_result(path)
    return (RLJob(**data["job"]) == job and made_with(data.get("settings"), settings)
            and data.get("policy") == policy)


def policy_fingerprint(weights: Mapping[str, Any]) -> str:
    """sha256 of a policy's weights (numpy arrays: names, dtypes, shapes and bytes, in name order),
    16 hex digits: which trained policy a result was made from."""
    import hashlib

    import numpy as np

    digest = hashlib.sha256()
    for name in sorted(weights):
        array = np.ascontiguousarray(weights[name])
        digest.update(f"{name}:{array.dtype}:{array.shape};".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()[:16]


def write_result(out: str | Path, key: str, payload: dict) -> Path:
    """Write a job's result atomically (a killed writer leaves no half file)."""
    path = result_path(out, key)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".tmp{os.getpid()}")
    tmp.write_text(json.dumps(payload) + "\n")
    os.replace(tmp, path)
    return path


class NotTrainedYet(ConfigError):
    """A suite entry the RL section reads has not finished training."""


def trained_run_dir(out: str | Path, entry: str) -> Path:
    """The seed-0 run of a suite entry, which must have finished training (all its rounds)."""

    run_dir = Path(out) / entry / "seed0"
    trained = rounds_trained(run_dir)
    if not trained or trained < load_config(run_dir / "config.yaml", plugins="none").training.num_rounds:
        raise NotTrainedYet(f"{run_dir} has not finished training yet: run 'gpl-dist suite run ... --only {entry} "
                            "--seeds 0' first")
    return run_dir


@dataclass(frozen=True)
class Pretrained:
    """An entry's trained policy (``rl-finetune`` starts from the instruction-only entry's)."""

    weights: Mapping[str, Any]
    """Its weights as numpy arrays (``state_dict_to_numpy``)."""
    model: ModelConfig
    """Its run's ``model`` section: the architecture the weights fit."""
    fingerprint: str
    """``policy_fingerprint(weights)``, recorded in every result made from it."""


def _trained(out: str | Path, entry: str) -> Pretrained:
    """An entry's trained policy (its training seed 0): weights, ``model`` section, fingerprint."""

    cfg, model, _ = load_trained_policy(trained_run_dir(out, entry))
    weights = state_dict_to_numpy(model)
    return Pretrained(weights, cfg.model, policy_fingerprint(weights))


def load_pretrained(out: str | Path, entry: str) -> Pretrained:
    """The trained policy of an instruction-only entry (its training seed 0)."""
    policy = _trained(out, entry)
    if policy.model.variant != "instruction_only":
        raise ConfigError(f"rl-finetune starts from an instruction-only policy; entry '{entry}' is {policy.model.variant}")
    return policy


def trained_fingerprint(out: str | Path, entry: str) -> str:
    """``policy_fingerprint`` of an entry's trained policy (its training seed 0)."""
    return _trained(out, entry).fingerprint


def run_attempts_job(job: AttemptsJob, plan: RLPlan, out: str | Path) -> dict:
    """Each RL task's completion after attempts 1..``ATTEMPTS`` of the entry's policy (meta-test)."""

    cfg, model, _ = load_trained_policy(trained_run_dir(out, job.entry))
    model.eval()
    tasks = plan.tasks[job.domain]
    attempts = meta_test_rollout(cfg, model).run(tasks, ATTEMPTS - 1, job.seed, split="rl").attempts
    per_task = [completion_by_attempt([a for a in attempts if a.task_id == t], ATTEMPTS).tolist() for t in tasks]
    return {"entry": job.entry, "domain": job.domain, "seed": job.seed, "variant": cfg.model.variant,
            "tasks": list(tasks), "completion": per_task, "policy": policy_fingerprint(state_dict_to_numpy(model))}


def attempts_current(out: str | Path, job: AttemptsJob, plan: RLPlan) -> bool:
    """Whether ``job``'s result is written for the plan's tasks of its domain, from the entry's
    current trained policy (an entry not trained yet keeps what is written)."""
    path = result_path(out, job.key)
    if not path.is_file():
        return False
    data = read_result(path)
    if data.get("tasks") != list(plan.tasks[job.domain]):
        return False
    try:
        return data.get("policy") == trained_fingerprint(out, job.entry)
    except NotTrainedYet:
        return True


def run_rl_plan(plan: RLPlan, out: str | Path, *, address: str | None = None, serial: bool = False,
                domains: tuple[str, ...] = (), log: Callable[[str], None] = print) -> int:
    """Run every job of ``plan`` whose result is not written yet; returns how many ran.

    The GPL/GPR points first (seconds each; an entry not trained yet is left for a later run), then
    the RL jobs, task by task: one after another with ``serial``, else each a Ray task (local Ray,
    or the cluster at ``address``).
    """

    commit = code_commit()  # read once: a commit made while the jobs run does not relabel them
    keep = (lambda d: d in domains) if domains else (lambda d: True)  # noqa: E731
    todo_attempts = [j for j in attempts_jobs(plan) if keep(j.domain) and not attempts_current(out, j, plan)]
    ran = 0
    for job in todo_attempts:
        try:
            write_result(out, job.key, {**run_attempts_job(job, plan, out), "commit": commit})
        except NotTrainedYet as err:  # the RL jobs do not need it
            log(f"[rl] {job.key} left for later: {err}")
            continue
        ran += 1
        log(f"[rl] {job.key} written")
    settings = {d: plan.settings(d) for d in plan.tasks}
    kept = [j for j in rl_jobs(plan) if keep(j.domain)]
    pretrained = {}
    for d in sorted({j.domain for j in kept if j.method == "rl-finetune"}):
        try:
            pretrained[d] = load_pretrained(out, plan.pretrained[d])
        except NotTrainedYet as err:  # its rl-finetune jobs wait; the others need nothing of it
            log(f"[rl] rl-finetune/{d} left for later: {err}")
    kept = [j for j in kept if j.method != "rl-finetune" or j.domain in pretrained]
    policy = lambda j: pretrained[j.domain].fingerprint if j.method == "rl-finetune" else None  # noqa: E731
    jobs = [j for j in kept if not is_current(out, j, settings[j.domain], policy(j))]
    log(f"[rl] {len(jobs)} RL job(s) to run ({len(kept) - len(jobs)} already done)")

    def finished(job, curve) -> None:
        write_result(out, job.key, {**curve.to_json(), "commit": commit, "policy": policy(job)})
        tail = curve.completion[-max(1, len(curve.completion) // 10):]
        solved = f", updates stopped at {curve.solved_at} (solved)" if curve.solved_at else ""
        log(f"[rl] {job.key}: {len(curve.completion)} trajectories in {curve.seconds:.0f}s, "
            f"completion over the last tenth {sum(tail) / len(tail):.3f}{solved}")

    if serial:
        for job in jobs:
            start = pretrained[job.domain] if job.method == "rl-finetune" else None
            weights, model = (dict(start.weights), start.model) if start else (None, None)
            finished(job, run_rl_job(job, settings[job.domain], weights, model))
    elif jobs:
        from gpl_dist.app.suite.rl.cluster import run_rl_on_ray

        run_rl_on_ray(jobs, settings, pretrained, address, finished, log)
    return ran + len(jobs)


def plan_of_copy(suite_yaml: str | Path) -> RLPlan | None:
    """The ``rl`` section of a suite file's copy (``OUT/suite.yaml``, written by ``suite run``),
    read without resolving its entries' base configs (relative to where the original lies); None
    when there is no copy or it has no ``rl`` section."""

    path = Path(suite_yaml)
    raw = load_yaml_text(path.read_text(), path) if path.is_file() else None
    if not isinstance(raw, dict) or "rl" not in raw:
        return None
    return parse_rl_plan(f"{path}: rl", raw["rl"], tuple(raw.get("entries") or ()))


def _of_plan(data: dict, key: str, plan: RLPlan, wanted: Mapping[str, Any]) -> bool:
    """Whether a result file's ``data`` is one of ``plan``'s jobs (``wanted``: key -> job), made as
    the plan says now: its job (task, seed, budget) and PPO settings, or for an attempts set its
    entry, seed and tasks."""

    job = wanted.get(key)
    if isinstance(job, AttemptsJob):
        return (AttemptsJob(data["entry"], data["domain"], data["seed"]) == job
                and data["tasks"] == list(plan.tasks[job.domain]))
    return (job is not None and RLJob(**data["job"]) == job
            and made_with(data.get("settings"), plan.settings(job.domain)))


def load_results(out: str | Path, plan: RLPlan | None = None) -> tuple[list, list[dict], dict[str, int], list[str]]:
    """Every RL curve (``gpl_dist.app.suite.rl.per_task.RLCurve``) and every attempts result under ``OUT/rl`` (with a
    ``plan``, only those of its jobs made with its settings), how many of them each code commit made
    (``unknown`` for results without one), and the keys of the results left out."""

    root = Path(out) / "rl"
    wanted = {j.key: j for j in [*rl_jobs(plan), *attempts_jobs(plan)]} if plan is not None else {}
    curves, attempts, left_out = [], [], []
    commits: dict[str, int] = {}
    for path in sorted(root.rglob("*.json")) if root.is_dir() else []:
        data = read_result(path)
        key = path.relative_to(root).with_suffix("").as_posix()
        if plan is not None and not _of_plan(data, key, plan, wanted):
            left_out.append(key)
            continue
        commit = data.get("commit", "unknown")
        commits[commit] = commits.get(commit, 0) + 1
        if path.parent.name == "attempts":
            attempts.append(data)
        else:
            curves.append(RLCurve.from_json(data))
    return curves, attempts, commits, left_out

"""The paper's sample-complexity comparison: RL per test task (``learner.rl``) against GPL and GPR,
which solve a new task within a handful of attempts.

A suite file's ``rl`` section names the test tasks of each domain (the same for every method),
the seeds, the budget of trajectories per task, the instruction-only entry each domain's
``rl-finetune`` starts from, and the entries (GPL, GPR) drawn as points. ``gpl-dist suite rl``
runs every (method, domain, task, seed) not yet done, one after another or as Ray tasks
(``gpl_dist.suite_ray.run_rl_on_ray``), and writes each result as it finishes:

- ``OUT/rl/<method>/<domain>/task<t>-seed<s>.json``: an ``RLCurve`` (every trajectory's completion);
- ``OUT/rl/attempts/<entry>-seed<s>.json``: each RL task's completion after attempts 1..6 of the
  entry's trained policy (its training seed 0), corrected by the run's oracle with evaluation seed ``s``.

A result made from a trained policy (``rl-finetune``'s start, the attempts) records that policy's
``policy_fingerprint``; once the entry is trained again, its results are redone. A killed run loses
only the jobs in flight; running it again does the rest. The report
(``gpl_dist.suite_report``) draws the figure from these files, from those of the suite's ``rl``
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

from gpl_dist.config import ConfigError, ModelConfig

#: Attempts drawn for GPL and GPR (the paper's figure: completion after k attempts at k trajectories).
ATTEMPTS = 6


@dataclass(frozen=True)
class RLPlan:
    """A suite's ``rl`` section."""

    tasks: Mapping[str, tuple[int, ...]]
    """Domain -> the test tasks every method learns (at least 20 each for the paper's figure)."""
    seeds: tuple[int, ...]
    """Seeds of every RL job and of the GPL/GPR rollouts."""
    trajectories: int
    """Training trajectories per RL job."""
    pretrained: Mapping[str, str]
    """Domain -> the suite entry (an instruction-only model) whose seed-0 run ``rl-finetune`` starts from."""
    attempts_from: Mapping[str, tuple[str, ...]]
    """Domain -> the suite entries (GPL, GPR) drawn as points at 1..6 trajectories."""
    ppo: Mapping[str, Any]
    """``learner.rl.PPOSettings`` fields that differ from their defaults, for every domain; a
    domain's name maps to its own further overrides (``relocation: {batch_size: 128}``)."""

    def settings(self, domain: str):
        """The ``learner.rl.PPOSettings`` of ``domain``'s jobs."""
        from learner.rl import PPOSettings

        common = {k: v for k, v in self.ppo.items() if not isinstance(v, Mapping)}
        return PPOSettings(**{**common, **self.ppo.get(domain, {})})


@dataclass(frozen=True)
class AttemptsJob:
    """Completion of one trained entry's attempts on the RL tasks of its domain."""

    entry: str
    domain: str
    seed: int

    @property
    def key(self) -> str:
        return f"attempts/{self.entry}-seed{self.seed}"


def parse_rl_plan(where: str, raw: Any, entry_names: tuple[str, ...]) -> RLPlan:
    """The ``rl`` section, checked: unknown keys, bad tasks, unknown entries or PPO settings fail in one line."""
    from gpl_dist.domains import get_domain
    from learner.rl import PPOSettings

    def expect(ok: bool, key: str, message: str) -> None:
        if not ok:
            raise ConfigError(f"{where}.{key}: {message}")

    expect(isinstance(raw, dict), "", "expected a mapping")
    allowed = {"tasks", "seeds", "trajectories", "pretrained", "attempts_from", "ppo"}
    unknown = sorted(set(raw) - allowed)
    expect(not unknown, unknown[0] if unknown else "", f"unknown key (known: {', '.join(sorted(allowed))})")
    missing = sorted({"tasks", "seeds", "trajectories"} - set(raw))
    expect(not missing, missing[0] if missing else "", "missing")
    expect(isinstance(raw["tasks"], dict) and bool(raw["tasks"]), "tasks", "expected domain: [task ids]")
    tasks = {}
    for domain, ids in raw["tasks"].items():
        spec = get_domain(domain)
        ok = isinstance(ids, list) and ids and all(isinstance(t, int) and not isinstance(t, bool) for t in ids)
        expect(bool(ok), f"tasks.{domain}", "expected a list of task ids")
        expect(all(0 <= t < spec.num_tasks for t in ids) and len(set(ids)) == len(ids), f"tasks.{domain}",
               f"task ids must be distinct and in 0..{spec.num_tasks - 1}")
        tasks[domain] = tuple(ids)
    seeds = raw["seeds"]
    expect(isinstance(seeds, list) and bool(seeds) and all(isinstance(s, int) and s >= 0 for s in seeds), "seeds",
           "expected a list of seeds >= 0")
    expect(isinstance(raw["trajectories"], int) and raw["trajectories"] >= 1, "trajectories", "expected an int >= 1")
    pretrained = raw.get("pretrained") or {}
    attempts_from = {d: tuple(v) for d, v in (raw.get("attempts_from") or {}).items()}
    for domain, name in [*pretrained.items(), *((d, n) for d, ns in attempts_from.items() for n in ns)]:
        expect(domain in tasks, f"{domain}", "names a domain without tasks")
        expect(name in entry_names, f"{domain}", f"no entry '{name}'")
    ppo = raw.get("ppo") or {}
    expect(isinstance(ppo, dict), "ppo", "expected a mapping of PPO settings")
    for domain in (k for k in ppo if k in tasks):
        expect(isinstance(ppo[domain], dict), f"ppo.{domain}", "expected a mapping of PPO settings")
    types = {f.name: str(f.type) for f in dataclasses.fields(PPOSettings)}  # "int", "float" or "bool"
    least = {"n_envs": 1, "n_steps": 0, "batch_size": 2, "n_epochs": 1, "value_hidden": 1}  # SB3 wants minibatches > 1
    overrides = [("ppo.", {k: v for k, v in ppo.items() if k not in tasks})]
    overrides += [(f"ppo.{d}.", ppo[d]) for d in ppo if d in tasks]
    for prefix, settings in overrides:
        for key, value in settings.items():
            expect(key in types, f"{prefix}{key}", f"unknown PPO setting (known: {', '.join(sorted(types))}, or a domain)")
            kind = types[key]
            if kind == "bool":
                expect(isinstance(value, bool), f"{prefix}{key}", "expected true or false")
            elif kind == "int":
                ok = isinstance(value, int) and not isinstance(value, bool) and value >= least.get(key, 0)
                expect(ok, f"{prefix}{key}", f"expected a whole number >= {least.get(key, 0)}")
            else:
                ok = isinstance(value, (int, float)) and not isinstance(value, bool) and value >= 0
                expect(ok, f"{prefix}{key}", "expected a number >= 0")
    return RLPlan(tasks, tuple(seeds), raw["trajectories"], dict(pretrained), attempts_from, dict(ppo))


def rl_jobs(plan: RLPlan, methods: tuple[str, ...] | None = None) -> list:
    """Every RL job of ``plan``: methods x domains x tasks x seeds (``rl-finetune`` only where a
    domain names its pretrained entry)."""
    from learner.rl import RL_METHODS, RLJob

    jobs = []  # task by task, every method of a task together: a partial run compares them on the same tasks
    for domain, tasks in plan.tasks.items():
        for seed in plan.seeds:
            for t in tasks:
                for method in methods or RL_METHODS:
                    if method == "rl-finetune" and domain not in plan.pretrained:
                        continue
                    pretrained = plan.pretrained.get(domain, "") if method == "rl-finetune" else ""
                    jobs.append(RLJob(method, domain, t, seed, plan.trajectories, pretrained))
    return jobs


def attempts_jobs(plan: RLPlan) -> list[AttemptsJob]:
    """Every (entry, seed) drawn as points."""
    return [AttemptsJob(entry, domain, seed) for domain, entries in plan.attempts_from.items()
            for entry in entries for seed in plan.seeds]


def result_path(out: str | Path, key: str) -> Path:
    """Where a job's result lives: ``OUT/rl/<key>.json``."""
    return Path(out) / "rl" / f"{key}.json"


def is_current(out: str | Path, job, settings, policy: str | None = None) -> bool:
    """Whether ``job``'s result is written for this very job (its budget is not in the file's
    name), made with ``settings`` (``learner.rl.PPOSettings``) and, for a job that starts from a
    trained policy, from the one of fingerprint ``policy``."""
    from learner.rl import RLJob

    path = result_path(out, job.key)
    if not path.is_file():
        return False
    data = json.loads(path.read_text())
    return (RLJob(**data["job"]) == job and data.get("settings") == dataclasses.asdict(settings)
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
    from gpl_dist.config import load_config
    from learner.checkpoint import rounds_trained

    run_dir = Path(out) / entry / "seed0"
    trained = rounds_trained(run_dir)
    if not trained or trained < load_config(run_dir / "config.yaml").training.num_rounds:
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
    from gpl_dist.models.gpl import state_dict_to_numpy
    from learner.evaluate import load_trained_policy

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
    from gpl_dist.models.gpl import state_dict_to_numpy
    from learner.evaluate import load_trained_policy, meta_test_rollout
    from workers.rollout import completion_by_attempt

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
    data = json.loads(path.read_text())
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
    from gpl_dist.suite import code_commit
    from learner.rl import run_rl_job

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
        from gpl_dist.suite_ray import run_rl_on_ray

        run_rl_on_ray(jobs, settings, pretrained, address, finished, log)
    return ran + len(jobs)


def plan_of_copy(suite_yaml: str | Path) -> RLPlan | None:
    """The ``rl`` section of a suite file's copy (``OUT/suite.yaml``, written by ``suite run``),
    read without resolving its entries' base configs (relative to where the original lies); None
    when there is no copy or it has no ``rl`` section."""
    import yaml

    path = Path(suite_yaml)
    raw = yaml.safe_load(path.read_text()) if path.is_file() else None
    if not isinstance(raw, dict) or "rl" not in raw:
        return None
    return parse_rl_plan(f"{path}: rl", raw["rl"], tuple(raw.get("entries") or ()))


def _of_plan(data: dict, key: str, plan: RLPlan, wanted: Mapping[str, Any]) -> bool:
    """Whether a result file's ``data`` is one of ``plan``'s jobs (``wanted``: key -> job), made as
    the plan says now: its job (task, seed, budget) and PPO settings, or for an attempts set its
    entry, seed and tasks."""
    from learner.rl import RLJob

    job = wanted.get(key)
    if isinstance(job, AttemptsJob):
        return (AttemptsJob(data["entry"], data["domain"], data["seed"]) == job
                and data["tasks"] == list(plan.tasks[job.domain]))
    return (job is not None and RLJob(**data["job"]) == job
            and data.get("settings") == dataclasses.asdict(plan.settings(job.domain)))


def load_results(out: str | Path, plan: RLPlan | None = None) -> tuple[list, list[dict], dict[str, int], list[str]]:
    """Every RL curve (``learner.rl.RLCurve``) and every attempts result under ``OUT/rl`` (with a
    ``plan``, only those of its jobs made with its settings), how many of them each code commit made
    (``unknown`` for results without one), and the keys of the results left out."""
    from learner.rl import RLCurve

    root = Path(out) / "rl"
    wanted = {j.key: j for j in [*rl_jobs(plan), *attempts_jobs(plan)]} if plan is not None else {}
    curves, attempts, left_out = [], [], []
    commits: dict[str, int] = {}
    for path in sorted(root.rglob("*.json")) if root.is_dir() else []:
        data = json.loads(path.read_text())
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


def sample_complexity_section(suite_out: str | Path, out: str | Path, read_from: str | Path | None = None,
                              plan: RLPlan | None = None) -> tuple[str, Path | None]:
    """The report's sample-complexity section (Markdown) and its figure, from ``OUT/rl`` (or the
    same files in ``read_from``, the report's archive of them), with a ``plan`` only the results of
    its jobs (results of an older task list, budget or PPO settings would mix into the medians);
    an empty text when nothing has run."""
    import numpy as np

    from learner.rl import log_points, summarize

    curves, attempts, commits, left_out = load_results(read_from if read_from is not None else suite_out, plan)
    if not curves and not attempts:
        return "", None
    domains = sorted({c.job.domain for c in curves} | {a["domain"] for a in attempts})
    lines = ["Completion on each test task against the trajectories spent on it: PPO (stable-baselines3) per task from "
             "scratch and fine-tuned from the DAgger-trained instruction-only policy, each training trajectory's final "
             "completion (mean over the last tenth of the trajectories up to each point); GPL and GPR after k attempts "
             "(k - 1 corrections) at k trajectories. Median over tasks, interquartile range in brackets. PPO stops "
             "updating once every copy of the task solved it in one round of episodes (where the authors' expert "
             "training stopped; the rest of the budget samples that policy); the last column counts those tasks and "
             "the median trajectories at which it happened. 'Trajectories to reach GPL' is the first count at which "
             "a method's median reaches GPL's median after 5 corrections on the same tasks. Made by "
             f"`gpl-dist suite rl configs/suites/paper.yaml --out {suite_out}`.", "",
             "| domain | method | tasks x seeds | after 1 | 3 | 6 | 10 | 100 | 1000 | last "
             "| trajectories to reach GPL after 5 corrections | solved (updates stopped), median trajectories |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    fig_rows: dict[str, dict[str, tuple]] = {}
    for domain in domains:
        gpl_by_task: dict[int, float] = {}  # GPL's completion after 5 corrections (mean over seeds), per task
        rows: dict[str, tuple] = {}
        for entry in sorted({a["entry"] for a in attempts if a["domain"] == domain}):
            per = np.mean([np.array(a["completion"]) for a in attempts if a["entry"] == entry], axis=0)  # tasks x attempts
            med, q25, q75 = np.median(per, 0), np.percentile(per, 25, 0), np.percentile(per, 75, 0)
            ks = tuple(range(1, per.shape[1] + 1))
            variant = next(a["variant"] for a in attempts if a["entry"] == entry)
            rows[entry] = (ks, med, q25, q75, variant)
            if variant == "gpl":
                tasks = next(a["tasks"] for a in attempts if a["entry"] == entry)
                gpl_by_task = dict(zip(tasks, per[:, -1].tolist()))
            cells = [_q(med, q25, q75, k - 1) if k <= len(ks) else "" for k in (1, 3, 6)]
            seeds = len({a["seed"] for a in attempts if a["entry"] == entry})
            lines.append(f"| {domain} | {entry} ({variant}) | {per.shape[0]} x {seeds} | {' | '.join(cells)} | | | | | | |")
        for method in sorted({c.job.method for c in curves if c.job.domain == domain}):
            mine = [c for c in curves if c.job.domain == domain and c.job.method == method]
            budget = min(len(c.completion) for c in mine)
            points = tuple(sorted(set(log_points(budget)) | {p for p in _COLUMNS if p <= budget}))
            s = summarize(mine, points)
            rows[method] = (points, np.array(s.median), np.array(s.q25), np.array(s.q75), method)
            at = {p: i for i, p in enumerate(points)}
            cells = [_q(s.median, s.q25, s.q75, at[p]) if p in at else "" for p in _COLUMNS]
            reach = _first_reach(mine, gpl_by_task)
            stops = [c.solved_at for c in mine if c.solved_at is not None]
            solved = f"{len(stops)} of {len(mine)}" + (f", {int(np.median(stops))}" if stops else "")
            lines.append(f"| {domain} | {method} | {len(mine)} | {' | '.join(cells)} | "
                         f"{_q(s.median, s.q25, s.q75, len(points) - 1)} | {reach} | {solved} |")
        fig_rows[domain] = rows
    seconds = sum(c.seconds for c in curves)
    made_by = ", ".join(f"`{c}` ({n})" for c, n in sorted(commits.items()))
    lines += ["", f"RL wall time: {seconds / 3600:.1f} hours summed over {len(curves)} jobs (one process each; more than "
              "their CPU time where other runs shared the cores). The paper: "
              "RL needs more than 1000 trajectories per task to reach GPL's completion after 5 corrections.", "",
              f"Code commits of these results (results each): {made_by}."]
    if plan is not None:
        lines += _not_run_yet(plan, curves, attempts)
    if left_out:
        lines += ["", f"Left out: {len(left_out)} result(s) under `rl/` that are not jobs of the suite's `rl` section "
                  f"as it stands (another task list, budget or PPO settings), e.g. `{left_out[0]}`."]
    png = Path(out) / "sample-complexity.png"
    _plot(fig_rows, png)
    return "\n".join(lines), png


#: trajectory counts of the table's columns
_COLUMNS = (1, 3, 6, 10, 100, 1000)


def _q(med, q25, q75, i: int) -> str:
    return f"{med[i]:.2f} [{q25[i]:.2f}, {q75[i]:.2f}]"


def _first_reach(curves: list, gpl_by_task: Mapping[int, float]) -> str:
    """The first trajectory count at which the median over ``curves``' tasks reaches GPL's median
    after 5 corrections on the same tasks (empty without GPL points on each of them)."""
    import numpy as np

    from learner.rl import summarize

    tasks = [c.job.task_id for c in curves]
    if not tasks or any(t not in gpl_by_task for t in tasks):
        return ""
    target = float(np.median([gpl_by_task[t] for t in tasks]))
    budget = min(len(c.completion) for c in curves)
    every = tuple(range(1, budget + 1))
    for p, m in zip(every, summarize(curves, every).median):
        if m >= target:
            return f"{p} (GPL: {target:.2f})"
    return f"not within {budget} (GPL: {target:.2f})"


def _not_run_yet(plan: RLPlan, curves: list, attempts: list[dict]) -> list[str]:
    """A line naming how many of the plan's jobs have no result yet, per domain and method."""
    done = {c.job.key for c in curves} | {AttemptsJob(a["entry"], a["domain"], a["seed"]).key for a in attempts}
    planned: dict[tuple[str, str], list[bool]] = {}
    for job in [*attempts_jobs(plan), *rl_jobs(plan)]:
        what = job.entry if isinstance(job, AttemptsJob) else job.method
        planned.setdefault((job.domain, what), []).append(job.key in done)
    missing = [f"{domain} {what}: {len(flags) - sum(flags)} of {len(flags)}"
               for (domain, what), flags in sorted(planned.items()) if not all(flags)]
    if not missing:
        return []
    return ["", "Not run yet (jobs of the suite's `rl` section without a result; `gpl-dist suite rl` runs them): "
            + "; ".join(missing) + "."]


def _plot(fig_rows: dict[str, dict[str, tuple]], png: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter

    from learner.rl import RL_METHODS

    fig, axes = plt.subplots(1, len(fig_rows), figsize=(5.5 * len(fig_rows), 3.8), dpi=110, squeeze=False)
    kinds = sorted({kind for rows in fig_rows.values() for *_, kind in rows.values()})
    colour = {kind: f"C{i % 10}" for i, kind in enumerate(kinds)}  # a method has one colour in every panel
    for ax, (domain, rows) in zip(axes[0], fig_rows.items()):
        for name, (xs, med, q25, q75, kind) in rows.items():
            if kind in RL_METHODS:
                ax.plot(xs, med, label=name, color=colour[kind])
                ax.fill_between(xs, q25, q75, alpha=0.2, color=colour[kind])
            else:  # an entry's points at k attempts, coloured by its variant (gpl, gpr)
                ax.errorbar(xs, med, yerr=[med - q25, q75 - med], marker="o", capsize=3, label=name, color=colour[kind])
        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{x:g}"))  # 1, 10, 100, not 10^0
        ax.xaxis.set_minor_formatter(FuncFormatter(lambda x, _: ""))
        ax.set_xlim(0.8, 1.25 * max([10, *(max(xs) for xs, *_ in rows.values())]))  # at least one decade
        ax.set_ylim(0, 1.02)
        ax.set_xlabel("trajectories on the task")
        ax.set_ylabel("completion (median over tasks)")
        ax.set_title(domain)
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png)
    plt.close(fig)

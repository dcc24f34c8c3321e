"""A suite file's ``rl`` section: the sample-complexity comparison's plan (``RLPlan``) and its jobs.

RL per test task (``gpl_dist.app.suite.rl.per_task``) against GPL and GPR; ``gpl_dist.app.suite.rl.jobs`` runs the
jobs and ``gpl_dist.app.suite.rl.report`` draws the figure.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Mapping

from gpl_dist.app.suite.rl.per_task import RL_METHODS, RLJob
from gpl_dist.config import ConfigError
from gpl_dist.domains import get_domain, is_loaded
from learner.ppo import PPOSettings

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
    """``learner.ppo.PPOSettings`` fields that differ from their defaults, for every domain; a
    domain's name maps to its own further overrides (``relocation: {batch_size: 128}``)."""

    def settings(self, domain: str):
        """The ``learner.ppo.PPOSettings`` of ``domain``'s jobs."""

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
        ok = isinstance(ids, list) and ids and all(isinstance(t, int) and not isinstance(t, bool) for t in ids)
        expect(bool(ok), f"tasks.{domain}", "expected a list of task ids")
        expect(len(set(ids)) == len(ids), f"tasks.{domain}", "task ids must be distinct")
        if is_loaded(domain):  # an installed plug-in's domain is not imported to read a suite file: checked when run
            num_tasks = get_domain(domain).num_tasks
            expect(all(0 <= t < num_tasks for t in ids), f"tasks.{domain}", f"task ids must be in 0..{num_tasks - 1}")
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
    # "int", "float", "bool" or "float | None"
    types = {f.name: str(f.type) for f in dataclasses.fields(PPOSettings)}
    # SB3 wants minibatches > 1
    least = {"n_envs": 1, "n_steps": 0, "batch_size": 2, "n_epochs": 1, "value_hidden": 1, "value_layers": 1}
    overrides = [("ppo.", {k: v for k, v in ppo.items() if k not in tasks})]
    overrides += [(f"ppo.{d}.", ppo[d]) for d in ppo if d in tasks]
    for prefix, settings in overrides:
        for key, value in settings.items():
            expect(key in types, f"{prefix}{key}", f"unknown PPO setting (known: {', '.join(sorted(types))}, or a domain)")
            kind = types[key]
            if kind.endswith(" | None") and value is None:
                continue  # an optional setting left unset (null)
            kind = kind.removesuffix(" | None")
            if kind == "bool":
                expect(isinstance(value, bool), f"{prefix}{key}", "expected true or false")
            elif kind == "int":
                ok = isinstance(value, int) and not isinstance(value, bool) and value >= least.get(key, 0)
                expect(ok, f"{prefix}{key}", f"expected a whole number >= {least.get(key, 0)}")
            else:
                ok = isinstance(value, (int, float)) and not isinstance(value, bool) and value >= 0
                expect(ok, f"{prefix}{key}", "expected a number >= 0" + (" or null" if types[key] != kind else ""))
    return RLPlan(tasks, tuple(seeds), raw["trajectories"], dict(pretrained), attempts_from, dict(ppo))


def rl_jobs(plan: RLPlan, methods: tuple[str, ...] | None = None) -> list:
    """Every RL job of ``plan``: methods x domains x tasks x seeds (``rl-finetune`` only where a
    domain names its pretrained entry)."""

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

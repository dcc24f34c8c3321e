"""The report's sample-complexity section: RL curves per method against GPL's and GPR's attempts,
as a table and a figure, from the results ``jobs.load_results`` reads.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

from gpl_dist.app.suite.rl.jobs import load_results
from gpl_dist.app.suite.rl.per_task import RL_METHODS, log_points, summarize
from gpl_dist.app.suite.rl.plan import AttemptsJob, RLPlan, attempts_jobs, rl_jobs
from gpl_dist.atomic import savefig_atomic


def sample_complexity_section(suite_out: str | Path, out: str | Path, read_from: str | Path | None = None,
                              plan: RLPlan | None = None) -> tuple[str, Path | None]:
    """The report's sample-complexity section (Markdown) and its figure, from ``OUT/rl`` (or the
    same files in ``read_from``, the report's archive of them), with a ``plan`` only the results of
    its jobs (results of an older task list, budget or PPO settings would mix into the medians);
    an empty text when nothing has run."""
    import numpy as np


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


    fig, axes = plt.subplots(1, len(fig_rows), figsize=(5.5 * len(fig_rows), 3.8), dpi=110, squeeze=False)
    kinds = sorted({kind for rows in fig_rows.values() for *_, kind in rows.values()})
    colour = {kind: f"C{i % 10}" for i, kind in enumerate(kinds)}  # a method has one colour in every panel
    readable = {"rl-scratch": "PPO from scratch", "rl-finetune": "PPO from the instruction-only policy"}
    for ax, (domain, rows) in zip(axes[0], fig_rows.items()):
        for name, (xs, med, q25, q75, kind) in rows.items():
            name = readable.get(name, name.removeprefix(f"{domain}-").replace("gpl", "GPL").replace("gpr", "GPR"))
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
        ax.legend(loc="lower right", fontsize=7, title="median over tasks; band, bars: quartiles", title_fontsize=7)
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    savefig_atomic(fig, png)
    plt.close(fig)

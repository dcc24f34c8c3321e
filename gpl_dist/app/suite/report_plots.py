"""The report's plots, drawn apart from its text: completion against corrections (a table's rows,
or a suite's entries) and completion over DAgger rounds (learning curves). Each is written whole
(``gpl_dist.atomic.savefig_atomic``) and enters the report as a ``report_render.Image``.
"""

from __future__ import annotations

import statistics
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from gpl_dist.app.suite.report_data import Cell
from gpl_dist.app.suite.run_facts import LearningCurve
from gpl_dist.atomic import savefig_atomic


@dataclass(frozen=True)
class PlotRow:
    """One line of a completion plot: ours over training seeds at ``columns``, and where a paper
    has numbers for it, the paper's."""

    label: str
    columns: tuple[int, ...]
    cells: tuple[Cell | None, ...]
    """Ours after each of ``columns`` corrections (None: no run)."""
    paper: tuple[float | None, ...] = ()


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_completion(rows: Sequence[PlotRow], columns: tuple[int, ...], title: str, path: Path, ours: str = "ours, ") -> bool:
    """Completion against corrections (ours solid with the band of the 95 % interval over training
    seeds, the paper's dashed where it has numbers; a row without corrections, a baseline, as a
    level line across); False, and nothing drawn, when no row has more than one column. ``ours``:
    what a legend entry says before its seeds (beside a paper's numbers: "ours, ")."""
    if not any(len(r.columns) > 1 for r in rows):
        return False
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7.2, 3.6), dpi=110)
    span = (min(columns), max(columns))
    for i, row in enumerate(rows):
        color = f"C{i}"
        flat = len(row.columns) == 1
        if any(p is not None for p in row.paper):
            xs = span if flat else row.columns
            ys = [float("nan") if p is None else p for p in ((row.paper[0],) * 2 if flat else row.paper)]
            ax.plot(xs, ys, ":" if flat else "--", color=color, alpha=0.7, label=f"{row.label} (paper)")
        cells = row.cells
        if not any(c is not None for c in cells):
            continue
        ks = [k for k, c in zip(row.columns, cells) if c is not None]
        means = [c.mean for c in cells if c is not None]
        half = [c.ci.half_width or 0.0 for c in cells if c is not None]
        if flat:
            ks, means, half = list(span), means * 2, half * 2
        seeds = max(c.n for c in cells if c is not None)
        ax.plot(ks, means, "-" if flat else "o-", color=color, label=f"{row.label} ({ours}{seeds} seeds)")
        ax.fill_between(ks, [m - h for m, h in zip(means, half)], [m + h for m, h in zip(means, half)], color=color, alpha=0.15)
    ax.set_xlabel("corrections")
    ax.set_ylabel("completion")
    ax.set_ylim(0, 1)
    ax.set_xticks(columns)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), title="band: 95 % interval", title_fontsize=7)
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    savefig_atomic(fig, path)
    plt.close(fig)
    return True


def plot_curves(curves: Mapping[str, Sequence[LearningCurve]], path: Path) -> bool:
    """Completion over DAgger rounds of each entry of ``curves`` (its runs' curves, in the order
    given), mean over its runs: on the training tasks during collection (after the last
    correction), and on the valid split where computed; False, and nothing drawn, without entries."""
    if not curves:
        return False
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(9.5, 3.6), dpi=110, sharey=True)
    for i, (entry, runs) in enumerate(curves.items()):
        for ax, part in zip(axes, ("train", "valid")):
            series = [(c.rounds if part == "train" else c.valid_rounds, getattr(c, part)) for c in runs]
            series = [(rs, v) for rs, v in series if v]
            if not series:
                continue
            n = min(len(v) for _, v in series)
            ys = [statistics.fmean(v[j][-1] for _, v in series) for j in range(n)]
            ax.plot(series[0][0][:n], ys, marker="o", ms=3, color=f"C{i % 10}", ls="-" if i < 10 else "--",
                    label=f"{entry} ({len(series)})")
    axes[0].set_title("training tasks, during collection (last attempt)", fontsize=8)
    axes[1].set_title("valid split, each round's weights (last attempt)", fontsize=8)
    for ax in axes:
        ax.set_xlabel("DAgger round")
        ax.grid(alpha=0.3)
        ax.set_ylim(0, 1)
    axes[0].set_ylabel("completion")
    axes[1].legend(*axes[0].get_legend_handles_labels(), fontsize=6, loc="upper left", bbox_to_anchor=(1.01, 1.0),
                   title="entry (runs)", title_fontsize=6)
    fig.tight_layout()
    savefig_atomic(fig, path)
    plt.close(fig)
    return True

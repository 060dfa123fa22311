"""PNG plots (matplotlib, Agg backend): uncertainty over an episode, and a bar chart of the table."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from sb3_pm.evaluation.harness import EvaluationResult
from sb3_pm.evaluation.statistics import Summary, split_by_graph


def _pyplot():  # type: ignore[no-untyped-def]
    import matplotlib

    matplotlib.use("Agg", force=False)  # no display needed; keeps headless runs working
    import matplotlib.pyplot as plt

    return plt


def plot_uncertainty(
    by_policy: Mapping[str, Sequence[EvaluationResult]], path: str | Path, title: str | None = None
) -> Path:
    """Summed target uncertainty per step, one line per policy (mean over its episodes, ±1 SD band).

    One panel per graph: graphs' scales differ several-fold, and a band pooled over them would
    mostly show the spread between graphs. Episodes of different lengths are cut to the shortest,
    so every line of a panel covers the same steps.
    """
    plt = _pyplot()
    split = split_by_graph(by_policy)
    graphs = list(split)
    figure, axes_row = plt.subplots(1, max(1, len(graphs)), figsize=(5 * max(1, len(graphs)) + 2, 4), dpi=100)
    axes_list = np.atleast_1d(axes_row)
    for axes, graph in zip(axes_list, graphs):
        for policy, results in split[graph].items():
            traces = [record.trace for result in results for record in result.episodes]
            if not traces:
                continue
            length = min(len(trace) for trace in traces)
            stacked = np.stack([trace[:length] for trace in traces])
            mean, sd = stacked.mean(axis=0), stacked.std(axis=0)
            steps = np.arange(1, length + 1)
            (line,) = axes.plot(steps, mean, label=policy, linewidth=1.2)
            axes.fill_between(steps, mean - sd, mean + sd, color=line.get_color(), alpha=0.15, linewidth=0)
        axes.set_xlabel("step")
        axes.set_ylabel("summed target uncertainty")
        axes.set_title(
            graph if len(graphs) > 1 else (title or f"Target uncertainty over an episode ({graph})")
        )
        axes.grid(alpha=0.3)
    axes_list[-1].legend(loc="best", fontsize="small")
    if len(graphs) > 1:
        figure.suptitle(title or "Target uncertainty over an episode")
    figure.tight_layout()
    path = Path(path)
    figure.savefig(path)
    plt.close(figure)
    return path


def plot_table(table: Mapping[str, Mapping[str, Summary]], path: str | Path) -> Path:
    """Two bar panels (Avg. Uncertainty, Avg. Neglect Time) with SD error bars, one bar per policy."""
    plt = _pyplot()
    policies = list(table)
    figure, axes = plt.subplots(1, 2, figsize=(9, 3.6), dpi=100)
    for ax, (metric, label) in zip(
        axes, (("avg_uncertainty", "Avg. Uncertainty"), ("max_neglect", "Avg. Neglect Time"))
    ):
        means = [table[p][metric].mean for p in policies]
        sds = [table[p][metric].sd for p in policies]
        ax.bar(range(len(policies)), means, yerr=sds, capsize=3, color="tab:blue", alpha=0.8)
        ax.set_xticks(range(len(policies)))
        ax.set_xticklabels(policies, rotation=30, ha="right", fontsize="small")
        ax.set_title(label)
        ax.grid(axis="y", alpha=0.3)
    figure.tight_layout()
    path = Path(path)
    figure.savefig(path)
    plt.close(figure)
    return path

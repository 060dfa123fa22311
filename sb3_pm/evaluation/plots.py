"""PNG plots (matplotlib, Agg backend): uncertainty over an episode, and a bar chart of the table."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from sb3_pm.evaluation.harness import EvaluationResult
from sb3_pm.evaluation.statistics import Summary


def _pyplot():  # type: ignore[no-untyped-def]
    import matplotlib

    matplotlib.use("Agg", force=False)  # no display needed; keeps headless runs working
    import matplotlib.pyplot as plt

    return plt


def plot_uncertainty(
    by_policy: Mapping[str, Sequence[EvaluationResult]], path: str | Path, title: str | None = None
) -> Path:
    """Summed target uncertainty per step, one line per policy (mean over its episodes, ±1 SD band).

    Episodes of different lengths are cut to the shortest, so every line covers the same steps.
    """
    plt = _pyplot()
    figure, axes = plt.subplots(figsize=(7, 4), dpi=100)
    for policy, results in by_policy.items():
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
    axes.set_title(title or "Target uncertainty over an episode")
    axes.legend(loc="best", fontsize="small")
    axes.grid(alpha=0.3)
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

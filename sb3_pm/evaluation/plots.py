"""PNG plots (matplotlib, Agg backend): uncertainty over an episode, and a bar chart of the table."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sb3_pm.evaluation.harness import EvaluationResult
from sb3_pm.evaluation.statistics import Summary, split_by_graph
from sb3_pm.files import atomic_path


def _pyplot():  # type: ignore[no-untyped-def]
    import matplotlib

    matplotlib.use("Agg", force=False)  # no display needed; keeps headless runs working
    import matplotlib.pyplot as plt

    return plt


def save_figure(figure: Any, path: str | Path, **kwargs: Any) -> Path:
    """``figure.savefig`` through a temporary file renamed over ``path``
    (:func:`~sb3_pm.files.atomic_path`): a full disk leaves the previous picture, not half of one.
    The format is the one ``path``'s suffix names (the temporary name has none of its own)."""
    path = Path(path)
    with atomic_path(path) as temporary:
        figure.savefig(temporary, format=path.suffix.lstrip(".") or None, **kwargs)
    return path


#: Above this many lines a legend goes beside the axes instead of over the curves.
LEGEND_INSIDE_MAX = 6


def line_colors(n: int) -> list[tuple[float, float, float, float]]:
    """``n`` distinguishable RGBA colours, one per line.

    matplotlib's default cycle repeats after 10 lines, so a sweep of 16 variants would draw pairs of
    lines in one colour: up to 10 lines use ``tab10`` (the default look), up to 20 ``tab20``, and
    beyond that evenly spaced samples of ``turbo``.
    """
    from matplotlib import colormaps

    if n <= 10:
        return [colormaps["tab10"](i) for i in range(n)]
    if n <= 20:
        return [colormaps["tab20"](i) for i in range(n)]
    return [colormaps["turbo"](x) for x in np.linspace(0.0, 1.0, n)]


def add_legend(axes, n_entries: int) -> None:  # type: ignore[no-untyped-def]
    """A legend over the axes for a few lines, beside them (right, outside) for many, so that it
    never hides the curves; save such figures with ``bbox_inches="tight"`` to keep it in frame."""
    if n_entries <= LEGEND_INSIDE_MAX:
        axes.legend(loc="best", fontsize="small")
    else:
        axes.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0, fontsize="small")
        # Widen the figure by about the legend's width, so the panels keep their size.
        width, height = axes.figure.get_size_inches()
        axes.figure.set_size_inches(width + 3.0, height)


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
    # One colour per policy, the same in every panel.
    policies = list(dict.fromkeys(policy for graph in graphs for policy in split[graph]))
    colors = dict(zip(policies, line_colors(len(policies))))
    for axes, graph in zip(axes_list, graphs):
        for policy, results in split[graph].items():
            traces = [record.trace for result in results for record in result.episodes]
            if not traces:
                continue
            length = min(len(trace) for trace in traces)
            stacked = np.stack([trace[:length] for trace in traces])
            mean, sd = stacked.mean(axis=0), stacked.std(axis=0)
            steps = np.arange(1, length + 1)
            axes.plot(steps, mean, label=policy, linewidth=1.2, color=colors[policy])
            axes.fill_between(steps, mean - sd, mean + sd, color=colors[policy], alpha=0.15, linewidth=0)
        axes.set_xlabel("step")
        axes.set_ylabel("summed target uncertainty")
        axes.set_title(
            graph if len(graphs) > 1 else (title or f"Target uncertainty over an episode ({graph})")
        )
        axes.grid(alpha=0.3)
    add_legend(axes_list[-1], len(policies))
    if len(graphs) > 1:
        figure.suptitle(title or "Target uncertainty over an episode")
    figure.tight_layout()
    path = Path(path)
    save_figure(figure, path, bbox_inches="tight")
    plt.close(figure)
    return path


def plot_table(table: Mapping[str, Mapping[str, Summary]], path: str | Path) -> Path:
    """Two bar panels (Avg. Uncertainty, Max Neglect) with SD error bars, one bar per policy."""
    plt = _pyplot()
    policies = list(table)
    figure, axes = plt.subplots(1, 2, figsize=(9, 3.6), dpi=100)
    for ax, (metric, label) in zip(
        axes, (("avg_uncertainty", "Avg. Uncertainty"), ("max_neglect", "Max Neglect (steps)"))
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
    save_figure(figure, path)
    plt.close(figure)
    return path

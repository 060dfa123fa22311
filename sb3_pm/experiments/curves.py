"""Training curves of a sweep, read back from the cells' TensorBoard logs.

Two figures: ``training.png`` (the episode metric ``metrics/avg_uncertainty`` against each
learner's timesteps) and ``estimator_loss.png`` (``estimator/loss``), one panel per graph and one
line per variant: the mean over its seeds and agents at each logged step.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

CURVES = {"training.png": "metrics/avg_uncertainty", "estimator_loss.png": "estimator/loss"}


def read_scalars(log_dir: Path, tag: str) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(steps, values)`` of ``tag`` for every TensorBoard run under ``log_dir``."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    series = []
    for run in sorted({path.parent for path in log_dir.rglob("events.out.tfevents.*")}):
        accumulator = EventAccumulator(str(run), size_guidance={"scalars": 0})
        accumulator.Reload()
        if tag in accumulator.Tags().get("scalars", []):
            events = accumulator.Scalars(tag)
            series.append((np.array([e.step for e in events]), np.array([e.value for e in events])))
    return series


def _mean_curve(series: Sequence[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Average curves on their common step grid (runs of a sweep log at the same steps)."""
    by_step: dict[int, list[float]] = defaultdict(list)
    for steps, values in series:
        for step, value in zip(steps.tolist(), values.tolist()):
            by_step[step].append(value)
    steps = np.array(sorted(by_step))
    return steps, np.array([np.mean(by_step[s]) for s in steps])


def _steps_per_learner(cell: Any) -> int:
    """What one logged step is worth in steps per learner: a centralized model logs the steps of all
    ``n_agents`` agents, a decentralized learner its own."""
    return cell.n_agents if cell.variant.get("kind") == "centralized" else 1


def plot_training_curves(cells: Sequence[Any], out: Path) -> list[Path]:
    """Write the figures of :data:`CURVES` for the learned cells that logged them.

    One panel per graph (their scales differ several-fold), one line per variant: the mean over
    its seeds and agents, against steps per learner (a centralized model's steps divided by its
    agents, so both kinds of team share the axis).
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    from sb3_pm.evaluation.plots import add_legend, line_colors, save_figure
    from sb3_pm.graphs import graph_label

    written = []
    for filename, tag in CURVES.items():
        panels: dict[str, dict[str, list[tuple[np.ndarray, np.ndarray]]]] = defaultdict(
            lambda: defaultdict(list)
        )
        for cell in cells:
            log_dir = Path(cell.folder) / "tb"
            if log_dir.is_dir():
                scale = _steps_per_learner(cell)
                series = [(steps // scale, values) for steps, values in read_scalars(log_dir, tag)]
                if series:
                    panels[graph_label(cell.graph)][cell.variant["label"]].extend(series)
        if not panels:
            continue
        # One colour per variant, the same in every panel.
        labels = list(dict.fromkeys(label for per_variant in panels.values() for label in per_variant))
        colors = dict(zip(labels, line_colors(len(labels))))
        figure, axes_row = plt.subplots(1, len(panels), figsize=(5 * len(panels) + 1, 4), squeeze=False)
        for axes, (graph, per_variant) in zip(axes_row[0], panels.items()):
            for label, series in per_variant.items():
                steps, values = _mean_curve(series)
                axes.plot(steps, values, label=label, color=colors[label])
            axes.set_xlabel("timesteps per learner")
            axes.set_ylabel(tag)
            axes.set_title(graph)
        add_legend(axes_row[0][-1], len(labels))
        figure.suptitle(f"{tag} during training (mean over seeds and agents)")
        figure.tight_layout()
        save_figure(figure, out / filename, dpi=100, bbox_inches="tight")
        plt.close(figure)
        written.append(out / filename)
    return written

"""Training curves of a sweep, read back from the cells' TensorBoard logs.

Two figures: ``training.png`` (the episode metric ``metrics/avg_uncertainty`` against each
learner's timesteps) and ``estimator_loss.png`` (``estimator/loss``), one line per variant: the
mean over its graphs, seeds and agents at each logged step.
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


def plot_training_curves(cells: Sequence[Any], out: Path) -> list[Path]:
    """Write the figures of :data:`CURVES` for the learned cells that logged them."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    written = []
    for filename, tag in CURVES.items():
        per_variant: dict[str, list[tuple[np.ndarray, np.ndarray]]] = defaultdict(list)
        for cell in cells:
            log_dir = Path(cell.folder) / "tb"
            if log_dir.is_dir():
                per_variant[cell.variant["label"]].extend(read_scalars(log_dir, tag))
        per_variant = {label: series for label, series in per_variant.items() if series}
        if not per_variant:
            continue
        figure, axes = plt.subplots(figsize=(7, 4))
        for label, series in per_variant.items():
            steps, values = _mean_curve(series)
            axes.plot(steps, values, label=label)
        axes.set_xlabel("timesteps per learner")
        axes.set_ylabel(tag)
        axes.set_title(f"{tag} during training (mean over graphs, seeds and agents)")
        axes.legend(fontsize=8)
        figure.tight_layout()
        figure.savefig(out / filename, dpi=100)
        plt.close(figure)
        written.append(out / filename)
    return written

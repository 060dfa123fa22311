"""Aggregates over training runs: IQM, stratified-bootstrap intervals, probability of improvement,
performance profiles, and marl-eval's JSON.

The episodes of one trained team are not independent replicates of *training*; its runs are. A
run is one (graph, seed) cell's evaluation (one :class:`~sb3_pm.evaluation.harness.EvaluationResult`),
and its score is the mean of a metric over the run's evaluation episodes. Over the runs of every
graph at once, this module gives what deep-RL papers report since Agarwal et al. (2021, "Deep
reinforcement learning at the edge of the statistical precipice"):

* the **interquartile mean** (IQM) of the run scores, the mean of their middle half, with a 95%
  **stratified-bootstrap** interval: each replicate resamples the runs with replacement within
  each graph, and the interval is the replicates' 2.5th and 97.5th percentiles;
* the **probability of improvement** of a policy over the reference, ``P(X < Y)`` (lower is better
  for the env's metrics) for a run ``X`` of the policy and a run ``Y`` of the reference on the same
  graph, ties counting one half, averaged over graphs, with its stratified-bootstrap interval
  (both sides' runs resampled with the same indices where they have as many runs);
* the **performance profile**: the fraction of all runs whose normalized score is at most ``tau``.

Scores are normalized per graph by the reference's mean run score on that graph (1: as good as the
reference), so graphs of different scales pool. The definitions are those of the ``rliable``
library's ``aggregate_iqm``, ``probability_of_improvement`` and ``create_performance_profile``
applied to negated scores (it treats higher as better); ``tests/test_run_statistics.py`` checks
them against it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from sb3_pm.errors import InputError
from sb3_pm.evaluation.harness import EvaluationResult
from sb3_pm.evaluation.statistics import graphs_of

#: Bootstrap replicates of each interval: the percentiles of 2,000 replicates move by about 1% of
#: the interval's width from one generator seed to another.
BOOTSTRAP_REPS = 2000
#: The interval's coverage.
CONFIDENCE = 0.95


def run_scores(results: Sequence[EvaluationResult], graphs: Sequence[str], metric: str) -> np.ndarray:
    """``(runs, graphs)``: each run's mean of ``metric`` over its episodes, graph by graph.

    :raises InputError: if the policy has no run on a graph, or not as many runs on every graph.
    """
    columns = []
    for graph in graphs:
        column = [float(r.values(metric).mean()) for r in results if r.graph == graph and r.episodes]
        if not column:
            raise InputError(f"no evaluated run on graph {graph!r}")
        columns.append(column)
    if len({len(column) for column in columns}) != 1:
        counts = ", ".join(f"{g}: {len(c)}" for g, c in zip(graphs, columns))
        raise InputError(f"run statistics need as many runs on every graph ({counts})")
    return np.array(columns, dtype=float).T


def normalized_scores(
    by_policy: Mapping[str, Sequence[EvaluationResult]], reference: str, metric: str
) -> dict[str, np.ndarray]:
    """Every policy's ``(runs, graphs)`` scores divided, graph by graph, by ``reference``'s mean
    run score there (1: as good as the reference)."""
    if reference not in by_policy:
        raise InputError(f"the reference {reference!r} has no results")
    graphs = graphs_of(by_policy)
    scale = run_scores(by_policy[reference], graphs, metric).mean(axis=0)  # (graphs,)
    if not np.all(np.isfinite(scale)) or np.any(scale == 0):
        raise InputError(f"the reference {reference!r} has a zero or undefined mean {metric} on a graph")
    return {name: run_scores(results, graphs, metric) / scale for name, results in by_policy.items()}


def iqm(scores: np.ndarray) -> float:
    """The interquartile mean of every entry of ``scores`` (any shape): the 25%-trimmed mean."""
    return float(stats.trim_mean(scores, proportiontocut=0.25, axis=None))


def probability_of_improvement(x: np.ndarray, y: np.ndarray) -> float:
    """``P(X < Y)`` (ties one half) for a run of ``x`` against a run of ``y`` on the same graph,
    averaged over graphs; ``x`` ``(runs_x, graphs)``, ``y`` ``(runs_y, graphs)``."""
    per_graph = []
    for graph in range(x.shape[1]):
        a, b = x[:, graph][:, None], y[:, graph][None, :]
        per_graph.append(float(((a < b) + 0.5 * (a == b)).mean()))
    return float(np.mean(per_graph))


def performance_profile(scores: np.ndarray, taus: np.ndarray) -> np.ndarray:
    """``(len(taus),)``: the fraction of the entries of ``scores`` at most each ``tau``."""
    return (scores.reshape(-1)[None, :] <= np.asarray(taus, dtype=float)[:, None]).mean(axis=1)  # type: ignore[no-any-return]


def stratified_bootstrap(
    statistic: Callable[..., float],
    samples: Sequence[np.ndarray],
    reps: int = BOOTSTRAP_REPS,
    seed: int = 0,
    confidence: float = CONFIDENCE,
) -> tuple[float, float]:
    """The percentile interval of ``statistic(*samples)`` over stratified-bootstrap replicates.

    Each replicate draws, graph by graph, runs with replacement; samples with the same number of
    runs share the drawn indices (a paired resample), others are drawn apart.

    :param samples: ``(runs, graphs)`` arrays with the same graphs.
    """
    rng = np.random.default_rng(seed)
    drawn: dict[int, np.ndarray] = {}
    values = np.empty(reps)
    for rep in range(reps):
        drawn.clear()
        replicate = []
        for sample in samples:
            runs, graphs = sample.shape
            if runs not in drawn:
                drawn[runs] = rng.integers(0, runs, size=(runs, graphs))
            replicate.append(np.take_along_axis(sample, drawn[runs], axis=0))
        values[rep] = statistic(*replicate)
    tail = 100 * (1 - confidence) / 2
    low, high = np.percentile(values, [tail, 100 - tail])
    return float(low), float(high)


@dataclass(frozen=True)
class RunStatistics:
    """One policy's aggregates over its runs (module docstring), normalized by the reference.

    ``improvement`` is ``P(policy < reference)``; NaN for the reference itself.
    """

    policy: str
    reference: str
    metric: str
    runs: int
    graphs: int
    iqm: float
    iqm_low: float
    iqm_high: float
    improvement: float
    improvement_low: float
    improvement_high: float


def run_statistics(
    by_policy: Mapping[str, Sequence[EvaluationResult]],
    reference: str,
    metric: str = "avg_uncertainty",
    reps: int = BOOTSTRAP_REPS,
    seed: int = 0,
) -> list[RunStatistics]:
    """:class:`RunStatistics` of every policy of ``by_policy`` against ``reference``."""
    scores = normalized_scores(by_policy, reference, metric)
    rows = []
    for name, sample in scores.items():
        low, high = stratified_bootstrap(iqm, [sample], reps, seed)
        improvement = improvement_low = improvement_high = math.nan
        if name != reference:
            improvement = probability_of_improvement(sample, scores[reference])
            improvement_low, improvement_high = stratified_bootstrap(
                probability_of_improvement, [sample, scores[reference]], reps, seed
            )
        rows.append(
            RunStatistics(
                policy=name,
                reference=reference,
                metric=metric,
                runs=sample.shape[0],
                graphs=sample.shape[1],
                iqm=iqm(sample),
                iqm_low=low,
                iqm_high=high,
                improvement=improvement,
                improvement_low=improvement_low,
                improvement_high=improvement_high,
            )
        )
    return rows


def run_statistics_markdown(rows: Sequence[RunStatistics]) -> str:
    """``runs.md``: the IQM and the probability of improvement of every policy, as a table."""
    if not rows:
        return "No runs.\n"
    first = rows[0]
    lines = [
        f"Over training runs: each run's mean `{first.metric}` over its episodes, divided by "
        f"{first.reference}'s mean on the same graph (lower is better; {first.graphs} graph(s)). "
        f"IQM with its 95% stratified-bootstrap interval ({BOOTSTRAP_REPS} replicates), and the "
        f"probability that a run of the policy scores below a run of {first.reference} on the same graph "
        f"(the reference).",
        "",
        "| policy | runs | IQM (× reference) | 95% CI | P(better than reference) | 95% CI |",
        "|---|---:|---:|---|---:|---|",
    ]
    for row in rows:
        undefined = math.isnan(row.improvement)  # the reference itself
        improvement = "—" if undefined else f"{row.improvement:.2f}"
        interval = "—" if undefined else f"[{row.improvement_low:.2f}, {row.improvement_high:.2f}]"
        lines.append(
            f"| {row.policy} | {row.runs} | {row.iqm:.3f} | [{row.iqm_low:.3f}, {row.iqm_high:.3f}] "
            f"| {improvement} | {interval} |"
        )
    if min(row.runs for row in rows) < 3:
        lines += ["", "With fewer than 3 runs per graph these intervals say little: train more seeds."]
    return "\n".join(lines) + "\n"


def plot_performance_profile(scores: Mapping[str, np.ndarray], reference: str, path: Path) -> Path:
    """Write the performance profiles of ``scores`` (normalized, :func:`normalized_scores`) to
    ``path``: the fraction of runs at most ``tau`` times the reference, with 95% bootstrap bands."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sb3_pm.evaluation.plots import save_figure

    everything = np.concatenate([s.reshape(-1) for s in scores.values()])
    taus = np.linspace(max(0.0, float(everything.min()) * 0.9), float(everything.max()) * 1.1, 101)
    figure, axes = plt.subplots(figsize=(6, 4))
    for name, sample in scores.items():
        curve = performance_profile(sample, taus)
        band = np.array(
            [
                stratified_bootstrap(lambda s, t=tau: float(performance_profile(s, [t])[0]), [sample], 500, 0)
                for tau in taus[::5]
            ]
        )
        (line,) = axes.plot(taus, curve, label=name)
        axes.fill_between(taus[::5], band[:, 0], band[:, 1], color=line.get_color(), alpha=0.2)
    axes.set_xlabel("normalized score τ (× the reference's mean; lower is better)")
    axes.set_title(f"reference: {reference}", fontsize="small")
    axes.set_ylabel("fraction of runs with score ≤ τ")
    axes.legend(fontsize="small")
    figure.tight_layout()
    save_figure(figure, path, dpi=120)
    plt.close(figure)
    return path


def marl_eval_record(
    by_policy: Mapping[str, Sequence[EvaluationResult]],
    metrics: Sequence[str] = ("avg_uncertainty", "max_neglect"),
    environment: str = "persistent_monitoring",
) -> dict[str, Any]:
    """The runs in marl-eval's raw-data layout: ``{environment: {graph: {policy: {run_<i>:
    {"step_0": {"step_count": <training steps>, metric: [per episode]}, "absolute_metrics": {...}}}}}}``.

    Each run holds its final evaluation only (``step_0``, at the run's training steps per learner,
    0 for rules). The env's metrics are costs: negate them where a tool expects returns.
    """
    tasks: dict[str, dict[str, Any]] = {}
    for policy, results in by_policy.items():
        for result in results:
            runs = tasks.setdefault(result.graph, {}).setdefault(policy, {})
            values = {m: [float(v) for v in result.values(m)] for m in metrics if m in result.metric_names}
            steps = int(result.config.get("timesteps") or 0)
            runs[f"run_{len(runs)}"] = {"step_0": {"step_count": steps, **values}, "absolute_metrics": values}
    return {environment: tasks}


__all__ = [
    "RunStatistics",
    "iqm",
    "marl_eval_record",
    "normalized_scores",
    "performance_profile",
    "plot_performance_profile",
    "probability_of_improvement",
    "run_scores",
    "run_statistics",
    "run_statistics_markdown",
    "stratified_bootstrap",
]

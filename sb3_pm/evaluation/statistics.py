"""Aggregates across graphs x seeds x episodes and the one-way ANOVA across algorithms.

See docs/METHOD.md, "Metrics".

Every episode is one point; an algorithm's mean and SD pool all its points, as the paper's
Table I does (3 graphs x 3 seeds x 10 episodes = 90 points per algorithm). SDs are sample SDs
(``ddof=1``).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import stats

from sb3_pm.errors import InputError
from sb3_pm.evaluation.harness import EvaluationResult

#: The paper's two Table I metrics.
TABLE_METRICS = ("avg_uncertainty", "max_neglect")
#: Also tabulated per graph when every result of a comparison has them: the worst uncertainty an
#: episode reached (the neglect bound's benefit) and the uncertainty after an agent failure.
EXTRA_TABLE_METRICS = (
    "peak_uncertainty",
    "avg_uncertainty_before_failure",
    "avg_uncertainty_after_failure",
    "x_lower_bound",
)
#: The optimality gap: each episode's ``avg_uncertainty`` over its lower bound
#: (:mod:`sb3_pm.evaluation.optimality`); a column of every results table when all results have it.
GAP_METRIC = "x_lower_bound"


@contextmanager
def _undefined_as_nan() -> Iterator[None]:
    """Silence scipy's and NumPy's warnings for degenerate samples (constant groups, zero variance):
    the tests then return NaN or inf, which the reports show as undefined."""
    with warnings.catch_warnings(), np.errstate(divide="ignore", invalid="ignore"):
        warnings.simplefilter("ignore")
        yield


def pooled_values(results: Sequence[EvaluationResult], metric: str) -> np.ndarray:
    """All episodes' values of ``metric`` across ``results`` (one algorithm's points)."""
    if not results:
        return np.zeros(0)
    return np.concatenate([result.values(metric) for result in results])


@dataclass(frozen=True)
class Summary:
    """Mean and sample SD of one metric over ``n`` points."""

    mean: float
    sd: float
    n: int

    @classmethod
    def of(cls, values: np.ndarray) -> Summary:
        """Mean, SD and count of the defined values: an episode with no value for a metric (NaN:
        ``avg_uncertainty_after_failure`` when no agent failed) is left out, not averaged in."""
        values = np.asarray(values, dtype=float)
        values = values[~np.isnan(values)]
        if len(values) == 0:
            return cls(math.nan, math.nan, 0)
        return cls(float(values.mean()), float(values.std(ddof=1)) if len(values) > 1 else 0.0, len(values))


def summarize(
    by_policy: Mapping[str, Sequence[EvaluationResult]], metrics: Sequence[str] = TABLE_METRICS
) -> dict[str, dict[str, Summary]]:
    """``{policy: {metric: Summary}}`` pooling every graph, seed and episode of each policy."""
    return {
        policy: {metric: Summary.of(pooled_values(results, metric)) for metric in metrics}
        for policy, results in by_policy.items()
    }


@dataclass(frozen=True)
class AnovaResult:
    """One-way ANOVA of one metric across algorithms (``scipy.stats.f_oneway``).

    ``statistic`` and ``p_value`` are NaN when the test is undefined: fewer than two algorithms,
    a group with fewer than two points, or no variance within any group.
    """

    metric: str
    statistic: float
    p_value: float
    groups: tuple[str, ...]
    df_between: int
    df_within: int


def anova(by_policy: Mapping[str, Sequence[EvaluationResult]], metric: str) -> AnovaResult:
    """One-way ANOVA of ``metric`` across the policies of ``by_policy``."""
    groups = {policy: pooled_values(results, metric) for policy, results in by_policy.items()}
    names = tuple(groups)
    n_total = sum(len(values) for values in groups.values())
    df_between, df_within = len(groups) - 1, n_total - len(groups)
    statistic = p_value = math.nan
    if len(groups) >= 2 and all(len(values) >= 2 for values in groups.values()):
        with _undefined_as_nan():
            result = stats.f_oneway(*groups.values())
        statistic, p_value = float(result.statistic), float(result.pvalue)
    return AnovaResult(metric, statistic, p_value, names, df_between, df_within)


@dataclass(frozen=True)
class Effect:
    """How one algorithm differs from a reference algorithm on one graph, for one metric.

    ``difference`` is ``mean(policy) - mean(reference)`` (negative: the policy has less of the
    metric); ``ci_low``/``ci_high`` bound it at 95% and ``p_value`` tests it against 0. When both
    algorithms were evaluated on exactly the same episodes (same graph and env seeds: the sweep
    runner's and ``sb3-pm compare``'s layout) the test is paired (``scipy.stats.ttest_rel``) and
    ``cohens_d`` is the mean difference over the SD of the differences (d_z); otherwise Welch's test
    (``scipy.stats.ttest_ind(equal_var=False)``) and d over the pooled SD. NaN where undefined
    (fewer than two points, or no variance).

    Episodes of one trained team are not independent replicates of *training*: a learned variant
    has as many independent replicates as training seeds. ``p_value_runs`` therefore repeats the
    paired test on the per-run means (one run = one :class:`EvaluationResult`, i.e. one (graph,
    seed) cell, paired by its evaluation seed), with ``n_runs`` pairs; trust it over ``p_value``
    when asking whether a *training* change matters.
    """

    policy: str
    reference: str
    graph: str
    metric: str
    mean: float
    reference_mean: float
    difference: float
    ci_low: float
    ci_high: float
    ratio: float
    cohens_d: float
    p_value: float
    n: int
    paired: bool
    p_value_runs: float = math.nan
    n_runs: int = 0


def _numbered(pairs: Iterable[tuple[Any, float]]) -> dict[tuple[Any, int], float]:
    """``{(key, k): value}``: the ``k``-th value under each key, in order. Several runs may hold the
    same episodes (training seeds evaluated on one set of env seeds); each is kept, and the
    ``k``-th run of one side pairs with the ``k``-th of the other."""
    seen: dict[Any, int] = {}
    numbered: dict[tuple[Any, int], float] = {}
    for key, value in pairs:
        k = seen.get(key, 0)
        seen[key] = k + 1
        numbered[(key, k)] = value
    return numbered


def _run_means(results: Sequence[EvaluationResult], graph: str, metric: str) -> dict[tuple[Any, int], float]:
    """``{(evaluation seed of the run, k): mean of its episodes}`` for the runs of ``results`` on
    ``graph`` (``k`` numbers runs with the same evaluation seed)."""
    return _numbered(
        (result.config.get("seed", index), float(result.values(metric).mean()))
        for index, result in enumerate(results)
        if result.graph == graph and result.episodes
    )


def _by_episode(results: Sequence[EvaluationResult], graph: str, metric: str) -> dict[tuple[int, int], float]:
    """``{(env seed, k): value}`` of one metric over the episodes of ``results`` on ``graph``
    (``k`` numbers the runs that hold the same episode)."""
    return _numbered(
        (record.seed, float(record.metrics[metric]))
        for result in results
        if result.graph == graph
        for record in result.episodes
    )


def effect(
    policy: Sequence[EvaluationResult],
    reference: Sequence[EvaluationResult],
    graph: str,
    metric: str,
    names: tuple[str, str] = ("policy", "reference"),
) -> Effect:
    """The :class:`Effect` of ``policy`` against ``reference`` on ``graph``."""
    ours, theirs = _by_episode(policy, graph, metric), _by_episode(reference, graph, metric)
    if not ours or not theirs:
        raise InputError(f"no episodes of {names[0] if not ours else names[1]!r} on graph {graph!r}")
    paired = ours.keys() == theirs.keys()
    a = np.array(list(ours.values()))
    b = np.array([theirs[k] for k in ours] if paired else list(theirs.values()))
    difference = float(a.mean() - b.mean())
    low = high = d = p = math.nan
    with _undefined_as_nan():
        if paired and len(a) >= 2:
            test = stats.ttest_rel(a, b)
            spread = float((a - b).std(ddof=1))
        elif not paired and len(a) >= 2 and len(b) >= 2:
            test = stats.ttest_ind(a, b, equal_var=False)
            spread = math.sqrt((a.var(ddof=1) + b.var(ddof=1)) / 2)
        else:
            test = None
        if test is not None:
            p = float(test.pvalue)
            interval = test.confidence_interval(0.95)
            low, high = float(interval.low), float(interval.high)
            d = difference / spread if spread > 0 else math.nan
    ratio = float(a.mean() / b.mean()) if b.mean() != 0 else math.nan
    runs_ours, runs_theirs = _run_means(policy, graph, metric), _run_means(reference, graph, metric)
    shared = [key for key in runs_ours if key in runs_theirs]
    p_runs = math.nan
    if paired and len(shared) >= 2:
        with _undefined_as_nan():
            p_runs = float(
                stats.ttest_rel([runs_ours[k] for k in shared], [runs_theirs[k] for k in shared]).pvalue
            )
    return Effect(
        policy=names[0],
        reference=names[1],
        graph=graph,
        metric=metric,
        mean=float(a.mean()),
        reference_mean=float(b.mean()),
        difference=difference,
        ci_low=low,
        ci_high=high,
        ratio=ratio,
        cohens_d=d,
        p_value=p,
        n=len(a),
        paired=paired,
        p_value_runs=p_runs,
        n_runs=len(shared) if paired else 0,
    )


def graphs_of(by_policy: Mapping[str, Sequence[EvaluationResult]]) -> list[str]:
    """The graph labels of a comparison, in first-seen order."""
    seen: dict[str, None] = {}
    for results in by_policy.values():
        for result in results:
            seen.setdefault(result.graph, None)
    return list(seen)


def split_by_graph(
    by_policy: Mapping[str, Sequence[EvaluationResult]],
) -> dict[str, dict[str, list[EvaluationResult]]]:
    """``{graph: {policy: its results on that graph}}``, graphs in first-seen order; a policy with
    no result on a graph is left out of that graph's mapping."""
    split: dict[str, dict[str, list[EvaluationResult]]] = {graph: {} for graph in graphs_of(by_policy)}
    for policy, results in by_policy.items():
        for result in results:
            split[result.graph].setdefault(policy, []).append(result)
    return split


def effects(
    by_policy: Mapping[str, Sequence[EvaluationResult]], reference: str, metric: str = "avg_uncertainty"
) -> list[Effect]:
    """Every other algorithm against ``reference``, graph by graph (rows in table order).

    Graphs are kept apart because their scales differ (a 200-node graph's uncertainty is several
    times a 50-node graph's), so a difference pooled over graphs would mostly measure the largest.
    """
    if reference not in by_policy:
        raise InputError(f"unknown reference algorithm {reference!r}; have {sorted(by_policy)}")
    rows = []
    for graph, on_graph in split_by_graph(by_policy).items():
        for policy, results in on_graph.items():
            if policy != reference and any(result.episodes for result in results):
                rows.append(effect(results, by_policy[reference], graph, metric, names=(policy, reference)))
    return rows


def summarize_by_graph(
    by_policy: Mapping[str, Sequence[EvaluationResult]], metric: str = "avg_uncertainty"
) -> dict[str, dict[str, Summary]]:
    """``{policy: {graph: Summary}}``: one algorithm's points on each graph (seeds x episodes)."""
    split = split_by_graph(by_policy)
    return {
        policy: {
            graph: Summary.of(pooled_values(on_graph.get(policy, []), metric))
            for graph, on_graph in split.items()
        }
        for policy in by_policy
    }

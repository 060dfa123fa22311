"""Aggregates across graphs x seeds x episodes and the one-way ANOVA across algorithms (METHOD.md "Metrics").

Every episode is one point; an algorithm's mean and SD pool all its points, as the paper's
Table I does (3 graphs x 3 seeds x 10 episodes = 90 points per algorithm). SDs are sample SDs
(``ddof=1``).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats

from sb3_pm.evaluation.harness import EvaluationResult

#: The paper's two Table I metrics.
TABLE_METRICS = ("avg_uncertainty", "max_neglect")


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
        values = np.asarray(values, dtype=float)
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
        with warnings.catch_warnings():
            # Constant groups make F undefined; scipy warns and returns nan/inf, which we report as is.
            warnings.simplefilter("ignore")
            result = stats.f_oneway(*groups.values())
        statistic, p_value = float(result.statistic), float(result.pvalue)
    return AnovaResult(metric, statistic, p_value, names, df_between, df_within)

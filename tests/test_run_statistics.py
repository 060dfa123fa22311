"""Aggregates over training runs agree with the rliable library's definitions.

rliable treats higher scores as better; the env's metrics are costs, so it is given negated
scores (and negated thresholds for the profiles).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from rliable import library as rly
from rliable import metrics

from sb3_pm.errors import InputError
from sb3_pm.evaluation.harness import EpisodeRecord, EvaluationResult
from sb3_pm.evaluation.run_statistics import (
    iqm,
    marl_eval_record,
    normalized_scores,
    performance_profile,
    probability_of_improvement,
    run_statistics,
    run_statistics_markdown,
    stratified_bootstrap,
)

RNG = np.random.default_rng(7)
X = RNG.gamma(4.0, 10.0, size=(7, 3))
Y = RNG.gamma(5.0, 10.0, size=(5, 3))


def test_iqm_is_rliables() -> None:
    assert iqm(X) == pytest.approx(-metrics.aggregate_iqm(-X), rel=1e-12)
    assert iqm(X) != pytest.approx(float(X.mean()), rel=1e-3)  # trimmed, not the plain mean


def test_probability_of_improvement_is_rliables_with_ties() -> None:
    tied = Y.copy()
    tied[0, 0] = X[2, 0]  # a tie counts one half
    assert probability_of_improvement(X, tied) == pytest.approx(
        metrics.probability_of_improvement(-X, -tied), rel=1e-12
    )
    assert probability_of_improvement(X, X) == pytest.approx(0.5)


def test_performance_profile_is_rliables() -> None:
    taus = np.linspace(X.min() - 1, X.max() + 1, 37) + 1e-6  # no threshold equals a score
    ours = performance_profile(X, taus)
    theirs, _ = rly.create_performance_profile({"x": -X}, -taus, reps=10)
    assert np.allclose(ours, theirs["x"])
    assert ours[0] == 0.0 and ours[-1] == 1.0 and np.all(np.diff(ours) >= 0)


def test_stratified_bootstrap_interval_matches_rliables() -> None:
    """Both are Monte Carlo: with 20,000 replicates each the interval ends agree to a few
    hundredths of the interval's width."""
    low, high = stratified_bootstrap(iqm, [X], reps=20_000, seed=1)
    _, theirs = rly.get_interval_estimates(
        {"x": -X},
        lambda s: np.array([metrics.aggregate_iqm(s)]),
        reps=20_000,
        random_state=np.random.RandomState(1),
    )
    their_low, their_high = -theirs["x"][1, 0], -theirs["x"][0, 0]
    width = high - low
    assert low < iqm(X) < high
    assert abs(low - their_low) < 0.05 * width and abs(high - their_high) < 0.05 * width


def result(policy: str, graph: str, seed: int, values: list[float], timesteps: int = 0) -> EvaluationResult:
    episodes = [
        EpisodeRecord(i, 100 + i, i, {"avg_uncertainty": v, "max_neglect": 2 * v}, np.zeros(1))
        for i, v in enumerate(values)
    ]
    return EvaluationResult(policy, graph, {"seed": seed, "timesteps": timesteps}, episodes)


def by_policy() -> dict[str, list[EvaluationResult]]:
    graphs = (("a", 1.0), ("b", 3.0))  # graph b's scores are graph a's times 3
    return {
        "team": [result("team", g, s, [10 * (1 + s) * f, 12 * f], 500) for g, f in graphs for s in range(3)],
        "grazing": [result("grazing", g, s, [30.0 * f, 30.0 * f]) for g, f in graphs for s in range(3)],
    }


def test_scores_are_normalized_by_the_reference_graph_by_graph() -> None:
    scores = normalized_scores(by_policy(), "grazing", "avg_uncertainty")
    assert np.allclose(scores["grazing"], 1.0)
    assert np.allclose(scores["team"][:, 0], scores["team"][:, 1])  # graph b is graph a times 3


def test_run_statistics_and_their_table() -> None:
    rows = {row.policy: row for row in run_statistics(by_policy(), "grazing", reps=500)}
    team = rows["team"]
    assert team.runs == 3 and team.graphs == 2
    assert team.iqm_low <= team.iqm <= team.iqm_high < 1.0
    assert team.improvement == 1.0  # every run of the team is below every run of grazing
    assert math.isnan(rows["grazing"].improvement)
    table = run_statistics_markdown(list(rows.values()))
    assert "| team | 3 |" in table and "P(better than reference)" in table and "grazing" in table


def test_unequal_runs_per_graph_are_refused_in_one_line() -> None:
    uneven = by_policy()
    uneven["team"] = uneven["team"][:-1]
    with pytest.raises(InputError, match="as many runs on every graph") as error:
        run_statistics(uneven, "grazing")
    assert "\n" not in str(error.value)


def test_marl_eval_layout() -> None:
    record = marl_eval_record(by_policy())
    runs = record["persistent_monitoring"]["a"]["team"]
    assert list(runs) == ["run_0", "run_1", "run_2"]
    expected = {"step_count": 500, "avg_uncertainty": [20.0, 12.0], "max_neglect": [40.0, 24.0]}
    assert runs["run_1"]["step_0"] == expected
    assert runs["run_1"]["absolute_metrics"]["avg_uncertainty"] == [20.0, 12.0]
    json.dumps(record)  # plain JSON

"""The evaluation grid behind ``sb3-pm compare``: policies x graphs x seeds x episodes.

Seed ``s`` of the grid evaluates episodes with env seeds ``s * SEED_STRIDE + e``, so different
grid seeds never share an episode (for up to ``SEED_STRIDE`` episodes).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sb3_pm.errors import InputError
from sb3_pm.evaluation.harness import EvaluationResult, evaluate
from sb3_pm.evaluation.plots import plot_table, plot_uncertainty
from sb3_pm.evaluation.reports import (
    anova_text,
    by_graph_markdown,
    csv_table,
    effects_markdown,
    latex_table,
    markdown_table,
)
from sb3_pm.evaluation.run_statistics import (
    RunStatistics,
    marl_eval_record,
    normalized_scores,
    plot_performance_profile,
    run_statistics,
    run_statistics_markdown,
)
from sb3_pm.evaluation.statistics import (
    EXTRA_TABLE_METRICS,
    GAP_METRIC,
    TABLE_METRICS,
    AnovaResult,
    Effect,
    Summary,
    anova,
    effects,
    split_by_graph,
    summarize,
    summarize_by_graph,
)
from sb3_pm.files import write_atomic
from sb3_pm.team_interface import Team

SEED_STRIDE = 1000


@dataclass
class Comparison:
    """All results of a grid, by policy label, plus the derived tables, ANOVAs and effects.

    :ivar reference: the algorithm the others are measured against in ``effects.md`` (default: the
        first one, e.g. the proposed method in an experiment's table order).
    """

    results: dict[str, list[EvaluationResult]] = field(default_factory=dict)
    config: dict[str, Any] = field(default_factory=dict)
    reference: str | None = None

    @property
    def table(self) -> dict[str, dict[str, Summary]]:
        """Table I's metrics per algorithm, with the optimality gap when every result records it."""
        results = [result for group in self.results.values() for result in group if result.episodes]
        gap = (GAP_METRIC,) if results and all(GAP_METRIC in r.metric_names for r in results) else ()
        return summarize(self.results, (*TABLE_METRICS, *gap))

    @property
    def anovas(self) -> list[AnovaResult]:
        """The paper's ANOVAs: every graph, seed and episode of an algorithm pooled into one group."""
        return [anova(self.results, metric) for metric in TABLE_METRICS]

    @property
    def anovas_by_graph(self) -> dict[str, list[AnovaResult]]:
        """The ANOVAs within each graph: pooled groups mix graphs whose scales differ several-fold,
        so their within-group variance is mostly the spread between graphs."""
        return {
            graph: [anova(on_graph, metric) for metric in TABLE_METRICS]
            for graph, on_graph in split_by_graph(self.results).items()
        }

    def anova_report(self) -> str:
        """``anova.txt``: the pooled ANOVAs, then (with several graphs) those within each graph."""
        text = anova_text(self.anovas)
        by_graph = self.anovas_by_graph
        if len(by_graph) > 1:
            for graph, results in by_graph.items():
                text += f"\nwithin {graph}:\n" + anova_text(results)
        return text

    @property
    def by_graph(self) -> dict[str, dict[str, dict[str, Summary]]]:
        """``{metric: {policy: {graph: Summary}}}``."""
        results = [result for group in self.results.values() for result in group if result.episodes]
        extra = [m for m in EXTRA_TABLE_METRICS if results and all(m in r.metric_names for r in results)]
        return {metric: summarize_by_graph(self.results, metric) for metric in (*TABLE_METRICS, *extra)}

    @property
    def reference_policy(self) -> str | None:
        """:attr:`reference`, or the first algorithm when unset (None without results)."""
        return self.reference or next(iter(self.results), None)

    @property
    def effects(self) -> list[Effect]:
        """Every algorithm against :attr:`reference_policy` on ``avg_uncertainty``, graph by graph."""
        reference = self.reference_policy
        return [] if reference is None else effects(self.results, reference)

    def run_statistics(self) -> tuple[list[RunStatistics], str | None]:
        """Every algorithm's aggregates over its training runs against :attr:`reference_policy`
        (:mod:`sb3_pm.evaluation.run_statistics`), or why there are none."""
        reference = self.reference_policy
        if reference is None:
            return [], "no results"
        try:
            return run_statistics(self.results, reference), None
        except InputError as error:
            return [], str(error)

    def write(self, out: str | Path) -> list[Path]:
        """Write ``table.md``, ``table.csv``, ``table.tex``, ``anova.txt``, ``by_graph.md``,
        ``effects.md``, ``runs.md``, ``results.json``, ``marl_eval.json``, ``uncertainty.png``,
        ``table.png`` and ``performance_profile.png`` into ``out`` (created if needed)."""
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        table, effect_rows = self.table, self.effects
        runs, missing = self.run_statistics()
        written = []
        for name, text in (
            ("runs.md", f"No run statistics: {missing}\n" if missing else run_statistics_markdown(runs)),
            ("table.md", markdown_table(table)),
            ("table.csv", csv_table(table)),
            ("table.tex", latex_table(table, caption="Average uncertainty and neglect time")),
            ("anova.txt", self.anova_report()),
            ("by_graph.md", by_graph_markdown(self.by_graph)),
            ("effects.md", effects_markdown(effect_rows)),
        ):
            write_atomic(out / name, text)
            written.append(out / name)
        payload = {
            "config": self.config,
            "table": {p: {m: vars(s) for m, s in row.items()} for p, row in table.items()},
            "anova": [vars(a) | {"groups": list(a.groups)} for a in self.anovas],
            "anova_by_graph": {
                graph: [vars(a) | {"groups": list(a.groups)} for a in results]
                for graph, results in self.anovas_by_graph.items()
            },
            "effects": [vars(e) for e in effect_rows],
            "run_statistics": [vars(row) for row in runs],
            "results": {p: [r.to_dict() for r in rs] for p, rs in self.results.items()},
        }
        write_atomic(out / "results.json", json.dumps(payload, indent=2, allow_nan=True))
        written.append(out / "results.json")
        write_atomic(out / "marl_eval.json", json.dumps(marl_eval_record(self.results), indent=1))
        written.append(out / "marl_eval.json")
        if missing is None and self.reference_policy is not None:
            reference = self.reference_policy
            scores = normalized_scores(self.results, reference, "avg_uncertainty")
            written.append(plot_performance_profile(scores, reference, out / "performance_profile.png"))
        written.append(plot_uncertainty(self.results, out / "uncertainty.png"))
        written.append(plot_table(table, out / "table.png"))
        return written


def compare(
    teams: Mapping[str, Callable[[str], Team]],
    graphs: Sequence[str],
    seeds: Sequence[int] = (0,),
    episodes: int = 10,
    n_agents: int | None = None,
    max_cycles: int = 500,
    env_kwargs: Mapping[str, Any] | None = None,
    progress: bool | None = False,
    threads: int | None = 1,
    deterministic: bool | None = None,
) -> Comparison:
    """Evaluate every team on every graph for every seed.

    :param teams: label -> factory of a fresh team for a graph (a fresh team per graph and seed keeps
        runs independent; a trained team is loaded for, and checked against, that graph).
        A trained team's own env settings apply, then ``env_kwargs`` (as in
        :func:`~sb3_pm.evaluation.evaluate`).
    :param graphs: preset names or ``.graphml`` paths.
    :param seeds: grid seeds (see the module docstring for the env seeds they give).
    :param threads: torch CPU threads while evaluating (see :func:`~sb3_pm.evaluation.evaluate`).
    :param deterministic: how learned teams act (see :func:`~sb3_pm.evaluation.evaluate`): ``None``
        by each team's own ``deploy_temperature``, ``True`` every team by its most likely actions.
    """
    if not teams:
        raise InputError("compare needs at least one policy")
    if not graphs:
        raise InputError("compare needs at least one graph")
    if episodes < 1:
        raise InputError(f"episodes must be at least 1, got {episodes}")
    if episodes > SEED_STRIDE:
        raise InputError(f"at most {SEED_STRIDE} episodes per seed, got {episodes}")
    comparison = Comparison(
        config={
            "policies": list(teams),
            "graphs": [str(g) for g in graphs],
            "seeds": list(seeds),
            "episodes": episodes,
            "n_agents": n_agents,
            "max_cycles": max_cycles,
            "env_kwargs": dict(env_kwargs or {}),
            "seed_stride": SEED_STRIDE,
            **({} if deterministic is None else {"deterministic": deterministic}),
        }
    )
    for label, factory in teams.items():
        runs = comparison.results.setdefault(label, [])
        for graph in graphs:
            for seed in seeds:
                team = factory(graph)
                runs.append(
                    evaluate(
                        team,
                        graph,
                        n_agents=n_agents,
                        episodes=episodes,
                        seed=seed * SEED_STRIDE,
                        max_cycles=max_cycles,
                        env_kwargs=env_kwargs,
                        progress=progress,
                        policy_name=label,
                        threads=threads,
                        deterministic=deterministic,
                    )
                )
    return comparison

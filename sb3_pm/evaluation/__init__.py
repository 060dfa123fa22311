"""Evaluation harness: run teams, aggregate metrics, test differences, write tables, plots and GIFs.

``evaluate(team, graph, n_agents, episodes, seed)`` is the entry point; ``compare`` runs a grid
of policies x graphs x seeds, and :class:`Comparison` writes its reports.
"""

from sb3_pm.evaluation.comparison import SEED_STRIDE, Comparison, compare
from sb3_pm.evaluation.gif import record_gif
from sb3_pm.evaluation.harness import (
    EpisodeRecord,
    EvaluationInterrupted,
    EvaluationResult,
    evaluate,
    run_episode,
    team_seed,
)
from sb3_pm.evaluation.plots import plot_table, plot_uncertainty
from sb3_pm.evaluation.reports import (
    anova_text,
    by_graph_markdown,
    csv_table,
    effects_markdown,
    latex_table,
    markdown_table,
)
from sb3_pm.evaluation.statistics import (
    TABLE_METRICS,
    AnovaResult,
    Effect,
    Summary,
    anova,
    effect,
    effects,
    pooled_values,
    summarize,
    summarize_by_graph,
)
from sb3_pm.evaluation.teams import PolicyError, policy_label, resolve_team

__all__ = [
    "SEED_STRIDE",
    "TABLE_METRICS",
    "AnovaResult",
    "Comparison",
    "Effect",
    "EpisodeRecord",
    "EvaluationInterrupted",
    "EvaluationResult",
    "PolicyError",
    "Summary",
    "anova",
    "anova_text",
    "by_graph_markdown",
    "compare",
    "csv_table",
    "effect",
    "effects",
    "effects_markdown",
    "evaluate",
    "latex_table",
    "markdown_table",
    "plot_table",
    "plot_uncertainty",
    "policy_label",
    "pooled_values",
    "record_gif",
    "resolve_team",
    "run_episode",
    "summarize",
    "summarize_by_graph",
    "team_seed",
]

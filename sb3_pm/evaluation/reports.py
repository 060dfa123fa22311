"""Tables shaped like the paper's Table I, as Markdown, CSV and LaTeX, plus the ANOVA as text.

Columns: Algorithm | Avg. Uncertainty | SD | Max Neglect | SD. "Avg. Uncertainty" is the mean over
points of ``avg_uncertainty``; "Max Neglect" is the mean over points of ``max_neglect``, each
episode's longest run of steps in which some target had no agent (docs/METHOD.md "Metrics"). The
paper calls its second column "Avg. Neglect Time"; the name here says what is measured. When
every result records it, a last column "× Lower Bound" gives the mean over points of
``x_lower_bound``, each episode's score over the bound no team can beat (the optimality gap).
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping, Sequence

from sb3_pm.evaluation.statistics import AnovaResult, Effect, Summary

HEADER = ("Algorithm", "Avg. Uncertainty", "SD", "Max Neglect", "SD")
#: The optimality-gap column, present when the summaries have ``x_lower_bound``.
GAP_HEADER = "× Lower Bound"


def _has_gap(table: Mapping[str, Mapping[str, Summary]]) -> bool:
    return bool(table) and all("x_lower_bound" in summaries for summaries in table.values())


def _header(table: Mapping[str, Mapping[str, Summary]]) -> tuple[str, ...]:
    return (*HEADER, GAP_HEADER) if _has_gap(table) else HEADER


def _rows(table: Mapping[str, Mapping[str, Summary]], digits: int) -> list[tuple[str, ...]]:
    gap = _has_gap(table)
    rows = []
    for policy, summaries in table.items():
        u, n = summaries["avg_uncertainty"], summaries["max_neglect"]
        cells = [f"{value:.{digits}f}" for value in (u.mean, u.sd, n.mean, n.sd)]
        if gap:
            cells.append(f"{summaries['x_lower_bound'].mean:.2f}")
        rows.append((policy, *cells))
    return rows


def markdown_table(table: Mapping[str, Mapping[str, Summary]], digits: int = 1) -> str:
    """A GitHub Markdown table, one row per algorithm (with the optimality gap when recorded)."""
    header = _header(table)
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(["---"] + ["---:"] * (len(header) - 1)) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in _rows(table, digits)]
    return "\n".join(lines) + "\n"


def csv_table(table: Mapping[str, Mapping[str, Summary]]) -> str:
    """CSV with full precision and the number of points per algorithm."""
    gap = _has_gap(table)
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(
        ["algorithm", "avg_uncertainty_mean", "avg_uncertainty_sd", "max_neglect_mean", "max_neglect_sd", "n"]
        + (["x_lower_bound_mean"] if gap else [])
    )
    for policy, summaries in table.items():
        u, n = summaries["avg_uncertainty"], summaries["max_neglect"]
        extra = [repr(summaries["x_lower_bound"].mean)] if gap else []
        writer.writerow([policy, repr(u.mean), repr(u.sd), repr(n.mean), repr(n.sd), u.n, *extra])
    return buffer.getvalue()


def _latex_escape(text: str) -> str:
    for char, escaped in (
        ("\\", r"\textbackslash{}"),
        ("_", r"\_"),
        ("&", r"\&"),
        ("%", r"\%"),
        ("#", r"\#"),
    ):
        text = text.replace(char, escaped)
    return text


def latex_table(
    table: Mapping[str, Mapping[str, Summary]], digits: int = 1, caption: str | None = None
) -> str:
    """A ``table`` environment with a ``tabular`` (booktabs rules), like the paper's Table I."""
    lines = [r"\begin{table}[t]", r"\centering"]
    if caption:
        lines.append(rf"\caption{{{_latex_escape(caption)}}}")
    header = [_latex_escape(cell).replace("×", r"$\times$") for cell in _header(table)]
    columns = "l" + "r" * (len(header) - 1)
    lines += [rf"\begin{{tabular}}{{{columns}}}", r"\toprule", " & ".join(header) + r" \\", r"\midrule"]
    lines += [" & ".join((_latex_escape(row[0]), *row[1:])) + r" \\" for row in _rows(table, digits)]
    lines += [r"\bottomrule", r"\end{tabular}", r"\end{table}"]
    return "\n".join(lines) + "\n"


def anova_text(results: Sequence[AnovaResult]) -> str:
    """One line per metric: ``F(df_b, df_w) = ..., p = ...`` across the named algorithms."""
    lines = []
    for result in results:
        if math.isnan(result.statistic):
            verdict = "undefined (needs >= 2 algorithms with >= 2 points each and some variance)"
        else:
            dof = f"F({result.df_between}, {result.df_within})"
            verdict = f"{dof} = {result.statistic:.4g}, p = {result.p_value:.3g}"
        lines.append(f"{result.metric}: {verdict}  [{', '.join(result.groups)}]")
    return "\n".join(lines) + "\n"


def by_graph_markdown(tables: Mapping[str, Mapping[str, Mapping[str, Summary]]], digits: int = 1) -> str:
    """One Markdown table per metric: algorithms x graphs, each cell ``mean ± sd (n)``.

    :param tables: ``{metric: {policy: {graph: Summary}}}`` (see ``summarize_by_graph``).
    """
    parts = []
    for metric, table in tables.items():
        graphs = list(next(iter(table.values()), {}))
        lines = [f"**{metric}** (mean ± SD over seeds × episodes, per graph)", ""]
        lines.append("| Algorithm | " + " | ".join(graphs) + " |")
        lines.append("|---|" + "---:|" * len(graphs))
        for policy, row in table.items():
            cells = [
                "–" if s.n == 0 else f"{s.mean:.{digits}f} ± {s.sd:.{digits}f} ({s.n})" for s in row.values()
            ]
            lines.append(f"| {policy} | " + " | ".join(cells) + " |")
        parts.append("\n".join(lines))
    return "\n\n".join(parts) + "\n"


def _p(value: float) -> str:
    return "–" if math.isnan(value) else ("< 1e-4" if value < 1e-4 else f"{value:.2g}")


def effects_markdown(effects: Sequence[Effect], digits: int = 1) -> str:
    """Differences from the reference algorithm, one row per (graph, algorithm)."""
    if not effects:
        return "No other algorithm to compare with the reference.\n"
    first = effects[0]
    lines = [
        f"**{first.metric}**: each algorithm minus **{first.reference}**, per graph "
        "(negative = less than the reference). 95% CI and p from a paired t-test over the same "
        "episodes (Welch's test where the episodes differ); d = Cohen's d. Episodes of one trained "
        "team are not independent training replicates: *p (runs)* repeats the paired test on the "
        "per-run means (one run per training seed), the test to read for a training change.",
        "",
        "| Graph | Algorithm | Mean | Reference | Difference [95% CI] | Ratio | d | p | n "
        "| p (runs) | runs |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for e in effects:
        interval = "" if math.isnan(e.ci_low) else f" [{e.ci_low:.{digits}f}, {e.ci_high:.{digits}f}]"
        d = "–" if math.isnan(e.cohens_d) else f"{e.cohens_d:.2f}"
        lines.append(
            f"| {e.graph} | {e.policy} | {e.mean:.{digits}f} | {e.reference_mean:.{digits}f} | "
            f"{e.difference:+.{digits}f}{interval} | {e.ratio:.2f} | {d} | {_p(e.p_value)} | {e.n}"
            f"{'' if e.paired else ' (Welch)'} | {_p(e.p_value_runs)} | {e.n_runs} |"
        )
    return "\n".join(lines) + "\n"

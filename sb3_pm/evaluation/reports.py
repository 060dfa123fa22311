"""Tables shaped like the paper's Table I, as Markdown, CSV and LaTeX, plus the ANOVA as text.

Columns: Algorithm | Avg. Uncertainty | SD | Avg. Neglect Time | SD, where "Avg. Neglect Time" is
the mean over points of ``max_neglect`` (METHOD.md "Metrics").
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping, Sequence

from sb3_pm.evaluation.statistics import AnovaResult, Summary

HEADER = ("Algorithm", "Avg. Uncertainty", "SD", "Avg. Neglect Time", "SD")


def _rows(table: Mapping[str, Mapping[str, Summary]], digits: int) -> list[tuple[str, ...]]:
    rows = []
    for policy, summaries in table.items():
        u, n = summaries["avg_uncertainty"], summaries["max_neglect"]
        rows.append((policy, *(f"{value:.{digits}f}" for value in (u.mean, u.sd, n.mean, n.sd))))
    return rows


def markdown_table(table: Mapping[str, Mapping[str, Summary]], digits: int = 1) -> str:
    """A GitHub Markdown table, one row per algorithm."""
    lines = ["| " + " | ".join(HEADER) + " |", "|" + "|".join(["---"] + ["---:"] * 4) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in _rows(table, digits)]
    return "\n".join(lines) + "\n"


def csv_table(table: Mapping[str, Mapping[str, Summary]]) -> str:
    """CSV with full precision and the number of points per algorithm."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(
        ["algorithm", "avg_uncertainty_mean", "avg_uncertainty_sd", "max_neglect_mean", "max_neglect_sd", "n"]
    )
    for policy, summaries in table.items():
        u, n = summaries["avg_uncertainty"], summaries["max_neglect"]
        writer.writerow([policy, repr(u.mean), repr(u.sd), repr(n.mean), repr(n.sd), u.n])
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
    lines += [r"\begin{tabular}{lrrrr}", r"\toprule", " & ".join(HEADER) + r" \\", r"\midrule"]
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

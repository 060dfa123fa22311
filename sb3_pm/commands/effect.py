"""``sb3-pm effect``: how one set of saved evaluation records differs from another.

Reads evaluation records (``sb3-pm evaluate --json`` files, or sweep cells' ``evaluation.json``)
and prints, per graph, the paired difference of a metric with its 95% interval, the p-values over
episodes and over runs (:func:`~sb3_pm.evaluation.statistics.effect`, the test the sweep reports
use), and each side's per-run means, 90th percentile, mean ``max_neglect`` and episodes that reached
the cap; then, over the runs of every shared graph, the policy's IQM relative to the reference and
its probability of improvement (:mod:`sb3_pm.evaluation.run_statistics`). Episodes are paired by
their env seed when both sides hold the same ones.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import asdict
from pathlib import Path
from typing import Any

from sb3_pm.commands.options import check_writable
from sb3_pm.files import write_atomic


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "effect",
        help="compare two sets of saved evaluation records (paired by episode)",
        description=(
            "Print how --policy's evaluation records differ from --reference's on each graph: the "
            "difference of --metric with its 95% interval, p over episodes and over runs, and each "
            "side's per-run means, 90th percentile, max_neglect and episodes at the cap."
        ),
    )
    parser.add_argument(
        "--policy", nargs="+", type=Path, required=True, metavar="FILE", help="evaluation records (JSON)"
    )
    parser.add_argument(
        "--reference", nargs="+", type=Path, required=True, metavar="FILE", help="evaluation records (JSON)"
    )
    parser.add_argument("--metric", default="avg_uncertainty", help="the metric (default avg_uncertainty)")
    parser.add_argument("--json", type=Path, metavar="FILE", help="also write the figures as JSON")
    parser.set_defaults(func=run)


def _side(label: str, name: str, t: Any, metric_mean: float) -> str:
    runs = " / ".join(f"{m:.1f}" for m in t.run_means)
    return (
        f"  {label:<10} {metric_mean:9.1f}  runs {runs}  p90 {t.p90:.1f}  "
        f"max_neglect {t.max_neglect:.1f}  at the cap {t.at_cap}/{t.episodes}  ({name})"
    )


def _p(value: float) -> str:
    return "n/a" if math.isnan(value) else f"{value:.2g}"


def _run_statistics(
    policy: list[Any], reference: list[Any], graphs: list[str], metric: str, names: tuple[str, str]
) -> dict[str, Any] | None:
    """Print and return the policy's IQM and probability of improvement over the reference's runs
    on the shared graphs (:mod:`sb3_pm.evaluation.run_statistics`), or say why there are none."""
    from sb3_pm.errors import InputError
    from sb3_pm.evaluation.run_statistics import run_statistics

    label = names[0] if names[0] != names[1] else f"{names[0]} (policy)"
    by_policy = {
        label: [r for r in policy if r.graph in graphs],
        names[1]: [r for r in reference if r.graph in graphs],
    }
    try:
        row = run_statistics(by_policy, names[1], metric)[0]
    except InputError as error:
        print(f"over runs: none ({error})")
        return None
    print(
        f"over runs ({row.runs} per graph, {row.graphs} graph(s), normalized by the reference): "
        f"IQM {row.iqm:.3f} [{row.iqm_low:.3f}, {row.iqm_high:.3f}]  "
        f"P(better than the reference) {row.improvement:.2f} "
        f"[{row.improvement_low:.2f}, {row.improvement_high:.2f}]"
    )
    return asdict(row)


def run(args: argparse.Namespace) -> int:
    from sb3_pm.errors import UsageError
    from sb3_pm.evaluation.records import load_record, tail
    from sb3_pm.evaluation.statistics import effect

    check_writable(args.json, "--json")
    policy = [load_record(path) for path in args.policy]
    reference = [load_record(path) for path in args.reference]
    known = set(policy[0].metric_names) & set(reference[0].metric_names)
    if args.metric not in known:
        raise UsageError(
            f"--metric {args.metric!r} is not in both sets of records; they share {sorted(known)}"
        )
    graphs = [g for g in dict.fromkeys(r.graph for r in policy) if any(r.graph == g for r in reference)]
    if not graphs:
        raise UsageError(
            f"--policy and --reference share no graph (policy: {sorted({r.graph for r in policy})}, "
            f"reference: {sorted({r.graph for r in reference})})"
        )
    names = (policy[0].policy, reference[0].policy)
    figures = []
    for graph in graphs:
        e = effect(policy, reference, graph, args.metric, names=names)
        ours, theirs = tail(policy, graph, args.metric), tail(reference, graph, args.metric)
        pairing = "paired by episode seed" if e.paired else "not the same episodes: Welch's test"
        n_runs = e.n_runs or len(ours.run_means)
        print(f"{args.metric} on {graph} ({pairing}; {n_runs} run{'' if n_runs == 1 else 's'})")
        print(_side("policy", names[0], ours, e.mean))
        print(_side("reference", names[1], theirs, e.reference_mean))
        print(
            f"  difference {e.difference:+.1f} [{e.ci_low:.1f}, {e.ci_high:.1f}]  ratio {e.ratio:.2f}  "
            f"p (episodes) {_p(e.p_value)}  p (runs) {_p(e.p_value_runs)}"
        )
        figures.append(
            {"graph": graph, "effect": asdict(e), "policy": asdict(ours), "reference": asdict(theirs)}
        )
    runs = _run_statistics(policy, reference, graphs, args.metric, names)
    if args.json is not None:
        payload = {"graphs": figures, "runs": runs}
        write_atomic(args.json, json.dumps(payload, indent=1, default=float))
        print(f"figures written to {args.json}", file=sys.stderr)
    return 0

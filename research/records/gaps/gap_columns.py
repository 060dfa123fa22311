"""The optimality gap of recorded evaluations: each episode's avg_uncertainty over the planner's and
the lower bound's on the same episode (same graph, team size and env seed).

Usage::

    python research/records/gaps/gap_columns.py research/records/comparison/results.json ...
    python research/records/gaps/gap_columns.py --label "transfer team" \
        research/records/transfer_advice_family/family_rgg-60_s*.json

Reads every ``<graph>_s<seed>.json`` of ``sb3-pm bound --planner --json`` beside this file (and
``bound_only_<graph>_s<seed>.json`` of ``sb3-pm bound --json``, the bound alone), and the record files named: a report's ``results.json`` (every row, per graph) or single
evaluations (``sb3-pm evaluate --json``, grouped under ``--label``). Prints one line per (row,
graph): the mean avg_uncertainty, the mean of the per-episode ratios to the planner and to the
lower bound, and how many episodes had both. An episode without a planner row is left out of
the ratios and counted.
"""

from __future__ import annotations

import argparse
import json
import re
from collections import defaultdict
from pathlib import Path

from sb3_pm.graphs import resolve_graph

HERE = Path(__file__).parent


def graph_key(name: str) -> str:
    """The preset name of a recorded graph: records before the presets were renamed say
    ``paper_50n_8t`` for ``paper-50``."""
    old = re.fullmatch(r"paper_(\d+)n_\d+t", name)
    return f"paper-{old.group(1)}" if old else resolve_graph(name).name


def bound_rows() -> dict[tuple[str, int, int], dict]:
    """``(graph name, agents, env seed) -> row`` of every bound file beside this script."""
    rows = {}
    for path in sorted(HERE.glob("*_s*.json")):
        data = json.loads(path.read_text())
        name = graph_key(data["graph"])
        for row in data["rows"]:
            # a bound-only file (no --planner) adds the bound where no planner row is known
            rows.setdefault((name, int(data["agents"]), int(row["env_seed"])), {}).update(row)
    return rows


def runs_of(path: Path, label: str | None) -> list[tuple[str, dict]]:
    data = json.loads(path.read_text())
    if "results" in data:  # a report: label -> runs
        return [(name, run) for name, runs in data["results"].items() for run in runs]
    if "evaluation" in data:  # benchmarks/benchmarl_peers.py's record around an evaluation
        data = data["evaluation"]
    return [(label or data["config"]["policy"], data)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("records", nargs="+", type=Path)
    parser.add_argument("--label", help="the row name of single evaluation files")
    args = parser.parse_args()
    bounds = bound_rows()
    table: dict[tuple[str, str], list[tuple[float, float | None, float | None]]] = defaultdict(list)
    for path in args.records:
        for label, run in runs_of(path, args.label):
            config = run["config"]
            name = graph_key(config["graph"])
            for episode in run["episodes"]:
                row = bounds.get((name, int(config["n_agents"]), int(episode["seed"])))
                value = float(episode["avg_uncertainty"])
                planner = value / row["planner"] if row and "planner" in row else None
                bound = value / row["lower_bound"] if row and row["lower_bound"] > 0 else None
                table[(label, name)].append((value, planner, bound))
    for (label, graph), values in table.items():
        n = len(values)
        mean = sum(v for v, _, _ in values) / n
        planner = [p for _, p, _ in values if p is not None]
        bound = [b for _, _, b in values if b is not None]
        cells = [
            f"{label:45s} {graph:16s} mean {mean:9.1f}",
            f"x planner {sum(planner) / len(planner):6.2f}" if planner else "x planner      -",
            f"x bound {sum(bound) / len(bound):7.2f}" if bound else "x bound       -",
            f"({len(planner)}/{n} episodes with a planner row)",
        ]
        print("  ".join(cells))


if __name__ == "__main__":
    main()

"""``sb3-pm bound``: the optimum's bracket on some episodes: the lower bound, and the planner.

For each episode (env seed ``SEED + e``, the episodes ``sb3-pm evaluate --seed SEED`` plays) it
prints the two lower bounds of :mod:`sb3_pm.planning.bound` and their maximum, the bound no team
can beat; with ``--planner`` also the ``optimal_planner``'s replayed ``avg_uncertainty``, an upper
bound on the optimum, and how far apart the two are.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from sb3_pm.commands.evaluate import check_counts


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "bound",
        help="lower bounds on avg_uncertainty, and the planner's best schedule",
        description=(
            "Per episode: the lower bound on any team's avg_uncertainty (docs/PLANNING.md) and, with "
            "--planner, the optimal_planner's replayed score, an upper bound on the optimum."
        ),
    )
    parser.add_argument("--graph", default="paper-50", help="a preset or a .graphml path (default paper-50)")
    parser.add_argument("--agents", type=int, default=4, help="team size (default 4)")
    parser.add_argument("--steps", type=int, default=500, help="episode length K (default 500)")
    parser.add_argument("--episodes", type=int, default=10, help="number of episodes (default 10)")
    parser.add_argument("--seed", type=int, default=0, help="episode e uses env seed SEED + e (default 0)")
    parser.add_argument("--planner", action="store_true", help="also run optimal_planner on each episode")
    parser.add_argument(
        "--search-seconds",
        type=float,
        default=30.0,
        help="the planner's search budget per episode, in seconds (default 30)",
    )
    parser.add_argument("--json", type=Path, default=None, metavar="FILE", help="also write the rows as JSON")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from sb3_pm.baselines import make_team
    from sb3_pm.envs import persistent_monitoring_v0
    from sb3_pm.errors import UsageError
    from sb3_pm.evaluation import evaluate
    from sb3_pm.files import write_atomic
    from sb3_pm.graphs import resolve_graph
    from sb3_pm.planning import priced_bound, stepwise_bound

    check_counts(args)
    if not args.search_seconds > 0:
        raise UsageError(f"--search-seconds must be positive, got {args.search_seconds}")
    graph = resolve_graph(args.graph)
    env = persistent_monitoring_v0.parallel_env(graph=graph, n_agents=args.agents, max_cycles=args.steps)
    rows: list[dict[str, Any]] = []
    for episode in range(args.episodes):
        seed = args.seed + episode
        env.reset(seed=seed)
        state = env.unwrapped
        stepwise = float(
            stepwise_bound(graph, state.positions, args.steps, state.u_max, state.uncertainty).mean()
        )
        priced = priced_bound(graph, state.positions, args.steps, state.u_max, state.uncertainty)
        rows.append(
            {"env_seed": seed, "stepwise": stepwise, "priced": priced, "lower_bound": max(stepwise, priced)}
        )
    if args.planner:
        planner = make_team("optimal_planner", search_seconds=args.search_seconds)
        result = evaluate(
            planner,
            graph,
            n_agents=args.agents,
            episodes=args.episodes,
            seed=args.seed,
            max_cycles=args.steps,
            progress=None,
        )
        for row, record in zip(rows, result.episodes):
            row["planner"] = float(record.metrics["avg_uncertainty"])
            row["planner_x_bound"] = (
                row["planner"] / row["lower_bound"] if row["lower_bound"] > 0 else float("inf")
            )
    columns = ["env_seed", "stepwise", "priced", "lower_bound"] + (
        ["planner", "planner_x_bound"] if args.planner else []
    )
    last = args.seed + args.episodes - 1
    print(f"{graph.name}: {args.agents} agents, {args.steps} steps, env seeds {args.seed}..{last}")
    print("  ".join(f"{c:>15}" for c in columns))
    for row in rows:
        print("  ".join(f"{row[c]:>15}" if c == "env_seed" else f"{row[c]:>15.3f}" for c in columns))
    means = {c: float(np.mean([row[c] for row in rows])) for c in columns if c != "env_seed"}
    print("  ".join([f"{'mean':>15}"] + [f"{means[c]:>15.3f}" for c in columns[1:]]))
    if args.json is not None:
        payload = {
            "graph": graph.name,
            "agents": args.agents,
            "steps": args.steps,
            "rows": rows,
            "means": means,
        }
        write_atomic(args.json, json.dumps(payload, indent=2))
    return 0

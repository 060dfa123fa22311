"""``sb3-pm bound``: the optimum's bracket on some episodes: the lower bound, and the planner.

For each episode (env seed ``SEED + e``, the episodes ``sb3-pm evaluate --seed SEED`` plays) it
prints the lower bounds of :mod:`sb3_pm.planning.bound` and :mod:`sb3_pm.planning.components`
and their maximum, the bound no team can beat; with ``--planner`` also the ``optimal_planner``'s
replayed ``avg_uncertainty``, an upper bound on the optimum, and how far apart the two are.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from sb3_pm.commands.evaluate import check_counts

#: The search budget, in seconds, of the plan whose score prunes the components bound without
#: ``--planner``.
QUICK_PLAN_SECONDS = 5.0


def _cell(value: Any, column: str) -> str:
    if column == "env_seed":
        return f"{value:>15}"
    return f"{'-':>15}" if value is None else f"{value:>15.3f}"


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "bound",
        help="lower bounds on avg_uncertainty, and the planner's best schedule",
        description=(
            "Per episode: the lower bounds on any team's avg_uncertainty (docs/PLANNING.md) and their "
            "maximum and, with --planner, the optimal_planner's replayed score, an upper bound on the "
            "optimum."
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
    parser.add_argument(
        "--no-components",
        action="store_true",
        help="skip the components bound (the slowest: seconds to a minute an episode where it applies)",
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
    from sb3_pm.planning import component_bound, priced_bound, stepwise_bound
    from sb3_pm.planning.components import component_bound_applies
    from sb3_pm.planning.team_plan import plan_team
    from sb3_pm.progress import progress_bar

    check_counts(args)
    if not args.search_seconds > 0:
        raise UsageError(f"--search-seconds must be positive, got {args.search_seconds}")
    graph = resolve_graph(args.graph)
    env = persistent_monitoring_v0.parallel_env(graph=graph, n_agents=args.agents, max_cycles=args.steps)
    planned: list[float] = []
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
        planned = [float(record.metrics["avg_uncertainty"]) for record in result.episodes]
    rows: list[dict[str, Any]] = []
    bar = progress_bar(args.episodes, "bounds", unit="episode")
    for episode in range(args.episodes):
        seed = args.seed + episode
        env.reset(seed=seed)
        state = env.unwrapped
        stepwise = float(
            stepwise_bound(graph, state.positions, args.steps, state.u_max, state.uncertainty).mean()
        )
        priced = priced_bound(graph, state.positions, args.steps, state.u_max, state.uncertainty)
        row = {"env_seed": seed, "stepwise": stepwise, "priced": priced, "components": None}
        if not args.no_components and component_bound_applies(graph, args.agents, state.u_max):
            # The components bound drops states by an achievable score: the planner's, or a quick plan's.
            ceiling = (
                planned[episode]
                if planned
                else plan_team(
                    graph, state.positions, args.steps, state.u_max, state.uncertainty, QUICK_PLAN_SECONDS
                ).simulated
            )
            row["components"] = component_bound(
                graph, state.positions, args.steps, state.u_max, state.uncertainty, ceiling=ceiling
            )
        found = [value for value in (stepwise, priced, row["components"]) if value is not None]
        row["lower_bound"] = max(found)
        if planned:
            row["planner"] = planned[episode]
            row["planner_x_bound"] = (
                row["planner"] / row["lower_bound"] if row["lower_bound"] > 0 else float("inf")
            )
        rows.append(row)
        bar.update(1)
    bar.close()
    columns = ["env_seed", "stepwise", "priced", "components", "lower_bound"] + (
        ["planner", "planner_x_bound"] if args.planner else []
    )
    last = args.seed + args.episodes - 1
    print(f"{graph.name}: {args.agents} agents, {args.steps} steps, env seeds {args.seed}..{last}")
    print("  ".join(f"{c:>15}" for c in columns))
    for row in rows:
        print("  ".join(_cell(row[c], c) for c in columns))
    # a column with an episode left out (the components bound where too large) has no mean
    means = {
        c: (None if any(row[c] is None for row in rows) else float(np.mean([row[c] for row in rows])))
        for c in columns
        if c != "env_seed"
    }
    print("  ".join([f"{'mean':>15}"] + [_cell(means[c], c) for c in columns[1:]]))
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

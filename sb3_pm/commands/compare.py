"""``sb3-pm compare``: evaluate several policies on several graphs and seeds; write tables and plots."""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path
from typing import Any

from sb3_pm.commands.evaluate import check_counts, check_evaluation_memory
from sb3_pm.commands.options import add_compute_options, check_compute_options


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "compare",
        help="compare policies over graphs x seeds x episodes",
        description=(
            "Evaluate every policy on every graph and seed, then write table.md/.csv/.tex, by_graph.md, "
            "effects.md, anova.txt, runs.md (IQM and probability of improvement over training runs), "
            "results.json, marl_eval.json, uncertainty.png, table.png and performance_profile.png into --out."
        ),
    )
    parser.add_argument(
        "--policies", nargs="+", required=True, help="baseline names and/or trained team directories"
    )
    parser.add_argument("--graphs", nargs="+", default=["paper-50"], help="presets or .graphml paths")
    parser.add_argument(
        "--seeds", nargs="+", type=int, default=[0], help="grid seeds; seed s uses env seeds s*1000+e"
    )
    parser.add_argument(
        "--episodes", type=int, default=10, help="episodes per policy, graph and seed (default 10)"
    )
    parser.add_argument("--steps", type=int, default=500, help="episode length K (default 500)")
    parser.add_argument(
        "--agents",
        type=int,
        default=None,
        help="team size (default: each trained team's own size, 4 for a rule-based policy)",
    )
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--overwrite", action="store_true", help="write into a non-empty --out")
    parser.add_argument(
        "--deterministic",
        action="store_true",
        help="every learned team takes its most likely actions; without it each team acts by its "
        "config's deploy_temperature, saved with it",
    )
    parser.add_argument("--no-progress", action="store_true", help="never show progress")
    add_compute_options(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from sb3_pm.errors import UsageError
    from sb3_pm.evaluation import compare, markdown_table, policy_label, resolve_team
    from sb3_pm.graphs import resolve_graph

    check_counts(args)
    check_compute_options(args)
    if args.out.exists() and not args.out.is_dir():
        raise UsageError(f"--out {args.out} exists and is not a directory")
    if args.out.is_dir() and any(args.out.iterdir()) and not args.overwrite:
        raise FileExistsError(f"--out {args.out} is not empty; pass --overwrite to write into it")
    if len(set(args.policies)) != len(args.policies):
        raise UsageError(f"--policies lists a policy twice: {args.policies}")
    graphs = {name: resolve_graph(name) for name in args.graphs}  # every graph checked before the long part
    for name, graph in graphs.items():  # sizes only: before any team loads or env is built
        for policy in args.policies:
            check_evaluation_memory(policy, graph, args.agents, name)
    teams = {}
    for policy in args.policies:
        team = resolve_team(policy, graph=args.graphs[0], device=args.device)  # checks it now
        label = policy_label(policy, team)
        if label in teams:
            raise UsageError(f"two policies share the label {label!r}")
        teams[label] = lambda graph, policy=policy: resolve_team(policy, graph=graph, device=args.device)
    comparison = compare(
        teams,
        args.graphs,
        seeds=args.seeds,
        episodes=args.episodes,
        n_agents=args.agents,
        max_cycles=args.steps,
        progress=False if args.no_progress else None,
        threads=args.threads,
        deterministic=True if args.deterministic else None,
    )
    comparison.config["command"] = shlex.join(getattr(args, "command_line", ["sb3-pm", *sys.argv[1:]]))
    written = comparison.write(args.out)
    print(markdown_table(comparison.table), end="")
    print(f"wrote {len(written)} files to {args.out}", file=sys.stderr)
    return 0

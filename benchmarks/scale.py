"""How the cost of an episode grows with the site: seconds per step and peak memory against N.

Run: ``python benchmarks/scale.py [--sizes 250 500 1000 2000] [--policies random grazing
territory_patrol] [--steps 100] [--layout dense|edges]``.

Each cell runs in its own process (one torch thread), so its peak resident memory is its own: it
builds a seeded ``city_streets`` site of N nodes (one target per 10 nodes) with one agent per 80
nodes (``suggested_agents``), plays ``--steps`` steps of the policy, and reports the build time,
the seconds per step and the process's peak memory. A fitted exponent ``b`` of ``seconds per step
∝ N^b`` (least squares on the logarithms, over the sizes each policy ran) says how the cost grows.

With ``--layout dense`` (the env's default) the environment stores each agent's map and the site's
distances densely (N × N), so memory and time grow at least quadratically in N. ``--layout edges``
runs the env's edges layout: maps and observations over the edge list, sensing tables as sparse
rows, and a trained team rebuilt for it (``resolve_team(..., layout="edges")``), whose actor reads
the allowed nodes' neighbourhoods on large sites; the territory rule reads per-target routes above
500 nodes, as do ``grazing``, ``sit_on_nodes`` and ``tour_patrol``, and ``local_greedy`` searches
each agent's known edges (the ``GraphSpec`` keeps its N × N bool adjacency; the planners still
build all-pairs distances).

``--agents`` fixes the team size; ``--neglect-bound B|off`` sets a trained team's bound (scope
``territory``); ``--territories`` sets a trained team's territory convention (``planned_tours``, as
``pretrained:transfer`` deploys on large sites; its plan is part of the build time).
``pretrained:transfer_split``'s ``deploy_filter: auto`` is calibrated only by ``sb3-pm evaluate``,
and only for its own 4 agents, so without ``--neglect-bound`` it acts with none.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time

import numpy as np


def cell(
    size: int,
    policy: str,
    steps: int,
    seed: int,
    layout: str = "dense",
    agents: int | None = None,
    bound: str | None = None,
    territories: str | None = None,
) -> dict[str, float]:
    """One (size, policy) measurement, in this process (``agents``: the team size, default
    ``suggested_agents``; ``bound``: a trained team's neglect bound, a number or ``off``;
    ``territories``: a trained team's convention, default its own)."""
    import torch

    torch.set_num_threads(1)
    from sb3_pm.baselines import BASELINES
    from sb3_pm.evaluation import resolve_team
    from sb3_pm.graphs.large_sites import city_streets, suggested_agents

    start = time.perf_counter()
    graph = city_streets(size, seed=seed)
    team = resolve_team(policy, graph=graph, layout=None if policy in BASELINES else layout)
    if bound is not None and policy not in BASELINES:  # else a deploy_filter auto acts with none
        if bound == "off":
            team.set_filter(neglect_bound=None)
        else:
            team.set_filter(neglect_bound=float(bound), neglect_scope="territory")
    n_agents = agents or suggested_agents(size)
    conventions = {} if territories is None or policy in BASELINES else {"territories": territories}
    env = team.make_env(graph, n_agents=n_agents, max_cycles=steps, layout=layout, **conventions)
    observations, _ = env.reset(seed=seed)
    team.reset(env, seed=seed)
    built = time.perf_counter() - start
    start = time.perf_counter()
    while env.agents:
        observations, *_ = env.step(team.predict_dict(observations))
    played = time.perf_counter() - start
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return {
        "nodes": size,
        "agents": n_agents,
        "build_s": built,
        "seconds_per_step": played / steps,
        "peak_mb": peak_mb,
        "avg_uncertainty": float(env.unwrapped.episode_metrics()["avg_uncertainty"]),
    }


def exponent(sizes: list[int], seconds: list[float]) -> float:
    """``b`` of ``seconds ∝ N^b``, least squares on the logarithms."""
    slope, _ = np.polyfit(np.log(sizes), np.log(seconds), 1)
    return float(slope)


def main() -> None:
    from sb3_pm.planning.conventions import TERRITORY_CONVENTIONS

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[250, 500, 1000, 2000])
    parser.add_argument("--policies", nargs="+", default=["random", "grazing", "territory_patrol"])
    parser.add_argument("--steps", type=int, default=100, help="steps per cell (default 100)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--layout", choices=("dense", "edges"), default="dense", help="the env's layout")
    parser.add_argument("--agents", type=int, default=None, help="team size (default: one per 80 nodes)")
    parser.add_argument(
        "--neglect-bound",
        default=None,
        metavar="B",
        help="a trained team's neglect bound (territory scope): a number, or off (default: the team's "
        "own, which for a deploy_filter auto means none here, as nothing calibrates it)",
    )
    parser.add_argument(
        "--territories",
        choices=TERRITORY_CONVENTIONS,
        default=None,
        help="a trained team's territory convention (default: its own)",
    )
    parser.add_argument("--json", default=None, help="also write the rows to this file")
    parser.add_argument("--cell", nargs=2, metavar=("SIZE", "POLICY"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.cell:
        size, policy = int(args.cell[0]), args.cell[1]
        row = cell(
            size,
            policy,
            args.steps,
            args.seed,
            args.layout,
            args.agents,
            args.neglect_bound,
            args.territories,
        )
        print(json.dumps(row))
        return
    environment = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    rows = []
    print(f"{'policy':>18} {'N':>6} {'agents':>6} {'build s':>8} {'ms/step':>9} {'peak MB':>8}")
    for policy in args.policies:
        for size in args.sizes:
            command = [sys.executable, __file__, "--cell", str(size), policy, "--steps", str(args.steps)]
            command += ["--layout", args.layout]
            command += [] if args.agents is None else ["--agents", str(args.agents)]
            command += [] if args.neglect_bound is None else ["--neglect-bound", args.neglect_bound]
            command += [] if args.territories is None else ["--territories", args.territories]
            done = subprocess.run(
                [*command, "--seed", str(args.seed)], capture_output=True, text=True, env=environment
            )
            if done.returncode != 0:
                print(f"{policy:>18} {size:>6} failed: {done.stderr.strip().splitlines()[-1]}")
                continue
            row = {"policy": policy, **json.loads(done.stdout.strip().splitlines()[-1])}
            rows.append(row)
            print(
                f"{policy:>18} {size:>6} {row['agents']:>6} {row['build_s']:>8.2f} "
                f"{1000 * row['seconds_per_step']:>9.2f} {row['peak_mb']:>8.0f}"
            )
    for policy in args.policies:
        mine = [row for row in rows if row["policy"] == policy]
        if len(mine) >= 2:
            b = exponent([row["nodes"] for row in mine], [row["seconds_per_step"] for row in mine])
            print(f"{policy}: seconds per step grow as N^{b:.2f}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as handle:
            json.dump(rows, handle, indent=2)


if __name__ == "__main__":
    main()

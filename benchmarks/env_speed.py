"""Environment throughput: parallel env steps per second with 4 agents and mental maps.

Run: ``python benchmarks/env_speed.py [--steps 20000] [--graphs paper-50 paper-100 paper-200]``.
Actions are drawn up front from each step's action masks by a tiny vectorized random walk, so
the figure measures the environment (dynamics, mental maps, observations, rewards, metrics),
not the policy.

Next to each graph's figure, the same random walk drives a *bare* eq. (1) loop in the same
process: NumPy arrays of positions and uncertainties, one ``bincount`` for presence and one
``where`` for the capped update, nothing else (no observations, maps, rewards or metrics). The
ratio env / bare is what the environment's bookkeeping costs over the dynamics alone.

The machine's speed drifts by a factor of two within minutes on shared virtual machines, so the
two loops alternate ``--repeats`` times. Two figures are printed: the median of the per-repeat
ratios (each compares two runs seconds apart), and the ratio of the best rates (each loop's
fastest repeat, the least disturbed one: the usual estimator of a micro-benchmark's cost).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from sb3_pm.envs import persistent_monitoring_v0


def measure(graph: str, n_agents: int, steps: int, observation: str, seed: int = 0) -> float:
    env = persistent_monitoring_v0.parallel_env(
        graph=graph, n_agents=n_agents, max_cycles=500, observation=observation
    )
    neighbour_lists = [np.flatnonzero(row).tolist() for row in env.graph.reachable]
    rng = np.random.default_rng(seed)
    draws = rng.random((steps, n_agents)).tolist()  # pre-drawn so the policy costs almost nothing
    observations, _ = env.reset(seed=seed)
    agents = env.possible_agents
    done = 0
    start = time.perf_counter()
    while done < steps:
        positions = env.core.positions.tolist()
        actions = {
            a: (options := neighbour_lists[p])[int(r * len(options))]
            for a, p, r in zip(agents, positions, draws[done])
        }
        observations, _, _, truncations, _ = env.step(actions)
        done += 1
        if truncations[agents[0]]:
            observations, _ = env.reset()
    return steps / (time.perf_counter() - start)


def bare_loop(graph: str, n_agents: int, steps: int, seed: int = 0) -> float:
    """Steps per second of eq. (1) alone, with the same random walk as :func:`measure`."""
    from sb3_pm.graphs import resolve_graph

    spec = resolve_graph(graph)
    neighbour_lists = [np.flatnonzero(row).tolist() for row in spec.reachable]
    rng = np.random.default_rng(seed)
    draws = rng.random((steps, n_agents)).tolist()
    targets = spec.target_indices
    n_nodes, u_max = spec.n_nodes, 100
    positions = rng.choice(n_nodes, size=n_agents, replace=False).tolist()
    u = np.zeros(len(targets), dtype=np.int64)
    start = time.perf_counter()
    for k in range(steps):
        positions = [
            (options := neighbour_lists[p])[int(r * len(options))] for p, r in zip(positions, draws[k])
        ]
        present = np.bincount(positions, minlength=n_nodes)[targets] > 0
        u = np.where(present, np.maximum(u - 1, 0), np.minimum(u + 1, u_max))
    return steps / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20000)
    parser.add_argument("--agents", type=int, default=4)
    parser.add_argument("--graphs", nargs="+", default=["paper-50", "paper-100", "paper-200"])
    parser.add_argument("--observation", default="map", choices=["map", "local"])
    parser.add_argument("--repeats", type=int, default=5, help="alternations of env and bare loop (median)")
    args = parser.parse_args()
    if args.repeats < 1 or args.steps < 1:
        parser.error("--steps and --repeats must be at least 1")
    print(
        f"env steps/s, {args.agents} agents, observation={args.observation}, {args.steps} steps per graph"
        f" and repeat, median of {args.repeats} alternations"
    )
    for graph in args.graphs:
        rates, bares = [], []
        for _ in range(args.repeats):
            rates.append(measure(graph, args.agents, args.steps, args.observation))
            bares.append(bare_loop(graph, args.agents, args.steps))
        ratios = [rate / bare for rate, bare in zip(rates, bares)]
        print(
            f"  {graph:>12s}: {statistics.median(rates):10,.0f} steps/s   bare eq. (1) loop"
            f" {statistics.median(bares):10,.0f} steps/s   ratio {statistics.median(ratios):.3f}"
            f" (range {min(ratios):.3f}-{max(ratios):.3f})   best {max(rates):,.0f} / {max(bares):,.0f}"
            f" = {max(rates) / max(bares):.3f}"
        )


if __name__ == "__main__":
    main()

"""Environment throughput: parallel env steps per second with 4 agents and mental maps.

Run: ``python benchmarks/env_speed.py [--steps 20000] [--graphs paper-50 paper-100 paper-200]``.
Actions are drawn up front from each step's action masks by a tiny vectorized random walk, so
the figure measures the environment (dynamics, mental maps, observations, rewards, metrics),
not the policy.
"""

from __future__ import annotations

import argparse
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20000)
    parser.add_argument("--agents", type=int, default=4)
    parser.add_argument("--graphs", nargs="+", default=["paper-50", "paper-100", "paper-200"])
    parser.add_argument("--observation", default="map", choices=["map", "local"])
    args = parser.parse_args()
    print(f"env steps/s, {args.agents} agents, observation={args.observation}, {args.steps} steps per graph")
    for graph in args.graphs:
        rate = measure(graph, args.agents, args.steps, args.observation)
        print(f"  {graph:>12s}: {rate:10,.0f} steps/s")


if __name__ == "__main__":
    main()

"""Seconds per plan of the library's plan search (``sb3_pm.planning.planner.plan_patrol``).

    python benchmarks/plan_speed.py [--cells paper-50:4 paper-100:8 rgg-60:4] [--episodes 3]
                                    [--seed 0] [--one-by-one]

Each cell is ``GRAPH:AGENTS``. For each, the start positions of ``--episodes`` env resets (env seeds
``--seed``, ``--seed + 1``, ...) are planned with the defaults (20 restarts, 60 s cap), as the
``planned`` territory convention and ``optimal_planner`` plan them at each reset. Prints the
seconds per plan (mean and worst), whether every search completed within its cap, and the
predicted ``avg_uncertainty``. ``--one-by-one`` prices every walk one at a time instead of in
NumPy batches; the plans are the same (``tests/test_planning.py``), so the two runs differ in time
only. The load average is printed: on a shared CPU the figures are higher. Large cells work too
(``city-5k:64`` takes the search over nearby changes, docs/PLANNING.md).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.graphs.resolve import resolve_graph
from sb3_pm.planning import planner, pricer


def plan_seconds(graph_name: str, agents: int, episodes: int, seed: int) -> tuple[list[float], bool, float]:
    """Seconds of each episode's plan, whether all completed, and the mean predicted figure."""
    graph = resolve_graph(graph_name)
    env = persistent_monitoring_v0.parallel_env(graph=graph_name, n_agents=agents)
    seconds, complete, predicted = [], True, []
    for episode in range(episodes):
        env.reset(seed=seed + episode)
        starts = np.asarray(env.unwrapped.positions)
        started = time.perf_counter()
        plan = planner.plan_patrol(graph, starts, env.unwrapped.max_cycles, env.unwrapped.u_max)
        seconds.append(time.perf_counter() - started)
        complete &= plan.complete
        predicted.append(plan.predicted)
    return seconds, complete, float(np.mean(predicted))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cells", nargs="+", default=["paper-50:4", "paper-100:8", "rgg-60:4"])
    parser.add_argument("--episodes", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--one-by-one", action="store_true", help="price every walk alone (no batches)")
    args = parser.parse_args()
    if args.one_by_one:
        pricer.BATCH_MIN_WALKS = 10**12
    print(f"load average {os.getloadavg()[0]:.2f}; pricing {'one by one' if args.one_by_one else 'batched'}")
    print("| cell | s per plan (mean) | worst | all complete | predicted |")
    print("|---|---:|---:|---|---:|")
    for cell in args.cells:
        graph_name, _, agents = cell.partition(":")
        if not agents.isdigit():
            parser.error(f"a cell is GRAPH:AGENTS, got {cell!r}")
        seconds, complete, predicted = plan_seconds(graph_name, int(agents), args.episodes, args.seed)
        print(f"| {cell} | {np.mean(seconds):.2f} | {max(seconds):.2f} | {complete} | {predicted:.2f} |")


if __name__ == "__main__":
    main()

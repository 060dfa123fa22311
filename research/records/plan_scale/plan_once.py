"""One plan of the planned convention's kind (stalest rule only, no restarts) for N agents on a
site, from seeded random starts: seconds, peak memory and the predicted figure (research/LOG.md §3r).

    python plan_once.py city-5k 64
"""

import resource
import sys
import time

import numpy as np

from sb3_pm.graphs.resolve import resolve_graph
from sb3_pm.planning.planner import plan_patrol

name, n_agents = sys.argv[1], int(sys.argv[2])
graph = resolve_graph(name)
starts = np.random.default_rng(3).choice(graph.n_nodes, n_agents, replace=False)
started = time.time()
plan = plan_patrol(graph, starts, 500, 100, search_seconds=600, restarts=0, tour_groups=False)
print(
    name,
    n_agents,
    "predicted",
    round(plan.predicted, 1),
    "split",
    round(plan.notes["territory_split"], 1),
    "complete",
    plan.complete,
    "seconds",
    round(time.time() - started, 1),
    "peak MB",
    resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024,
)

"""One plan both ways, for N agents on a site from seeded random starts, no restarts: with the
stalest rule alone (the planned convention's search) and free to walk groups as tours
(research/LOG.md §3t). Prints each plan's prediction, the split's, and how many groups take each rule.

    python tour_vs_stalest.py city-5k 64
"""

import sys
import time
from collections import Counter

import numpy as np

from sb3_pm.graphs.resolve import resolve_graph
from sb3_pm.planning.planner import plan_patrol

name, n_agents = sys.argv[1], int(sys.argv[2])
graph = resolve_graph(name)
starts = np.random.default_rng(3).choice(graph.n_nodes, n_agents, replace=False)
for tours in (False, True):
    started = time.time()
    plan = plan_patrol(graph, starts, 500, 100, search_seconds=600, restarts=0, tour_groups=tours)
    print(
        name,
        n_agents,
        "tours" if tours else "stalest",
        "predicted",
        round(plan.predicted, 1),
        "split",
        round(plan.notes["territory_split"], 1),
        dict(Counter(plan.rules)),
        "dropped",
        len(plan.dropped),
        "seconds",
        round(time.time() - started, 1),
    )

"""The exhaustive plan search against the search over nearby changes, both forced, on a 300-node
street site with 24 agents on 30 targets, from three seeded starts (research/LOG.md §3r).

    python compare_searches.py K U_MAX
"""

import sys
import time

import numpy as np

from sb3_pm.graphs.large_sites import city_streets
from sb3_pm.planning import owned_search
from sb3_pm.planning.planner import plan_patrol

max_cycles, u_max = int(sys.argv[1]), int(sys.argv[2])
graph = city_streets(300, seed=3)
for seed in (0, 1, 2):
    starts = np.random.default_rng(seed).choice(graph.n_nodes, 24, replace=False)
    found = []
    for limit in (10**12, 0):  # every plan exhaustive, then none
        owned_search.EXACT_SEARCH_MAX_WALKS = limit
        started = time.time()
        plan = plan_patrol(graph, starts, max_cycles, u_max, tour_groups=False)
        found.append((round(plan.predicted, 2), round(time.time() - started, 1)))
    print(seed, "exhaustive", found[0], "nearby", found[1], "ratio", round(found[1][0] / found[0][0], 3))

"""Dump plan_patrol's plans on seven sites, both ways of pricing groups, from seeded starts, to
compare two commits of the plan search (research/LOG.md §3r).

    python same_plans.py OUT.json        # at each commit, then compare the two files
    ONLY=paper-50,karate python same_plans.py OUT.json
"""

import json
import os
import sys

import numpy as np

from sb3_pm.graphs.resolve import resolve_graph
from sb3_pm.planning.planner import plan_patrol

SITES = [
    ("paper-50", 4),
    ("karate", 4),
    ("cliques-6x8", 4),
    ("rgg-60", 4),
    ("paper-100", 8),
    ("paper-200", 16),
    ("city-1k", 12),
]
only = os.environ.get("ONLY")
out = {}
for name, n_agents in SITES:
    if only and name not in only.split(","):
        continue
    graph = resolve_graph(name)
    starts = np.random.default_rng(3).choice(graph.n_nodes, n_agents, replace=False)
    for tours in (True, False):
        restarts = 0 if name == "city-1k" else 2
        plan = plan_patrol(graph, starts, 500, 100, search_seconds=1e6, restarts=restarts, tour_groups=tours)
        out[f"{name}/{tours}"] = [plan.groups, plan.rules, plan.dropped, plan.predicted, plan.searched]
        print(name, tours, plan.predicted, plan.searched, flush=True)
with open(sys.argv[1], "w") as file:
    json.dump(out, file)

"""Plan times and plans at a given BATCH_MIN_WALKS (research/LOG.md §3u).

python plan_threshold.py GRAPH N_AGENTS BATCH_MIN_WALKS [REPEATS]: REPEATS seeded random starts,
each planned by the stalest search and by the search free to take tours; prints (tours, seconds,
prediction) per plan and a digest of every plan's groups, which must not depend on the threshold.
"""

import hashlib
import sys
import time

import numpy as np

from sb3_pm.graphs import resolve_graph
from sb3_pm.planning import conventions, pricer
from sb3_pm.planning.planner import plan_patrol

graph = resolve_graph(sys.argv[1])
n_agents = int(sys.argv[2])
pricer.BATCH_MIN_WALKS = int(sys.argv[3])
repeats = int(sys.argv[4]) if len(sys.argv) > 4 else 1
rng = np.random.default_rng(0)
rows = []
for _ in range(repeats):
    starts = rng.choice(graph.n_nodes, size=n_agents, replace=False)
    for tours in (False, True):
        start = time.perf_counter()
        plan = plan_patrol(
            graph,
            starts,
            500,
            100,
            search_seconds=conventions.PLAN_SECONDS,
            restarts=conventions.PLAN_RESTARTS,
            tour_groups=tours,
        )
        rows.append((tours, round(time.perf_counter() - start, 2), plan.predicted, plan.groups))
digest = hashlib.md5(str([groups for *_, groups in rows]).encode()).hexdigest()[:10]
print(sys.argv[1:], [(tours, seconds, predicted) for tours, seconds, predicted, _ in rows], digest)

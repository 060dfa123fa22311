"""How many targets the planned convention leaves to nobody in each held-out episode (rule 12
sweeps them), with zoo/ippo_transfer.yml's env settings. Run: python plan_drops.py G [G ...]."""

import sys

from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.graphs import resolve_graph

SETTINGS = dict(
    graph_knowledge="known", target_knowledge="known", territory_input=True, advice_input=True, territories="planned"
)

for name in sys.argv[1:]:
    graph = resolve_graph(name)
    env = persistent_monitoring_v0.parallel_env(graph=graph, n_agents=4, **SETTINGS)
    counts = []
    for seed in range(3):
        for episode in range(10):  # the held-out episodes of seed S (paper-50: env seeds 1,000,000+)
            env.reset(seed=(1000000 if name == "paper-50" else 1000000 + 1000 * seed) + episode)
            territory = env.unwrapped._territory
            counts.append(int((~territory[:, graph.target_indices].any(0)).sum()))
    print(name, f"{sum(c > 0 for c in counts)} of {len(counts)} episodes leave targets to nobody:", counts)

"""How often a team takes the territory rule's move, by the agent's hop distance to its own territory.

One episode (seed 1,000,000) per graph, no bound, the team's own deployment temperature. Counted
on the steps where the agent has a choice and is not on a target being cleared (its node's
observed u is 0), as in ../transfer_advice/agree.py.

python docs/results/transfer_advice_family/agree_hops.py TEAM rgg-60 rooms-4
"""

import sys

import networkx as nx
import numpy as np
import torch as th

from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.evaluation.teams import load_trained_team, team_env_kwargs

th.set_num_threads(1)
BANDS = ((0, 2), (3, 4), (5, 10**6))
team_dir = sys.argv[1]
for graph in sys.argv[2:]:
    team = load_trained_team(team_dir, graph)
    team.set_filter(neglect_bound=None)
    env = persistent_monitoring_v0.parallel_env(
        graph=graph, n_agents=4, max_cycles=500, **team_env_kwargs(team)
    )
    obs, _ = env.reset(seed=1000000)
    team.reset(env, seed=1000000)
    hops = None
    counts = []  # (hops to the nearest node of the own territory, took the rule's move)
    while env.agents:
        actions = team.predict_dict(obs, deterministic=False)
        for agent, o in obs.items():
            if hops is None:  # the known map: every agent's adjacency is the site's
                hops = dict(nx.all_pairs_shortest_path_length(nx.from_numpy_array(o["adjacency"] > 0)))
            position = int(o["position"])
            if o["action_mask"].sum() > 1 and o["nodes"][position, 0] == 0:
                advised = int(np.flatnonzero(o["nodes"][:, -1])[0])
                territory = np.flatnonzero(o["nodes"][:, -2])
                distance = min((hops[position][t] for t in territory), default=10**6)
                counts.append((distance, actions[agent] == advised))
        obs, *_ = env.step(actions)
    table = np.array(counts, dtype=float).reshape(-1, 2)
    parts = []
    for lo, hi in BANDS:
        rows = table[(table[:, 0] >= lo) & (table[:, 0] <= hi)]
        label = f"{lo}-{hi}" if hi < 10**6 else f">={lo}"
        share = f"{rows[:, 1].mean():.0%}" if len(rows) else "-"
        parts.append(f"{label} hops: {share} of {len(rows)}")
    avg_u = env.episode_metrics()["avg_uncertainty"]
    print(
        f"{team_dir} {graph}: the rule's move by hops to the own territory: "
        f"{'; '.join(parts)}; avg_u {avg_u:.1f}"
    )

"""A probe: `planned_patrol` on a plan that may not leave any target to nobody (research/LOG.md §3q).

The plan search prices a dropped target at its cost at the cap; this probe makes that price
prohibitive, so every target is in some agent's group, and evaluates the rule on those groups.

    python planned_patrol_without_drops.py nodrop rgg-60 4                     # groups without drops
    python planned_patrol_without_drops.py drop rgg-60 4                       # the convention as shipped
    python planned_patrol_without_drops.py drop rgg-60 4 territory_patrol      # the split rule

Each prints the five episodes' avg_uncertainty and max_neglect on env seeds 11-15.
"""

import sys

import torch

import sb3_pm.planning.pricer as pricer
from sb3_pm.baselines import make_team
from sb3_pm.evaluation import evaluate

torch.set_num_threads(1)
mode, graph, n_agents = sys.argv[1], sys.argv[2], int(sys.argv[3])
policy = sys.argv[4] if len(sys.argv) > 4 else "planned_patrol"
if mode == "nodrop":
    pricer.GroupPricer.dropped = lambda self, target: 10**12  # no plan drops a target
result = evaluate(make_team(policy), graph, n_agents=n_agents, episodes=5, seed=11)
print(
    mode,
    graph,
    n_agents,
    policy,
    [round(e.metrics["avg_uncertainty"], 1) for e in result.episodes],
    "mean",
    round(result.mean["avg_uncertainty"], 2),
    "max_neglect",
    [e.metrics["max_neglect"] for e in result.episodes],
)

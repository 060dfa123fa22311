"""Probes on one prior-4 transfer team (research/LOG.md §3q): deploy-time changes, one at a time.

    python probes.py TEAM tree-50 1000000 '{"avoid_collisions": false}'   # without the filter's rule 6
    python probes.py TEAM tree-50 1000000 '{}' 8                          # a prior of 8 while acting

TEAM is a saved team folder (results/held_out_p4/trained/transfer_planned_prior4/family-er/seed0/team);
the third argument is the first episode's env seed, the fourth DCBF filter settings for
team.set_filter, the fifth (optional) an advice prior that replaces the trained one while acting.
"""

import json
import sys

import torch

from sb3_pm import IndependentPPO
from sb3_pm.evaluation import evaluate

torch.set_num_threads(1)
path, graph, seed = sys.argv[1], sys.argv[2], int(sys.argv[3])
changes = json.loads(sys.argv[4]) if len(sys.argv) > 4 else {}
team = IndependentPPO.load(path)
if len(sys.argv) > 5:
    for model in team.models.values():
        model.policy.advice_prior = float(sys.argv[5])
team = team.on_graph(graph)
if changes:
    team.set_filter(**changes)
result = evaluate(team, graph, episodes=10, seed=seed)
print(
    graph,
    seed,
    changes,
    round(result.mean["avg_uncertainty"], 2),
    [round(e.metrics["avg_uncertainty"], 1) for e in result.episodes],
    "max_neglect",
    [int(e.metrics["max_neglect"]) for e in result.episodes],
)

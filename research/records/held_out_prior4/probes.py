"""Probes on one prior-4 transfer team (research/LOG.md §3q): deploy-time changes, one at a time.

    python probes.py TEAM tree-50 1000000 '{"avoid_collisions": false}'   # without the filter's rule 6
    python probes.py TEAM tree-50 1000000 '{}' 8                          # a prior of 8 while acting
    python probes.py TEAM tree-50 1000000 '{}' --pass-held                # wait a step, then pass

TEAM is a saved team folder (results/held_out_p4/trained/transfer_planned_prior4/family-er/seed0/team);
the third argument is the first episode's env seed, the fourth DCBF filter settings for
team.set_filter, the fifth (optional) an advice prior that replaces the trained one while acting.
``--pass-held`` adds a rule after the filter: an agent off targets whose rule's next node holds
another agent waits one step, then takes that node if it is still held (research/LOG.md §3q).
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
if len(sys.argv) > 5 and sys.argv[5] != "--pass-held":
    for model in team.models.values():
        model.policy.advice_prior = float(sys.argv[5])
team = team.on_graph(graph)
if changes:
    team.set_filter(**changes)
if "--pass-held" in sys.argv:
    import sb3_pm.policies.policy as policy_module
    from sb3_pm.envs.mental_map import AGE, OCCUPIED, TARGET

    filtered = policy_module.dcbf_filter_from_map

    def pass_held(pre, u_hat, config, u_max):
        """The filter, then: off targets, where the node the advice flags (the map's last column)
        holds another agent, stay one step (dwell 0), and take that node if it is still held."""
        mask, forced = filtered(pre, u_hat, config, u_max)
        nodes = pre["nodes"]
        rows = torch.arange(nodes.shape[0])
        position = pre.get("position_index")
        position = pre["position"].argmax(-1) if position is None else position.long()
        advice = nodes[..., -1] > 0.5
        held = (nodes[..., OCCUPIED] > 0.5) & (nodes[..., AGE] == 0)
        off_target = nodes[rows, position][:, TARGET] <= 0.5
        blocked = off_target & (advice & held).any(-1) & ~advice[rows, position]
        stay = torch.nn.functional.one_hot(position, nodes.shape[1]).bool()
        waited = pre["dwell"].reshape(-1) >= 1
        choice = torch.where(waited[:, None], advice, stay)
        return torch.where(blocked[:, None], choice, mask), forced

    policy_module.dcbf_filter_from_map = pass_held
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

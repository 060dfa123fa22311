"""How often a team's move is the territory rule's (the advice column), one episode per graph.

python docs/results/transfer_advice/agree.py RUN cliques-6x8 rgg-60
"""

import sys

import numpy as np
import torch as th

from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.evaluation.teams import load_trained_team, team_env_kwargs

th.set_num_threads(1)
team_dir = sys.argv[1]
for graph in sys.argv[2:]:
    team = load_trained_team(team_dir, graph)
    env = persistent_monitoring_v0.parallel_env(
        graph=graph, n_agents=4, max_cycles=500, **team_env_kwargs(team)
    )
    obs, _ = env.reset(seed=1000000)
    team.reset(env, seed=1000000)
    same = total = choice = same_choice = 0
    while env.agents:
        actions = team.predict_dict(obs, deterministic=False)
        for agent, o in obs.items():
            advised = int(np.flatnonzero(o["nodes"][:, -1])[0])
            total += 1
            same += actions[agent] == advised
            # a step with a choice that is not the dwell on a target being cleared
            if o["action_mask"].sum() > 1 and o["nodes"][int(o["position"]), 0] == 0:
                choice += 1
                same_choice += actions[agent] == advised
        obs, *_ = env.step(actions)
    avg_u = env.episode_metrics()["avg_uncertainty"]
    print(
        f"{team_dir} {graph}: the rule's move on {same / total:.1%} of agent-steps; "
        f"{same_choice / max(choice, 1):.1%} of {choice} steps off a target being cleared; avg_u {avg_u:.1f}"
    )

"""Where pretrained:transfer's agents leave the advised move on one tree-50 episode (research/LOG.md §3y).

    python trace_tree.py 1000003      # env seed; prints, per agent, the steps it did not take the advised node

Run from anywhere with sb3_pm installed; one torch thread. The team acts under rule 10 without
rule 11, as it was shipped when this was traced.
"""
import sys, numpy as np, torch
torch.set_num_threads(1)
from sb3_pm.evaluation.teams import resolve_team
from sb3_pm.evaluation.harness import team_seed
seed = int(sys.argv[1])
team = resolve_team("pretrained:transfer", graph="tree-50")
team.set_filter(pass_held=True, keep_moving=False)  # as shipped before rule 11
env = team.make_env("tree-50")
obs, _ = env.reset(seed=seed)
team.reset(env, seed=team_seed(seed))
u = env.unwrapped
pos_hist = []
stuck = {}
for t in range(500):
    adv = {a: int(np.flatnonzero(obs[a]["nodes"][:, -1])[0]) if obs[a]["nodes"][:, -1].any() else -1 for a in obs}
    acts = team.predict_dict(obs, deterministic=False)
    pos = [int(p) for p in u.positions]
    pos_hist.append(pos)
    for i, a in enumerate(obs):
        if adv[a] != -1 and acts[a] != adv[a]:
            stuck.setdefault(a, []).append((t, pos[i], adv[a], acts[a]))
    obs, *_ = env.step(acts)
m = u.episode_metrics()
print("avg", round(m["avg_uncertainty"], 1), "max_neglect", m["max_neglect"])
for a, l in stuck.items():
    print(a, "off-advice steps", len(l), l[:8], l[-4:])
ph = np.array(pos_hist)
for i in range(ph.shape[1]):
    vals, counts = np.unique(ph[250:, i], return_counts=True)
    print(f"agent_{i} second half nodes", dict(zip(vals.tolist(), counts.tolist())))

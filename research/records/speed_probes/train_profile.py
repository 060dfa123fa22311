"""Op-level profile of one learner's train() (one rollout, 10 epochs), one torch thread.

python docs/results/speed_probes/train_profile.py paper-200 default
python docs/results/speed_probes/train_profile.py paper-200 fast-sparse
"""

import sys
import time

import torch
from torch.profiler import ProfilerActivity, profile

from sb3_pm.agents.team import IndependentPPO
from sb3_pm.zoo import load_config

torch.set_num_threads(1)
graph, arithmetic = sys.argv[1], sys.argv[2]
KERNELS = {
    "default": {},
    "fast-sparse": {"gat_sparse_kernel": "csr", "actor_nodes": "allowed", "gat_backend": "sparse"},
}
overrides = {"policy_kwargs": KERNELS[arithmetic]} if KERNELS[arithmetic] else None
team = IndependentPPO.from_config(load_config("ippo", graph, overrides=overrides), graph, seed=0)
team.learn(total_timesteps=1000)  # fills every learner's rollout buffer
model = next(iter(team.model_files().values()))
start = time.perf_counter()
model.train()
print("train() s", time.perf_counter() - start)
with profile(activities=[ProfilerActivity.CPU]) as prof:
    model.train()
print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=25))

"""Time one learner's train() on a 200-node graph with the dense attention through plain autograd
(the default below FUSED_MIN_SCORES) and through the chunked custom kernel, alternated.

    python docs/results/speed_probes/chunked_kernel_200.py paper-200
"""

import copy
import sys
import time

import numpy as np
import torch

import sb3_pm.policies.layers as layers
from sb3_pm.agents.team import IndependentPPO
from sb3_pm.zoo import load_config

torch.set_num_threads(1)
graph = sys.argv[1]
team = IndependentPPO.from_config(load_config("ippo", graph), graph, seed=0)
team.learn(total_timesteps=500)
model = next(iter(team.model_files().values()))
state = copy.deepcopy(model.policy.state_dict())
optimizer = copy.deepcopy(model.policy.optimizer.state_dict())
for threshold in (65536, 1, 65536, 1):  # 65536: plain autograd at 1 head x 200^2; 1: chunked
    layers.FUSED_MIN_SCORES = threshold
    model.policy.load_state_dict(state)
    model.policy.optimizer.load_state_dict(optimizer)
    np.random.seed(0)  # noqa: NPY002 (SB3 draws the minibatch orders from the global NumPy generator)
    torch.manual_seed(0)
    start = time.perf_counter()
    model.train()
    print("chunked" if threshold == 1 else "autograd", f"{time.perf_counter() - start:.2f} s")

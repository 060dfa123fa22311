"""One learner's train() on a graph with the dense attention's minibatches through plain autograd
and through the chunked custom kernel, alternated from the same state; then a short seeded team run
both ways, to compare the trained parameters bit for bit.

    python docs/results/speed_probes/chunked_kernel_200.py paper-200 [team steps per learner]

The threshold patched is ``FUSED_MIN_BATCH_SCORES``: 10**12 forces plain autograd, its default lets
a minibatch of 250 maps of 200 nodes take the chunked kernel.
"""

import copy
import dataclasses
import sys
import time

import numpy as np
import torch

import sb3_pm.policies.attention as attention
from sb3_pm.agents.team import IndependentPPO
from sb3_pm.zoo import load_config

torch.set_num_threads(1)
graph = sys.argv[1]
team_steps = int(sys.argv[2]) if len(sys.argv) > 2 else 1000
default = attention.FUSED_MIN_BATCH_SCORES
team = IndependentPPO.from_config(load_config("ippo", graph), graph, seed=0)
team.learn(total_timesteps=500)
model = next(iter(team.model_files().values()))
state = copy.deepcopy(model.policy.state_dict())
optimizer = copy.deepcopy(model.policy.optimizer.state_dict())
for threshold in (10**12, default, 10**12, default):
    attention.FUSED_MIN_BATCH_SCORES = threshold
    model.policy.load_state_dict(state)
    model.policy.optimizer.load_state_dict(optimizer)
    np.random.seed(0)  # noqa: NPY002
    torch.manual_seed(0)
    start = time.perf_counter()
    model.train()
    seconds = time.perf_counter() - start
    print("chunked" if threshold == default else "autograd", f"{seconds:.2f} s per train()")

trained = []
for threshold in (10**12, default):
    attention.FUSED_MIN_BATCH_SCORES = threshold
    config = dataclasses.replace(load_config("ippo", graph), n_agents=2)
    team = IndependentPPO.from_config(config, graph, seed=0)
    start = time.perf_counter()
    team.learn(total_timesteps=team_steps)
    name = "chunked" if threshold == default else "autograd"
    print(f"{name}: 2 learners x {team_steps} steps in {time.perf_counter() - start:.1f} s")
    trained.append([p.detach().clone() for m in team.model_files().values() for p in m.policy.parameters()])
same = all(torch.equal(a, b) for a, b in zip(*trained, strict=True))
print("same parameters bit for bit:", same)

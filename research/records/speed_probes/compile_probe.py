"""torch.compile on one learner's train() (one rollout, 10 epochs, one torch thread), eager first.

Every timed call starts from the same parameters and optimizer state.

python docs/results/speed_probes/compile_probe.py extractor   # the GAT features extractor only
python docs/results/speed_probes/compile_probe.py evaluate    # the whole evaluate_actions
"""

import copy
import sys
import time

import torch

from sb3_pm.agents.team import IndependentPPO
from sb3_pm.zoo import load_config

torch.set_num_threads(1)
team = IndependentPPO.from_config(load_config("ippo", "paper-50"), "paper-50", seed=0)
team.learn(total_timesteps=1000)  # fills every learner's rollout buffer
model = next(iter(team.model_files().values()))
state = copy.deepcopy(model.policy.state_dict())
optimizer_state = copy.deepcopy(model.policy.optimizer.state_dict())


def timed(label: str) -> None:
    model.policy.load_state_dict(state)
    model.policy.optimizer.load_state_dict(optimizer_state)
    start = time.perf_counter()
    model.train()
    print(label, round(time.perf_counter() - start, 2), flush=True)


timed("eager")
timed("eager")
if sys.argv[1] == "extractor":
    model.policy.features_extractor.compile()  # in place: the state_dict keys stay
else:
    model.policy.evaluate_actions = torch.compile(model.policy.evaluate_actions)
timed("compiled, first call (compiles)")
timed("compiled")
timed("compiled")

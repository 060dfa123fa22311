"""Training speed with the side-by-side update phases limited to two at a time (a semaphore held
from each learner's rollout end to its next rollout start), against all four at once.

    for m in none sem none sem; do python docs/results/speed_probes/updates_two_at_a_time.py $m 2000; done
"""

import sys
import threading
import time

import torch

from sb3_pm.agents import agent_vec_env
from sb3_pm.agents.team import IndependentPPO
from sb3_pm.zoo import load_config

torch.set_num_threads(1)
mode, steps = sys.argv[1], int(sys.argv[2])
if mode == "sem":
    slots = threading.Semaphore(2)
    barrier = agent_vec_env.RolloutBarrier
    end, start = barrier._on_rollout_end, barrier._on_rollout_start

    def on_rollout_end(self):
        end(self)
        slots.acquire()
        self._held = True

    def release(self):
        if getattr(self, "_held", False):
            slots.release()
            self._held = False

    def on_rollout_start(self):
        release(self)
        start(self)

    barrier._on_rollout_end, barrier._on_rollout_start = on_rollout_end, on_rollout_start
    barrier._on_training_end = release
team = IndependentPPO.from_config(load_config("ippo", "paper-50"), "paper-50", seed=0)
team.learn(total_timesteps=500)
begin = time.perf_counter()
team.learn(total_timesteps=steps, reset_num_timesteps=False)
seconds = time.perf_counter() - begin
print(mode, f"{seconds:.2f} s", f"{4 * steps / seconds:.0f} agent-steps/s")
policy = next(iter(team.model_files().values())).policy
print("parameter checksum", sum(float(v.double().sum()) for v in policy.state_dict().values()))

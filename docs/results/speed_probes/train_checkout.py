"""Time one learner's ``train()`` and hash the parameters it leaves, to compare two checkouts.

Run it against each checkout, alternating, e.g. with a worktree of the previous commit:

    git worktree add /tmp/before HEAD~1
    PYTHONPATH=/tmp/before python docs/results/speed_probes/train_checkout.py paper-200
    PYTHONPATH=. python docs/results/speed_probes/train_checkout.py paper-200

A default team (seed 0, one torch thread, updates one after another) trains one rollout; then the
first learner's ``train()`` runs once more, timed. The hash covers every parameter of that learner
after it, so two checkouts that compute the same bits print the same hash.
"""

from __future__ import annotations

import hashlib
import sys
import time

import torch as th

from sb3_pm.agents.team import IndependentPPO
from sb3_pm.zoo.config import load_config


def main() -> None:
    graph = sys.argv[1] if len(sys.argv) > 1 else "paper-50"
    th.set_num_threads(1)
    team = IndependentPPO(graph, seed=0, concurrent_updates=False, **load_config("ippo", graph).team_kwargs())
    team.learn(500)
    model = team.models[team.agents[0]]
    start = time.perf_counter()
    model.train()
    seconds = time.perf_counter() - start
    digest = hashlib.sha256(b"".join(p.detach().numpy().tobytes() for p in model.policy.parameters()))
    print(f"{graph}: train() {seconds:.3f} s, parameters {digest.hexdigest()[:16]}")


if __name__ == "__main__":
    main()

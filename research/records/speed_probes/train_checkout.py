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

from _one_learner import first_learner_after_one_rollout  # this folder's helper


def main() -> None:
    graph = sys.argv[1] if len(sys.argv) > 1 else "paper-50"
    model = first_learner_after_one_rollout(graph)
    start = time.perf_counter()
    model.train()
    seconds = time.perf_counter() - start
    digest = hashlib.sha256(b"".join(p.detach().numpy().tobytes() for p in model.policy.parameters()))
    print(f"{graph}: train() {seconds:.3f} s, parameters {digest.hexdigest()[:16]}")


if __name__ == "__main__":
    main()

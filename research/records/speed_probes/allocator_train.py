"""Time one learner's ``train()`` on one rollout (two minibatches), and count its page faults.

Run it twice, once as is and once under another memory allocator, to see what the allocator
costs (the arithmetic, and so the parameters, do not depend on it):

    python docs/results/speed_probes/allocator_train.py paper-50
    LD_PRELOAD=/usr/lib/x86_64-linux-gnu/libtcmalloc_minimal.so.4 \\
        python docs/results/speed_probes/allocator_train.py paper-50

A default team is trained for one rollout; then the first learner's ``train()`` runs three times,
each from the same policy weights (the optimizer's state and the shuffling move on, which does not
matter for the timing), and the median time is printed with the minor page faults of those runs.
"""

from __future__ import annotations

import copy
import resource
import statistics
import sys
import time

from _one_learner import first_learner_after_one_rollout  # this folder's helper


def main() -> None:
    graph = sys.argv[1] if len(sys.argv) > 1 else "paper-50"
    model = first_learner_after_one_rollout(graph)
    state = copy.deepcopy(model.policy.state_dict())
    times = []
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(3):
        model.policy.load_state_dict(state)
        start = time.perf_counter()
        model.train()
        times.append(time.perf_counter() - start)
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults
    median = statistics.median(times)
    print(f"{graph}: train() {median:.3f} s (median of 3), {faults // 3} minor page faults each")


if __name__ == "__main__":
    main()

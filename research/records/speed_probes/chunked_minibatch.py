"""Would one minibatch's forward and backward pass run faster in slices (gradient accumulation)?

    python docs/results/speed_probes/chunked_minibatch.py paper-50 [--chunks 1 5] [--repeats 7]
    python docs/results/speed_probes/chunked_minibatch.py paper-200

The update's elementwise passes run over ``(250, N, 64)`` activations and, on 200 nodes,
``(250, 1, N, N)`` attention scores: tens of megabytes that no cache holds. Splitting the minibatch
into slices and accumulating their gradients keeps each slice's activations small. The summed
gradient is the same up to rounding (the sums run in another order), so this would be a
statistical equivalence, not the same bits.

A default team (seed 0, one torch thread) trains one rollout; its first learner's first minibatch
of 250 maps then runs forward and backward through the policy's ``evaluate_actions`` with a
PPO-shaped loss (policy-gradient, value and entropy terms over the whole minibatch), once in one
piece and once per slice count, alternated ``--repeats`` times. Prints the median and best time of
each. The optimizer step is not timed (it is the same either way).
"""

from __future__ import annotations

import argparse
import statistics
import time

from _one_learner import first_learner_after_one_rollout  # this folder's helper


def forward_backward(policy: object, data: object, chunks: int) -> None:
    """One minibatch's loss gradient accumulated over ``chunks`` equal slices."""
    n = data.actions.shape[0]
    size = n // chunks
    policy.optimizer.zero_grad()
    for c in range(chunks):
        rows = slice(c * size, n if c == chunks - 1 else (c + 1) * size)
        observations = {key: value[rows] for key, value in data.observations.items()}
        values, log_prob, entropy = policy.evaluate_actions(
            observations, data.actions[rows].long().flatten(), action_masks=data.action_masks[rows]
        )
        # Sums over the slice divided by the whole minibatch: the slices add up to the means.
        policy_term = -(log_prob * data.advantages[rows]).sum()
        value_term = ((values.flatten() - data.returns[rows]) ** 2).sum()
        ((policy_term + value_term - entropy.sum()) / n).backward()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("graph", nargs="?", default="paper-50")
    parser.add_argument("--chunks", type=int, nargs="+", default=[1, 5])
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    model = first_learner_after_one_rollout(args.graph)
    data = next(iter(model.rollout_buffer.get(model.batch_size)))
    times: dict[int, list[float]] = {chunks: [] for chunks in args.chunks}
    for chunks in args.chunks:  # warm-up: the allocator's first requests of each size
        forward_backward(model.policy, data, chunks)
    for _ in range(args.repeats):
        for chunks in args.chunks:
            start = time.perf_counter()
            forward_backward(model.policy, data, chunks)
            times[chunks].append(time.perf_counter() - start)
    for chunks, seconds in times.items():
        print(
            f"{args.graph}: minibatch of {data.actions.shape[0]} in {chunks} slice(s): "
            f"median {1000 * statistics.median(seconds):.1f} ms, best {1000 * min(seconds):.1f} ms"
        )


if __name__ == "__main__":
    main()

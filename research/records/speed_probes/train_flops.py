"""How close one learner's ``train()`` runs to this core's matrix-product speed.

    python docs/results/speed_probes/train_flops.py paper-50
    python docs/results/speed_probes/train_flops.py paper-200

A default team (seed 0, one torch thread) trains one rollout; then the first learner's ``train()``
runs twice more: once under torch's ``FlopCounterMode``, which counts the floating-point operations
of its matrix products (``mm``, ``addmm``, ``bmm``: forward and backward; elementwise work such as
softmax, activations and the optimizer is not counted), and once timed. The same core's speed on
plain ``float32`` matrix products, one thread, gives the rate the counted work could run at.

What it prints bounds the paper's training budget from below: ``rollouts x learners x counted
FLOPs`` spread over the machine's cores at that rate, before a single rollout step, elementwise
operation or memory stall is paid for.
"""

from __future__ import annotations

import os
import sys
import time

import torch as th
from _one_learner import first_learner_after_one_rollout  # this folder's helper
from torch.utils.flop_counter import FlopCounterMode

from sb3_pm.zoo.config import load_config


def matmul_rate(size: int = 1024, repeats: int = 20) -> float:
    """This core's single-thread ``float32`` matrix-product rate in FLOP/s (best of ``repeats``)."""
    a, b = th.randn(size, size), th.randn(size, size)
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        th.mm(a, b)
        best = min(best, time.perf_counter() - start)
    return 2 * size**3 / best


def main() -> None:
    graph = sys.argv[1] if len(sys.argv) > 1 else "paper-50"
    model = first_learner_after_one_rollout(graph)
    counter = FlopCounterMode(display=False)
    with counter:
        model.train()
    flops = counter.get_total_flops()
    start = time.perf_counter()
    model.train()
    seconds = time.perf_counter() - start
    rate = matmul_rate()
    config = load_config("ippo", graph)  # the team _one_learner trained: its size and budget
    n_agents, budget = config.n_agents, config.n_timesteps
    rollouts = budget // (model.n_steps * model.n_envs)
    cores = os.cpu_count() or 1
    floor = rollouts * n_agents * flops / (cores * rate)
    print(
        f"{graph}: train() {seconds:.3f} s, {flops / 1e9:.2f} GFLOP in matrix products "
        f"({flops / seconds / 1e9:.1f} GFLOP/s achieved)"
    )
    print(
        f"one core's float32 matrix products: {rate / 1e9:.1f} GFLOP/s "
        f"(train() runs its counted work at {flops / seconds / rate:.0%} of it)"
    )
    print(
        f"paper budget ({n_agents} x {budget:,} agent-steps, {rollouts} rollouts each): updates alone "
        f"need at least {floor:.0f} s on {cores} cores at that rate"
    )


if __name__ == "__main__":
    main()

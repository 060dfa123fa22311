"""Forward and backward pass of the dense attention through plain autograd and through the chunked
kernel, for batches of several sizes (the figures that set ``FUSED_MIN_BATCH_SCORES``), with one
torch thread; each path timed three times, alternated, best of three printed.

    python docs/results/speed_probes/attention_kernel_sizes.py
"""

import time

import torch as th

from sb3_pm.policies.attention import attention_bias, chunked_attention

th.set_num_threads(1)
th.manual_seed(0)
# (heads, nodes, maps): PPO minibatches of 250 maps, and a few other batch sizes
SHAPES = [(4, 50, 250), (1, 64, 250), (1, 90, 250), (1, 100, 250), (1, 100, 500), (1, 200, 64), (1, 200, 250)]
CHANNELS = 32
for heads, n, batch in SHAPES:
    adjacency = (th.rand(1, n, n) < 0.03).to(th.int8)
    bias = attention_bias(adjacency | adjacency.transpose(1, 2))
    index = th.zeros(batch, dtype=th.long)
    a_dst = th.randn(batch, heads, n, requires_grad=True)
    a_src = th.randn(batch, heads, n, requires_grad=True)
    h = th.randn(batch, heads, n, CHANNELS, requires_grad=True)
    grad = th.randn(batch, heads, n, CHANNELS)
    best = {False: float("inf"), True: float("inf")}
    for custom in (False, True) * 3:
        start = time.perf_counter()
        chunked_attention(a_dst, a_src, h, bias, index, 0.2, custom_kernel=custom).backward(grad)
        best[custom] = min(best[custom], time.perf_counter() - start)
    scores = batch * heads * n * n
    print(
        f"{batch} maps x {n} nodes ({heads} heads), {scores / 1e6:.2f}M scores: "
        f"plain {1e3 * best[False]:.1f} ms, chunked {1e3 * best[True]:.1f} ms"
    )

"""The chunked custom attention kernel and its plain-autograd fallback compute the same thing.

:func:`sb3_pm.policies.attention.chunked_attention` runs either the custom autograd function (which
calls private ATen backward functions) or ordinary differentiable torch operations. Both must give
equal outputs and equal gradients, on dense and on sparse graphs, and inside a GAT layer whichever
backend (dense or sparse kernel) the layer runs.
"""

from __future__ import annotations

import pytest
import torch as th

from sb3_pm.agents.training.team import IndependentPPO
from sb3_pm.graphs import erdos_renyi
from sb3_pm.policies import GraphAttention, attention, layers
from sb3_pm.policies.attention import attention_bias, chunked_attention, unique_graphs, use_chunked

# Graphs with many edges, and graphs with few edges and an isolated node (only its self loop).
DENSITIES = {"dense": 0.5, "sparse": 0.03}


def random_graphs(batch: int, n: int, density: float, seed: int = 0) -> th.Tensor:
    generator = th.Generator().manual_seed(seed)
    upper = th.triu((th.rand(batch, n, n, generator=generator) < density).float(), diagonal=1)
    adjacency = upper + upper.transpose(1, 2)
    adjacency[:, 0, :] = adjacency[:, :, 0] = 0.0
    return adjacency


@pytest.fixture
def count_custom_calls(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Counts calls of the custom autograd function, to prove each test exercised it."""
    calls: list[int] = []
    original = attention._ChunkedAttention.apply

    def counted(*args: object) -> th.Tensor:
        calls.append(1)
        return original(*args)

    monkeypatch.setattr(attention._ChunkedAttention, "apply", counted)
    return calls


@pytest.mark.parametrize("graphs", list(DENSITIES))
@pytest.mark.parametrize("chunk", [1, 3, None])
def test_custom_kernel_matches_fallback(
    graphs: str, chunk: int | None, count_custom_calls: list[int]
) -> None:
    th.manual_seed(0)
    batch, heads, n, channels = 12, 3, 17, 5
    adjacency = random_graphs(batch, n, DENSITIES[graphs])
    adjacency[6:] = adjacency[1]  # repeated graphs go through the distinct-graph index
    distinct, index = unique_graphs(adjacency)
    bias = attention_bias(distinct)
    inputs = (
        th.randn(batch, heads, n, requires_grad=True),
        th.randn(batch, heads, n, requires_grad=True),
        th.randn(batch, heads, n, channels, requires_grad=True),
    )
    a_dst, a_src, h = inputs
    custom = chunked_attention(a_dst, a_src, h, bias, index, 0.2, chunk=chunk, custom_kernel=True)
    assert count_custom_calls, "the custom kernel did not run"
    fallback = chunked_attention(a_dst, a_src, h, bias, index, 0.2, chunk=chunk, custom_kernel=False)
    assert len(count_custom_calls) == 1, "the fallback ran the custom kernel"
    th.testing.assert_close(custom, fallback)
    weight = th.randn_like(custom)
    custom_grads = th.autograd.grad((custom * weight).sum(), inputs)
    fallback_grads = th.autograd.grad((fallback * weight).sum(), inputs)
    for got, want in zip(custom_grads, fallback_grads):
        th.testing.assert_close(got, want, atol=1e-5, rtol=1e-5)


def test_fallback_uses_no_private_op(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError("private op called")

    monkeypatch.setattr(th, "_softmax_backward_data", refuse)
    a_dst, a_src = th.randn(2, 1, 6, requires_grad=True), th.randn(2, 1, 6, requires_grad=True)
    h = th.randn(2, 1, 6, 3, requires_grad=True)
    distinct, index = unique_graphs(random_graphs(2, 6, 0.5))
    out = chunked_attention(a_dst, a_src, h, attention_bias(distinct), index, 0.2, custom_kernel=False)
    out.sum().backward()
    with pytest.raises(AssertionError, match="private op"):
        chunked_attention(a_dst, a_src, h, attention_bias(distinct), index, 0.2).sum().backward()


def layer_outputs_and_grads(
    layer: GraphAttention, x: th.Tensor, adjacency: th.Tensor, dense: bool
) -> tuple[th.Tensor, ...]:
    layer.zero_grad()
    x = x.clone().requires_grad_(True)
    out = layer(x, adjacency, dense=dense)
    weight = th.linspace(-1.0, 1.0, out.numel()).view_as(out)
    (out * weight).sum().backward()
    return (out.detach(), x.grad) + tuple(p.grad.clone() for p in layer.parameters())


@pytest.mark.parametrize("graphs", list(DENSITIES))
@pytest.mark.parametrize("backend", ["dense", "sparse"])
def test_layer_kernels_agree(
    graphs: str, backend: str, monkeypatch: pytest.MonkeyPatch, count_custom_calls: list[int]
) -> None:
    """A GAT layer gives the same outputs and gradients with the custom kernel, with the fallback,
    and with the sparse kernel; ``FUSED_MIN_SCORES = 0`` routes these small graphs through the
    chunked attention that large graphs use."""
    monkeypatch.setattr(attention, "FUSED_MIN_SCORES", 0)
    th.manual_seed(0)
    custom = GraphAttention(6, 8, heads=4, backend=backend)
    fallback = GraphAttention(6, 8, heads=4, backend=backend, custom_kernel=False)
    fallback.load_state_dict(custom.state_dict())
    x, adjacency = th.randn(10, 23, 6), random_graphs(10, 23, DENSITIES[graphs])
    adjacency[4:] = adjacency[2]
    dense = backend == "dense"
    got = layer_outputs_and_grads(custom, x, adjacency, dense)
    assert bool(count_custom_calls) == dense  # the sparse kernel never runs the attention kernel
    want = layer_outputs_and_grads(fallback, x, adjacency, dense)
    for a, b in zip(got, want):
        th.testing.assert_close(a, b, atol=1e-5, rtol=1e-5)
    # ... and whichever backend ran, it agrees with the other one.
    other = layer_outputs_and_grads(fallback, x, adjacency, not dense)
    for a, b in zip(got, other):
        th.testing.assert_close(a, b, atol=1e-5, rtol=1e-5)


def test_chunked_kernel_follows_the_size_of_the_map_and_of_the_batch() -> None:
    """Large maps always take the chunked kernel; small maps only in a batch past the caches."""
    assert use_chunked(1, 1, 256)  # 65,536 scores in one map
    assert not use_chunked(2, 1, 200)  # a rollout step on 200 nodes: 80,000 scores
    assert use_chunked(250, 1, 200)  # a PPO minibatch on 200 nodes: 10M scores
    assert not use_chunked(250, 1, 50)  # the default minibatch on 50 nodes: 625,000 scores
    assert not use_chunked(250, 4, 50)  # ... at four heads: 2.5M
    assert use_chunked(500, 4, 50)  # 5M
    assert not use_chunked(250, 1, 200, on_cpu=False)  # on a GPU only the map's size counts
    assert use_chunked(1, 1, 256, on_cpu=False)


@pytest.mark.parametrize("heads", [1, 2])
def test_chunked_kernel_gives_the_same_bits_as_plain_autograd(
    heads: int, monkeypatch: pytest.MonkeyPatch, count_custom_calls: list[int]
) -> None:
    """Not only close: the chunked kernel and plain autograd over the whole batch give equal outputs
    and gradients, which is what lets the batch's size choose between them without changing a
    seeded run. A 130-node graph as sparse as the published ones, 40 maps."""
    th.manual_seed(0)
    layer = GraphAttention(9, 32, heads=heads, backend="dense")
    x, adjacency = th.randn(40, 130, 9), random_graphs(40, 130, 0.03)
    adjacency[10:] = adjacency[3]
    monkeypatch.setattr(attention, "FUSED_MIN_BATCH_SCORES", 10**12)
    plain = layer_outputs_and_grads(layer, x, adjacency, dense=True)
    assert not count_custom_calls
    monkeypatch.setattr(attention, "FUSED_MIN_BATCH_SCORES", 1)
    chunked = layer_outputs_and_grads(layer, x, adjacency, dense=True)
    assert count_custom_calls, "the chunked kernel did not run"
    for a, b in zip(chunked, plain, strict=True):
        assert th.equal(a, b)


def test_a_team_trains_the_same_parameters_with_either_kernel(
    monkeypatch: pytest.MonkeyPatch, count_custom_calls: list[int]
) -> None:
    """A seeded team whose minibatches take the chunked kernel ends with the parameters of the same
    team trained through plain autograd, bit for bit (rollout steps take plain autograd both ways)."""
    monkeypatch.setattr(attention, "CHUNK_FLOATS", 5 * 40 * 40)  # chunks of 5 maps: 32 = 6 x 5 + 2
    graph = erdos_renyi(40, 0.1, n_targets=6, seed=5)
    hyperparams = {"n_steps": 32, "batch_size": 32, "n_epochs": 2, "policy_kwargs": {"hidden_dim": 16}}
    minibatch_scores = 32 * 40 * 40
    trained = []
    for threshold in (10**12, minibatch_scores):
        monkeypatch.setattr(attention, "FUSED_MIN_BATCH_SCORES", threshold)
        team = IndependentPPO(
            graph, n_agents=2, n_envs=2, seed=0, env_kwargs={"max_cycles": 40}, hyperparams=hyperparams
        )
        team.learn(128)
        trained.append([p.detach().clone() for a in team.agents for p in team.models[a].policy.parameters()])
        assert bool(count_custom_calls) == (threshold == minibatch_scores)
    for a, b in zip(*trained, strict=True):
        assert th.equal(a, b)


@pytest.mark.parametrize("path", ["plain", "chunked", "chunked-autograd"])
def test_one_adjacency_broadcasts_its_mask_with_the_same_bits(
    path: str, monkeypatch: pytest.MonkeyPatch, count_custom_calls: list[int]
) -> None:
    """With one adjacency for every map (a known topology), the mask broadcasts over the batch
    instead of being gathered per map; outputs and gradients are equal to the gathered mask's, bit
    for bit, through plain autograd, the chunked kernel (5 chunks, the last one short) and its
    autograd fallback."""
    th.manual_seed(0)
    chunked = path != "plain"
    layer = GraphAttention(9, 32, heads=1, backend="dense", custom_kernel=path == "chunked")
    x = th.randn(24, 60, 9)
    upper = th.triu((th.rand(60, 60, generator=th.Generator().manual_seed(1)) < 0.05).float(), diagonal=1)
    adjacency = upper.expand(24, 60, 60).contiguous()  # one-way edges: a transposed mask would differ
    monkeypatch.setattr(attention, "FUSED_MIN_BATCH_SCORES", 1 if chunked else 10**12)
    monkeypatch.setattr(attention, "CHUNK_FLOATS", 5 * 60 * 60)
    shapes: list[tuple[int, ...]] = []
    broadcast = attention.maps_bias

    def recorded(bias: th.Tensor, index: th.Tensor) -> th.Tensor:
        mask = broadcast(bias, index)
        shapes.append(tuple(mask.shape))
        return mask

    def gathered(bias: th.Tensor, index: th.Tensor) -> th.Tensor:
        return bias[index]

    for module in (attention, layers):
        monkeypatch.setattr(module, "maps_bias", recorded)
    with_broadcast = layer_outputs_and_grads(layer, x, adjacency, dense=True)
    assert shapes and all(shape[0] == 1 for shape in shapes), "the mask was not broadcast"
    for module in (attention, layers):
        monkeypatch.setattr(module, "maps_bias", gathered)
    with_copies = layer_outputs_and_grads(layer, x, adjacency, dense=True)
    assert bool(count_custom_calls) == (path == "chunked")
    for a, b in zip(with_broadcast, with_copies, strict=True):
        assert th.equal(a, b)

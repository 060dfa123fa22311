"""The sparse CSR kernel of the GAT layer: the same function and gradients as PyG's GATConv."""

from __future__ import annotations

import pytest
import torch as th

from sb3_pm.policies import GATFeaturesExtractor, GraphAttention, layers
from sb3_pm.policies.attention import unique_graphs
from sb3_pm.policies.csr_attention import _CSRAggregate, csr_gat_attention, csr_graph


def random_graphs(batch: int, n: int, density: float, seed: int = 0) -> th.Tensor:
    generator = th.Generator().manual_seed(seed)
    upper = th.triu((th.rand(batch, n, n, generator=generator) < density).float(), diagonal=1)
    return upper + upper.transpose(1, 2)


def twin_layers(in_channels: int, heads: int) -> tuple[GraphAttention, GraphAttention]:
    th.manual_seed(0)
    csr = GraphAttention(in_channels, 8, heads=heads, backend="sparse", sparse_kernel="csr")
    pyg = GraphAttention(in_channels, 8, heads=heads, backend="sparse")  # the default, "pyg"
    pyg.load_state_dict(csr.state_dict())
    return csr, pyg


@pytest.mark.parametrize("heads", [1, 3])
@pytest.mark.parametrize("density", [0.0, 0.15, 0.6])
def test_csr_kernel_matches_pyg_values_and_gradients(heads: int, density: float) -> None:
    csr, pyg = twin_layers(7, heads)
    adjacency = random_graphs(6, 13, density)
    x = th.randn(6, 13, 7, requires_grad=True)
    out_csr, out_pyg = csr(x, adjacency), pyg(x, adjacency)
    th.testing.assert_close(out_csr, out_pyg, atol=1e-5, rtol=1e-5)
    weight = th.randn_like(out_pyg)
    grads_csr = th.autograd.grad((out_csr * weight).sum(), [x, *csr.parameters()])
    grads_pyg = th.autograd.grad((out_pyg * weight).sum(), [x, *pyg.parameters()])
    for got, want in zip(grads_csr, grads_pyg):
        th.testing.assert_close(got, want, atol=1e-5, rtol=1e-4)


def test_csr_kernel_with_a_per_graph_encoding() -> None:
    """The encoding's columns, given once per distinct graph, enter the CSR kernel like the input's."""
    csr, pyg = twin_layers(5 + 9, heads=2)
    adjacency = random_graphs(12, 9, 0.3)
    adjacency[5:] = adjacency[0]
    graphs, index = unique_graphs(adjacency)
    encoding = th.randn(len(graphs), 9, 9)
    x = th.randn(12, 9, 5)
    full = th.cat((x, encoding[index]), dim=-1)
    th.testing.assert_close(
        csr(x, adjacency, encoding=(encoding, index)), pyg(full, adjacency), atol=1e-5, rtol=1e-5
    )


def test_aggregation_gradients_pass_gradcheck() -> None:
    """The custom backward pass (transposed product, sampled product) against finite differences."""
    adjacency = random_graphs(3, 7, 0.4, seed=2)
    graph = csr_graph(adjacency)
    values = th.rand(graph.col.numel(), dtype=th.float64, requires_grad=True)
    features = th.randn(graph.size, 4, dtype=th.float64, requires_grad=True)
    assert th.autograd.gradcheck(lambda v, f: _CSRAggregate.apply(v, f, graph), (values, features))


def test_the_pattern_from_distinct_graphs_is_the_direct_one() -> None:
    adjacency = random_graphs(20, 10, 0.3)
    adjacency[::3] = adjacency[1]
    direct, shared = csr_graph(adjacency), csr_graph(adjacency, unique_graphs(adjacency))
    for name in ("crow", "col", "row", "t_crow", "t_col", "perm"):
        assert th.equal(getattr(direct, name), getattr(shared, name)), name
    # Every node has its self loop, and the transposed pattern lists the same edges.
    assert (direct.crow[1:] - direct.crow[:-1] >= 1).all()
    assert th.equal(direct.row[direct.perm], direct.t_col) and th.equal(
        direct.col[direct.perm].diff() >= 0, th.ones(len(direct.perm) - 1, dtype=th.bool)
    )


def test_extractor_sparse_kernels_agree(monkeypatch: pytest.MonkeyPatch) -> None:
    """A whole encoder on a sparse minibatch: CSR and PyG kernels give the same embeddings."""
    from gymnasium import spaces

    n = 70  # above the size where "auto" always runs the dense kernel
    space = spaces.Dict(
        {
            "nodes": spaces.Box(0.0, 1.0, (n, 5)),
            "adjacency": spaces.Box(0, 1, (n, n), dtype="int8"),
            "position": spaces.Discrete(n),
        }
    )
    th.manual_seed(0)
    csr = GATFeaturesExtractor(
        space, hidden_dim=8, gat_heads=2, laplacian="none", backend="sparse", sparse_kernel="csr"
    )
    pyg = GATFeaturesExtractor(
        space, hidden_dim=8, gat_heads=2, laplacian="none", backend="sparse", sparse_kernel="pyg"
    )
    pyg.load_state_dict(csr.state_dict())
    adjacency = random_graphs(16, n, 0.03).to(th.int8)
    obs = {"nodes": th.rand(16, n, 5), "adjacency": adjacency, "position": th.zeros(16, n)}
    calls = []
    monkeypatch.setattr(
        layers, "csr_gat_attention", lambda *a, **k: calls.append(1) or csr_gat_attention(*a, **k)
    )
    th.testing.assert_close(csr.node_embeddings(obs), pyg.node_embeddings(obs), atol=1e-5, rtol=1e-5)
    assert len(calls) == len(csr.gat)  # the CSR encoder really ran its kernel, the PyG one did not


def test_the_policy_passes_its_kernel_options_down() -> None:
    from sb3_pm.envs.single_agent import SingleAgentMonitoringEnv
    from sb3_pm.graphs import erdos_renyi
    from sb3_pm.policies import DCBFActorCriticPolicy

    env = SingleAgentMonitoringEnv(erdos_renyi(10, 0.3, n_targets=3, seed=1), n_agents=2, max_cycles=5)
    policy = DCBFActorCriticPolicy(
        env.observation_space,
        env.action_space,
        lambda _: 3e-4,
        gat_sparse_kernel="csr",
        actor_nodes="allowed",
    )
    assert all(layer.sparse_kernel == "csr" for layer in policy.features_extractor.gat)
    saved = policy._get_constructor_parameters()
    assert saved["gat_sparse_kernel"] == "csr" and saved["actor_nodes"] == "allowed"


def test_unknown_sparse_kernel_is_refused() -> None:
    with pytest.raises(ValueError, match="sparse_kernel must be one of"):
        GraphAttention(4, 4, sparse_kernel="fast")

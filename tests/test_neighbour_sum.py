"""The GAT layer's sum over neighbours by sparse products (:mod:`sb3_pm.policies.neighbour_sum`):
PyG's GATConv's function, values and gradients, up to float32 rounding; and where it runs."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from torch_geometric.nn import GATConv

from sb3_pm.envs.single_agent import SingleAgentMonitoringEnv
from sb3_pm.graphs import erdos_renyi
from sb3_pm.policies import DCBFActorCriticPolicy, edges
from sb3_pm.policies.neighbour_sum import TargetSortedEdges, applies_to, gat_by_products

SITE = erdos_renyi(60, 0.06, n_targets=6, seed=3)
#: The env settings under which an agent is told the territory rule's move.
ADVISED = {"advice_input": True, "graph_knowledge": "known", "target_knowledge": "known"}
FIELDS = ("source", "target", "target_rows", "by_source", "source_rows")


def random_edges(n_nodes: int, count: int, seed: int) -> th.Tensor:
    """A random symmetric edge list ``(2, E)`` without self loops or duplicates."""
    generator = th.Generator().manual_seed(seed)
    pairs = th.randint(0, n_nodes, (2, count), generator=generator)
    pairs = pairs[:, pairs[0] != pairs[1]]
    return th.unique(th.cat((pairs, pairs.flip(0)), dim=1), dim=1)


@pytest.mark.parametrize("heads", [1, 3])
def test_values_and_gradients_are_gatconvs(heads: int) -> None:
    th.manual_seed(heads)
    n_nodes = 200
    conv = GATConv(6, 8, heads=heads, concat=False, add_self_loops=True, negative_slope=0.3)
    with th.no_grad():
        conv.bias.normal_()  # PyG starts it at 0, which would hide a missing bias
    edges = random_edges(n_nodes, 300, seed=heads)  # sparse enough to leave some nodes isolated
    x = th.randn(n_nodes, 6, requires_grad=True)
    upstream = th.randn(n_nodes, 8)

    def run(forward) -> list[th.Tensor]:
        x.grad = None
        conv.zero_grad()
        out = forward()
        (out * upstream).sum().backward()
        return [out.detach(), x.grad.clone(), *(p.grad.clone() for p in conv.parameters())]

    expected = run(lambda: conv(x, edges))
    got = run(lambda: gat_by_products(conv, x, TargetSortedEdges.of(edges, n_nodes)))
    for name, a, b in zip(["output", "x.grad", *(n for n, _ in conv.named_parameters())], got, expected):
        th.testing.assert_close(a, b, rtol=1e-5, atol=1e-5, msg=name)


def test_the_edges_order_and_self_loops_do_not_matter() -> None:
    """Edges sorted by target (the env's lists, merged with the loops) and in any other order,
    with or without self loops, give the same structure: one self loop per node."""
    n_nodes = 40
    edges = random_edges(n_nodes, 150, seed=0)
    by_target = edges[:, th.argsort(edges[1] * n_nodes + edges[0])]
    shuffled = edges[:, th.randperm(edges.shape[1], generator=th.Generator().manual_seed(1))]
    with_loops = th.cat((shuffled, th.arange(5).repeat(2, 1)), dim=1)
    structures = [TargetSortedEdges.of(e, n_nodes) for e in (by_target, shuffled, with_loops)]
    for other in structures[1:]:
        for field in FIELDS:
            assert th.equal(getattr(other, field), getattr(structures[0], field)), field
    first = structures[0]
    assert first.source.numel() == edges.shape[1] + n_nodes
    assert int((first.source == first.target).sum()) == n_nodes
    key = first.target * n_nodes + first.source
    assert bool((key[1:] > key[:-1]).all())


def test_it_stands_aside_where_it_would_compute_otherwise() -> None:
    conv = GATConv(4, 4, heads=2, concat=False, dropout=0.2)
    assert applies_to(conv, training=False)
    assert not applies_to(conv, training=True)  # attention dropout
    for other in (
        dict(concat=True),  # heads concatenated
        dict(concat=False, add_self_loops=False),
        dict(concat=False, residual=True),
        dict(concat=False, edge_dim=2),
    ):
        assert not applies_to(GATConv(4, 4, heads=2, **other), training=False), other
    assert not applies_to(GATConv((4, 3), 4, heads=2, concat=False, add_self_loops=False), training=False)


def _observations(env: SingleAgentMonitoringEnv, steps: int = 10) -> dict[str, th.Tensor]:
    obs, _ = env.reset(seed=0)
    rng = np.random.default_rng(0)
    collected = [obs]
    for _ in range(steps - 1):
        obs, *_ = env.step(int(rng.choice(np.flatnonzero(env.action_masks()))))
        collected.append(obs)
    return {key: th.as_tensor(np.stack([np.asarray(o[key]) for o in collected])).float() for key in obs}


def _policy(env: SingleAgentMonitoringEnv, **settings: object) -> DCBFActorCriticPolicy:
    th.manual_seed(0)
    settings = {"laplacian": "none", "gat_backend": "sparse", **settings}
    return DCBFActorCriticPolicy(env.observation_space, env.action_space, lambda _: 3e-4, **settings)


@pytest.mark.parametrize(
    "settings",
    [{}, {"net_arch": {"pi": [], "vf": [16]}}, {"use_estimator": False, "advice_prior": 2.0}],
    ids=["default", "actor-without-hidden-layer", "no-estimator-with-advice"],
)
def test_the_policy_takes_the_large_site_path_only_there(
    monkeypatch: pytest.MonkeyPatch, settings: dict[str, object]
) -> None:
    """Below :data:`~sb3_pm.policies.edges.LARGE_SITE_NODES` the edges layout runs PyG's kernel
    and the actor on every node, so recorded trainings repeat bit for bit; from there on, the
    products and the actor on the allowed nodes alone, whose update (values, log-probabilities,
    entropies and every parameter's gradient) agrees up to rounding."""
    advice = "advice_prior" in settings
    env = SingleAgentMonitoringEnv(
        SITE, n_agents=2, max_cycles=20, layout="edges", **(ADVISED if advice else {})
    )
    obs = _observations(env)
    calls: list[str] = []
    from sb3_pm.policies import layers

    products = layers.neighbour_sum.gat_by_products

    def counted(*args: object) -> th.Tensor:
        calls.append("gat")
        return products(*args)

    monkeypatch.setattr(layers.neighbour_sum, "gat_by_products", counted)

    def update(policy: DCBFActorCriticPolicy) -> list[th.Tensor]:
        with th.no_grad():
            masks = policy.compute_masks(obs)
        actions = masks.float().argmax(-1)  # an allowed node per map
        values, log_prob, entropy = policy.evaluate_actions(obs, actions, masks)
        (values.sum() + log_prob.sum() + entropy.sum()).backward()
        grads = [p.grad if p.grad is not None else th.zeros_like(p) for p in policy.parameters()]
        return [values, log_prob, entropy, *grads]

    below = update(_policy(env, **settings))
    assert not calls
    assert SITE.n_nodes < edges.LARGE_SITE_NODES
    monkeypatch.setattr(edges, "LARGE_SITE_NODES", SITE.n_nodes)
    at = update(_policy(env, **settings))
    assert calls.count("gat") == 2  # both GAT layers, forward
    assert any(not th.equal(a, b) for a, b in zip(at, below))  # another path, rounded otherwise
    for a, b in zip(at, below):
        th.testing.assert_close(a.detach(), b.detach(), rtol=1e-4, atol=1e-5)

"""Derived node features (policy option ``derived_features``): hop distances and projected uncertainty."""

from __future__ import annotations

import networkx as nx
import numpy as np
import pytest
import torch as th
from stable_baselines3.common.preprocessing import preprocess_obs

from sb3_pm.envs.mental_map import AGE, TARGET, U
from sb3_pm.envs.single_agent import SingleAgentMonitoringEnv
from sb3_pm.graphs import erdos_renyi
from sb3_pm.policies import DCBFActorCriticPolicy, GATFeaturesExtractor
from sb3_pm.policies.features import derived_node_features, hop_distances


def test_hop_distances_match_networkx_including_unreachable_nodes() -> None:
    rng = np.random.default_rng(0)
    n, batch = 15, 6
    adjacency = np.zeros((batch, n, n), dtype=np.int8)
    for b in range(batch):
        upper = np.triu(rng.random((n, n)) < 0.12, 1)  # sparse: several components
        adjacency[b] = upper | upper.T
    starts = rng.integers(0, n, size=batch)
    start = np.eye(n, dtype=np.float32)[starts]
    got = hop_distances(th.as_tensor(adjacency), th.as_tensor(start)).numpy()
    for b in range(batch):
        lengths = nx.single_source_shortest_path_length(nx.from_numpy_array(adjacency[b]), int(starts[b]))
        expected = np.array([lengths.get(m, -1) for m in range(n)])
        np.testing.assert_array_equal(got[b], expected)


def test_hop_distances_on_an_empty_graph_reach_only_the_start() -> None:
    start = th.zeros(1, 4)
    start[0, 2] = 1.0
    assert hop_distances(th.zeros(1, 4, 4), start).tolist() == [[-1, -1, 0, -1]]


def test_projected_uncertainty_and_closeness_by_hand() -> None:
    # A path 0 - 1 - 2 and an isolated node 3; the agent is on node 0.
    nodes = th.zeros(1, 4, 5)
    nodes[0, :, U] = th.tensor([5.0, 0.0, 90.0, 30.0])
    nodes[0, :, AGE] = th.tensor([0.0, 3.0, 40.0, 7.0])
    nodes[0, :, TARGET] = th.tensor([1.0, 0.0, 1.0, 1.0])
    adjacency = th.zeros(1, 4, 4)
    adjacency[0, 0, 1] = adjacency[0, 1, 0] = adjacency[0, 1, 2] = adjacency[0, 2, 1] = 1.0
    position = th.tensor([[1.0, 0.0, 0.0, 0.0]])
    derived = derived_node_features(nodes, adjacency, position, u_max=100.0)
    # projected: min(u + age, cap) on known targets only, over the cap.
    th.testing.assert_close(derived[0, :, 0], th.tensor([0.05, 0.0, 1.0, 0.37]))
    th.testing.assert_close(derived[0, :, 1], th.tensor([1.0, 0.5, 1.0 / 3.0, 0.0]))


@pytest.fixture(scope="module")
def env() -> SingleAgentMonitoringEnv:
    return SingleAgentMonitoringEnv(erdos_renyi(12, 0.3, n_targets=3, seed=1), n_agents=2, max_cycles=20)


def test_extractor_with_derived_features(env: SingleAgentMonitoringEnv) -> None:
    obs, _ = env.reset(seed=0)
    batch = {key: th.as_tensor(np.asarray(value))[None] for key, value in obs.items()}
    pre = preprocess_obs(batch, env.observation_space)
    plain = GATFeaturesExtractor(env.observation_space, hidden_dim=8, laplacian="none")
    derived = GATFeaturesExtractor(
        env.observation_space, hidden_dim=8, laplacian="none", derived_features=True
    )
    x_plain, x_derived = plain.node_inputs(pre), derived.node_inputs(pre)
    assert x_derived.shape == (1, 12, x_plain.shape[-1] + 2)
    th.testing.assert_close(x_derived[..., : x_plain.shape[-1]], x_plain)
    assert x_derived.min() >= 0.0 and x_derived.max() <= 1.0
    assert derived(pre).shape == (1, 12 * 8)


def test_policy_flag_round_trips_through_constructor_parameters(env: SingleAgentMonitoringEnv) -> None:
    policy = DCBFActorCriticPolicy(
        env.observation_space, env.action_space, lambda _: 3e-4, derived_features=True, gat_heads=1
    )
    assert policy.features_extractor.derived_features  # type: ignore[union-attr]
    assert policy._get_constructor_parameters()["derived_features"] is True
    obs, _ = env.reset(seed=1)
    action, _ = policy.predict(obs, deterministic=True)
    assert env.action_masks()[int(action)]

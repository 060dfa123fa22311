"""Mental maps: stale values, ages, occupancy, edge discovery and the two knowledge modes."""

from __future__ import annotations

import numpy as np
import pytest

from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.envs.mental_map import AGE, FEATURES, OCCUPIED, SELF, TARGET, MentalMaps, U
from sb3_pm.errors import InputError
from tests.conftest import path_graph


def env_on_path(positions, **kwargs):
    # 0 - 1 - 2 - 3 - 4, targets 0 and 4
    env = persistent_monitoring_v0.parallel_env(
        graph=path_graph(5, [0, 4]), n_agents=len(positions), initial_positions=positions, **kwargs
    )
    observations, _ = env.reset(seed=0)
    return env, observations


def test_feature_order_is_documented() -> None:
    assert FEATURES == ("u", "age", "target", "occupied", "self")


def test_initial_observation_sees_the_neighbourhood_only() -> None:
    env, obs = env_on_path([1])
    nodes = obs["agent_0"]["nodes"]
    assert nodes[:, TARGET].tolist() == [1, 0, 0, 0, 0]  # target 4 not seen yet
    assert nodes[:, SELF].tolist() == [0, 1, 0, 0, 0]
    assert nodes[:, AGE].tolist() == [0, 0, 0, 0, 0]


def test_stale_values_and_ages() -> None:
    env, obs = env_on_path([4])
    for _ in range(3):  # stay on target 4; target 0 grows unseen
        obs, *_ = env.step({"agent_0": 4})
    nodes = obs["agent_0"]["nodes"]
    assert env.unwrapped.uncertainty[0] == 3
    assert nodes[0, U] == 0 and nodes[0, AGE] == 3  # never observed: stale 0, age counts from the start
    for destination in (3, 2, 1):
        obs, *_ = env.step({"agent_0": destination})
    nodes = obs["agent_0"]["nodes"]
    assert nodes[0, U] == 6 and nodes[0, AGE] == 0 and nodes[0, TARGET] == 1  # observed from node 1
    assert nodes[4, AGE] == 2 and nodes[4, TARGET] == 1  # last seen from node 3, two steps ago
    assert nodes[4, U] == 1  # seen from node 3 the step the agent left it: 0 + 1 - 0
    for _ in range(2):
        obs, *_ = env.step({"agent_0": 1})
    assert env.unwrapped.uncertainty[4] == 5
    assert obs["agent_0"]["nodes"][4, U] == 1 and obs["agent_0"]["nodes"][4, AGE] == 4  # stale value kept


def test_occupancy_of_others_only() -> None:
    env, obs = env_on_path([1, 2])
    assert obs["agent_0"]["nodes"][:, OCCUPIED].tolist() == [0, 0, 1, 0, 0]
    assert obs["agent_1"]["nodes"][:, OCCUPIED].tolist() == [0, 1, 0, 0, 0]
    obs, *_ = env.step({"agent_0": 2, "agent_1": 2})
    assert obs["agent_0"]["nodes"][2, OCCUPIED] == 1  # shares node 2 with agent_1
    assert obs["agent_0"]["nodes"][1, OCCUPIED] == 0  # node 1 seen empty now


def test_edges_are_discovered_and_persist_across_episodes() -> None:
    env, obs = env_on_path([0])
    known = obs["agent_0"]["adjacency"]
    assert known.sum() == 2 and known[0, 1] == known[1, 0] == 1  # radius 1: edges at its own node
    for destination in (1, 2):
        obs, *_ = env.step({"agent_0": destination})
    assert obs["agent_0"]["adjacency"].sum() == 6  # edges 0-1, 1-2, 2-3
    obs, _ = env.reset(seed=1, options={"initial_positions": [4]})
    known = obs["agent_0"]["adjacency"]
    assert known[2, 3] == 1 and known[3, 4] == 1 and known.sum() == 8  # kept, plus 3-4 seen now
    assert obs["agent_0"]["nodes"][0, TARGET] == 0  # node features were reset


def test_known_mode_gives_the_whole_topology() -> None:
    graph = path_graph(5, [0, 4])
    env, obs = env_on_path([0], graph_knowledge="known")
    np.testing.assert_array_equal(obs["agent_0"]["adjacency"], graph.adjacency.astype(np.int8))


def test_known_targets_are_flagged_from_the_start_of_every_episode() -> None:
    env, obs = env_on_path([1], target_knowledge="known")
    nodes = obs["agent_0"]["nodes"]
    assert nodes[:, TARGET].tolist() == [1, 0, 0, 0, 1]  # target 4 flagged though never seen
    assert nodes[4, U] == 0 and nodes[4, AGE] == 0  # its uncertainty and age are still only observed
    for _ in range(3):
        obs, *_ = env.step({"agent_0": 1})
    nodes = obs["agent_0"]["nodes"]
    assert nodes[4, U] == 0 and nodes[4, AGE] == 3 and env.unwrapped.uncertainty[4] == 3
    obs, _ = env.reset(seed=1, options={"initial_positions": [2]})
    assert obs["agent_0"]["nodes"][:, TARGET].tolist() == [1, 0, 0, 0, 1]  # again after the reset
    assert obs["agent_0"]["adjacency"].sum() == 6  # the topology is still discovered: 0-1, 1-2, 2-3


def test_discovered_targets_are_the_default_and_known_needs_the_flags() -> None:
    env, obs = env_on_path([1])
    assert env.unwrapped.target_knowledge == "discovered"
    with pytest.raises(InputError, match="target_knowledge must be one of"):
        env_on_path([1], target_knowledge="psychic")
    with pytest.raises(InputError, match="needs the graph's target flags"):
        MentalMaps(1, path_graph(3, [0]).adjacency, target_knowledge="known")


def test_radius_two_sees_further_and_learns_edges_inside_the_ball() -> None:
    env, obs = env_on_path([2], obs_radius=2)
    nodes = obs["agent_0"]["nodes"]
    assert nodes[:, TARGET].tolist() == [1, 0, 0, 0, 1]
    # Nodes within radius - 1 = 1 hop (1, 2, 3) have their incident edges observed: all 4 edges.
    assert obs["agent_0"]["adjacency"].sum() == 8


def test_maps_are_private() -> None:
    maps = MentalMaps(2, path_graph(3, [2]).adjacency)
    observed = np.array([[True, True, False], [False, False, False]])
    maps.update(
        np.array([0, 2]),
        observed,
        np.array([5, 6, 7]),
        np.array([0, 0, 1]),
        np.array([1, 0, 1]),
        np.array([[True, False, False], [False, False, False]]),
    )
    assert maps.features[1, :, U].tolist() == [0, 0, 0]
    assert maps.adjacency[1].sum() == 0 and maps.adjacency[0].sum() == 2


def test_shared_map_is_the_union_of_the_team_observations() -> None:
    env, obs = env_on_path([0, 4], shared_map=True)
    for agent in ("agent_0", "agent_1"):
        nodes = obs[agent]["nodes"]
        assert nodes[:, TARGET].tolist() == [1, 0, 0, 0, 1]  # each sees both ends of the path
    obs, *_ = env.step({"agent_0": 0, "agent_1": 4})
    for agent in ("agent_0", "agent_1"):
        assert obs[agent]["nodes"][:, AGE].tolist() == [0, 0, 1, 0, 0]  # only the middle is unseen by both
    assert obs["agent_0"]["nodes"][:, SELF].tolist() == [1, 0, 0, 0, 0]
    assert obs["agent_1"]["nodes"][:, SELF].tolist() == [0, 0, 0, 0, 1]
    assert obs["agent_0"]["adjacency"].sum() == 4  # edges 0-1 and 3-4, from both agents


def test_separate_maps_do_not_share() -> None:
    env, obs = env_on_path([0, 4])
    assert obs["agent_0"]["nodes"][:, TARGET].tolist() == [1, 0, 0, 0, 0]
    assert obs["agent_0"]["adjacency"].sum() == 2


def test_new_lifetime_forgets_edges_and_history() -> None:
    env, obs = env_on_path([0])
    env.step({"agent_0": 1})
    obs, _ = env.reset(seed=0, options={"initial_positions": [4], "new_lifetime": True})
    assert obs["agent_0"]["adjacency"].sum() == 2  # only the edge 3-4, seen now


@pytest.mark.parametrize("obs_radius", [1, 2])
def test_skipping_folded_positions_discovers_the_same_edges(obs_radius: int) -> None:
    # The env tells the maps each agent's node so that a map back on a node it has folded skips
    # the array work; the known adjacency, the explored rows and the int8 copies handed out must be
    # those of the maps that are told nothing, step by step.
    from sb3_pm.graphs import resolve_graph

    graph = resolve_graph("paper-50")
    hops = graph.hop_distances
    edge_rows = hops <= obs_radius - 1
    told, untold = (MentalMaps(3, graph.adjacency) for _ in range(2))
    rng = np.random.default_rng(0)
    positions = rng.choice(graph.n_nodes, size=3, replace=False)
    for step in range(300):
        if step == 150:  # a new lifetime starts over, folded positions included
            told.forget_edges()
            untold.forget_edges()
        positions = np.array([rng.choice(np.flatnonzero(graph.reachable[p])) for p in positions])
        observed = hops[positions] <= obs_radius
        counts = np.bincount(positions, minlength=graph.n_nodes)
        u = rng.integers(0, 100, graph.n_nodes)
        edges = edge_rows[positions]
        untold.update(positions, observed, u, graph.targets, counts, edges)
        told.update(positions, observed, u, graph.targets, counts, edges, edge_positions=positions.tolist())
        assert np.array_equal(told.adjacency, untold.adjacency)
        assert np.array_equal(told.explored, untold.explored)
        for mine, theirs in zip(told.adjacency_observations(), untold.adjacency_observations()):
            assert np.array_equal(mine, theirs)
    assert told._adjacency_cached and any(told._folded_positions)


def test_adjacency_observations_stay_read_only_through_a_pickle() -> None:
    # Callers keep these arrays without copying; an unpickled map (a copy) must not hand out
    # arrays a caller could write into the map's cache through.
    import pickle

    env, obs = env_on_path([1])
    assert not obs["agent_0"]["adjacency"].flags.writeable
    env.unwrapped.maps = pickle.loads(pickle.dumps(env.unwrapped.maps))
    obs, *_ = env.step({"agent_0": 1})
    assert not obs["agent_0"]["adjacency"].flags.writeable
    with pytest.raises(ValueError, match="read-only"):
        obs["agent_0"]["adjacency"][0, 0] = 1

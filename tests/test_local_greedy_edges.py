"""``local_greedy`` in the env's edges layout: searches from the agent's position and goal over its
known edges (:class:`sb3_pm.baselines.local_greedy._KnownEdges`) instead of an all-pairs table of
its known adjacency; the moves must be the dense layout's, step for step."""

from __future__ import annotations

import numpy as np
import pytest

from sb3_pm.baselines import make_team
from sb3_pm.baselines.local_greedy import _KnownEdges, _KnownGraph
from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.graphs import resolve_graph
from sb3_pm.graphs.large_sites import city_streets
from tests.conftest import episode_moves

GRAPHS = {
    "paper-50": lambda: resolve_graph("paper-50"),
    "rooms-4": lambda: resolve_graph("rooms-4"),
    "city-300": lambda: city_streets(300, seed=3),
}


def _moves(name: str, layout: str, knowledge: str, steps: int = 80) -> list[dict[str, int]]:
    env = persistent_monitoring_v0.parallel_env(
        graph=GRAPHS[name](), n_agents=5, max_cycles=steps, layout=layout, graph_knowledge=knowledge
    )
    return episode_moves(env, make_team("local_greedy"), seed=4)


@pytest.mark.parametrize("name", GRAPHS)
@pytest.mark.parametrize("knowledge", ["discovered", "known"])
def test_local_greedy_moves_alike_in_both_layouts(name: str, knowledge: str) -> None:
    assert _moves(name, "edges", knowledge) == _moves(name, "dense", knowledge)


def test_the_edge_searches_give_the_all_pairs_distances_and_hops() -> None:
    graph = city_streets(300, seed=3)
    env = persistent_monitoring_v0.parallel_env(graph=graph, n_agents=1, max_cycles=5, layout="edges")
    observations, _ = env.reset(seed=0)
    edge_index = np.asarray(observations["agent_0"]["edge_index"])
    rng = np.random.default_rng(0)
    mask = (rng.random(edge_index.shape[1]) < 0.7).astype(np.int8)
    mask = mask & mask[np.lexsort((edge_index[0], edge_index[1]))]  # an edge and its reverse alike
    adjacency = np.zeros((graph.n_nodes, graph.n_nodes), dtype=bool)
    adjacency[edge_index[0, mask != 0], edge_index[1, mask != 0]] = True
    assert np.array_equal(adjacency, adjacency.T)
    dense, edges = _KnownGraph(adjacency), _KnownEdges(edge_index, mask, graph.n_nodes)
    for node in rng.choice(graph.n_nodes, 20, replace=False):
        distance = edges.distances(int(node))
        assert np.array_equal(distance, dense.dist[node])
        for goal in np.flatnonzero(distance < dense.dist.max())[:15]:
            assert edges.step_towards(int(node), int(goal)) == dense.step_towards(int(node), int(goal))


def test_the_edge_searches_are_rebuilt_only_when_a_map_gains_edges(monkeypatch: pytest.MonkeyPatch) -> None:
    from sb3_pm.baselines import local_greedy

    builds: list[int] = []

    class Counting(_KnownEdges):
        def __init__(self, *args: object) -> None:
            builds.append(1)
            super().__init__(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(local_greedy, "_KnownEdges", Counting)
    moves = _moves("city-300", "edges", "discovered")
    assert 0 < len(builds) < len(moves) * 5 / 2  # 5 agents: not every agent-step

"""Hand-computed dynamics (docs/METHOD.md "Dynamics": eq. 1, the cap, collisions) and illegal actions."""

from __future__ import annotations

import numpy as np
import pytest

from sb3_pm.envs import IllegalActionError, persistent_monitoring_v0
from sb3_pm.graphs import GraphSpec
from tests.conftest import path_graph


def make(graph, n_agents, positions, **kwargs):
    env = persistent_monitoring_v0.parallel_env(
        graph=graph, n_agents=n_agents, initial_positions=positions, **kwargs
    )
    env.reset(seed=0)
    return env


def act(env, *destinations):
    return env.step({agent: d for agent, d in zip(env.possible_agents, destinations)})


class TestEquationOne:
    def test_unvisited_target_grows_by_one_from_zero(self) -> None:
        env = make(path_graph(3, [2]), 1, [0])
        act(env, 0)
        assert env.unwrapped.uncertainty.tolist() == [0, 0, 1]
        act(env, 0)
        assert env.unwrapped.uncertainty.tolist() == [0, 0, 2]

    def test_visited_positive_target_drops_by_one(self) -> None:
        env = make(path_graph(3, [2]), 1, [0])
        act(env, 1)  # u2: 0 -> 1
        act(env, 1)  # u2: 1 -> 2
        act(env, 2)  # arrive: 2 + 1 - 2 = 1
        assert env.unwrapped.uncertainty[2] == 1
        act(env, 2)  # 1 + 1 - 2 = 0
        assert env.unwrapped.uncertainty[2] == 0

    def test_visited_zero_target_stays_zero(self) -> None:
        env = make(path_graph(3, [1]), 1, [1])
        for _ in range(3):
            act(env, 1)  # u = 0, p = 1: 0 + 1 - 1 = 0
            assert env.unwrapped.uncertainty[1] == 0

    def test_non_targets_stay_zero(self) -> None:
        env = make(path_graph(4, [3]), 1, [0])
        for _ in range(5):
            act(env, 0)
        assert env.unwrapped.uncertainty[:3].tolist() == [0, 0, 0]

    def test_cap(self) -> None:
        env = make(path_graph(3, [2]), 1, [0], u_max=3)
        for _ in range(6):
            act(env, 0)
        assert env.unwrapped.uncertainty[2] == 3
        act(env, 1)
        act(env, 2)  # at the cap, a visit still lowers u by one
        assert env.unwrapped.uncertainty[2] == 2

    def test_two_agents_on_a_target_lower_it_once(self) -> None:
        env = make(path_graph(3, [1]), 2, [0, 2])
        act(env, 0, 2)  # u1 = 1
        act(env, 0, 2)  # u1 = 2
        _, rewards, *_ = act(env, 1, 1)
        assert env.unwrapped.uncertainty[1] == 1  # presence is 0/1: 2 + 1 - 2
        assert env.episode_metrics()["collisions"] == 2  # two agent-steps in collision

    def test_simultaneous_moves_swap(self) -> None:
        env = make(path_graph(2, [0]), 2, [0, 1])
        act(env, 1, 0)
        assert env.unwrapped.positions.tolist() == [1, 0]


class TestIllegalActions:
    def test_raises_value_error_naming_agent_node_and_reachable_set(self) -> None:
        env = make(path_graph(4, [3]), 2, [0, 3])
        with pytest.raises(
            ValueError, match=r"agent_0 on node 0 cannot move to node 2; its reachable set is \[0, 1\]"
        ):
            act(env, 2, 3)
        assert issubclass(IllegalActionError, ValueError)

    def test_out_of_range(self) -> None:
        env = make(path_graph(3, [2]), 1, [0])
        with pytest.raises(ValueError, match="cannot move to node 7"):
            act(env, 7)
        with pytest.raises(ValueError, match="cannot move to node -1"):
            act(env, -1)

    @pytest.mark.parametrize("destination", [-1, -2, -3, 3, 4, 5, 10**12, -(10**12)])
    def test_out_of_range_from_every_node_of_a_complete_graph(self, destination: int) -> None:
        # Every node reaches every node, so a legality check that let an out-of-range destination
        # spill into a neighbouring row of the reachable matrix would call the move legal.
        adjacency = ~np.eye(3, dtype=bool)
        graph = GraphSpec(adjacency=adjacency, targets=np.array([True, False, False]), name="k3")
        for node in range(3):
            env = make(graph, 1, [node])
            with pytest.raises(IllegalActionError, match=f"cannot move to node {destination}"):
                act(env, destination)
            stay = make(graph, 1, [node], illegal_action="stay")
            *_, infos = act(stay, destination)
            assert stay.unwrapped.positions.tolist() == [node]
            assert infos["agent_0"]["illegal_action"] == destination

    def test_the_core_refuses_a_destination_list_of_another_length(self) -> None:
        from sb3_pm.envs.core import MonitoringCore

        core = MonitoringCore(path_graph(4, [3]), 2)
        core.reset(np.array([0, 3]))
        for destinations in ([1], [1, 2, 3]):
            with pytest.raises(ValueError, match="expected 2 destinations"):
                core.step(np.array(destinations))

    @pytest.mark.parametrize("u_max", [1, 7, 100])
    def test_the_update_table_is_eq_1_with_the_cap(self, u_max: int) -> None:
        # Every level and both presences, against eq. (1) written out.
        from sb3_pm.envs.core import MonitoringCore

        core = MonitoringCore(path_graph(2, [0]), 1, u_max=u_max)
        for u in range(u_max + 1):
            for occupied in (False, True):
                expected = max(u - 1, 0) if occupied else min(u + 1, u_max)
                assert core._next_u[u + occupied * (u_max + 1)] == expected

    def test_an_action_that_is_not_one_node_is_refused(self) -> None:
        env = make(path_graph(4, [3]), 2, [0, 3])
        with pytest.raises(ValueError, match="every action must be one node index"):
            env.step({"agent_0": np.array([1]), "agent_1": np.array([3])})

    def test_a_defaultdict_does_not_fill_in_a_missing_action(self) -> None:
        from collections import defaultdict

        env = make(path_graph(4, [3]), 2, [0, 3], illegal_action="stay")
        actions = defaultdict(int, {"agent_0": 1})
        with pytest.raises(ValueError, match=r"no action given for \['agent_1'\]"):
            env.step(actions)
        assert "agent_1" not in actions

    def test_stay_mode_reports_in_infos(self) -> None:
        env = make(path_graph(4, [3]), 1, [0], illegal_action="stay")
        *_, infos = act(env, 3)
        assert env.unwrapped.positions.tolist() == [0]
        assert infos["agent_0"]["illegal_action"] == 3

    def test_missing_action(self) -> None:
        env = make(path_graph(3, [2]), 2, [0, 1])
        with pytest.raises(ValueError, match="no action given for"):
            env.step({"agent_0": 0})


class TestEpisodes:
    def test_truncation_not_termination(self) -> None:
        env = make(path_graph(3, [2]), 1, [0], max_cycles=3)
        for k in range(3):
            _, _, terminations, truncations, infos = act(env, 0)
            assert terminations == {"agent_0": False}
            assert truncations == {"agent_0": k == 2}
        assert env.agents == []
        assert infos["agent_0"]["metrics"]["steps"] == 3
        with pytest.raises(RuntimeError, match="reset"):
            act(env, 0)

    def test_metrics_by_hand(self) -> None:
        # Path 0-1-2, target 2, one agent: stays on 0 twice, then 1, then 2, then 2.
        env = make(path_graph(3, [2]), 1, [0], max_cycles=5)
        for destination in (0, 0, 1, 2, 2):
            *_, infos = act(env, destination)
        # u2 after each step: 1, 2, 3, 2, 1 -> mean 9/5; unvisited run 0..2 is 3 steps long.
        metrics = infos["agent_0"]["metrics"]
        assert metrics["avg_uncertainty"] == pytest.approx(9 / 5)
        assert metrics["max_neglect"] == 3
        assert metrics["peak_uncertainty"] == 3
        assert metrics["collisions"] == 0
        np.testing.assert_array_equal(env.uncertainty_trace(), [1, 2, 3, 2, 1])

    def test_idle_fraction_counts_agents_alone_on_a_cleared_target(self) -> None:
        # Path 0-1-2, target 2. Agent 0: 1, 2 (u2 1 -> 0, clearing), 2, 2 (idle twice).
        # Agent 1 stays on the non-target 0 (never idle). 2 idle of 8 agent-steps.
        env = make(path_graph(3, [2]), 2, [0, 0], max_cycles=4)
        for destination in (1, 2, 2, 2):
            *_, infos = act(env, destination, 0)
        assert infos["agent_0"]["metrics"]["idle_fraction"] == pytest.approx(2 / 8)
        # Two agents together on the cleared target share it: neither is idle alone.
        env = make(path_graph(3, [2]), 2, [2, 2], max_cycles=3)
        for _ in range(3):
            *_, infos = act(env, 2, 2)
        assert infos["agent_0"]["metrics"]["idle_fraction"] == 0

    def test_never_visited_target_neglected_whole_episode(self) -> None:
        env = make(path_graph(3, [2]), 1, [0], max_cycles=4, u_max=2)
        for _ in range(4):
            *_, infos = act(env, 0)
        assert infos["agent_0"]["metrics"]["max_neglect"] == 4
        assert infos["agent_0"]["metrics"]["saturated_fraction"] == pytest.approx(3 / 4)


class TestBadConfiguration:
    def test_more_agents_than_nodes(self) -> None:
        with pytest.raises(ValueError, match=r"more agents \(4\) than nodes \(3\)"):
            persistent_monitoring_v0.parallel_env(graph=path_graph(3, [1]), n_agents=4)

    def test_bad_initial_positions(self) -> None:
        with pytest.raises(ValueError, match="initial_positions"):
            persistent_monitoring_v0.parallel_env(
                graph=path_graph(3, [1]), n_agents=2, initial_positions=[0, 9]
            )

    @pytest.mark.parametrize(
        ("kwargs", "message"),
        [
            ({"observation": "full"}, "observation must be one of"),
            ({"graph_knowledge": "psychic"}, "graph_knowledge must be one of"),
            ({"reward": "nice"}, "unknown reward preset"),
            ({"reward": {"bonus": 1.0}}, "unknown reward terms"),
            ({"max_cycles": 0}, "max_cycles"),
            ({"render_mode": "video"}, "render_mode"),
            ({"graph": "no-such-graph"}, "unknown graph"),
        ],
    )
    def test_clear_errors(self, kwargs, message) -> None:
        with pytest.raises(ValueError, match=message):
            persistent_monitoring_v0.parallel_env(**{"graph": path_graph(4, [3]), "n_agents": 1, **kwargs})

"""The DCBF's neglect bound (rule 8, sb3_pm.policies.neglect_bound): its pieces and its guarantee.

The guarantee is tested on the environment itself: agents whose actions come from an adversarial
or random actor restricted by the filter, against the same actors unfiltered.
"""

from __future__ import annotations

import networkx as nx
import numpy as np
import pytest
import torch as th

from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.envs.mental_map import AGE, TARGET, U
from sb3_pm.errors import InputError
from sb3_pm.graphs import GraphSpec, erdos_renyi
from sb3_pm.policies.dcbf import DCBFConfig, dcbf_filter_from_map
from sb3_pm.policies.neglect_bound import UNREACHABLE, hop_distances, neglect_deadline
from tests.conftest import path_graph

U_MAX = 100.0


def map_tensors(observations: dict[str, dict], agents: list[str]) -> dict[str, th.Tensor]:
    """The agents' observations as one SB3-preprocessed batch (what the policy's filter reads)."""
    obs = [observations[a] for a in agents]
    n = obs[0]["nodes"].shape[0]
    position = th.tensor([o["position"] for o in obs])
    return {
        "nodes": th.as_tensor(np.stack([o["nodes"] for o in obs])).float(),
        "adjacency": th.as_tensor(np.stack([o["adjacency"] for o in obs])),
        "position": th.nn.functional.one_hot(position, n).float(),
        "position_index": position,
        "dwell": th.as_tensor(np.stack([o["dwell"] for o in obs])).float().reshape(-1, 1),
        "action_mask": th.as_tensor(np.stack([o["action_mask"] for o in obs])).float(),
    }


def run_episode(
    graph: GraphSpec,
    actor: str,
    bound: float | None,
    positions: list[int],
    steps: int,
    seed: int = 0,
    territories: list[tuple[int, ...]] | None = None,
    graph_knowledge: str = "discovered",
) -> tuple[np.ndarray, int]:
    """Play one episode with ``actor`` under the filter (no barrier, no freeze, so the actor decides
    whenever rule 8 does not); return the true target uncertainties ``(steps, T)`` and the number of
    forced masks.

    ``actor``: ``"flee"`` always takes the lowest-index allowed node (on a path graph: away from a
    target at the high end, then stays at node 0); ``"random"`` samples uniformly among the allowed.
    ``territories``: one per agent, to bound each agent's own targets (scope ``"territory"``).
    """
    env = persistent_monitoring_v0.parallel_env(
        graph=graph,
        n_agents=len(positions),
        max_cycles=steps,
        initial_positions=positions,
        graph_knowledge=graph_knowledge,
    )
    config = DCBFConfig(freeze_steps=0, barrier=False, neglect_bound=bound)
    own = {
        f"agent_{i}": DCBFConfig(
            freeze_steps=0, barrier=False, neglect_bound=bound, neglect_scope="territory", territory=t
        )
        for i, t in enumerate(territories or [])
    }
    rng = np.random.default_rng(seed)
    observations, _ = env.reset(seed=seed)
    targets = graph.target_indices
    trace, forced_total = [], 0
    while env.agents:
        agents = list(env.agents)
        if own:  # each agent its own filter: one batch of one per agent
            rows = [map_tensors(observations, [agent]) for agent in agents]
            pairs = [dcbf_filter_from_map(b, b["nodes"][..., U], own[a], U_MAX) for b, a in zip(rows, agents)]
            mask, forced = th.cat([m for m, _ in pairs]), th.cat([f for _, f in pairs])
        else:
            batch = map_tensors(observations, agents)
            mask, forced = dcbf_filter_from_map(batch, batch["nodes"][..., U], config, U_MAX)
        forced_total += int(forced.sum())
        actions = {}
        for row, agent in enumerate(agents):
            allowed = np.flatnonzero(mask[row].numpy())
            actions[agent] = int(allowed[0] if actor == "flee" else rng.choice(allowed))
        observations, _, _, _, _ = env.step(actions)
        trace.append(env.unwrapped.uncertainty[targets].copy())
    env.close()
    return np.array(trace), forced_total


class TestGuarantee:
    def test_a_fleeing_actor_neglects_the_target_and_the_filter_does_not(self) -> None:
        # 0 - 1 - ... - 9, target 9; the agent starts beside it (so it knows it) and the actor runs
        # to node 0 and stays there: unfiltered, the target saturates at u_max.
        graph = path_graph(10, targets=[9])
        unfiltered, forced = run_episode(graph, "flee", None, positions=[8], steps=300)
        assert unfiltered.max() == U_MAX and forced == 0
        for bound in (12.0, 25.0, 60.0):
            filtered, forced = run_episode(graph, "flee", bound, positions=[8], steps=300)
            assert filtered.max() <= bound, f"B={bound}: the target reached {filtered.max()}"
            assert forced > 0
            # The bound is not slack: the worst-case projection lets u come close to B.
            assert filtered.max() >= bound - 10

    @pytest.mark.parametrize("seed", range(6))
    def test_random_actors_on_random_graphs_keep_a_known_single_target_below_the_bound(
        self, seed: int
    ) -> None:
        # One target, an agent starting on it (known from step 0 with slack), two teammates
        # elsewhere with their own filters; every actor random among the allowed nodes.
        graph = erdos_renyi(16, edge_prob=0.15, n_targets=1, seed=seed)
        target = int(graph.target_indices[0])
        others = [n for n in range(graph.n_nodes) if n != target][:2]
        bound = 15.0
        unfiltered, _ = run_episode(graph, "random", None, [target, *others], steps=400, seed=seed)
        filtered, forced = run_episode(graph, "random", bound, [target, *others], steps=400, seed=seed)
        assert filtered.max() <= bound
        assert forced > 0
        # The test can fail: unfiltered random walks do let the target pass the bound.
        assert unfiltered.max() > bound

    def test_two_targets_due_at_once_can_pass_the_bound(self) -> None:
        # The stated limit: one agent between two targets 9 hops apart cannot keep both under a
        # bound smaller than the round trip; the filter serves the most urgent and the other passes.
        graph = path_graph(10, targets=[0, 9])
        filtered, forced = run_episode(graph, "flee", 8.0, positions=[8], steps=200)
        assert forced > 0 and filtered.max() > 8.0


class TestTerritoryScope:
    """Scope ``"territory"``: each agent bounds the targets of its own territory, from the site's
    target list, whether or not its map has seen them, and no others."""

    def test_every_target_has_an_owner_who_keeps_it_below_the_bound(self) -> None:
        # Path 0-...-9, targets 0 and 9, agent_0 owning 0 and agent_1 owning 9 (the split of
        # sb3_pm.graphs.territories). Both actors flee to node 0: unfiltered, target 9 saturates;
        # with the scope, agent_1 comes back to its own target, and target 0 is agent_0's.
        graph = path_graph(10, targets=[0, 9])
        unfiltered, _ = run_episode(graph, "flee", None, positions=[1, 8], steps=300)
        assert unfiltered[:, 1].max() == U_MAX
        for bound in (15.0, 40.0):
            filtered, forced = run_episode(
                graph, "flee", bound, positions=[1, 8], steps=300, territories=[(0,), (9,)]
            )
            assert filtered.max() <= bound and forced > 0

    def test_a_target_the_map_never_saw_is_bounded_from_the_episode_start(self) -> None:
        # The agent starts 9 hops from its target and never sees it, its map knowing the road network
        # (as the default's does); the map-based scope cannot bound a target it has not seen, the
        # territory can (u = 0 at the start, and u + age bounds it since).
        graph = path_graph(10, targets=[9])
        known, forced_known = run_episode(
            graph, "flee", 30.0, positions=[0], steps=300, graph_knowledge="known"
        )
        assert known.max() == U_MAX and forced_known == 0
        own, forced = run_episode(
            graph, "flee", 30.0, positions=[0], steps=300, territories=[(9,)], graph_knowledge="known"
        )
        assert own.max() <= 30.0 and forced > 0

    def test_a_teammates_target_is_left_to_the_teammate(self) -> None:
        # One agent whose territory is target 0, standing on it; target 9 belongs to nobody here:
        # the filter never sends it there, so target 9 saturates while target 0 stays bounded.
        graph = path_graph(10, targets=[0, 9])
        filtered, _ = run_episode(graph, "flee", 20.0, positions=[0], steps=300, territories=[(0,)])
        assert filtered[:, 0].max() <= 20.0 and filtered[:, 1].max() == U_MAX

    def test_a_territory_outside_the_graph_is_an_error(self) -> None:
        graph = path_graph(5, targets=[4])
        with pytest.raises(InputError, match="territory names node 7"):
            run_episode(graph, "flee", 10.0, positions=[0], steps=5, territories=[(7,)])
        with pytest.raises(InputError, match="territory must list node indices"):
            DCBFConfig(neglect_scope="territory", territory=(-1,))


class TestHopDistances:
    @pytest.mark.parametrize("seed", range(3))
    def test_match_networkx(self, seed: int) -> None:
        graph = erdos_renyi(20, edge_prob=0.12, n_targets=2, seed=seed)
        adjacency = th.as_tensor(graph.adjacency.astype(np.int8)).unsqueeze(0).repeat(3, 1, 1)
        adjacency[2, :, 5] = adjacency[2, 5, :] = 0  # node 5 cut off in the third map
        sources = th.tensor([0, 7, 3])
        distance = hop_distances(adjacency, sources)
        for row in range(3):
            g = nx.from_numpy_array(adjacency[row].numpy())
            expected = nx.single_source_shortest_path_length(g, int(sources[row]))
            for node in range(20):
                assert int(distance[row, node]) == expected.get(node, UNREACHABLE)


def deadline_row(
    u: list[float],
    age: list[float],
    targets: list[int],
    edges: list[tuple[int, int]],
    position: int,
    bound: float,
) -> tuple[bool, list[int]]:
    n = len(u)
    adjacency = th.zeros(1, n, n, dtype=th.int8)
    for i, j in edges:
        adjacency[0, i, j] = adjacency[0, j, i] = 1
    reachable = adjacency[0, position].bool().clone()
    reachable[position] = True
    forced, allowed = neglect_deadline(
        th.tensor([u]),
        th.tensor([age]),
        th.tensor([[i in targets for i in range(n)]]),
        adjacency,
        th.tensor([position]),
        reachable.unsqueeze(0),
        bound,
        U_MAX,
    )
    return bool(forced[0]), th.nonzero(allowed[0]).flatten().tolist()


class TestDeadline:
    # A 6-cycle 0-1-2-3-4-5-0 plus a chord 1-4.
    EDGES = [(0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (5, 0), (1, 4)]

    def test_not_due_leaves_the_actor_free(self) -> None:
        # Target 3 at distance 3 from node 0, projected 5 + 3 = 8 < B - 1 = 19.
        assert deadline_row([0, 0, 0, 5, 0, 0], [0] * 6, [3], self.EDGES, 0, 20.0)[0] is False

    def test_due_target_forces_every_shortest_next_hop(self) -> None:
        # From 0 to 3: 0-1-2-3, 0-5-4-3 and 0-1-4-3 are all 3 hops, so 1 and 5 are next hops.
        forced, allowed = deadline_row([0, 0, 0, 10, 0, 0], [0, 0, 0, 6, 0, 0], [3], self.EDGES, 0, 20.0)
        assert forced and allowed == [1, 5]

    def test_the_projection_uses_age_and_is_capped(self) -> None:
        # u 2 seen 14 steps ago: projected 16, + 3 hops = 19 = B - 1 -> due.
        assert deadline_row([0, 0, 0, 2, 0, 0], [0, 0, 0, 14, 0, 0], [3], self.EDGES, 0, 20.0)[0]
        assert not deadline_row([0, 0, 0, 2, 0, 0], [0, 0, 0, 13, 0, 0], [3], self.EDGES, 0, 20.0)[0]
        # A bound above u_max + distance can never be reached: never due.
        assert not deadline_row([0, 0, 0, 100, 0, 0], [0, 0, 0, 50, 0, 0], [3], self.EDGES, 0, 200.0)[0]

    def test_on_the_due_target_the_agent_stays(self) -> None:
        assert deadline_row([0, 0, 0, 19, 0, 0], [0] * 6, [3], self.EDGES, 3, 20.0) == (True, [3])

    def test_least_slack_first_then_nearer(self) -> None:
        # From 0: targets 2 and 4 are both 2 hops away; next hops to 4 are 1 and 5, to 2 only 1.
        forced, allowed = deadline_row([0, 0, 17, 0, 18, 0], [0] * 6, [2, 4], self.EDGES, 0, 20.0)
        assert forced and allowed == [1, 5]  # 4 arrives at 20, 2 at 19: 4 has less slack
        forced, allowed = deadline_row([0, 0, 18, 0, 17, 0], [0] * 6, [2, 4], self.EDGES, 0, 20.0)
        assert forced and allowed == [1]
        # Equal arrival bounds (19): target 5 (1 hop) beats target 3 (3 hops).
        forced, allowed = deadline_row([0, 0, 0, 16, 0, 18], [0] * 6, [3, 5], self.EDGES, 0, 20.0)
        assert forced and allowed == [5]

    def test_least_slack_breaks_ties_even_when_some_node_has_no_known_path(self) -> None:
        # Path 0-1-2 and a node 3 with no known edge; from 1, targets 0 (u 10) and 2 (u 20) are
        # both 1 hop away and due: 2 has less slack. (Node 3's huge distance once swamped the key.)
        forced, allowed = deadline_row([10, 0, 20, 0], [0] * 4, [0, 2], [(0, 1), (1, 2)], 1, 10.0)
        assert forced and allowed == [2]

    def test_unknown_and_unreachable_targets_are_never_due(self) -> None:
        # Node 3 is not a known target; with it known but no known edge to it, it cannot be due.
        assert not deadline_row([0, 0, 0, 99, 0, 0], [0] * 6, [], self.EDGES, 0, 20.0)[0]
        assert not deadline_row([0, 0, 0, 99, 0, 0], [0] * 6, [3], [(0, 1)], 0, 20.0)[0]


class TestFilterIntegration:
    def _observation(self, dwell: float) -> dict[str, th.Tensor]:
        # Path 0-1-2-3; the agent stands on target 0 (u 10, frozen), target 3 projected 18 + 3 = 21.
        n = 4
        nodes = th.zeros(1, n, 5)
        nodes[0, 0, TARGET] = nodes[0, 3, TARGET] = 1.0
        nodes[0, 0, U] = 10.0
        nodes[0, 3, U], nodes[0, 3, AGE] = 10.0, 8.0
        adjacency = th.zeros(1, n, n, dtype=th.int8)
        for i in range(n - 1):
            adjacency[0, i, i + 1] = adjacency[0, i + 1, i] = 1
        return {
            "nodes": nodes,
            "adjacency": adjacency,
            "position": th.nn.functional.one_hot(th.tensor([0]), n).float(),
            "position_index": th.tensor([0]),
            "dwell": th.tensor([[dwell]]),
            "action_mask": th.tensor([[1.0, 1.0, 0.0, 0.0]]),
        }

    def test_the_bound_overrides_the_freeze_and_is_off_by_default(self) -> None:
        obs = self._observation(dwell=0.0)
        u_hat = obs["nodes"][..., U]
        frozen, forced = dcbf_filter_from_map(obs, u_hat, DCBFConfig(freeze_steps=500, barrier=False))
        assert frozen[0].tolist() == [True, False, False, False] and not bool(forced[0])
        bounded, forced = dcbf_filter_from_map(
            obs, u_hat, DCBFConfig(freeze_steps=500, barrier=False, neglect_bound=22.0), U_MAX
        )
        assert bounded[0].tolist() == [False, True, False, False] and bool(forced[0])

    def test_config_validation(self) -> None:
        with pytest.raises(InputError, match="neglect_bound"):
            DCBFConfig(neglect_bound=0.0)

    def test_policy_takes_it_as_a_keyword_and_needs_the_dcbf(self) -> None:
        from sb3_pm.policies.policy import DCBFActorCriticPolicy

        env = persistent_monitoring_v0.parallel_env(graph=path_graph(5, [4]), n_agents=1)
        space, action = env.observation_space("agent_0"), env.action_space("agent_0")
        policy = DCBFActorCriticPolicy(space, action, lambda _: 1e-3, neglect_bound=30)
        assert policy.dcbf_config.neglect_bound == 30.0
        assert policy._get_constructor_parameters()["neglect_bound"] == 30.0
        with pytest.raises(InputError, match="use_dcbf"):
            DCBFActorCriticPolicy(space, action, lambda _: 1e-3, neglect_bound=30, use_dcbf=False)


class TestDeployment:
    def test_a_trained_team_takes_the_bound_and_counts_its_overrides(self, tmp_path) -> None:
        from sb3_pm.agents.training.team import IndependentPPO
        from sb3_pm.evaluation import evaluate

        graph = path_graph(12, targets=[0, 11])
        team = IndependentPPO(
            graph,
            n_agents=1,
            seed=0,
            env_kwargs={"max_cycles": 60},
            hyperparams={
                "n_steps": 30,
                "batch_size": 30,
                "n_epochs": 1,
                "policy_kwargs": {"dcbf_barrier": False, "freeze_steps": 0},
            },
        )
        with pytest.raises(InputError, match="unknown DCBF filter setting"):
            team.set_filter(neglect_bund=5)
        team.set_filter(neglect_bound=15.0)
        # Sampled actions: the untrained actor wanders, so the bound has something to override.
        result = evaluate(
            team,
            graph,
            n_agents=1,
            episodes=1,
            max_cycles=200,
            env_kwargs={"initial_positions": [0]},
            deterministic=False,
        )
        activity = team.filter_activity()
        assert activity["masks"] == 200 and 0 < activity["forced"] < 200
        # A saved team keeps the setting.
        team.save(tmp_path / "t")
        loaded = IndependentPPO.load(tmp_path / "t")
        assert loaded.models["agent_0"].policy.dcbf_config.neglect_bound == 15.0
        assert result.mean["steps"] == 200

    def test_the_territory_scope_gives_each_learner_its_agents_territory(self, tmp_path) -> None:
        from sb3_pm.agents.training.team import IndependentPPO

        graph = path_graph(10, targets=[0, 1, 8, 9])
        team = IndependentPPO(
            graph,
            n_agents=2,
            seed=0,
            env_kwargs={"max_cycles": 20},
            hyperparams={"n_steps": 10, "batch_size": 10, "n_epochs": 1},
        )
        with pytest.raises(InputError, match="territory is set by neglect_scope"):
            team.set_filter(territory=(0,))
        team.set_filter(neglect_bound=15.0, neglect_scope="territory")
        configs = {a: team.models[a].policy.dcbf_config for a in team.agents}
        assert configs["agent_0"].territory == (0, 1) and configs["agent_1"].territory == (8, 9)
        team.save(tmp_path / "t")
        loaded = IndependentPPO.load(tmp_path / "t")
        assert loaded.models["agent_1"].policy.dcbf_config.territory == (8, 9)
        assert loaded.models["agent_1"].policy.dcbf_config.neglect_scope == "territory"

    def test_the_command_line_refuses_it_for_a_baseline(self, capsys) -> None:
        from sb3_pm.cli import main

        assert main(["evaluate", "--policy", "grazing", "--neglect-bound", "50", "--episodes", "1"]) == 2
        assert "needs a trained DCBF team;" in capsys.readouterr().err

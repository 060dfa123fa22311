"""Territory conventions: ``territories: planned`` gives each agent the plan's group for the
episode's starts, in the env's territory inputs and advice and in the ``planned_patrol`` rule."""

from __future__ import annotations

import numpy as np
import pytest

from sb3_pm.baselines import make_team
from sb3_pm.baselines.territory_patrol import PlannedPatrolTeam
from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.errors import InputError
from sb3_pm.graphs import preset
from sb3_pm.graphs.territories import territory_nodes
from sb3_pm.planning.controllers import GroupController, simulate
from sb3_pm.planning.conventions import planned_territory, team_territory
from sb3_pm.planning.planner import plan_patrol
from tests.conftest import episode_moves

KNOWN = {"graph_knowledge": "known", "target_knowledge": "known"}


def make_env(graph: str = "paper-50", n_agents: int = 4, **kwargs):
    options = {"max_cycles": 60, "advice_input": True, "territories": "planned", **KNOWN, **kwargs}
    return persistent_monitoring_v0.parallel_env(graph=graph, n_agents=n_agents, **options)


def test_the_split_convention_is_the_territory_split() -> None:
    graph = preset("rooms-4")
    expected = territory_nodes(graph.hop_distances, graph.target_indices, 4, graph.n_nodes)
    split = team_territory("split", graph, np.array([0, 1, 2, 3]), 500, 100)
    assert np.array_equal(split.territory, expected) and split.tours == (None,) * 4


def test_the_planned_convention_is_the_plans_groups_for_the_starts() -> None:
    graph = preset("rgg-60")
    starts = np.array([3, 17, 29, 41])
    plan = plan_patrol(graph, starts, 500, 100, search_seconds=600.0, restarts=20, tour_groups=False)
    territory = planned_territory(graph, starts, 500, 100).territory
    assert territory.shape == (4, graph.n_nodes)
    for agent, group in enumerate(plan.groups):
        assert set(np.flatnonzero(territory[agent]).tolist()) == set(group)
    assert territory.sum(axis=0).max() <= 1  # no target in two groups
    assert not territory[:, list(plan.dropped)].any()  # a dropped target is nobody's
    assert not territory[:, ~graph.targets].any()


def test_the_convention_plans_with_the_rule_its_agents_play() -> None:
    """Every planned group, walked by the territory rule's stalest-first choice, costs what the plan
    priced: on these starts a plan free to price a group by the ``tour`` rule gives an agent three
    targets that the stalest rule walks far worse."""
    graph = preset("rgg-60")
    starts = np.array([3, 17, 29, 41])
    distances = graph.hop_distances.astype(int).tolist()
    next_hop = graph.next_hop.astype(int).tolist()

    def played(groups) -> float:
        controllers = [GroupController(group, distances, next_hop, "stalest") for group in groups]
        return simulate(controllers, starts, graph.target_indices, np.zeros(graph.n_nodes), 500, 100)

    territory = planned_territory(graph, starts, 500, 100).territory
    groups = [tuple(np.flatnonzero(row).tolist()) for row in territory]
    plan = plan_patrol(graph, starts, 500, 100, search_seconds=600.0, restarts=20, tour_groups=False)
    assert set(plan.rules) == {"stalest"}
    assert played(groups) <= plan.predicted + 1e-9  # crossing another's target only lowers it
    mixed = plan_patrol(graph, starts, 500, 100, search_seconds=600.0, restarts=20)
    assert "tour" in mixed.rules
    assert played(mixed.groups) > 1.1 * mixed.predicted


def test_the_planned_groups_follow_the_starts_of_each_episode() -> None:
    """Two episodes with other starts: the env's territories are each episode's plan."""
    env = make_env("rgg-60", territory_input=True)
    seen = set()
    for seed in (1, 2):
        observations, _ = env.reset(seed=seed)
        state = env.unwrapped
        expected = planned_territory(state.graph, state.positions, state.max_cycles, state.u_max).territory
        for i, agent in enumerate(state.possible_agents):
            column = observations[agent]["nodes"][:, -2]  # territory_input, before the advice column
            assert np.array_equal(column.astype(bool), expected[i])
        seen.add(expected.tobytes())
    assert len(seen) == 2  # the starts changed the groups, so the comparison covered a re-plan


@pytest.mark.parametrize("graph", ["paper-50", "cliques-6x8"])
def test_the_advice_is_the_planned_patrol_move_on_every_step(graph: str) -> None:
    env = make_env(graph)
    rule = PlannedPatrolTeam()
    rng = np.random.default_rng(0)
    compared = 0
    for episode in range(2):
        observations, _ = env.reset(seed=episode)
        rule.reset(env, seed=episode)
        while env.agents:
            moves = rule.predict_dict(observations)
            for i, (agent, observation) in enumerate(observations.items()):
                flagged = np.flatnonzero(observation["nodes"][:, -1])
                if rule.rule.own[i].size == 0:  # no group: no advice, and the rule acts greedily
                    assert flagged.size == 0
                    continue
                assert flagged.tolist() == [moves[agent]]
                compared += 1
            actions = {a: int(rng.choice(np.flatnonzero(o["action_mask"]))) for a, o in observations.items()}
            observations, *_ = env.step(actions)
    assert compared > 0


def test_a_saved_state_resumes_the_episode_with_its_planned_territories() -> None:
    env, other = make_env("rgg-60", territory_input=True), make_env("rgg-60", territory_input=True)
    rng = np.random.default_rng(3)
    observations, _ = env.reset(seed=5)
    other.reset(seed=6)  # other starts, so other groups until the state is loaded
    for _ in range(7):
        actions = {a: int(rng.choice(np.flatnonzero(o["action_mask"]))) for a, o in observations.items()}
        observations, *_ = env.step(actions)
    other.unwrapped.load_state_dict(env.unwrapped.state_dict())
    for _ in range(20):
        actions = {a: int(rng.choice(np.flatnonzero(o["action_mask"]))) for a, o in observations.items()}
        observations, *_ = env.step(actions)
        resumed, *_ = other.step(actions)
        for agent in observations:
            assert np.array_equal(observations[agent]["nodes"], resumed[agent]["nodes"])


def test_planned_patrol_acts_legally_and_differs_from_the_split_where_the_plan_does() -> None:
    """On rooms-4 the plan's groups are not the split's, so the two rules play other episodes."""
    scores = {}
    for name in ("territory_patrol", "planned_patrol"):
        env = persistent_monitoring_v0.parallel_env(graph="rooms-4", max_cycles=80)
        episode_moves(env, make_team(name), seed=11)  # the env raises on an illegal move
        scores[name] = env.unwrapped.episode_metrics()["avg_uncertainty"]
    assert scores["planned_patrol"] != scores["territory_patrol"]


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"territories": "voronoi"}, "territories must be one of"),
        ({"territories": "planned", "advice_input": False}, "none of them is on"),
        (
            {"territories": "planned", "advice_input": False, "reward": {"territory": 0.04}},
            "needs territory_input",
        ),
    ],
)
def test_bad_territory_settings_are_refused_in_one_line(options: dict, message: str) -> None:
    with pytest.raises(InputError, match=message) as error:
        make_env(**options)
    assert "\n" not in str(error.value)


@pytest.mark.parametrize("convention", ["planned", "planned_tours"])
def test_a_territory_bound_guards_each_episodes_planned_territory(convention: str) -> None:
    from sb3_pm.agents.training.team import IndependentPPO

    env_kwargs = {"max_cycles": 30, "territories": convention, "territory_input": True, **KNOWN}
    team = IndependentPPO(
        "rooms-4",
        n_agents=4,
        seed=0,
        env_kwargs=env_kwargs,
        hyperparams={"n_steps": 10, "batch_size": 10, "n_epochs": 1},
    )
    team.set_filter(neglect_bound=60.0, neglect_scope="territory")
    # Before an episode there is no plan, so the bound guards nothing yet.
    assert all(team.models[a].policy.dcbf_config.territory == () for a in team.agents)
    env = team.make_env()
    seen = set()
    for seed in range(4):
        observations, _ = env.reset(seed=seed)
        team.reset(env, seed=seed)
        planned = env.unwrapped._territory
        guarded = tuple(team.models[a].policy.dcbf_config.territory for a in team.agents)
        assert guarded == tuple(tuple(np.flatnonzero(row).tolist()) for row in planned)
        seen.add(guarded)
        actions = team.predict_dict(observations)
        assert all(observations[a]["action_mask"][actions[a]] for a in actions)  # legal moves
    assert len(seen) > 1  # the starts changed the groups, and the bound followed them

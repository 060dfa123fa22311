"""``territories: planned_tours``: the plan's groups, each group the plan walks as a tour walked so
by the territory rule, in the ``planned_tour_patrol`` baseline and in the env's advice."""

from __future__ import annotations

import numpy as np
import pytest

from sb3_pm.baselines import make_team
from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.envs.territory_rule import TerritoryAdvice
from sb3_pm.errors import InputError
from sb3_pm.graphs.generators import erdos_renyi
from sb3_pm.graphs.large_sites import city_streets
from sb3_pm.graphs.resolve import resolve_graph
from sb3_pm.planning.conventions import team_territory
from sb3_pm.planning.planner import plan_patrol
from tests.conftest import episode_moves

KNOWN = {"graph_knowledge": "known", "target_knowledge": "known"}
STEPS = 120


@pytest.fixture(scope="module")
def street_site():
    """A small street site on which the plan walks some groups as tours."""
    return city_streets(120, seed=1)


def test_a_touring_agent_dwells_then_takes_its_tours_next_target_or_its_nearest() -> None:
    spec = erdos_renyi(20, 0.3, n_targets=4, seed=1)
    targets = [int(t) for t in spec.target_indices]
    territory = np.zeros((1, 20), dtype=bool)
    territory[0, targets] = True
    tour = [targets[2], targets[0], targets[3], targets[1]]
    advice = TerritoryAdvice(territory, spec.hop_distances, spec.next_hop, u_max=100, tours=[tour])
    u, age = np.zeros((1, 20), np.float32), np.zeros((1, 20), np.float32)
    active = np.array([True])
    here = tour[1]
    u[0, here] = 3
    assert advice.moves(np.array([here]), u, age, active)[0] == here  # dwell while u > 0
    u[0, here] = 0
    age[0, tour[3]] = 90  # the stalest target is not the tour's next: the tour wins
    move = advice.moves(np.array([here]), u, age, active)[0]
    assert advice.goals[0] == tour[2]
    assert spec.hop_distances[move, tour[2]] == spec.hop_distances[here, tour[2]] - 1
    off = next(v for v in range(20) if v not in targets)
    advice.reset()
    advice.moves(np.array([off]), u, age, active)
    distances = spec.hop_distances[off, targets]
    nearest = min(targets, key=lambda t: (spec.hop_distances[off, t], t))
    assert advice.goals[0] == nearest and spec.hop_distances[off, nearest] == distances.min()


def test_tours_must_order_the_agents_own_targets() -> None:
    spec = erdos_renyi(20, 0.3, n_targets=4, seed=1)
    territory = np.zeros((1, 20), dtype=bool)
    territory[0, spec.target_indices] = True
    with pytest.raises(ValueError, match="tours must order"):
        TerritoryAdvice(territory, spec.hop_distances, spec.next_hop, 100, tours=[[0, 1]])


def lower_plan(graph, starts, steps: int = STEPS):
    """The lower of the two searches the convention runs."""
    searches = [
        plan_patrol(
            graph, np.asarray(starts), steps, 100, search_seconds=600.0, restarts=20, tour_groups=tours
        )
        for tours in (True, False)
    ]
    return min(searches, key=lambda plan: plan.predicted)


def test_the_convention_carries_the_plans_groups_and_tours(street_site) -> None:
    starts = np.array([3, 40, 77, 101])
    plan = lower_plan(street_site, starts)
    territories = team_territory("planned_tours", street_site, starts, STEPS, 100)
    assert "tour" in plan.rules and "stalest" in plan.rules
    for agent, (group, rule) in enumerate(zip(plan.groups, plan.rules)):
        assert set(np.flatnonzero(territories.territory[agent]).tolist()) == set(group)
        assert territories.tours[agent] == (group if rule == "tour" else None)
    assert team_territory("planned", street_site, starts, STEPS, 100).tours == (None,) * 4


@pytest.mark.parametrize("starts", [[3, 40, 77, 101], [5, 6, 7, 8]])
def test_planned_tour_patrol_scores_its_plan_and_beats_the_stalest_walk(street_site, starts) -> None:
    """Alone on its group each agent plays the plan's walk (another agent crossing one of its
    targets only lowers it), so the episode costs at most what the plan priced; on these starts
    the stalest walk of the same convention's groups costs more."""
    scores = {}
    for name in ("planned_patrol", "planned_tour_patrol"):
        env = persistent_monitoring_v0.parallel_env(
            graph=street_site, n_agents=4, max_cycles=STEPS, initial_positions=starts
        )
        episode_moves(env, make_team(name), seed=0)  # the env raises on an illegal move
        scores[name] = env.unwrapped.episode_metrics()["avg_uncertainty"]
    assert scores["planned_tour_patrol"] <= lower_plan(street_site, starts).predicted + 1e-9
    assert scores["planned_tour_patrol"] < scores["planned_patrol"]


def test_the_convention_keeps_the_stalest_search_where_it_plans_lower() -> None:
    """On these small-world starts the search free to take tours ends in a local optimum above the
    stalest rule's search; the convention keeps the lower."""
    graph = resolve_graph("small-world-60")
    starts = np.array([23, 1, 41, 51])
    with_tours = plan_patrol(graph, starts, 500, 100, search_seconds=600.0, restarts=20, tour_groups=True)
    stalest = plan_patrol(graph, starts, 500, 100, search_seconds=600.0, restarts=20, tour_groups=False)
    assert stalest.predicted < with_tours.predicted
    territories = team_territory("planned_tours", graph, starts, 500, 100)
    assert territories.tours == (None,) * 4
    for agent, group in enumerate(stalest.groups):
        assert set(np.flatnonzero(territories.territory[agent]).tolist()) == set(group)


@pytest.mark.parametrize("tours_lower", [True, False])
def test_the_two_searches_in_two_processes_plan_as_in_one(
    street_site, monkeypatch, tours_lower: bool
) -> None:
    """On large sites the search free to take tours runs in a worker process: the same plan as both
    searches in this one, the lower kept either way (the street site plans lower with tours, the
    small-world starts above lower without)."""
    from sb3_pm.planning import planner

    graph, starts = (
        (street_site, np.array([3, 40, 77, 110]))
        if tours_lower
        else (
            resolve_graph("small-world-60"),
            np.array([23, 1, 41, 51]),
        )
    )
    monkeypatch.setattr(planner, "_second_core_free", lambda: False)
    alone = planner.plan_both_ways(graph, starts, 200, 100, search_seconds=600.0, restarts=2)
    started = []
    start_search = planner._start_search
    monkeypatch.setattr(planner, "_start_search", lambda *a: started.append(a) or start_search(*a))
    monkeypatch.setattr(planner, "_second_core_free", lambda: True)
    monkeypatch.setattr(planner, "PARALLEL_MIN_NODES", 0)
    beside = planner.plan_both_ways(graph, starts, 200, 100, search_seconds=600.0, restarts=2)
    assert len(started) == 1 and beside == alone
    assert ("tour" in alone.rules) is tours_lower


def test_a_failed_search_worker_is_one_line() -> None:
    from sb3_pm.planning import planner

    worker = planner._start_search(
        resolve_graph("karate"), {"starts": np.array([0, 1]), "no_such_argument": 1}
    )
    with pytest.raises(RuntimeError, match=r"the plan search's worker process failed \(exit status 1\)"):
        planner._plan_of(worker)


def make_env(graph, **kwargs):
    options = {"max_cycles": 60, "advice_input": True, "territories": "planned_tours", **KNOWN, **kwargs}
    return persistent_monitoring_v0.parallel_env(graph=graph, n_agents=4, **options)


def test_the_advice_is_the_planned_tour_patrol_move_on_every_step(street_site) -> None:
    env = make_env(street_site)
    rule = make_team("planned_tour_patrol")
    rng = np.random.default_rng(0)
    toured = 0
    for episode in range(2):
        observations, _ = env.reset(seed=episode)
        rule.reset(env, seed=episode)
        toured += sum(tour is not None for tour in env.unwrapped._team_territories.tours)
        while env.agents:
            moves = rule.predict_dict(observations)
            for i, (agent, observation) in enumerate(observations.items()):
                flagged = np.flatnonzero(observation["nodes"][:, -1])
                assert flagged.tolist() == ([moves[agent]] if rule.rule.own[i].size else [])
            actions = {a: int(rng.choice(np.flatnonzero(o["action_mask"]))) for a, o in observations.items()}
            observations, *_ = env.step(actions)
    assert toured > 0  # some agent walked a tour, so the comparison covered one


def test_a_saved_state_resumes_the_episode_with_its_tours(street_site) -> None:
    env, other = make_env(street_site), make_env(street_site)
    rng = np.random.default_rng(3)
    observations, _ = env.reset(seed=5)
    other.reset(seed=6)  # other starts, so other groups and tours until the state is loaded
    for _ in range(7):
        actions = {a: int(rng.choice(np.flatnonzero(o["action_mask"]))) for a, o in observations.items()}
        observations, *_ = env.step(actions)
    other.unwrapped.load_state_dict(env.unwrapped.state_dict())
    tours = env.unwrapped._team_territories.tours
    assert any(tour is not None for tour in tours)  # the state carries a tour to lose
    assert other.unwrapped._team_territories.tours == tours
    for _ in range(30):
        actions = {a: int(rng.choice(np.flatnonzero(o["action_mask"]))) for a, o in observations.items()}
        observations, *_ = env.step(actions)
        resumed, *_ = other.step(actions)
        for agent in observations:
            assert np.array_equal(observations[agent]["nodes"], resumed[agent]["nodes"])


def test_a_saved_state_with_tours_that_do_not_fit_is_refused_in_one_line(street_site) -> None:
    env = make_env(street_site)
    env.reset(seed=5)
    saved = env.unwrapped.state_dict()
    touring = next(i for i, tour in enumerate(saved["tours"]) if tour is not None)
    no_tours = {**saved, "tours": None}  # as a state saved before tours
    one_short = {**saved, "tours": saved["tours"][:-1]}
    wrong = {**saved, "tours": [list(tour) if tour else tour for tour in saved["tours"]]}
    wrong["tours"][touring] = wrong["tours"][touring][:-1]
    for state, message in [
        (no_tours, "has no tours"),
        (one_short, "not one per agent"),
        (wrong, "do not order"),
    ]:
        with pytest.raises(InputError, match=message) as error:
            make_env(street_site).unwrapped.load_state_dict(state)
        assert "\n" not in str(error.value)
    planned = make_env(street_site, territories="planned")  # walks no tours
    with pytest.raises(InputError, match="walks tours, and this env's territories are planned"):
        planned.unwrapped.load_state_dict(saved)
    planned.unwrapped.load_state_dict({**saved, "tours": None})  # a planned state before tours loads

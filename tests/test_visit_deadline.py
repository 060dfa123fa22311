"""The DCBF filter's rule 12, the visit deadline: every target of an agent's visit set (its
territory, and the targets no territory holds that it sweeps) is stood on at least once every
``D`` steps, from the agent's own memory of its visits, which the deployed team keeps."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch as th

from sb3_pm.agents.deployment.visit_memory import VisitMemory
from sb3_pm.errors import InputError
from sb3_pm.evaluation.harness import evaluate
from sb3_pm.planning.conventions import sweep_targets
from sb3_pm.policies.dcbf import DCBFConfig, check_deploy_filter, dcbf_mask
from sb3_pm.policies.visit_deadline import run_projection, visit_hops
from tests.conftest import path_graph
from tests.test_advice_input import small_team
from tests.test_leave_cleared import N


def _row(nodes: list[int], n: int = N) -> th.Tensor:
    return th.tensor([[i in nodes for i in range(n)]])


class TestProjection:
    def test_the_map_bounds_the_run_below_the_cap_and_the_memory_always(self) -> None:
        u_last = th.tensor([[3.0, 100.0, 100.0, 40.0]])
        age = th.tensor([[2.0, 5.0, 0.0, 1.0]])
        since = th.tensor([[50.0, 7.0, 300.0, 20.0]])
        # node 0: 3 + 2 < 50; node 1: at the cap, so the memory's 7; node 2: the memory's 300
        # (seen at the cap, never remembered lower); node 3: 40 + 1 > 20
        assert run_projection(u_last, age, since, 100.0).tolist() == [[5.0, 7.0, 300.0, 20.0]]


class TestHops:
    """An agent on node 0 of the path 0 - 1 - ... - 5, with target 5 in its visit set."""

    def hops(self, since: float, deadline: int) -> tuple[bool, list[int]]:
        n = 6
        adjacency = th.zeros(1, n, n)
        for i in range(n - 1):
            adjacency[0, i, i + 1] = adjacency[0, i + 1, i] = 1
        forced, hops = visit_hops(
            th.full((1, n), 100.0),  # every node last seen at the cap: the memory decides
            th.zeros(1, n),
            th.full((1, n), since),
            _row([5], n),
            adjacency,
            th.tensor([0]),
            _row([0, 1], n),
            deadline,
            100.0,
        )
        return bool(forced[0]), th.nonzero(hops[0]).flatten().tolist()

    def test_due_once_the_memory_and_the_walk_reach_the_deadline(self) -> None:
        # 5 hops away: due when since + 5 >= D (walking then, the run ends at since + 5 - 1 < D)
        assert self.hops(since=194, deadline=200) == (False, [])
        forced, hops = self.hops(since=195, deadline=200)
        assert forced and hops == [1]

    def test_a_deadline_above_the_cap_binds_which_rule_8_cannot(self) -> None:
        assert self.hops(since=400, deadline=418)[0] is False
        assert self.hops(since=413, deadline=418)[0] is True


class TestRule:
    def allowed(self, visit: list[int] | None, deadline: list[int] | None = None, **config) -> list[int]:
        """An agent on node 0, on a target it observes cleared (rule 9 would move it on)."""
        mask = dcbf_mask(
            th.zeros(1, N),
            _row(list(range(N))),
            th.tensor([0]),
            th.tensor([True]),
            th.tensor([0.0]),
            th.tensor([5.0]),
            _row([]),
            DCBFConfig(barrier=False, **config),
            None if deadline is None else (th.tensor([True]), _row(deadline)),
            None,
            None if visit is None else (th.tensor([True]), _row(visit)),
        )
        return th.nonzero(mask[0]).flatten().tolist()

    def test_its_hops_override_rules_2_to_11_and_yield_to_rule_8(self) -> None:
        assert self.allowed(None, leave_cleared=True) == list(range(1, N))
        assert self.allowed([0], leave_cleared=True) == [0]
        assert self.allowed([2], deadline=[3]) == [3]

    def test_on_a_target_it_only_sweeps_the_agent_is_not_held(self) -> None:
        def on_target(sweeping: bool) -> list[int]:
            mask = dcbf_mask(
                th.zeros(1, N),
                _row(list(range(N))),
                th.tensor([0]),
                th.tensor([True]),
                th.tensor([90.0]),  # u > 0: the freeze would hold it
                th.tensor([0.0]),
                _row([]),
                DCBFConfig(barrier=False, freeze_steps=500),
                None,
                None,
                (th.tensor([False]), _row([])),
                th.tensor([sweeping]),
            )
            return th.nonzero(mask[0]).flatten().tolist()

        assert on_target(False) == [0]
        assert on_target(True) == list(range(1, N))

    def test_its_settings_are_checked(self) -> None:
        assert DCBFConfig(visit_deadline=418).visit_deadline == 418
        for bad in (0, -3, 1.5, True, "auto"):
            with pytest.raises(InputError, match="visit_deadline must be a whole number of steps >= 1"):
                DCBFConfig(visit_deadline=bad)  # type: ignore[arg-type]


class TestSweep:
    def test_a_target_no_territory_holds_goes_to_the_nearest_territory(self) -> None:
        graph = path_graph(10, [0, 2, 5, 9])
        territory = np.zeros((2, 10), dtype=bool)
        territory[0, [0, 2]] = True
        territory[1, 9] = True
        swept = sweep_targets(territory, graph.target_indices, graph.routes, np.array([0, 9]))
        # target 5: 3 hops from agent 0's node 2, 4 from agent 1's node 9
        assert [np.flatnonzero(row).tolist() for row in swept] == [[5], []]

    def test_ties_go_to_the_lower_agent_and_an_empty_territory_counts_from_its_start(self) -> None:
        graph = path_graph(9, [0, 4, 8])
        territory = np.zeros((3, 9), dtype=bool)
        territory[0, 0] = True
        territory[1, 8] = True
        swept = sweep_targets(territory, graph.target_indices, graph.routes, np.array([0, 8, 5]))
        assert [np.flatnonzero(row).tolist() for row in swept] == [[], [], [4]]
        territory[2] = False
        swept = sweep_targets(territory, graph.target_indices, graph.routes, np.array([0, 8, 0]))
        assert [np.flatnonzero(row).tolist() for row in swept] == [[4], [], []]

    def test_nothing_to_sweep_where_every_target_has_a_territory(self) -> None:
        graph = path_graph(4, [0, 3])
        territory = np.array([[True, False, False, False], [False, False, False, True]])
        assert not sweep_targets(territory, graph.target_indices, graph.routes, np.array([0, 3])).any()


class TestMemory:
    def test_it_counts_steps_since_each_agent_stood_on_each_node(self) -> None:
        memory = VisitMemory(["a", "b"], np.ones((2, 4), dtype=np.int8))
        memory.observe({"a": 0, "b": 3})  # the reset's observation is step 0
        memory.observe({"a": 1, "b": 3})
        memory.observe({"a": 2, "b": 3})
        assert memory.since.tolist() == [[2, 1, 0, 2], [2, 2, 2, 0]]


class TestDeployFilter:
    def test_it_is_kept_where_given_and_checks_again_as_itself(self) -> None:
        checked = check_deploy_filter({"visit_deadline": 120, "pass_held": True})
        assert checked == {
            "neglect_bound": None,
            "neglect_scope": "known",
            "pass_held": True,
            "visit_deadline": 120,
        }
        assert check_deploy_filter(checked) == checked
        with_bound = check_deploy_filter(
            {"neglect_bound": 50, "neglect_scope": "territory", "visit_deadline": 80}
        )
        assert with_bound is not None and with_bound["visit_deadline"] == 80

    def test_a_bad_deadline_is_refused_by_name(self) -> None:
        with pytest.raises(InputError, match="visit_deadline must be a whole number of steps >= 1"):
            check_deploy_filter({"visit_deadline": 0})


def _episodes_max_neglect(team, graph, deadline: int | None, episodes: int = 4) -> list[float]:
    team.set_filter(visit_deadline=deadline)
    result = evaluate(team, graph, n_agents=2, episodes=episodes, seed=3, max_cycles=200)
    return [float(record.metrics["max_neglect"]) for record in result.episodes]


class TestTeam:
    def test_each_agent_keeps_its_one_target_within_the_deadline(self) -> None:
        """On a path with one target in each agent's territory, no two targets of an agent are ever
        due together, so the guarantee holds on every episode; the same untrained team without the
        rule leaves some target longer (the test can fail)."""
        graph = path_graph(16, [3, 12], name="path16")
        team = small_team({}, graph=graph, freeze_steps=0)
        try:
            without = _episodes_max_neglect(team, graph, None)
            within = _episodes_max_neglect(team, graph, 25)
        finally:
            team.close()
        assert max(without) > 25
        assert max(within) <= 25

    def test_a_deadline_of_one_step_alternates_between_two_adjacent_targets(self) -> None:
        """With ``D = 1`` the target underfoot is not due (its run has not begun), so each agent
        goes back and forth between its two adjacent targets; were it due, the agent would stay on
        the first and leave the other unvisited all episode."""
        graph = path_graph(8, [0, 1, 6, 7], name="pairs8")
        team = small_team({}, graph=graph, freeze_steps=0)
        try:
            within = _episodes_max_neglect(team, graph, 1)
        finally:
            team.close()
        assert max(within) <= 8  # the walk to the first target; then each run is one step

    def test_a_bare_policy_refuses_it_and_a_team_needs_a_reset_after_setting_it(self) -> None:
        from dataclasses import replace

        from sb3_pm.envs import persistent_monitoring_v0

        team = small_team({})
        try:
            policy = team.models["agent_0"].policy
            policy.dcbf_config = replace(policy.dcbf_config, visit_deadline=30)
            env = persistent_monitoring_v0.parallel_env(graph="paper-50", n_agents=2, max_cycles=20)
            observations, _ = env.reset(seed=0)
            with pytest.raises(InputError, match="reads the team's memory of its visits"):
                policy.predict(observations["agent_0"], action_masks=observations["agent_0"]["action_mask"])
            team.set_filter(visit_deadline=30)
            with pytest.raises(InputError, match=r"reset the team on the env \(team.reset\(env\)\)"):
                team.predict_dict(observations)
            team.reset(env)
            assert set(team.predict_dict(observations)) == {"agent_0", "agent_1"}
            env.close()
        finally:
            team.close()

    def test_the_flag_sets_and_clears_it_and_auto_calibrates_it(self, tmp_path, capsys) -> None:
        from sb3_pm.cli import main

        team = small_team({})
        try:
            team.deploy_filter = {"visit_deadline": 40}
            assert team.acting_record(True) == {"visit_deadline": 40}
            team.save(tmp_path / "team")
        finally:
            team.close()
        out = tmp_path / "e.json"
        argv = ["evaluate", "--policy", str(tmp_path / "team"), "--graph", "paper-50", "--agents", "2"]
        argv += ["--episodes", "1", "--steps", "30", "--json", str(out)]
        assert main(argv) == 0
        assert json.loads(out.read_text())["config"]["visit_deadline"] == 40
        assert main([*argv, "--visit-deadline", "off"]) == 0
        assert "visit_deadline" not in json.loads(out.read_text())["config"]
        assert main([*argv, "--visit-deadline", "auto"]) == 0
        said = capsys.readouterr().err
        assert "territory_patrol's worst max_neglect over 10 calibration episodes" in said
        assert json.loads(out.read_text())["config"]["visit_deadline"] >= 1

    def test_a_baseline_refuses_the_flag(self, capsys) -> None:
        from sb3_pm.cli import main

        assert main(["evaluate", "--policy", "grazing", "--graph", "paper-50", "--visit-deadline", "9"]) == 2
        assert "--visit-deadline needs a trained DCBF team" in capsys.readouterr().err


def test_a_deploy_filter_of_auto_takes_the_rules_worst_neglect_on_each_site_at_reset() -> None:
    from sb3_pm.baselines.rule_neglect import rule_worst_neglect
    from sb3_pm.envs import persistent_monitoring_v0

    team = small_team({})
    try:
        team.deploy_filter = {"visit_deadline": "auto"}
        assert team.acting_record(True) == {}  # no number before a site is calibrated
        for steps in (30, 60):
            env = persistent_monitoring_v0.parallel_env(graph="paper-50", n_agents=2, max_cycles=steps)
            env.reset(seed=0)
            team.reset(env)
            env.close()
            expected = rule_worst_neglect("paper-50", 2, team.env_settings(), max_cycles=steps)
            assert team.acting_record(True) == {"visit_deadline": expected}
        assert expected > 30  # the two episode lengths gave two deadlines
        assert team.filter_settings["visit_deadline"] == "auto"
    finally:
        team.close()


def test_no_deadline_where_the_rule_left_a_target_unvisited_all_episode() -> None:
    from sb3_pm.baselines.rule_neglect import rule_worst_neglect, site_deadline
    from sb3_pm.envs import persistent_monitoring_v0

    assert rule_worst_neglect("paper-50", 2, max_cycles=8) == 8
    assert site_deadline("paper-50", 2, max_cycles=8) is None
    team = small_team({})
    try:
        team.deploy_filter = {"visit_deadline": "auto"}
        env = persistent_monitoring_v0.parallel_env(graph="paper-50", n_agents=2, max_cycles=8)
        observations, _ = env.reset(seed=0)
        team.reset(env)
        assert team.acting_record(True) == {}
        assert set(team.predict_dict(observations)) == {"agent_0", "agent_1"}
        env.close()
    finally:
        team.close()


def test_auto_calibrates_on_the_teams_own_planned_groups_too_and_takes_the_lower() -> None:
    from sb3_pm.baselines.rule_neglect import calibration_rules, rule_worst_neglect, site_deadline
    from sb3_pm.baselines.territory_patrol import (
        PlannedPatrolTeam,
        PlannedTourPatrolTeam,
        TerritoryPatrolTeam,
    )

    assert calibration_rules({}) == [TerritoryPatrolTeam]
    assert calibration_rules({"territories": "split"}) == [TerritoryPatrolTeam]
    assert calibration_rules({"territories": "planned"}) == [TerritoryPatrolTeam, PlannedPatrolTeam]
    assert calibration_rules({"territories": "planned_tours"})[1] is PlannedTourPatrolTeam
    known = {"territory_input": True, "graph_knowledge": "known", "target_knowledge": "known"}
    planned = {**known, "territories": "planned"}
    split = rule_worst_neglect("rooms-4", 4, planned)
    own = rule_worst_neglect("rooms-4", 4, planned, rule=PlannedPatrolTeam)
    assert own < split  # on rooms-4 the planned groups keep every target closer
    assert site_deadline("rooms-4", 4, planned) == own
    assert site_deadline("rooms-4", 4, known) == split  # no planned groups told


def test_auto_calibrates_on_the_envs_convention_not_the_one_the_team_trained_on() -> None:
    """A team trained on the split deployed in an env of planned territories (what
    ``--territories planned`` builds) calibrates on the planned groups too, and caches per convention."""
    from sb3_pm.baselines.rule_neglect import rule_worst_neglect
    from sb3_pm.baselines.territory_patrol import PlannedPatrolTeam
    from sb3_pm.envs import persistent_monitoring_v0

    team = small_team({"territory_input": True}, graph="rooms-4", n_agents=4)
    try:
        team.deploy_filter = {"visit_deadline": "auto"}
        deployed = {}
        for territories in ("planned", "split"):
            settings = {**team.env_settings(), "territories": territories}
            env = persistent_monitoring_v0.parallel_env(
                graph="rooms-4", n_agents=4, **{**settings, "max_cycles": 150}
            )
            env.reset(seed=0)
            team.reset(env)
            env.close()
            deployed[territories] = team.acting_record(True)["visit_deadline"]
        planned = {**team.env_settings(), "territories": "planned"}
        split = rule_worst_neglect("rooms-4", 4, planned, max_cycles=150)
        own = rule_worst_neglect("rooms-4", 4, planned, max_cycles=150, rule=PlannedPatrolTeam)
        assert own < split  # so the two conventions give two deadlines
        assert deployed == {"planned": own, "split": split}
    finally:
        team.close()


def test_the_calibration_is_the_rules_worst_episode_as_evaluate_measures_it() -> None:
    from sb3_pm.baselines import make_team
    from sb3_pm.baselines.rule_neglect import rule_worst_neglect

    measured = evaluate(make_team("territory_patrol"), "rooms-4", n_agents=4, episodes=3, seed=9_000_000)
    worst = max(int(record.metrics["max_neglect"]) for record in measured.episodes)
    assert rule_worst_neglect("rooms-4", 4, episodes=3) == worst


class TestPasses:
    """Rule 12 reads each agent's own row in every pass of the team."""

    def test_the_team_pass_and_one_pass_per_agent_act_alike_under_it(self) -> None:
        team = small_team({"territory_input": True}, n_agents=3)
        try:
            team.set_filter(visit_deadline=12)
            together = evaluate(team, "paper-50", n_agents=3, episodes=1, seed=5, max_cycles=60)
            team.stacked_inference = False
            apart = evaluate(team, "paper-50", n_agents=3, episodes=1, seed=5, max_cycles=60)
        finally:
            team.close()
        assert together.episodes[0].metrics == apart.episodes[0].metrics

    def test_learners_shared_by_more_agents_read_each_agents_row(self) -> None:
        """Two learners moved to a larger team of five agents; the env's territories give each
        agent its own visit set, and the shared and unshared passes act alike."""
        from tests.conftest import path_graph as path

        team = small_team({"territory_input": True}, n_agents=2)
        graph = path(24, [2, 6, 11, 17, 22], name="path24")
        try:
            moved = team.on_graph(graph)
            moved.set_filter(visit_deadline=30)
            first = [
                m.metrics["max_neglect"]
                for m in evaluate(moved, graph, n_agents=5, episodes=2, seed=1, max_cycles=150).episodes
            ]
            moved.stacked_inference = False
            apart = evaluate(moved, graph, n_agents=5, episodes=2, seed=1, max_cycles=150)
            moved.stacked_inference = True
            together = evaluate(moved, graph, n_agents=5, episodes=2, seed=1, max_cycles=150)
        finally:
            team.close()
        assert [r.metrics for r in together.episodes] == [r.metrics for r in apart.episodes]
        assert first == [r.metrics["max_neglect"] for r in together.episodes]
        assert moved.acting_record(True)["visit_deadline"] == 30

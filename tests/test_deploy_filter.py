"""A team's ``deploy_filter``: the DCBF neglect bound a trained team acts under, never trained under.

It is a config key (``zoo/ippo.yml``'s ``paper-50`` entry sets it), saved with the team, switched off
while :meth:`IndependentPPO.learn` runs and on again when it returns, and followed by everything that
evaluates the team unless ``sb3-pm evaluate --neglect-bound`` says otherwise.
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import pytest
from stable_baselines3.common.callbacks import BaseCallback

from sb3_pm.errors import InputError
from sb3_pm.policies.dcbf import DCBFConfig, check_deploy_filter
from sb3_pm.zoo.config import ConfigError, load_config
from tests.conftest import path_graph
from tests.paths import experiment_file

TINY = {"n_steps": 10, "batch_size": 10, "n_epochs": 1}
TERRITORY_BOUND = {"neglect_bound": 15.0, "neglect_scope": "territory"}


def tiny_team(deploy_filter=TERRITORY_BOUND, **hyperparams):
    from sb3_pm.agents.training.team import IndependentPPO

    return IndependentPPO(
        path_graph(10, targets=[0, 1, 8, 9]),
        n_agents=2,
        seed=0,
        env_kwargs={"max_cycles": 20},
        hyperparams={**TINY, **hyperparams},
        deploy_filter=deploy_filter,
    )


class BoundsSeen(BaseCallback):
    """Records the neglect bound of the learner's policy at every training step."""

    def __init__(self) -> None:
        super().__init__()
        self.bounds: set[float | None] = set()

    def _on_step(self) -> bool:
        self.bounds.add(self.model.policy.dcbf_config.neglect_bound)
        return True


def assert_trains_unbounded(loaded) -> None:
    """A loaded team trains a few steps with no bound at any step, and acts under its territory
    bound again afterwards."""
    seen = {a: BoundsSeen() for a in loaded.agents}
    loaded.learn(10, callback=seen, reset_num_timesteps=False)
    assert all(s.bounds == {None} for s in seen.values())
    assert loaded.acting_filter() == TERRITORY_BOUND


class TestCheck:
    def test_a_bound_with_or_without_a_scope(self) -> None:
        assert check_deploy_filter(None) is None
        assert check_deploy_filter({"neglect_bound": 50}) == {"neglect_bound": 50.0, "neglect_scope": "known"}
        territory = check_deploy_filter({"neglect_bound": 50, "neglect_scope": "territory"})
        assert territory == {"neglect_bound": 50.0, "neglect_scope": "territory"}

    @pytest.mark.parametrize(
        ("value", "message"),
        [
            (50, "expected null or a mapping"),
            ({"neglect_bound": 50, "scope": "known"}, "unknown key 'scope'"),
            ({"neglect_scope": "known"}, "neglect_bound must be a number"),
            ({"neglect_bound": True}, "neglect_bound must be a number"),
            ({"neglect_bound": 0.5}, "neglect_bound must be at least 1"),
            ({"neglect_bound": 50, "neglect_scope": "mine"}, "neglect_scope must be one of"),
        ],
    )
    def test_anything_else_is_refused_by_name(self, value, message) -> None:
        with pytest.raises(InputError, match=message):
            check_deploy_filter(value)


class TestConfig:
    def test_the_shipped_default_bounds_paper_50_only(self) -> None:
        """The bound was measured on paper-50 (B = 50, about the grazing baseline's worst neglect
        there); other graphs keep the filter as trained until a bound is measured for them."""
        paper = load_config("ippo", "paper-50")
        rule = {"neglect_bound": 50.0, "neglect_scope": "territory", "leave_cleared": True}
        assert paper.deploy_filter == rule
        assert paper.team_kwargs()["deploy_filter"] == paper.deploy_filter
        assert paper.to_dict()["deploy_filter"] == paper.deploy_filter
        for graph in ("paper-100", "rooms-4", "karate"):
            assert load_config("ippo", graph).deploy_filter is None
        # rgg-60 deploys the filter's rule 12 alone (no bound), as measured there
        rgg = load_config("ippo", "rgg-60").deploy_filter
        assert rgg == {"neglect_bound": None, "neglect_scope": "known", "visit_deadline": "auto"}
        assert load_config("ippo_paper", "paper-50").deploy_filter is None

    def test_an_override_can_switch_it_off(self) -> None:
        assert load_config("ippo", "paper-50", overrides={"deploy_filter": None}).deploy_filter is None

    def test_a_malformed_one_names_the_file_entry_and_key(self, tmp_path: Path) -> None:
        path = tmp_path / "c.yml"
        path.write_text("default:\n  n_envs: 1\n  deploy_filter: {neglect_bound: fifty}\n")
        message = r"c\.yml: default\.deploy_filter: neglect_bound must be a number"
        with pytest.raises(ConfigError, match=message):
            load_config(path, "paper-50")

    def test_a_centralized_team_refuses_it(self) -> None:
        from sb3_pm.sharing.centralized import CentralizedPPO

        config = load_config("ippo", "paper-50", overrides={"learning_rate_spread": 1.0})
        config.env_kwargs["reward"] = {"clearing": 0.04}
        with pytest.raises(InputError, match="deploy_filter is not available for a centralized team"):
            CentralizedPPO.from_config(config, "paper-50")


class TestTeam:
    def test_it_acts_under_the_bound_but_trains_without_it(self, tmp_path: Path) -> None:
        team = tiny_team()
        try:
            configs = {a: team.models[a].policy.dcbf_config for a in team.agents}
            assert configs["agent_0"].neglect_bound == 15.0 and configs["agent_1"].territory == (8, 9)
            seen = {a: BoundsSeen() for a in team.agents}
            team.learn(20, callback=seen)
            assert all(s.bounds == {None} for s in seen.values())  # every training step unbounded
            after = team.models["agent_1"].policy.dcbf_config
            assert (after.neglect_bound, after.neglect_scope, after.territory) == (15.0, "territory", (8, 9))
            team.save(tmp_path / "t")
        finally:
            team.close()
        manifest = json.loads((tmp_path / "t" / "manifest.json").read_text())
        assert manifest["deploy_filter"] == TERRITORY_BOUND

        from sb3_pm.agents.training.team import IndependentPPO

        loaded = IndependentPPO.load(tmp_path / "t")
        try:
            assert loaded.deploy_filter == TERRITORY_BOUND
            assert loaded.acting_filter() == TERRITORY_BOUND
            assert loaded.models["agent_0"].policy.dcbf_config.territory == (0, 1)
            # Further training is unbounded too, and the bound is back afterwards.
            assert_trains_unbounded(loaded)
        finally:
            loaded.close()

    def test_a_team_saved_with_the_bound_in_its_policy_kwargs_converts_and_trains_without_it(
        self, tmp_path: Path
    ) -> None:
        """Teams saved before the manifest held ``filter_settings`` carried the deploy filter in
        their learners' ``policy_kwargs``, in the old format (``sb3_pm.team/1``), which loads only by
        unpickling: refused, then converted (a trusted file), they act under it and train without it."""
        from sb3_pm import convert_team
        from sb3_pm.agents.deployment.saved_teams import OldTeamFormatError
        from sb3_pm.agents.training.team import IndependentPPO

        team = tiny_team()
        try:
            for model in team.models.values():  # the earlier format: the bound in the kwargs
                model.policy_kwargs = {**model.policy_kwargs, "neglect_bound": 15.0}
            team.save(tmp_path / "t")
        finally:
            team.close()
        manifest_path = tmp_path / "t" / "manifest.json"
        manifest = json.loads(manifest_path.read_text())
        for key in ("filter_settings", "hyperparams", "per_agent"):  # none of them in that format
            del manifest[key]
        manifest["format"] = "sb3_pm.team/1"
        manifest_path.write_text(json.dumps(manifest))
        with pytest.raises(OldTeamFormatError, match="convert-team"):
            IndependentPPO.load(tmp_path / "t")
        loaded = IndependentPPO.load(convert_team(tmp_path / "t", tmp_path / "converted"))
        try:
            assert loaded.acting_filter() == TERRITORY_BOUND
            assert all("neglect_bound" not in m.policy_kwargs for m in loaded.models.values())
            assert_trains_unbounded(loaded)
        finally:
            loaded.close()

    def test_the_same_seed_trains_the_same_parameters_with_or_without_it(self) -> None:
        """Training never reads the deploy filter: the parameters match a team without one."""
        import torch as th

        teams = [tiny_team(), tiny_team(deploy_filter=None)]
        try:
            for team in teams:
                team.learn(20)
            for agent in teams[0].agents:
                a, b = (t.models[agent].policy.state_dict() for t in teams)
                assert all(th.equal(a[key], b[key]) for key in a)
        finally:
            for team in teams:
                team.close()

    def test_training_with_a_bound_and_a_deploy_filter_is_refused(self) -> None:
        with pytest.raises(InputError, match="trains with a neglect bound .* keep one of them"):
            tiny_team(policy_kwargs={"neglect_bound": 20.0})

    def test_a_graph_family_has_no_territories(self) -> None:
        from sb3_pm.agents.training.team import IndependentPPO

        with pytest.raises(InputError, match="scope 'territory' needs one graph"):
            IndependentPPO("family:er", n_agents=2, deploy_filter=TERRITORY_BOUND)


class TestTransfer:
    def test_a_moved_bound_takes_the_new_graphs_territories(self) -> None:
        from sb3_pm.agents.deployment.transfer import retarget_territories
        from sb3_pm.graphs.territories import target_territories

        graph = path_graph(12, targets=[0, 2, 9, 11])
        bounded = DCBFConfig(neglect_bound=20.0, neglect_scope="territory", territory=(0, 1))
        policies = {f"agent_{i}": SimpleNamespace(dcbf_config=bounded) for i in range(2)}
        retarget_territories(policies, graph)
        owner = target_territories(graph.hop_distances, graph.target_indices, 2)
        for i, policy in enumerate(policies.values()):
            expected = tuple(int(t) for t, o in zip(graph.target_indices, owner) if o == i)
            assert policy.dcbf_config.territory == expected
        assert {t for p in policies.values() for t in p.dcbf_config.territory} == {0, 2, 9, 11}

    def test_policies_without_a_territory_bound_are_left_alone(self) -> None:
        from sb3_pm.agents.deployment.transfer import retarget_territories

        known = DCBFConfig(neglect_bound=20.0, neglect_scope="known")
        policies = {"agent_0": SimpleNamespace(dcbf_config=known)}
        retarget_territories(policies, path_graph(6, targets=[0, 5]))
        assert policies["agent_0"].dcbf_config is known


def saved_tiny_team(folder: Path, deploy_filter=TERRITORY_BOUND) -> Path:
    """A tiny team with ``deploy_filter``, trained a little and saved to ``folder``."""
    team = tiny_team(deploy_filter=deploy_filter)
    try:
        team.learn(10)
        team.save(folder)
    finally:
        team.close()
    return folder


@pytest.fixture(scope="module")
def saved(tmp_path_factory) -> Path:
    """A trained two-agent team saved with a territory deploy filter."""
    return saved_tiny_team(tmp_path_factory.mktemp("deploy") / "team")


class TestCommandLine:
    def evaluate(self, saved: Path, tmp_path: Path, *flags: str) -> dict:
        from sb3_pm.cli import main

        out = tmp_path / "e.json"
        graph = saved / "graph.graphml"
        argv = ["evaluate", "--policy", str(saved), "--graph", str(graph), "--agents", "2", "--episodes", "1"]
        assert main([*argv, "--steps", "20", "--json", str(out), *flags]) == 0
        return json.loads(out.read_text())["config"]

    def test_evaluate_follows_the_saved_filter_and_says_so(self, saved, tmp_path, capsys) -> None:
        config = self.evaluate(saved, tmp_path)
        assert (config["neglect_bound"], config["neglect_scope"]) == (15.0, "territory")
        assert config["filter_activity"]["masks"] > 0
        assert "acts under its deploy_filter: neglect bound 15, scope territory" in capsys.readouterr().err

    def test_off_acts_without_it(self, saved, tmp_path) -> None:
        config = self.evaluate(saved, tmp_path, "--neglect-bound", "off")
        assert "neglect_bound" not in config and "filter_activity" not in config

    def test_off_takes_no_scope_and_a_word_is_refused(self, saved, tmp_path, capsys) -> None:
        from sb3_pm.cli import main

        base = ["evaluate", "--policy", str(saved), "--graph", str(saved / "graph.graphml"), "--agents", "2"]
        assert main([*base, "--neglect-bound", "off", "--neglect-scope", "known"]) == 2
        assert "--neglect-scope needs --neglect-bound B" in capsys.readouterr().err
        with pytest.raises(SystemExit):
            main([*base, "--neglect-bound", "fifty"])
        assert "expected a number, 'off' or 'auto'" in capsys.readouterr().err

    def test_auto_calibrates_a_territory_bound_on_the_graph(self, saved, tmp_path, capsys) -> None:
        from sb3_pm.evaluation.neglect_calibration import calibrate_neglect_bound
        from sb3_pm.graphs import load_graphml

        config = self.evaluate(saved, tmp_path, "--neglect-bound", "auto")
        expected = calibrate_neglect_bound(load_graphml(saved / "graph.graphml"), 2, max_cycles=20)
        assert expected.bound is not None and expected.bound != 15.0  # not the saved filter's B
        assert (config["neglect_bound"], config["neglect_scope"]) == (expected.bound, "territory")
        assert config["neglect_calibration"] == expected.to_dict()
        assert expected.describe() in capsys.readouterr().err

    def test_auto_acts_without_a_bound_where_the_territories_cannot_be_held(
        self, saved, tmp_path, monkeypatch
    ) -> None:
        from sb3_pm.evaluation import neglect_calibration

        hopeless = neglect_calibration.CalibratedBound(None, 100.0, 100.0, 10, 9_000_000, 1.2, 2, 20)
        monkeypatch.setattr(neglect_calibration, "calibrate_neglect_bound", lambda *a, **k: hopeless)
        config = self.evaluate(saved, tmp_path, "--neglect-bound", "auto")
        assert "neglect_bound" not in config and "filter_activity" not in config  # not the saved B 15
        assert config["neglect_calibration"]["bound"] is None

    def test_auto_calibrates_the_team_as_deployed_without_its_failures(
        self, saved, tmp_path, monkeypatch
    ) -> None:
        from sb3_pm.evaluation import neglect_calibration
        from sb3_pm.evaluation.teams import resolve_team

        calls = []
        real = neglect_calibration.calibrate_neglect_bound

        def recording(graph, n_agents, env_kwargs, max_cycles):
            calls.append((graph, n_agents, dict(env_kwargs), max_cycles))
            return real(graph, n_agents, env_kwargs, max_cycles=max_cycles)

        monkeypatch.setattr(neglect_calibration, "calibrate_neglect_bound", recording)
        config = self.evaluate(saved, tmp_path, "--neglect-bound", "auto", "--fail", "agent_1:5")
        ((graph, n_agents, env_kwargs, max_cycles),) = calls
        team_env = {k: v for k, v in resolve_team(str(saved)).env_kwargs.items() if k != "max_cycles"}
        assert (graph.name, n_agents, max_cycles) == ("graph", 2, 20)  # --steps 20, not the default 500
        assert env_kwargs == team_env and "failures" not in env_kwargs
        assert config["env_kwargs"]["failures"] == {"agent_1": 5}  # the episodes themselves fail
        assert config["neglect_calibration"]["max_cycles"] == 20

    def test_auto_refuses_another_team_size(self, saved, capsys) -> None:
        from sb3_pm.cli import main

        graph = str(saved / "graph.graphml")
        argv = [
            "evaluate",
            "--policy",
            str(saved),
            "--graph",
            graph,
            "--agents",
            "3",
            "--neglect-bound",
            "auto",
        ]
        assert main(argv) == 2
        assert (
            "calibrates the 2-agent team's territories; deploy it with --agents 2" in capsys.readouterr().err
        )

    def test_auto_is_a_territory_bound_for_trained_teams(self, saved, capsys) -> None:
        from sb3_pm.cli import main

        graph = str(saved / "graph.graphml")
        base = ["evaluate", "--graph", graph, "--agents", "2", "--episodes", "1", "--neglect-bound", "auto"]
        assert main([*base, "--policy", str(saved), "--neglect-scope", "known"]) == 2
        assert "--neglect-scope known cannot go with it" in capsys.readouterr().err
        assert main([*base, "--policy", "territory_patrol"]) == 2
        assert "needs a trained DCBF team" in capsys.readouterr().err


class TestSetting:
    def test_a_new_rule_replaces_the_old_and_null_restores_the_trained_filter(self) -> None:
        team = tiny_team()
        try:
            team.deploy_filter = {"neglect_bound": 30, "neglect_scope": "known"}
            assert team.acting_filter() == {"neglect_bound": 30.0, "neglect_scope": "known"}
            assert team.models["agent_0"].policy.dcbf_config.territory == ()
            with pytest.raises(InputError, match="neglect_scope must be one of"):
                team.deploy_filter = {"neglect_bound": 30, "neglect_scope": "mine"}
            assert team.deploy_filter == {"neglect_bound": 30.0, "neglect_scope": "known"}  # unchanged
            team.deploy_filter = None
            assert team.acting_filter() is None
            assert "neglect_bound" not in team.models["agent_0"].policy_kwargs
        finally:
            team.close()


class TestExperiments:
    def test_the_record_names_the_rule_so_a_folder_never_mixes_cells(self) -> None:
        from sb3_pm.experiments import load_experiment
        from sb3_pm.experiments.runner import experiment_record

        assert experiment_record(load_experiment("headline"))["deploy_filter"] == {
            "default": {"neglect_bound": 50.0, "neglect_scope": "territory", "leave_cleared": True}
        }
        assert "deploy_filter" not in experiment_record(load_experiment(experiment_file("territory_reward")))
        assert "deploy_filter" not in experiment_record(load_experiment("families"))

    def test_a_malformed_pin_names_the_file(self, tmp_path: Path) -> None:
        from sb3_pm.experiments import load_experiment
        from sb3_pm.experiments.spec import ExperimentError
        from sb3_pm.zoo.shipped import resolve_config_path

        path = tmp_path / "e.yml"
        path.write_text(
            f"name: e\ngraphs: [paper-50]\nseeds: [0]\nconfig: {resolve_config_path('ippo')}\n"
            "hyperparams: {deploy_filter: {neglect_bound: -1}}\nvariants: {default: {}}\n"
        )
        message = r"e\.yml.*hyperparams\.deploy_filter: neglect_bound must be at least 1"
        with pytest.raises(ExperimentError, match=message):
            load_experiment(path)


class TestFaults:
    def test_a_failed_learn_leaves_the_bound_on(self) -> None:
        team = tiny_team()
        try:
            with pytest.raises(InputError):
                team.learn(10, callback=[None])  # refused before training starts
            assert team.acting_filter() == TERRITORY_BOUND
        finally:
            team.close()

    def test_a_rule_the_learners_cannot_take_leaves_the_previous_one(self) -> None:
        from sb3_pm.agents.training.team import IndependentPPO

        team = IndependentPPO(
            path_graph(10, targets=[0, 9]),
            n_agents=2,
            algo="maskable_ppo",
            env_kwargs={"max_cycles": 20},
            hyperparams=TINY,
        )
        try:
            with pytest.raises(InputError, match="no DCBF filter to change"):
                team.deploy_filter = {"neglect_bound": 20}
            assert team.deploy_filter is None
            team.learn(10)  # still trains
        finally:
            team.close()

    def test_a_bound_trained_in_is_not_replaced_by_a_deploy_filter(self) -> None:
        team = tiny_team(deploy_filter=None, policy_kwargs={"neglect_bound": 20.0})
        try:
            with pytest.raises(InputError, match="trains with a neglect bound"):
                team.deploy_filter = {"neglect_bound": 30}
            assert team.acting_filter() == {"neglect_bound": 20.0, "neglect_scope": "known"}
        finally:
            team.close()

    def test_an_infinite_bound_is_refused(self) -> None:
        with pytest.raises(InputError, match="neglect_bound must be finite"):
            check_deploy_filter({"neglect_bound": float("inf")})

    def test_a_centralized_team_refuses_it_as_an_attribute_too(self) -> None:
        from sb3_pm.sharing.centralized import CentralizedPPO

        team = CentralizedPPO(
            path_graph(8, targets=[0, 7]), n_agents=2, env_kwargs={"max_cycles": 20}, hyperparams=TINY
        )
        try:
            with pytest.raises(InputError, match="not available for a CentralizedPPO team"):
                team.deploy_filter = {"neglect_bound": 20}
            assert team.deploy_filter is None
        finally:
            team.close()


def test_a_bound_without_a_scope_keeps_the_teams_scope(saved, tmp_path) -> None:
    from sb3_pm.cli import main

    out = tmp_path / "e.json"
    argv = ["evaluate", "--policy", str(saved), "--graph", str(saved / "graph.graphml"), "--agents", "2"]
    assert main([*argv, "--episodes", "1", "--steps", "20", "--neglect-bound", "12", "--json", str(out)]) == 0
    config = json.loads(out.read_text())["config"]
    assert (config["neglect_bound"], config["neglect_scope"]) == (12.0, "territory")


def test_a_bound_above_u_max_is_refused_as_it_could_never_bind() -> None:
    """rule 8 projects at most u_max (100 here), so B = 155 would leave the team as it was."""
    team = tiny_team(deploy_filter=None)
    try:
        with pytest.raises(InputError, match="neglect_bound 155 is above the environment's u_max 100"):
            team.set_filter(neglect_bound=155.0)
        assert team.acting_filter() is None
        team.set_filter(neglect_bound=100.0)  # at the cap it still binds
    finally:
        team.close()
    with pytest.raises(InputError, match="above the environment's u_max 100"):
        tiny_team(deploy_filter={"neglect_bound": 155})
    with pytest.raises(InputError, match="above the environment's u_max 100"):
        tiny_team(deploy_filter=None, policy_kwargs={"neglect_bound": 101})


SITE_BOUND = {"neglect_bound": "auto", "neglect_scope": "territory"}


class TestSiteBound:
    """``deploy_filter: {neglect_bound: auto}``: the bound is calibrated on each site the team is
    deployed on, before its first episode there (``zoo/ippo_transfer.yml`` ships it)."""

    def test_auto_is_a_territory_bound_and_nothing_else(self) -> None:
        assert check_deploy_filter({"neglect_bound": "auto"}) == SITE_BOUND
        assert check_deploy_filter(SITE_BOUND) == SITE_BOUND
        with pytest.raises(InputError, match="neglect_bound auto is a territory bound"):
            check_deploy_filter({"neglect_bound": "auto", "neglect_scope": "known"})
        with pytest.raises(InputError, match=r"neglect_bound must be a number \(the bound B\) or auto"):
            check_deploy_filter({"neglect_bound": "automatic"})

    def test_evaluate_calibrates_the_site_first_and_the_team_keeps_its_bound(self, tmp_path) -> None:
        from sb3_pm.agents.training.team import IndependentPPO
        from sb3_pm.evaluation import evaluate
        from sb3_pm.evaluation.neglect_calibration import calibrate_neglect_bound

        team = tiny_team(deploy_filter=SITE_BOUND)
        try:
            assert team.site_bound_pending and team.acting_filter() is None  # no number before a site
            team.learn(10)
            assert team.site_bound_pending  # training ends waiting for a site again
            team.save(tmp_path / "t")
        finally:
            team.close()
        loaded = IndependentPPO.load(tmp_path / "t")
        try:
            assert loaded.deploy_filter == SITE_BOUND and loaded.site_bound_pending
            result = evaluate(loaded, loaded.graph, n_agents=2, episodes=1, max_cycles=20)
            expected = calibrate_neglect_bound(loaded.graph, 2, {}, max_cycles=20)
            assert expected.bound is not None
            assert result.config["neglect_calibration"] == expected.to_dict()
            acted = (result.config["neglect_bound"], result.config["neglect_scope"])
            assert acted == (expected.bound, "territory")
            assert not loaded.site_bound_pending
            assert loaded.acting_filter() == {"neglect_bound": expected.bound, "neglect_scope": "territory"}
            again = evaluate(loaded, loaded.graph, n_agents=2, episodes=1, max_cycles=20)
            assert "neglect_calibration" not in again.config  # settled: not calibrated twice
        finally:
            loaded.close()

    def test_a_set_bound_wins_and_another_team_size_is_refused(self) -> None:
        from sb3_pm.evaluation import evaluate

        team = tiny_team(deploy_filter=SITE_BOUND)
        try:
            asked = "calibrates its 2 agents' territories, and 3 agents were asked"
            with pytest.raises(InputError, match=asked):
                evaluate(team, team.graph, n_agents=3, episodes=1, max_cycles=20)
            team.set_filter(neglect_bound=None)  # the user's choice: no bound
            result = evaluate(team, team.graph, n_agents=3, episodes=1, max_cycles=20)
            assert "neglect_calibration" not in result.config and "neglect_bound" not in result.config
        finally:
            team.close()

    def test_a_moved_team_calibrates_its_new_site_not_the_old_one(self) -> None:
        from sb3_pm.evaluation import evaluate
        from sb3_pm.evaluation.neglect_calibration import calibrate_neglect_bound
        from sb3_pm.graphs.territories import agent_territories

        team = tiny_team(deploy_filter=SITE_BOUND, policy_kwargs={"laplacian": "none"})
        other = path_graph(14, targets=[0, 2, 11, 13], name="longer")
        try:
            evaluate(team, team.graph, n_agents=2, episodes=1, max_cycles=20)  # settles its own graph
            moved = team.on_graph(other)
            assert moved.site_bound_pending and moved.acting_filter() is None  # not the old site's B
            result = evaluate(moved, other, n_agents=2, episodes=1, max_cycles=20)
            expected = calibrate_neglect_bound(other, 2, {}, max_cycles=20)
            assert expected.bound is not None
            assert result.config["neglect_calibration"] == expected.to_dict()
            assert result.config["neglect_bound"] == expected.bound
            territory = moved.policies["agent_1"].dcbf_config.territory
            assert territory == agent_territories(other, 2)[1] != agent_territories(team.graph, 2)[1]
        finally:
            team.close()

    def test_a_team_trained_on_a_family_takes_it_and_calibrates_where_it_is_deployed(self) -> None:
        from sb3_pm.agents.training.team import IndependentPPO
        from sb3_pm.evaluation import evaluate
        from sb3_pm.evaluation.neglect_calibration import calibrate_neglect_bound
        from sb3_pm.graphs.distributions import ErdosRenyiFamily

        team = IndependentPPO(
            ErdosRenyiFamily(n_nodes_range=(8, 14), edge_prob=(0.25, 0.4)),
            n_agents=2,
            seed=0,
            env_kwargs={"max_cycles": 20},
            hyperparams={**TINY, "policy_kwargs": {"laplacian": "none"}},
            deploy_filter=SITE_BOUND,
        )
        try:
            assert team.site_bound_pending
            with pytest.raises(InputError, match="deploy_filter scope 'territory' needs one graph"):
                team.deploy_filter = {"neglect_bound": 15, "neglect_scope": "territory"}
            team.learn(10)
            site = path_graph(12, targets=[0, 1, 10, 11])
            result = evaluate(team.on_graph(site), site, n_agents=2, episodes=1, max_cycles=20)
            expected = calibrate_neglect_bound(site, 2, {}, max_cycles=20)
            assert result.config["neglect_calibration"] == expected.to_dict()
        finally:
            team.close()

    def test_the_command_line_calibrates_a_saved_auto_team_and_says_so(self, tmp_path, capsys) -> None:
        from sb3_pm.cli import main
        from sb3_pm.evaluation.neglect_calibration import calibrate_neglect_bound
        from sb3_pm.graphs import load_graphml

        saved = saved_tiny_team(tmp_path / "t", SITE_BOUND)
        out, graph = tmp_path / "e.json", saved / "graph.graphml"
        argv = ["evaluate", "--policy", str(saved), "--graph", str(graph), "--agents", "2"]
        assert main([*argv, "--episodes", "1", "--steps", "20", "--json", str(out)]) == 0
        config = json.loads(out.read_text())["config"]
        expected = calibrate_neglect_bound(load_graphml(graph), 2, max_cycles=20)
        assert config["neglect_calibration"] == expected.to_dict()
        assert config["filter_activity"]["masks"] > 0
        err = capsys.readouterr().err
        assert "deploy_filter is auto" in err and expected.describe() in err
        assert main([*argv[:-1], "3", "--episodes", "1", "--steps", "20"]) == 2
        assert "deploy it with --agents 2, or give a number B (or off)" in capsys.readouterr().err

    def test_failures_are_left_out_of_the_calibration(self) -> None:
        from sb3_pm.evaluation import evaluate

        team = tiny_team(deploy_filter=SITE_BOUND)
        try:
            failing = evaluate(
                team,
                team.graph,
                n_agents=2,
                episodes=1,
                max_cycles=20,
                env_kwargs={"failures": {"agent_1": 5}},
            )
        finally:
            team.close()
        team = tiny_team(deploy_filter=SITE_BOUND)
        try:
            whole = evaluate(team, team.graph, n_agents=2, episodes=1, max_cycles=20)
        finally:
            team.close()
        # the bound is for the team as deployed: the same calibration with or without the failure
        assert failing.config["neglect_calibration"] == whole.config["neglect_calibration"]
        assert failing.config["env_kwargs"]["failures"] == {"agent_1": 5}

    def test_a_failed_evaluation_leaves_the_team_waiting_for_its_site(self) -> None:
        from sb3_pm.evaluation import evaluate
        from sb3_pm.evaluation.neglect_calibration import calibrate_neglect_bound

        team = tiny_team(deploy_filter=SITE_BOUND)
        other = path_graph(14, targets=[0, 2, 11, 13], name="longer")
        try:
            with pytest.raises(InputError, match="graph"):  # not the team's graph: refused at reset
                evaluate(team, other, n_agents=2, episodes=1, max_cycles=20)
            assert team.site_bound_pending and team.acting_filter() is None  # not the other's bound
            result = evaluate(team, team.graph, n_agents=2, episodes=1, max_cycles=20)
            expected = calibrate_neglect_bound(team.graph, 2, {}, max_cycles=20)
            assert result.config["neglect_calibration"] == expected.to_dict()
        finally:
            team.close()

    def test_acting_without_a_calibrated_site_warns_once(self) -> None:
        from sb3_pm.envs import persistent_monitoring_v0

        team = tiny_team(deploy_filter=SITE_BOUND)
        env = persistent_monitoring_v0.parallel_env(graph=team.graph, n_agents=2, max_cycles=20)
        try:
            with pytest.warns(UserWarning, match="no neglect bound has been calibrated for this graph"):
                team.reset(env, seed=0)
            team.set_filter(neglect_bound=None)  # settled by the user: no bound, said
            import warnings

            with warnings.catch_warnings():
                warnings.simplefilter("error")
                team.reset(env, seed=1)
        finally:
            env.close()
            team.close()

    def test_an_explicit_bound_on_the_command_line_is_a_territory_bound(self, tmp_path) -> None:
        from sb3_pm.cli import main

        saved = saved_tiny_team(tmp_path / "t", SITE_BOUND)
        out = tmp_path / "e.json"
        argv = ["evaluate", "--policy", str(saved), "--graph", str(saved / "graph.graphml")]
        assert main([*argv, "--agents", "2", "--episodes", "1", "--steps", "20", "--neglect-bound", "12",
                     "--json", str(out)]) == 0  # fmt: skip
        config = json.loads(out.read_text())["config"]
        assert (config["neglect_bound"], config["neglect_scope"]) == (12.0, "territory")
        assert "neglect_calibration" not in config

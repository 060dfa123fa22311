"""A team's deployment rule: the config's ``deploy_temperature``, saved with the team, decides how
``predict``, ``evaluate`` and ``sb3-pm evaluate`` act unless the caller says otherwise."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch as th
import yaml

from sb3_pm.agents.training.team import IndependentPPO
from sb3_pm.evaluation import evaluate
from sb3_pm.experiments.spec import ExperimentError, load_experiment
from sb3_pm.graphs import erdos_renyi
from sb3_pm.graphs.io import save_graphml
from sb3_pm.zoo.config import ConfigError, load_config
from tests.paths import every_experiment_file, experiment_file
from tests.test_sampling_temperature import ENV, GRAPH, spread_logits
from tests.test_sampling_temperature import TINY as SAMPLING_TINY

# test_sampling_temperature's tiny team (the actor chooses on every step), made transferable.
TINY = {**SAMPLING_TINY, "policy_kwargs": {**SAMPLING_TINY["policy_kwargs"], "laplacian": "none"}}


def make_team(deploy_temperature: float | None) -> IndependentPPO:
    """An untrained transferable team whose output layers are redrawn so its logits are far apart
    (an untrained actor's lie within ~1e-4, where sampling at any temperature looks uniform)."""
    team = IndependentPPO(
        GRAPH, n_agents=2, seed=0, env_kwargs=ENV, hyperparams=TINY, deploy_temperature=deploy_temperature
    )
    return spread_logits(team, 3.0)


def traces(team: object, deterministic: bool | None = None, graph: object = GRAPH) -> list[list[float]]:
    result = evaluate(team, graph, n_agents=2, episodes=2, seed=5, max_cycles=30, deterministic=deterministic)  # type: ignore[arg-type]
    return [record.trace.tolist() for record in result.episodes]


def test_a_team_with_a_deploy_temperature_samples_at_it_unless_told_otherwise() -> None:
    team = make_team(0.5)
    assert {m.policy.sampling_temperature for m in team.models.values()} == {0.5}
    by_rule = evaluate(team, GRAPH, n_agents=2, episodes=2, seed=5, max_cycles=30)
    assert by_rule.config["deterministic"] is False and by_rule.config["temperature"] == 0.5
    assert traces(team) == traces(team, deterministic=False)  # seeded: the same draws again
    greedy = traces(team, deterministic=True)
    assert traces(team) != greedy
    # The same parameters without the rule act by the argmax by default, and sample at 0.5 when set.
    plain = make_team(None)
    assert traces(plain) == greedy
    plain.set_sampling_temperature(0.5)
    assert traces(plain) == greedy and traces(plain, deterministic=False) == traces(team)


def test_the_rule_is_saved_with_the_team_and_follows_it_to_another_graph(tmp_path: Path) -> None:
    team = make_team(0.5)
    sampled = traces(team)
    team.save(tmp_path / "team")
    assert json.loads((tmp_path / "team" / "manifest.json").read_text())["deploy_temperature"] == 0.5
    loaded = IndependentPPO.load(tmp_path / "team")
    assert loaded.deploy_temperature == 0.5 and traces(loaded) == sampled
    other = erdos_renyi(16, 0.3, n_targets=4, seed=2)
    moved = loaded.on_graph(other)
    assert moved.deploy_temperature == 0.5
    assert traces(moved, graph=other) == traces(moved, deterministic=False, graph=other)
    assert traces(moved, graph=other) != traces(moved, deterministic=True, graph=other)
    # Switching the rule off restores the argmax and the trained distribution for sampling.
    loaded.deploy_temperature = None
    assert traces(loaded) == traces(loaded, deterministic=True)
    assert {m.policy.sampling_temperature for m in loaded.models.values()} == {1.0}


def test_a_manifest_without_the_field_loads_as_the_argmax(tmp_path: Path) -> None:
    team = make_team(None)
    team.save(tmp_path / "team")
    manifest = tmp_path / "team" / "manifest.json"
    data = json.loads(manifest.read_text())
    del data["deploy_temperature"]  # a team saved before the rule existed
    manifest.write_text(json.dumps(data))
    loaded = IndependentPPO.load(tmp_path / "team")
    assert loaded.deploy_temperature is None
    assert traces(loaded) == traces(team, deterministic=True)


@pytest.mark.parametrize("bad", [0, -1.0, math.inf, "hot", True])
def test_a_bad_deploy_temperature_is_refused_in_a_config_a_team_and_an_experiment(
    tmp_path: Path, bad: object
) -> None:
    config = tmp_path / "team.yml"
    config.write_text(yaml.safe_dump({"default": {"algo": "dcbf_ppo", "deploy_temperature": bad}}))
    with pytest.raises(ConfigError, match=r"default\.deploy_temperature: the sampling temperature must be"):
        load_config(config, "paper-50")
    with pytest.raises(ValueError, match="the sampling temperature must be"):
        IndependentPPO(GRAPH, n_agents=2, env_kwargs=ENV, hyperparams=TINY, deploy_temperature=bad)  # type: ignore[arg-type]
    experiment = tmp_path / "exp.yml"
    experiment.write_text(
        yaml.safe_dump(
            {
                "name": "x",
                "graphs": ["karate"],
                "seeds": [0],
                "config": str(config),
                "variants": {"learned": {"hyperparams": {"deploy_temperature": bad}}},
            }
        )
    )
    with pytest.raises(ExperimentError, match=r"variant 'learned': hyperparams\.deploy_temperature"):
        load_experiment(experiment)


def test_a_config_sets_it_and_a_run_folder_records_it() -> None:
    config = load_config("ippo_transfer", "paper-50")
    assert config.deploy_temperature == 0.25 and config.to_dict()["deploy_temperature"] == 0.25
    assert "deploy_temperature" not in load_config("ippo", "paper-100").to_dict()
    # the default on paper-50 samples; the families that merge its entry pin the most likely action
    assert load_config("ippo", "paper-50").to_dict()["deploy_temperature"] == 0.25
    for family in ("rgg-60", "rooms-4", "cliques-6x8"):
        assert load_config("ippo", family).deploy_temperature is None, family
    assert load_config("ippo_transfer", "paper-50", {"deploy_temperature": None}).deploy_temperature is None


def test_an_experiment_variant_pins_it_without_training_differently() -> None:
    from sb3_pm.experiments.runner import cell_config, plan_cells

    experiment = load_experiment(experiment_file("transfer_known_map"))
    variant = next(v for v in experiment.variants if v.key == "known_map")
    learned = next(c for c in plan_cells(experiment, Path("unused")) if c.variant["key"] == "known_map")
    config = cell_config(learned, variant)
    assert config.deploy_temperature is None  # pinned: the file measured the most likely actions
    assert "deploy_temperature" not in config.hyperparams  # a team key, never the algorithm's


def test_the_command_line_follows_the_rule_and_overrides_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from sb3_pm.cli import main

    make_team(0.5).save(tmp_path / "team")
    graph_file = save_graphml(GRAPH, tmp_path / "g.graphml")
    base = ["evaluate", "--policy", str(tmp_path / "team"), "--graph", str(graph_file), "--agents", "2"]
    base += ["--steps", "30", "--episodes", "2", "--seed", "5"]

    def run(*extra: str) -> dict:
        out = tmp_path / "out.json"
        out.unlink(missing_ok=True)
        assert main([*base, *extra, "--json", str(out)]) == 0
        return json.loads(out.read_text())  # type: ignore[no-any-return]

    by_rule = run()
    assert "samples its actions at its deploy_temperature 0.5" in capsys.readouterr().err
    assert by_rule["config"]["deterministic"] is False and by_rule["config"]["temperature"] == 0.5
    team = make_team(0.5)
    assert by_rule["mean"]["avg_uncertainty"] == pytest.approx(
        evaluate(team, GRAPH, n_agents=2, episodes=2, seed=5, max_cycles=30).mean["avg_uncertainty"], abs=0
    )
    argmax = run("--deterministic")
    assert argmax["config"]["deterministic"] is True
    assert (
        argmax["mean"]
        == evaluate(team, GRAPH, n_agents=2, episodes=2, seed=5, max_cycles=30, deterministic=True).mean
    )
    stochastic = run("--stochastic")  # the trained distribution, not the team's own 0.5
    team.set_sampling_temperature(1.0)
    assert (
        stochastic["mean"]
        == evaluate(team, GRAPH, n_agents=2, episodes=2, seed=5, max_cycles=30, deterministic=False).mean
    )
    assert stochastic["mean"] != by_rule["mean"]
    with pytest.raises(SystemExit) as exit_info:  # argparse: one way of acting at a time
        main([*base, "--deterministic", "--temperature", "0.5"])
    assert exit_info.value.code == 2
    assert "not allowed with argument" in capsys.readouterr().err


def test_a_centralized_team_keeps_its_rule_too(tmp_path: Path) -> None:
    from sb3_pm.sharing.centralized import CentralizedPPO

    team = CentralizedPPO(GRAPH, n_agents=2, env_kwargs=ENV, hyperparams=TINY, deploy_temperature=0.5)
    assert team.model.policy.sampling_temperature == 0.5
    assert not team.acts_deterministically(None) and team.acts_deterministically(True)
    team.save(tmp_path / "shared")
    loaded = CentralizedPPO.load(tmp_path / "shared")
    assert loaded.deploy_temperature == 0.5 and loaded.model.policy.sampling_temperature == 0.5
    team.close()
    loaded.close()


def test_predict_without_deterministic_follows_the_rule() -> None:
    from sb3_pm.envs import persistent_monitoring_v0

    env = persistent_monitoring_v0.parallel_env(graph=GRAPH, n_agents=2, **ENV)
    observations, _ = env.reset(seed=3)
    env.close()

    def draws(team: IndependentPPO, deterministic: bool | None) -> list[dict[str, int]]:
        th.manual_seed(11)
        if deterministic is None:
            return [team.predict_dict(observations) for _ in range(20)]
        return [team.predict_dict(observations, deterministic) for _ in range(20)]

    sampling, plain = make_team(0.5), make_team(None)
    assert draws(sampling, None) == draws(sampling, False)
    assert len({str(d) for d in draws(sampling, None)}) > 1  # it does sample
    assert draws(plain, None) == draws(plain, True) == draws(sampling, True)
    assert len({str(d) for d in draws(plain, None)}) == 1
    th.manual_seed(11)  # SB3's shape, deterministic=None by default: the same rule
    assert [sampling.predict(observations)[0] for _ in range(20)] == draws(sampling, None)


def test_a_moved_team_samples_at_the_rule_on_its_rebuilt_policies() -> None:
    other = erdos_renyi(16, 0.3, n_targets=4, seed=2)
    moved = make_team(0.5).on_graph(other)
    assert {p.sampling_temperature for p in moved.policies.values()} == {0.5}  # type: ignore[attr-defined]
    moved.deploy_temperature = None  # type: ignore[misc]
    assert {p.sampling_temperature for p in moved.policies.values()} == {1.0}  # type: ignore[attr-defined]
    assert traces(moved, graph=other) == traces(moved, deterministic=True, graph=other)


def test_training_never_reads_the_rule() -> None:
    teams = [
        IndependentPPO(GRAPH, n_agents=2, seed=4, env_kwargs=ENV, hyperparams=TINY, deploy_temperature=t)
        for t in (None, 0.5)
    ]
    for team in teams:
        team.learn(60)
    for agent in teams[0].agents:
        first, second = (team.models[agent].policy.state_dict() for team in teams)
        assert all(th.equal(first[key], second[key]) for key in first)
    for team in teams:
        team.close()


def test_a_rule_for_learners_without_the_dcbf_policy_is_refused_and_leaves_the_team_as_it_was() -> None:
    team = IndependentPPO(GRAPH, n_agents=2, env_kwargs=ENV, algo="maskable_ppo", hyperparams={"n_steps": 30})
    with pytest.raises(ValueError, match="no DCBF policy"):
        team.deploy_temperature = 0.5
    assert team.deploy_temperature is None and team.manifest()["deploy_temperature"] is None
    team.close()
    with pytest.raises(ValueError, match="no DCBF policy"):
        IndependentPPO(GRAPH, n_agents=2, env_kwargs=ENV, algo="maskable_ppo", deploy_temperature=0.5)


def test_every_shipped_experiment_declares_how_its_learned_variants_act() -> None:
    """Only the headline's default (zoo/ippo.yml's paper-50 entry), known_map_family,
    transfer_territory's and transfer_advice's variants, the regimes' transfer rows and held_out's
    planned transfer team (zoo/ippo_transfer.yml's own rule) sample; the other transfer files pin
    the argmax their tables measured.
    Removing a pin (or a config gaining a rule) shows here, and in the record a folder resumes by."""
    from sb3_pm.experiments.record import experiment_record, team_rules

    rules = {
        path.stem: team_rules(load_experiment(path)).get("deploy_temperature", {})
        for path in every_experiment_file()
    }
    assert {name: rule for name, rule in rules.items() if rule} == {
        "headline": {"default": 0.25},
        "transfer_known_map": {"known_map_family": 0.25},
        "transfer_territory": {"known_map_territory": 0.25, "known_map_territory_family": 0.25},
        "transfer_advice": {"advice_prior": 0.25, "advice_prior_family": 0.25, "advice": 0.25},
        "regime_100": {"transfer": 0.25, "transfer_advice": 0.25, "transfer_family": 0.25},
        "regime_200": {"transfer": 0.25, "transfer_advice": 0.25, "transfer_family": 0.25},
        "held_out": {
            "transfer_planned": 0.25,
            "transfer_planned_prior4": 0.25,
            "transfer_planned_prior8": 0.25,
            "transfer_planned_prior4_no_rule6": 0.25,
            "transfer_planned_tours_prior4": 0.25,
            "transfer_planned_prior4_imitation": 0.25,
        },
    }
    assert experiment_record(load_experiment(experiment_file("transfer_known_map")))[
        "deploy_temperature"
    ] == {"known_map_family": 0.25}
    assert "deploy_temperature" not in experiment_record(load_experiment("comparison"))


def test_the_runner_evaluates_by_the_experiment_files_rule_and_refuses_a_changed_one(tmp_path: Path) -> None:
    from sb3_pm.cli import main

    config = tmp_path / "team.yml"
    team_entry = {
        "algo": "dcbf_ppo",
        "n_envs": 1,
        "n_steps": 20,
        "batch_size": 20,
        "n_epochs": 1,
        "deploy_temperature": 0.5,
        "policy_kwargs": {"dcbf_barrier": False, "freeze_steps": 0},
    }
    config.write_text(yaml.safe_dump({"default": team_entry}))
    experiment = {
        "name": "rule",
        "graphs": ["karate"],
        "seeds": [0],
        "episodes": 1,
        "max_cycles": 20,
        "n_agents": 2,
        "config": str(config),
        "timesteps": 20,
        "variants": {"by_config": {}, "pinned": {"hyperparams": {"deploy_temperature": None}}},
    }
    path = tmp_path / "rule.yml"
    path.write_text(yaml.safe_dump(experiment))
    out = tmp_path / "out"
    args = ["reproduce", str(path), "--out", str(out), "--jobs", "1", "--no-progress"]
    assert main(args) == 0
    cells = out / "cells"
    by_config = json.loads((cells / "by_config" / "karate" / "seed0" / "evaluation.json").read_text())
    pinned = json.loads((cells / "pinned" / "karate" / "seed0" / "evaluation.json").read_text())
    assert (by_config["config"]["deterministic"], by_config["config"]["temperature"]) == (False, 0.5)
    assert pinned["config"]["deterministic"] is True and "temperature" not in pinned["config"]
    # A team already in a cell (trained by an earlier run, or copied in) acts by the file's rule, not
    # by its manifest's: give the pinned cell's team a sampling rule and evaluate the cell again.
    pinned_cell = cells / "pinned" / "karate" / "seed0"
    manifest = pinned_cell / "team" / "manifest.json"
    manifest.write_text(json.dumps({**json.loads(manifest.read_text()), "deploy_temperature": 0.5}))
    (pinned_cell / "DONE").unlink()
    (pinned_cell / "evaluation.json").unlink()
    assert main(args) == 0
    again = json.loads((pinned_cell / "evaluation.json").read_text())
    assert again["config"]["deterministic"] is True and again["episodes"] == pinned["episodes"]
    # The rule is part of the record: a resumed folder cannot mix the two ways of acting.
    config.write_text(yaml.safe_dump({"default": {**team_entry, "deploy_temperature": 0.7}}))
    assert main(args) != 0


def test_the_train_command_can_switch_the_rule_off() -> None:
    from sb3_pm.commands.train import parse_overrides
    from sb3_pm.errors import UsageError

    overrides = parse_overrides(["deploy_temperature:null"], "--hyperparams")
    assert overrides == {"deploy_temperature": None}
    assert load_config("ippo_transfer", "paper-50", overrides).deploy_temperature is None
    for slip in ("deploy_temperature:", "n_steps:null"):
        with pytest.raises(UsageError, match="has no value"):
            parse_overrides([slip], "--hyperparams")


def test_compare_follows_each_teams_rule_unless_told_to_take_the_most_likely_actions() -> None:
    from sb3_pm.evaluation import compare

    teams = {"sampling": lambda graph: make_team(0.5), "plain": lambda graph: make_team(None)}
    by_rule = compare(teams, [GRAPH], seeds=[0], episodes=1, n_agents=2, max_cycles=30)
    assert [run.config["deterministic"] for run in by_rule.results["sampling"]] == [False]
    assert [run.config["deterministic"] for run in by_rule.results["plain"]] == [True]
    argmax = compare(teams, [GRAPH], seeds=[0], episodes=1, n_agents=2, max_cycles=30, deterministic=True)
    assert argmax.config["deterministic"] is True
    assert argmax.results["sampling"][0].mean == argmax.results["plain"][0].mean  # same parameters
    assert by_rule.results["sampling"][0].mean != argmax.results["sampling"][0].mean


def test_the_compare_command_passes_deterministic_on(tmp_path: Path) -> None:
    from sb3_pm.cli import main

    make_team(0.5).save(tmp_path / "team")
    graph_file = save_graphml(GRAPH, tmp_path / "g.graphml")
    base = ["compare", "--policies", str(tmp_path / "team"), "--graphs", str(graph_file), "--agents", "2"]
    base += ["--steps", "30", "--episodes", "1", "--no-progress"]
    assert main([*base, "--out", str(tmp_path / "rule")]) == 0
    assert main([*base, "--deterministic", "--out", str(tmp_path / "argmax")]) == 0
    rule, argmax = (json.loads((tmp_path / name / "results.json").read_text()) for name in ("rule", "argmax"))
    assert "deterministic" not in rule["config"] and argmax["config"]["deterministic"] is True
    assert rule["results"] != argmax["results"]

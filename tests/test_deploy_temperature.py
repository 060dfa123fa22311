"""A team's deployment rule: the config's ``deploy_temperature``, saved with the team, decides how
``predict``, ``evaluate`` and ``sb3-pm evaluate`` act unless the caller says otherwise."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch as th
import yaml

from sb3_pm.agents.team import IndependentPPO
from sb3_pm.evaluation import evaluate
from sb3_pm.experiments.spec import ExperimentError, load_experiment
from sb3_pm.graphs import erdos_renyi
from sb3_pm.graphs.io import save_graphml
from sb3_pm.zoo.config import ConfigError, load_config

GRAPH = erdos_renyi(12, 0.4, n_targets=3, seed=1)
ENV = {"max_cycles": 30}
# No barrier and no freeze, so the actor chooses on every step (as in test_sampling_temperature).
TINY = {
    "n_steps": 30,
    "batch_size": 30,
    "n_epochs": 1,
    "policy_kwargs": {"dcbf_barrier": False, "freeze_steps": 0, "laplacian": "none"},
}


def make_team(deploy_temperature: float | None) -> IndependentPPO:
    """An untrained transferable team whose output layers are redrawn so its logits are far apart
    (an untrained actor's lie within ~1e-4, where sampling at any temperature looks uniform)."""
    team = IndependentPPO(
        GRAPH, n_agents=2, seed=0, env_kwargs=ENV, hyperparams=TINY, deploy_temperature=deploy_temperature
    )
    generator = th.Generator().manual_seed(0)
    with th.no_grad():
        for model in team.models.values():
            weight = model.policy.action_net.weight
            weight.copy_(th.randn(weight.shape, generator=generator) * 3.0)
    return team


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
    assert "deploy_temperature" not in load_config("ippo", "paper-50").to_dict()
    assert load_config("ippo_transfer", "paper-50", {"deploy_temperature": None}).deploy_temperature is None


def test_an_experiment_variant_pins_it_without_training_differently() -> None:
    from sb3_pm.experiments.runner import cell_config, plan_cells

    experiment = load_experiment("transfer_known_map")
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

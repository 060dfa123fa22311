"""The teams that ship with the package load safely and act legally, with no training."""

from __future__ import annotations

import json

import pytest

from sb3_pm.cli import main
from sb3_pm.errors import InputError
from sb3_pm.evaluation import resolve_team
from sb3_pm.pretrained import pretrained_names, pretrained_path, provenance


def test_every_pretrained_team_says_how_it_was_made() -> None:
    assert {"paper-50", "transfer", "transfer_prior4", "transfer_split"} <= set(pretrained_names())
    for name in pretrained_names():
        record = provenance(name)
        assert record["seed"] == 0 and "sb3-pm train" in record["command"] and "commit" in record["code"]


def test_the_pretrained_default_deploys_as_the_default_config_says() -> None:
    """The shipped paper-50 team acts under the deploy filter of the entry it was trained from."""
    from sb3_pm.zoo.config import load_config

    manifest = json.loads((pretrained_path("paper-50") / "manifest.json").read_text())
    assert manifest["deploy_filter"] == load_config("ippo", "paper-50").deploy_filter
    team = resolve_team("pretrained:paper-50")
    assert team.deploy_filter == manifest["deploy_filter"]
    assert team.acting_record(True) == {**manifest["deploy_filter"]}
    assert manifest["deploy_temperature"] == load_config("ippo", "paper-50").deploy_temperature
    assert team.deploy_temperature == manifest["deploy_temperature"]


def test_the_pretrained_default_leaves_the_loop_that_its_most_likely_actions_fall_into() -> None:
    """On env seed 13 the shipped team's most likely actions send two agents back and forth
    together for 48 steps, and the two targets left behind never come back down (each step an
    agent is off a target adds to the total for good). Its deployment temperature breaks the loop."""
    from sb3_pm.baselines import make_team
    from sb3_pm.evaluation import evaluate

    team = resolve_team("pretrained:paper-50")
    sampled = evaluate(team, episodes=1, seed=13).episodes[0].metrics
    argmax = evaluate(team, episodes=1, seed=13, deterministic=True).episodes[0].metrics
    rule = evaluate(make_team("planned_patrol"), "paper-50", episodes=1, seed=13).episodes[0].metrics
    assert argmax["avg_uncertainty"] > 2 * rule["avg_uncertainty"] and argmax["collisions"] > 0
    assert sampled["avg_uncertainty"] <= 1.05 * rule["avg_uncertainty"] and sampled["collisions"] == 0


def test_the_pretrained_team_acts_legally() -> None:
    team = resolve_team("pretrained:paper-50")
    assert team.learned and team.n_agents == 4
    env = team.make_env()
    observations, _ = env.reset(seed=3)
    team.reset(env, seed=3)
    for _ in range(60):
        actions = team.predict_dict(observations, deterministic=True)
        for agent, node in actions.items():
            assert observations[agent]["action_mask"][node] == 1
        observations, *_ = env.step(actions)


def test_the_command_line_evaluates_it_with_a_gif(tmp_path, capsys) -> None:
    code = main(
        [
            "evaluate",
            "--policy",
            "pretrained:paper-50",
            "--episodes",
            "1",
            "--steps",
            "30",
            "--json",
            str(tmp_path / "r.json"),
            "--gif",
            str(tmp_path / "r.gif"),
        ]
    )
    assert code == 0 and (tmp_path / "r.gif").stat().st_size > 0
    assert json.loads((tmp_path / "r.json").read_text())["episodes"][0]["steps"] == 30


def test_the_transfer_team_acts_legally_on_a_graph_it_never_saw() -> None:
    from sb3_pm.baselines.rule_neglect import rule_worst_neglect, site_deadline

    team = resolve_team("pretrained:transfer", graph="karate")
    assert team.acting_record(True) == {"pass_held": True, "keep_moving": True}  # its deploy_filter
    env = team.make_env("karate")
    observations, _ = env.reset(seed=4)
    team.reset(env, seed=4)
    # rule 12's deadline, taken from the territory rule on karate at the reset (the split's or the
    # planned groups', whichever is lower)
    expected = site_deadline("karate", 4, team.env_settings(), env.unwrapped.max_cycles)
    split = rule_worst_neglect("karate", 4, team.env_settings(), env.unwrapped.max_cycles)
    assert expected is not None and expected < split  # the planned groups' figure, lower on karate
    assert team.acting_record(True) == {"pass_held": True, "keep_moving": True, "visit_deadline": expected}
    for _ in range(40):
        actions = team.predict_dict(observations)
        assert all(observations[agent]["action_mask"][node] == 1 for agent, node in actions.items())
        observations, *_ = env.step(actions)


def test_an_unknown_pretrained_team_is_one_line() -> None:
    names = "paper-50, transfer, transfer_prior4, transfer_split"
    with pytest.raises(InputError, match=f"no pretrained team 'nope': use one of {names}"):
        pretrained_path("pretrained:nope")

"""The rl-zoo style config loader, registries and schedules."""

from __future__ import annotations

import pathlib
import textwrap

import pytest
import torch as th
import yaml
from stable_baselines3.common.utils import LinearSchedule

from sb3_pm.agents.training.team import IndependentPPO
from sb3_pm.graphs import erdos_renyi
from sb3_pm.zoo import ConfigError, load_config, parse_schedule, resolve_algo, resolve_policy_kwargs
from sb3_pm.zoo.registry import RegistryError

th.set_num_threads(1)

CONFIG = """
default: &default
  n_timesteps: 5e4
  n_envs: 2
  n_agents: 2
  algo: maskable_ppo
  n_steps: 16
  batch_size: 32
  n_epochs: 1
  learning_rate: lin_3e-4
  gamma: 0.98
  ent_coef: 1e-3
  policy_kwargs:
    net_arch: [16]
    activation_fn: ReLU
  env_kwargs: {max_cycles: 20}
  agents:
    agent_1: {learning_rate: 1e-4}
paper-50:
  <<: *default
  n_timesteps: 50000
  n_envs: 4
"""


def write(tmp_path, text: str):
    path = tmp_path / "cfg.yml"
    path.write_text(textwrap.dedent(text))
    return path


def test_default_fallback_and_own_entry(tmp_path) -> None:
    path = write(tmp_path, CONFIG)
    own = load_config(path, "paper-50")
    assert own.entry == "paper-50" and own.n_envs == 4 and own.n_timesteps == 50000
    fallback = load_config(path, "paper-200")
    assert fallback.entry == "default" and fallback.n_envs == 2
    assert fallback.n_timesteps == 50000  # "5e4" (a string to PyYAML) is read as a number
    assert load_config(path, "some/dir/paper-50.graphml").entry == "paper-50"  # by file stem
    assert fallback.hyperparams["ent_coef"] == pytest.approx(1e-3)
    assert fallback.agents == {"agent_1": {"learning_rate": 1e-4}}
    assert fallback.to_dict()["learning_rate"] == "lin_3e-4"


def test_no_entry_and_no_default(tmp_path) -> None:
    path = write(tmp_path, "paper-50: {n_envs: 1}\n")
    with pytest.raises(ConfigError, match="no entry for 'paper-100' and no 'default'"):
        load_config(path, "paper-100")


def test_lin_schedule() -> None:
    schedule = parse_schedule("lin_3e-4")
    assert isinstance(schedule, LinearSchedule)
    assert (
        schedule(1.0) == pytest.approx(3e-4) and schedule(0.5) == pytest.approx(1.5e-4) and schedule(0.0) == 0
    )
    assert parse_schedule("1e-4") == pytest.approx(1e-4)
    assert parse_schedule(0.2) == 0.2
    with pytest.raises(ValueError, match="lin_<number>"):
        parse_schedule("lin_fast", "learning_rate")


def test_config_builds_team_with_overrides(tmp_path) -> None:
    config = load_config(write(tmp_path, CONFIG), "tiny")
    team = IndependentPPO.from_config(config, erdos_renyi(12, 0.3, n_targets=3, seed=1), seed=0)
    first, second = team.models["agent_0"], team.models["agent_1"]
    assert first.lr_schedule(1.0) == pytest.approx(3e-4) and first.lr_schedule(0.5) == pytest.approx(1.5e-4)
    assert second.lr_schedule(1.0) == pytest.approx(1e-4)
    assert first.gamma == pytest.approx(0.98)
    assert isinstance(first.policy.mlp_extractor.policy_net[1], th.nn.ReLU)
    assert team.n_envs == 2 and first.n_steps == 16


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("default: {n_steps: [1, 2\n", "malformed YAML"),
        ("- a\n- b\n", "expected a mapping of entries"),
        ("default: 3\n", "entry 'default' must be a mapping"),
        ("default: {algo: maskable_ppo, learnin_rate: 0.1}\n", "default: unknown key 'learnin_rate'"),
        ("default: {algo: maskable_ppo, n_steps: many}\n", r"default.n_steps: expected an integer"),
        ("default: {algo: maskable_ppo, gamma: high}\n", r"default.gamma: expected a number"),
        ("default: {algo: maskable_ppo, normalize_advantage: 3}\n", "expected true/false"),
        ("default: {algo: maskable_ppo, learning_rate: lin_x}\n", "lin_<number>"),
        ("default: {algo: maskable_ppo, policy_kwargs: 'dict(net_arch=[8])'}\n", "not a string to eval"),
        (
            "default: {algo: maskable_ppo, policy_kwargs: {activation_fn: Relu}}\n",
            "unknown activation_fn 'Relu'",
        ),
        (
            "default: {algo: maskable_ppo, env_kwargs: {max_cycle: 5}}\n",
            "env_kwargs: unknown key 'max_cycle'",
        ),
        ("default: {algo: nope}\n", "default.algo: unknown algo 'nope'"),
        ("default: {algo: maskable_ppo, n_envs: 0}\n", r"default.n_envs: expected an integer >= 1"),
        ("default: {algo: maskable_ppo, agents: {agent_7: {gamma: 0.9}}}\n", "unknown agent 'agent_7'"),
        (
            "default: {algo: maskable_ppo, agents: {agent_1: {n_envs: 2}}}\n",
            "'n_envs' is set for the whole team",
        ),
        (
            "default: {algo: maskable_ppo, learning_rate_spread: 0}\n",
            r"default.learning_rate_spread: expected a number >= 1",
        ),
        (
            "default: {algo: maskable_ppo, learning_rate: 0.001, learning_rate_spread: 0.5}\n",
            r"default.learning_rate_spread: expected a number >= 1",
        ),
        (
            "default: {algo: maskable_ppo, learning_rate_spread: wide}\n",
            r"default.learning_rate_spread: expected a number >= 1",
        ),
        (
            "default: {algo: maskable_ppo, learning_rate_spread: 2}\n",
            "learning_rate_spread needs the entry's learning_rate",
        ),
        (
            "default: {algo: maskable_ppo, agents: {agent_1: {learning_rate_spread: 2}}}\n",
            "'learning_rate_spread' is set for the whole team",
        ),
    ],
)
def test_malformed_configs_name_file_and_key(tmp_path, text: str, message: str) -> None:
    path = write(tmp_path, text)
    with pytest.raises(ConfigError, match=message) as info:
        load_config(path, "paper-50")
    assert str(path) in str(info.value)


def test_missing_file(tmp_path) -> None:
    with pytest.raises(FileNotFoundError, match="config file not found"):
        load_config(tmp_path / "nope.yml", "paper-50")


def test_registries() -> None:
    from sb3_contrib import MaskablePPO

    assert resolve_algo("maskable_ppo") is MaskablePPO
    with pytest.raises(RegistryError, match="unknown algo"):
        resolve_algo("dqn")
    resolved = resolve_policy_kwargs({"activation_fn": "Tanh", "optimizer_class": "AdamW", "net_arch": [8]})
    assert resolved["activation_fn"] is th.nn.Tanh and resolved["optimizer_class"] is th.optim.AdamW
    assert resolved["net_arch"] == [8]


def test_a_config_never_imports_a_module_it_names(
    tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A class key naming ``module:attr`` is refused in one line, and the module is not imported."""
    import sys

    module = tmp_path / "planted_module.py"
    marker = tmp_path / "imported"
    module.write_text(f"import pathlib\npathlib.Path({str(marker)!r}).touch()\nclass Act: pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    for key in ("activation_fn", "optimizer_class", "features_extractor_class"):
        refused = f"unknown {key} 'planted_module:Act'.*does not import"
        with pytest.raises(RegistryError, match=refused) as error:
            resolve_policy_kwargs({key: "planted_module:Act"})
        assert "\n" not in str(error.value)
    assert not marker.exists() and "planted_module" not in sys.modules


def test_register_class_names_a_class_of_ones_own() -> None:
    from sb3_pm.zoo import registry

    class Softsign(th.nn.Softsign):
        pass

    try:
        registry.register_class("activation_fn", "MySoftsign", Softsign)
        assert resolve_policy_kwargs({"activation_fn": "MySoftsign"})["activation_fn"] is Softsign
        with pytest.raises(RegistryError, match="already names another class"):
            registry.register_class("activation_fn", "Tanh", Softsign)
        with pytest.raises(RegistryError, match="not a class-valued key"):
            registry.register_class("net_arch", "x", Softsign)
    finally:
        registry.ACTIVATIONS.pop("MySoftsign", None)


def test_repository_config_is_valid() -> None:
    from pathlib import Path

    for name in ("ippo.yml", "ippo_split.yml"):
        path = Path(__file__).resolve().parents[1] / "zoo" / name
        for env in ("paper-50", "paper-100", "paper-200", "custom.graphml"):
            config = load_config(path, env)
            assert config.n_agents == 4
        assert load_config(path, "paper-50").n_timesteps == 50_000


#: What paper-50's default adds to the default before it (zoo/ippo_split.yml): territories planned
#: per episode, the targets known, each agent told its territory and the rule's move, a prior of 2.
PLANNED_ENV = {
    "target_knowledge": "known",
    "territory_input": True,
    "advice_input": True,
    "territories": "planned",
}
PLANNED_POLICY = {"advice_prior": 2.0}


#: paper-50's deploy filter: the neglect bound and rule 9 (the families' planned entries deploy
#: without one, but rgg-60's rule 12).
PAPER_50_BOUND = {"neglect_bound": 50.0, "neglect_scope": "territory", "leave_cleared": True}
RGG_60_DEADLINE = {"neglect_bound": None, "neglect_scope": "known", "visit_deadline": "auto"}


@pytest.mark.parametrize(
    ("graph", "deploy_filter"),
    [
        ("paper-50", PAPER_50_BOUND),
        ("paper_50n_8t", PAPER_50_BOUND),
        ("rgg-60", RGG_60_DEADLINE),
        ("rooms-4", None),
    ],
)
def test_a_planned_default_is_the_split_default_with_planned_territories(graph: str, deploy_filter) -> None:
    default, split = load_config("ippo", graph).team_kwargs(), load_config("ippo_split", graph).team_kwargs()
    assert default["env_kwargs"] == {**split["env_kwargs"], **PLANNED_ENV}
    assert PLANNED_ENV.keys().isdisjoint(split["env_kwargs"])
    policy = default["hyperparams"].pop("policy_kwargs")
    split_policy = split["hyperparams"].pop("policy_kwargs")
    assert policy == {**split_policy, **PLANNED_POLICY} and "advice_prior" not in split_policy
    default.pop("env_kwargs"), split.pop("env_kwargs")
    assert default.pop("deploy_filter") == deploy_filter
    # the split default's filter: the same neglect bound, without rules 9 and 12
    extra = ("leave_cleared", "visit_deadline")
    bound = {key: value for key, value in (deploy_filter or {}).items() if key not in extra}
    bound_only = bound if bound.get("neglect_bound") is not None else {}
    assert split.pop("deploy_filter") == (bound_only or None)
    # paper-50's planned default samples at a temperature; the split default and the families act
    # by their most likely actions
    assert split.pop("deploy_temperature") is None
    assert default.pop("deploy_temperature") == (0.25 if graph in ("paper-50", "paper_50n_8t") else None)
    assert default == split  # the rest


#: The entries of zoo/ippo.yml that play planned territories; every other is zoo/ippo_split.yml's.
PLANNED_ENTRIES = {"paper-50", "paper_50n_8t", "rgg-60", "rooms-4", "cliques-6x8"}


def test_the_split_default_differs_from_the_default_on_the_planned_entries_alone() -> None:
    from sb3_pm.zoo.config import read_yaml

    zoo = pathlib.Path(__file__).resolve().parents[1] / "zoo"
    entries = set(read_yaml(zoo / "ippo.yml")) | set(read_yaml(zoo / "ippo_split.yml"))
    for entry in sorted(entries - PLANNED_ENTRIES) + ["custom.graphml", "karate"]:
        assert load_config("ippo", entry).to_dict() == load_config("ippo_split", entry).to_dict(), entry
    for entry in PLANNED_ENTRIES:
        assert load_config("ippo", entry).to_dict() != load_config("ippo_split", entry).to_dict(), entry


def test_overrides_merge_kwargs_and_replace_the_rest(tmp_path) -> None:
    from sb3_pm.zoo.config import apply_overrides

    raw = {"n_steps": 16, "policy_kwargs": {"gat_heads": 1}, "env_kwargs": {"max_cycles": 10}}
    merged = apply_overrides(raw, {"n_steps": 8, "policy_kwargs": {"avoid_collisions": True}})
    assert merged == {
        "n_steps": 8,
        "policy_kwargs": {"gat_heads": 1, "avoid_collisions": True},
        "env_kwargs": {"max_cycles": 10},
    }
    assert raw["policy_kwargs"] == {"gat_heads": 1}  # the input is not modified
    path = tmp_path / "c.yml"
    path.write_text("default:\n  n_steps: 16\n  policy_kwargs: {gat_heads: 1}\n")
    config = load_config(path, "paper-50", {"policy_kwargs": {"dcbf_barrier": False}})
    assert config.hyperparams["policy_kwargs"] == {"gat_heads": 1, "dcbf_barrier": False}
    with pytest.raises(ConfigError, match="command-line overrides"):
        load_config(path, "paper-50", {"n_stepz": 3})


SPREAD = """
default:
  algo: maskable_ppo
  n_agents: 4
  n_steps: 16
  batch_size: 16
  n_epochs: 1
  learning_rate: 0.001
  learning_rate_spread: 2
  policy_kwargs: {net_arch: [8]}
  env_kwargs: {max_cycles: 20}
"""


def test_a_learning_rate_spread_staggers_the_learners_geometrically(tmp_path) -> None:
    config = load_config(write(tmp_path, SPREAD), "paper-50")
    rates = [config.per_agent()[f"agent_{i}"]["learning_rate"] for i in range(4)]
    # the fastest learner twice the slowest, evenly spaced on a log scale, geometric mean 1e-3
    assert rates == pytest.approx([1e-3 * 2 ** (0.5 - i / 3) for i in range(4)])
    assert rates[0] / rates[-1] == pytest.approx(2.0)
    assert float(th.tensor(rates).log().mean().exp()) == pytest.approx(1e-3)
    assert config.to_dict()["learning_rate_spread"] == 2.0
    # the team size is read when the team is built (an experiment may change it after loading)
    config.n_agents = 8
    eight = [config.per_agent()[f"agent_{i}"]["learning_rate"] for i in range(8)]
    assert eight[0] == pytest.approx(rates[0]) and eight[-1] == pytest.approx(rates[-1])
    team = IndependentPPO.from_config(config, erdos_renyi(14, 0.3, n_targets=3, seed=1), seed=0)
    try:
        learned = [team.models[f"agent_{i}"].lr_schedule(1.0) for i in range(8)]
    finally:
        team.close()
    assert learned == pytest.approx(eight)


def test_an_agent_block_wins_over_the_spread_and_a_spread_of_one_changes_nothing(tmp_path) -> None:
    text = SPREAD + "  agents:\n    agent_2: {learning_rate: 0.005}\n"
    config = load_config(write(tmp_path, text), "paper-50")
    assert config.per_agent()["agent_2"] == {"learning_rate": 0.005}
    assert config.per_agent()["agent_1"]["learning_rate"] == pytest.approx(1e-3 * 2 ** (1 / 6))
    config.learning_rate_spread = 1.0
    assert config.per_agent() == {"agent_2": {"learning_rate": 0.005}}
    assert "learning_rate_spread" not in config.to_dict()


def test_a_spread_scales_a_linear_schedule_and_needs_a_learning_rate(tmp_path) -> None:
    linear = SPREAD.replace("learning_rate: 0.001", "learning_rate: lin_1e-3")
    config = load_config(write(tmp_path, linear), "x")
    first = parse_schedule(config.per_agent()["agent_0"]["learning_rate"])
    assert first(1.0) == pytest.approx(2**0.5 * 1e-3) and first(0.0) == 0
    config.hyperparams.pop("learning_rate")  # as a later override might: built teams check again
    with pytest.raises(ConfigError, match="learning_rate_spread needs the entry's learning_rate"):
        config.team_kwargs()


def test_the_default_config_staggers_its_learners() -> None:
    config = load_config("ippo", "paper-50")
    assert config.learning_rate_spread == 2.0 and config.hyperparams["learning_rate"] == 1e-3
    assert [round(config.per_agent()[f"agent_{i}"]["learning_rate"], 6) for i in range(4)] == [
        0.001414,
        0.001122,
        0.000891,
        0.000707,
    ]


#: One setting per removed research switch, as a config writes it: (where, key, value).
REMOVED = [
    ("policy_kwargs", "extra_attention", True),
    ("policy_kwargs", "derived_features", True),
    ("policy_kwargs", "estimator_target", "observed"),
    ("policy_kwargs", "actor_nodes", "allowed"),
    ("policy_kwargs", "gat_sparse_kernel", "csr"),
    ("policy_kwargs", "laplacian", "eigen"),
    (None, "ent_coef_final", 0.0),
    (None, "estimator_update_at", "rollout_end"),
    ("reward", "crowding", 0.002),
    ("reward", "urgency", 0.04),
    ("reward", "neglect", 0.02),
]


def _setting(where: str | None, key: str, value: object) -> dict:
    if where is None:
        return {key: value}
    if where == "reward":
        return {"env_kwargs": {"reward": {"clearing": 0.04, key: value}}}
    return {where: {key: value}}


def _removed_name(where: str | None, key: str, value: object) -> str:
    if where == "reward":
        return f"reward: {key}"
    return f"laplacian: {value}" if key == "laplacian" else key


@pytest.mark.parametrize(("where", "key", "value"), REMOVED, ids=[key for _, key, _ in REMOVED])
def test_a_removed_research_switch_is_one_line_naming_the_tag(tmp_path, where, key, value) -> None:
    """Every path that reads a config (a YAML entry, an agent's overrides, a command-line override,
    a team's Python kwargs, an experiment's variant) refuses the switch in one line that names it
    and the research snapshot tag that still has it."""
    from sb3_pm.errors import InputError
    from sb3_pm.experiments.spec import load_experiment
    from sb3_pm.zoo.schema import REMOVED_KEYS

    name = _removed_name(where, key, value)
    assert name in REMOVED_KEYS
    setting = _setting(where, key, value)
    entry = {"algo": "dcbf_ppo", "n_agents": 2, "n_steps": 16, **setting}
    path = tmp_path / "removed.yml"
    path.write_text(yaml.safe_dump({"default": entry}))
    per_agent = tmp_path / "per_agent.yml"
    per_agent.write_text(
        yaml.safe_dump({"default": {"algo": "dcbf_ppo", "n_agents": 2, "agents": {"agent_1": setting}}})
    )
    experiment = tmp_path / "experiment.yml"
    experiment.write_text(
        yaml.safe_dump(
            {
                "name": "removed",
                "graphs": ["paper-50"],
                "seeds": [0],
                "config": str(path.parent / "ok.yml"),
                "variants": {"v": setting if where is not None else {"hyperparams": setting}},
            }
        )
    )
    (tmp_path / "ok.yml").write_text(yaml.safe_dump({"default": {"algo": "dcbf_ppo"}}))
    hyperparams = {k: v for k, v in setting.items() if k != "env_kwargs"}
    env_kwargs = setting.get("env_kwargs")
    calls = [
        lambda: load_config(path, "paper-50"),
        lambda: load_config(per_agent, "paper-50"),
        lambda: load_config(tmp_path / "ok.yml", "paper-50", overrides=setting),
        lambda: load_experiment(experiment),
        lambda: IndependentPPO(
            erdos_renyi(8, 0.4, n_targets=2, seed=0),
            n_agents=2,
            hyperparams=hyperparams,
            env_kwargs=env_kwargs,
        ),
    ]
    for call in calls:
        with pytest.raises(InputError) as info:
            call()
        message = str(info.value)
        assert "\n" not in message
        assert repr(name) in message and "was removed" in message and "v0.1.0-research" in message

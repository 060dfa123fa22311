"""The config schema (sb3_pm/zoo/schema.py): the one list of keys the loaders check and the docs
show, kept equal to what the algorithms, the policy and the environment actually take."""

from __future__ import annotations

import inspect
import subprocess
import sys
from dataclasses import fields as dataclass_fields
from pathlib import Path

import pytest

from sb3_pm.experiments.spec import ExperimentError, load_experiment
from sb3_pm.zoo.config import ConfigError, load_config
from sb3_pm.zoo.schema import KEYS, POLICY_KEYS, REMOVED_KEYS, SECTIONS, TEAM_KEYS, algorithm_keys

ROOT = Path(__file__).resolve().parents[1]
BASE = "default:\n  algo: maskable_ppo\n  n_steps: 16\n"


@pytest.mark.parametrize(
    ("line", "key", "message"),
    [
        # the learning rate: positive and finite, as a number or a lin_ schedule
        ("learning_rate: 0", "learning_rate", "expected a number or lin_<number> > 0, got 0"),
        ("learning_rate: -1.0e-3", "learning_rate", "> 0"),
        ("learning_rate: .inf", "learning_rate", "> 0"),
        ("learning_rate: .nan", "learning_rate", "> 0"),
        ("learning_rate: lin_-3e-4", "learning_rate", "> 0, got 'lin_-3e-4'"),
        ("learning_rate: lin_inf", "learning_rate", "> 0"),
        # discount and GAE factors in (0, 1]
        ("gamma: 0", "gamma", r"expected a number in \(0, 1\], got 0"),
        ("gamma: 1.01", "gamma", r"\(0, 1\]"),
        ("gae_lambda: -0.5", "gae_lambda", r"\(0, 1\]"),
        # clipping, coefficients and gradient norm
        ("clip_range: 0", "clip_range", "> 0"),
        ("clip_range: .inf", "clip_range", "> 0"),
        ("ent_coef: -0.01", "ent_coef", "expected a number >= 0"),
        ("ent_coef: .inf", "ent_coef", ">= 0"),
        ("vf_coef: .nan", "vf_coef", ">= 0"),
        ("max_grad_norm: 0", "max_grad_norm", "> 0"),
        ("max_grad_norm: .inf", "max_grad_norm", "> 0"),
        # sizes
        ("n_steps: 1", "n_steps", "expected an integer >= 2, got 1"),
        ("n_epochs: 0", "n_epochs", "expected an integer >= 1"),
        ("batch_size: 17", "batch_size", r"at most n_steps × n_envs = 16 × 1 = 16 \(one rollout\), got 17"),
        # env keys reach the environment as written, so no float or string stands for an integer
        ("env_kwargs: {max_cycles: 0}", "env_kwargs.max_cycles", "expected an integer >= 1, got 0"),
        ("env_kwargs: {max_cycles: 50.0}", "env_kwargs.max_cycles", "expected an integer >= 1, got 50.0"),
        ("env_kwargs: {max_cycles: '50'}", "env_kwargs.max_cycles", "got '50'"),
        ("env_kwargs: {graph_knowledge: all}", "env_kwargs.graph_knowledge", "one of discovered, known"),
        ("env_kwargs: {reward: {clearing: x}}", "env_kwargs.reward.clearing", "a finite number"),
        ("env_kwargs: {reward: {idling: 1}}", "env_kwargs.reward", "unknown reward term 'idling'"),
        ("env_kwargs: {reward: papers}", "env_kwargs.reward", "unknown reward preset 'papers'"),
        ("env_kwargs: {failure_rate: 2}", "env_kwargs.failure_rate", r"in \[0, 1\]"),
        # policy keys: the DCBF policy's own, checked against its ranges
        ("policy_kwargs: {eta: 1.5}", "policy_kwargs.eta", r"in \[0, 1\]"),
        ("policy_kwargs: {gat_heads: 0}", "policy_kwargs.gat_heads", "expected an integer >= 1"),
        ("policy_kwargs: {neglect_scope: everyone}", "policy_kwargs.neglect_scope", "one of known"),
        ("policy_kwargs: {gat_backend: fast}", "policy_kwargs.gat_backend", "one of auto, dense, sparse"),
        ("policy_kwargs: {freeze_steps: 2.5}", "policy_kwargs.freeze_steps", "expected an integer >= 0"),
    ],
)
def test_a_value_out_of_range_is_one_line_naming_the_key(
    tmp_path: Path, line: str, key: str, message: str
) -> None:
    algo = "algo: dcbf_ppo" if line.startswith("policy_kwargs") else "algo: maskable_ppo"
    path = tmp_path / "c.yml"
    path.write_text(BASE.replace("algo: maskable_ppo", algo) + f"  {line}\n")
    with pytest.raises(ConfigError, match=message) as info:
        load_config(path, "paper-50")
    text = str(info.value)
    assert "\n" not in text and text.startswith(f"{path}: default.{key}: "), text


@pytest.mark.parametrize(
    ("line", "message"),
    [
        (
            "policy_kwargs: {gat_heads: 1}",
            r"policy_kwargs: unknown key 'gat_heads' \(not an argument of MultiInputPolicy\)",
        ),
        ("use_sde: true", r"unknown key 'use_sde' \(not a team key, nor an argument of maskable_ppo\)"),
        (
            "env_kwargs: {n_agents: 3}",
            r"env_kwargs: unknown key 'n_agents' \(not an argument of the environment\)",
        ),
    ],
)
def test_a_key_the_learner_does_not_take_is_refused(tmp_path: Path, line: str, message: str) -> None:
    path = tmp_path / "c.yml"
    path.write_text(BASE + f"  {line}\n")
    with pytest.raises(ConfigError, match=message):
        load_config(path, "paper-50")


def test_values_are_kept_or_normalised_as_before(tmp_path: Path) -> None:
    """Team and algorithm numbers as PyYAML reads them (5e4 and 1e-4 are strings) are normalised;
    schedules stay as written; env and policy values reach their classes unchanged."""
    path = tmp_path / "c.yml"
    path.write_text(
        BASE + "  n_timesteps: 5e4\n  learning_rate: 1e-4\n  clip_range: lin_0.2\n  vf_coef: 1\n"
        "  env_kwargs: {max_cycles: 50, u_max: 80}\n"
    )
    config = load_config(path, "paper-50")
    assert config.n_timesteps == 50_000 and config.hyperparams["learning_rate"] == 1e-4
    assert config.hyperparams["clip_range"] == "lin_0.2" and config.hyperparams["vf_coef"] == 1.0
    assert config.env_kwargs == {"max_cycles": 50, "u_max": 80}
    assert type(config.env_kwargs["u_max"]) is int  # as written


def test_a_variants_setting_out_of_range_fails_when_the_experiment_is_read(tmp_path: Path) -> None:
    path = tmp_path / "e.yml"
    path.write_text(
        f"graphs: [paper-50]\nseeds: [0]\nconfig: {ROOT / 'zoo' / 'ippo.yml'}\n"
        "variants:\n  hot: {hyperparams: {gamma: 1.5}}\n"
    )
    message = r"e\.yml: variant 'hot': hyperparams\.gamma: expected a number in \(0, 1\]"
    with pytest.raises(ExperimentError, match=message):
        load_experiment(path)
    path.write_text(path.read_text().replace("hyperparams: {gamma: 1.5}", "env_kwargs: {max_cycle: 5}"))
    with pytest.raises(ExperimentError, match=r"variant 'hot': env_kwargs: unknown key 'max_cycle'"):
        load_experiment(path)


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("max_cycles: 50.0", "max_cycles: expected an integer >= 1, got 50.0"),
        ("max_cycles: '50'", "max_cycles: expected an integer >= 1, got '50'"),
        ("episodes: 0", "episodes: expected an integer >= 1, got 0"),
        ("timesteps: 1.5e3", "timesteps: expected an integer >= 1 or null, got '1.5e3'"),
        ("quick: {max_cycles: 2.5}", r"quick\.max_cycles: expected an integer >= 1, got 2\.5"),
    ],
)
def test_an_experiments_own_setting_is_not_coerced(tmp_path: Path, line: str, message: str) -> None:
    path = tmp_path / "e.yml"
    variants = "variants: {r: {kind: baseline, policy: random}}"
    path.write_text(f"graphs: [paper-50]\nseeds: [0]\n{line}\n{variants}\n")
    with pytest.raises(ExperimentError, match=message) as info:
        load_experiment(path)
    assert "\n" not in str(info.value) and str(info.value).count(str(path)) == 1


def test_the_schema_lists_what_the_algorithms_take() -> None:
    from sb3_pm.zoo.registry import resolve_algo

    managed = {"self", "policy", "env", "seed", "tensorboard_log", "verbose", "device", "_init_setup_model"}
    managed.add("update_device")  # DCBF-PPO's: where the updates run, set by the team
    for algo in ("ppo", "maskable_ppo", "dcbf_ppo"):
        taken: dict[str, inspect.Parameter] = {}
        for klass in resolve_algo(algo).__mro__:
            if "__init__" not in vars(klass):
                continue
            parameters = inspect.signature(vars(klass)["__init__"]).parameters
            for name, parameter in parameters.items():
                named = (parameter.POSITIONAL_OR_KEYWORD, parameter.KEYWORD_ONLY)
                if name not in managed and parameter.kind in named:
                    taken.setdefault(name, parameter)
            if not any(p.kind is p.VAR_KEYWORD for p in parameters.values()):
                break
        keys = algorithm_keys(algo)
        assert set(keys) == set(taken), algo
        for name, key in keys.items():
            assert key.default == taken[name].default, (algo, name)


def test_the_schema_lists_what_the_environment_and_the_policy_take() -> None:
    from sb3_pm.envs.persistent_monitoring import PersistentMonitoringEnv
    from sb3_pm.envs.rewards import REWARD_PRESETS, TERMS
    from sb3_pm.policies.dcbf import NEGLECT_SCOPES, DCBFConfig
    from sb3_pm.policies.policy import DCBFActorCriticPolicy
    from sb3_pm.policies.settings import EncoderSettings, EstimatorSettings, FilterSettings, PolicySettings
    from sb3_pm.zoo.schema import REWARD_PRESETS as SCHEMA_PRESETS

    PARTS = ("encoder", "estimator", "filter")

    env = inspect.signature(PersistentMonitoringEnv.__init__).parameters
    env_defaults = {name: p.default for name, p in env.items() if name not in ("self", "graph", "n_agents")}
    assert {name: key.default for name, key in KEYS["env"].items()} == env_defaults
    assert tuple(KEYS["reward"]) == TERMS
    assert SCHEMA_PRESETS == tuple(REWARD_PRESETS) and KEYS["env"]["reward"].default in SCHEMA_PRESETS
    # SB3's own arguments from the signature, the rest from the settings objects they fill
    policy = inspect.signature(DCBFActorCriticPolicy.__init__).parameters
    spaces = ("self", "observation_space", "action_space", "lr_schedule", "settings")
    taken = {name: p.default for name, p in policy.items() if name not in spaces}
    for part in (EncoderSettings, EstimatorSettings, FilterSettings, PolicySettings):
        taken.update({f.name: f.default for f in dataclass_fields(part) if f.name not in PARTS})
    assert set(POLICY_KEYS) == set(taken)
    for name, key in POLICY_KEYS.items():
        default = taken[name]
        if isinstance(default, type):
            assert key.default == default.__name__, name
        elif name not in ("net_arch",):  # None in the signature: the documented pi/vf sizes apply
            assert key.default == (list(default) if isinstance(default, tuple) else default), name
    # The DCBF section describes DCBFConfig's fields (barrier and territory by their policy names).
    fields = {"barrier": "dcbf_barrier", "territory": "neglect_territory"}
    # ... but rule 12's deadline, which only deploy_filter sets: it reads the deployed team's memory.
    assert "visit_deadline" not in KEYS["dcbf"] and "visit_deadline" not in POLICY_KEYS
    for name, value in vars(DCBFConfig()).items():
        if name == "visit_deadline":
            continue
        key = KEYS["dcbf"][fields.get(name, name)]
        assert key.default == (list(value) if isinstance(value, tuple) else value), name
    assert KEYS["dcbf"]["neglect_scope"].choices == NEGLECT_SCOPES


def test_team_defaults_and_removed_keys() -> None:
    assert TEAM_KEYS == (
        "n_timesteps", "n_envs", "n_agents", "algo", "policy", "env_kwargs", "agents", "env",
        "deploy_temperature", "deploy_filter", "learning_rate_spread",
    )  # fmt: skip
    every = {name for section in SECTIONS for name in KEYS[section.name]}
    assert not every & {name.split(": ")[0] for name in REMOVED_KEYS if ": " not in name}


def test_config_md_holds_the_tables_the_schema_generates() -> None:
    from sb3_pm.zoo.schema_doc import render_doc

    text = (ROOT / "docs" / "CONFIG.md").read_text()
    assert render_doc(text) == text, "run: python -m sb3_pm.zoo.schema_doc --write docs/CONFIG.md"


def test_the_schema_module_and_the_file_readers_import_no_torch() -> None:
    code = (
        "import importlib.util, sys\n"
        f"spec = importlib.util.spec_from_file_location('schema', {str(ROOT / 'sb3_pm/zoo/schema.py')!r})\n"
        "module = importlib.util.module_from_spec(spec); sys.modules['schema'] = module\n"
        "spec.loader.exec_module(module)\n"
        "assert module.KEYS and 'torch' not in sys.modules, sorted(sys.modules)\n"
        # nor does reading a config file or an experiment file
        "from sb3_pm.zoo.config import read_yaml\n"
        "from sb3_pm.experiments.spec import load_experiment\n"
        "read_yaml('ippo'), load_experiment('comparison')\n"
        "assert 'torch' not in sys.modules\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)

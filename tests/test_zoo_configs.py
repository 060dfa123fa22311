"""Every config in ``zoo/`` builds, and rl-zoo trains on our ids end to end.

* rl-zoo YAMLs (``zoo/<algo>.yml``, all but the team files ``zoo/ippo*.yml``): each entry is read
  by rl-zoo's own :class:`~rl_zoo3.exp_manager.ExperimentManager`, which builds the model exactly as
  ``rl_zoo3.train`` would (schedules, env_kwargs, policy_kwargs, n_envs).
* ``zoo/ippo.yml``, ``zoo/ippo_split.yml``, ``zoo/ippo_paper.yml``, ``zoo/ippo_improved.yml``,
  ``zoo/ippo_transfer.yml``, ``zoo/ippo_transfer_prior4.yml`` and ``zoo/ippo_transfer_split.yml``
  (our team format): each entry builds an :class:`IndependentPPO` team.
* ``python -m rl_zoo3.train --gym-packages sb3_pm ...`` (a subprocess) and our launcher
  ``python -m sb3_pm.zoo --algo dcbf_ppo ...`` run end to end and save a model.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch as th
import yaml

from sb3_pm.graphs import PRESETS
from sb3_pm.registration import ENV_IDS
from sb3_pm.zoo import load_config
from sb3_pm.zoo.config import ConfigError

rl_zoo3 = pytest.importorskip("rl_zoo3", reason="rl-zoo is the optional extra sb3_pm[zoo]")

from sb3_pm.zoo.rl_zoo import RL_ZOO_ALGOS, register_rl_zoo_algos  # noqa: E402

th.set_num_threads(1)

ROOT = Path(__file__).resolve().parents[1]
ZOO = ROOT / "zoo"
#: Files in zoo/ that are not rl-zoo hyperparameter files.
NOT_RL_ZOO = {
    "ippo.yml",
    "ippo_split.yml",
    "ippo_paper.yml",
    "ippo_improved.yml",
    "ippo_transfer.yml",
    "ippo_transfer_prior4.yml",
    "ippo_transfer_split.yml",
}
RL_ZOO_FILES = sorted(p for p in ZOO.glob("*.yml") if p.name not in NOT_RL_ZOO)
#: Small settings so that building (and the end-to-end runs) stay fast.
TINY = {"n_envs": 1, "n_steps": 32, "batch_size": 32}


def rl_zoo_entries() -> list[tuple[Path, str]]:
    return [(path, entry) for path in RL_ZOO_FILES for entry in yaml.safe_load(path.read_text())]


def env_id_for(path: Path, entry: str) -> str:
    """The id rl-zoo would read ``entry`` for: the entry itself, or (``default``) an id without one."""
    if entry != "default":
        return entry
    data = yaml.safe_load(path.read_text())
    unclaimed = [env_id for env_id in ENV_IDS if env_id not in data]
    if not unclaimed:
        pytest.skip(f"{path.name}: every registered id has its own entry; default is unreachable")
    return unclaimed[0]


def test_there_are_rl_zoo_files() -> None:
    names = {p.stem for p in RL_ZOO_FILES}
    assert {"ppo", "maskable_ppo", "dcbf_ppo"} <= names


@pytest.mark.parametrize("path", RL_ZOO_FILES, ids=lambda p: p.name)
def test_rl_zoo_file_is_keyed_by_env_id(path: Path) -> None:
    data = yaml.safe_load(path.read_text())
    assert isinstance(data, dict) and "default" in data
    for entry, values in data.items():
        assert entry == "default" or entry in ENV_IDS, f"{path.name}: {entry!r} is no registered id"
        assert isinstance(values, dict) and "n_timesteps" in values and "policy" in values
        # rl-zoo eval()s string policy_kwargs; ours are real mappings.
        assert isinstance(values.get("policy_kwargs", {}), dict)


@pytest.mark.parametrize(("path", "entry"), rl_zoo_entries(), ids=lambda x: getattr(x, "name", x))
def test_rl_zoo_entry_builds(path: Path, entry: str, tmp_path: Path) -> None:
    from rl_zoo3.exp_manager import ExperimentManager
    from rl_zoo3.utils import ALGOS

    register_rl_zoo_algos()
    algo = path.stem  # rl-zoo convention: one file per algorithm, named after it
    assert algo in ALGOS, f"{path.name}: no algorithm {algo!r} in rl-zoo's table"
    manager = ExperimentManager(
        argparse.Namespace(),
        algo,
        env_id_for(path, entry),
        str(tmp_path),
        n_timesteps=64,
        eval_freq=-1,
        hyperparams=dict(TINY),
        seed=0,
        verbose=0,
        device="cpu",
        config=str(path),
    )
    model, saved = manager.setup_experiment()
    try:
        assert isinstance(model, ALGOS[algo])
        # The YAML's own values reached the model (TINY overrides only n_envs/n_steps/batch_size).
        written = yaml.safe_load(path.read_text())[entry]
        assert model.gamma == pytest.approx(written["gamma"])
        assert model.n_epochs == written["n_epochs"]
        if "policy_kwargs" in written:
            for key, value in written["policy_kwargs"].items():
                assert model.policy_kwargs[key] == value
        if "teammates" in written.get("env_kwargs", {}):
            env = model.get_env().envs[0].unwrapped
            assert env.teammates is None or env.teammates.name == written["env_kwargs"]["teammates"]
        assert (Path(manager.params_path) / "config.yml").is_file()  # rl-zoo's run record
    finally:
        model.get_env().close()


def test_register_rl_zoo_algos_is_idempotent() -> None:
    from rl_zoo3.utils import ALGOS

    from sb3_pm.ppo_dcbf import DCBFPPO

    register_rl_zoo_algos()
    assert register_rl_zoo_algos() == []
    assert ALGOS["dcbf_ppo"] is DCBFPPO
    assert set(RL_ZOO_ALGOS) <= set(ALGOS)


TEAM_ENTRIES = [
    (name, entry) for name in sorted(NOT_RL_ZOO) for entry in yaml.safe_load((ZOO / name).read_text())
]


@pytest.mark.parametrize(("name", "entry"), TEAM_ENTRIES, ids=lambda value: str(value))
def test_ippo_entry_builds_a_team(name: str, entry: str) -> None:
    from sb3_pm.agents.training.team import IndependentPPO

    config = load_config(ZOO / name, entry)
    assert config.entry == entry
    graph = entry if entry in PRESETS else "paper-50"
    team = IndependentPPO.from_config(config, graph=graph, seed=0, n_envs=1)
    try:
        assert len(team.models) == config.n_agents
        model = next(iter(team.models.values()))
        assert model.n_steps == config.hyperparams.get("n_steps", model.n_steps)
    finally:
        team.close()


def _run(args: list[str], cwd: Path, timeout: int = 240) -> subprocess.CompletedProcess:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    result = subprocess.run(
        [sys.executable, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return result


def test_rl_zoo_train_runs_end_to_end(tmp_path: Path) -> None:
    """The issue's command, with a tiny budget: exits 0 and saves a model."""
    _run(
        [
            "-m", "rl_zoo3.train",
            "--gym-packages", "sb3_pm",
            "--env", "sb3_pm/PersistentMonitoring-paper50-v0",
            "--algo", "ppo",
            "-conf", str(ZOO / "ppo.yml"),
            "-n", "128",
            "-f", str(tmp_path / "logs"),
            "--seed", "0",
            "--eval-freq", "-1",
            "--num-threads", "1",
            "--device", "cpu",
            "-params", "n_envs:1", "n_steps:64", "batch_size:64", "n_epochs:1",
        ],
        cwd=tmp_path,
    )  # fmt: skip
    run = tmp_path / "logs" / "ppo" / "sb3_pm-PersistentMonitoring-paper50-v0_1"
    assert (run / "sb3_pm-PersistentMonitoring-paper50-v0.zip").is_file()
    assert (run / "sb3_pm-PersistentMonitoring-paper50-v0" / "config.yml").is_file()


def test_launcher_trains_dcbf_ppo_through_rl_zoo(tmp_path: Path) -> None:
    """``python -m sb3_pm.zoo --algo dcbf_ppo ...`` (rl-zoo's train with our algorithm registered)."""
    _run(
        [
            "-m", "sb3_pm.zoo",
            "--algo", "dcbf_ppo",
            "--env", "sb3_pm/PersistentMonitoring-paper50-v0",
            "-conf", str(ZOO / "dcbf_ppo.yml"),
            "-n", "128",
            "-f", str(tmp_path / "logs"),
            "--seed", "0",
            "--eval-freq", "64",
            "--eval-episodes", "1",
            "--num-threads", "1",
            "--device", "cpu",
            "--env-kwargs", "max_cycles:32", "teammates:'local_greedy'",
            "-params", "n_envs:1", "n_steps:64", "batch_size:64", "n_epochs:1",
        ],
        cwd=tmp_path,
    )  # fmt: skip
    run = tmp_path / "logs" / "dcbf_ppo" / "sb3_pm-PersistentMonitoring-paper50-v0_1"
    assert (run / "sb3_pm-PersistentMonitoring-paper50-v0.zip").is_file()
    assert (run / "best_model.zip").is_file()  # rl-zoo's EvalCallback ran the DCBF policy

    from sb3_pm.ppo_dcbf import DCBFPPO

    model = DCBFPPO.load(run / "sb3_pm-PersistentMonitoring-paper50-v0.zip", device="cpu")
    assert model.num_timesteps == 128


def test_ippo_transfer_is_the_prior4_config_imitating_the_rule_and_passing_held_nodes() -> None:
    """zoo/ippo_transfer.yml against zoo/ippo_transfer_prior4.yml, the config before it: taught
    the rule's move after each update, and deployed with the filter's rules 10 to 12."""
    transfer = load_config("ippo_transfer", "paper-50")
    prior4 = load_config("ippo_transfer_prior4", "paper-50")
    t_kwargs, p_kwargs = transfer.team_kwargs(), prior4.team_kwargs()
    assert t_kwargs["hyperparams"].pop("advice_imitation") == 1.0
    assert "advice_imitation" not in p_kwargs["hyperparams"]
    rules = {
        "neglect_bound": None,
        "neglect_scope": "known",
        "pass_held": True,
        "keep_moving": True,
        "visit_deadline": "auto",
    }
    assert t_kwargs.pop("deploy_filter") == rules
    assert p_kwargs.pop("deploy_filter") is None
    assert t_kwargs == p_kwargs and (transfer.env, prior4.env) == ("family:er", "family:er")


def test_ippo_transfer_prior4_is_the_default_without_rows_with_a_known_map_territory_and_advice() -> None:
    """zoo/ippo_transfer_prior4.yml against the default it was built from: paper-50's default
    before planned territories, kept as zoo/ippo_split.yml."""
    transfer, default = load_config("ippo_transfer_prior4", "paper-50"), load_config("ippo_split", "paper-50")
    t_kwargs, d_kwargs = transfer.team_kwargs(), default.team_kwargs()
    t_policy = dict(t_kwargs["hyperparams"].pop("policy_kwargs"))
    d_policy = dict(d_kwargs["hyperparams"].pop("policy_kwargs"))
    assert t_policy.pop("laplacian") == "none" and "laplacian" not in d_policy
    # The territory rule's move as an input, with a prior of 4 on its logit.
    assert t_policy.pop("advice_prior") == 4.0 and "advice_prior" not in d_policy
    # A known static map: each agent's map lists the targets and edges from the first step; the
    # default knows the edges only and discovers the targets.
    t_env, d_env = dict(t_kwargs.pop("env_kwargs")), dict(d_kwargs.pop("env_kwargs"))
    assert (t_env.pop("target_knowledge"), t_env.pop("graph_knowledge")) == ("known", "known")
    assert "target_knowledge" not in d_env and d_env.pop("graph_knowledge") == "known"
    # Told its group of the plan for the episode's starts on whatever graph it runs (computed
    # from the known map), and paid the territory reward as the default is.
    assert t_env.pop("territories") == "planned" and "territories" not in d_env
    assert t_env.pop("territory_input") is True and "territory_input" not in d_env
    assert t_env.pop("advice_input") is True and "advice_input" not in d_env
    assert t_env["reward"] == d_env["reward"] and t_env["reward"]["territory"] == 0.04
    # Deployed by sampling at temperature 0.25, the default by its most likely actions.
    assert (t_kwargs.pop("deploy_temperature"), d_kwargs.pop("deploy_temperature")) == (0.25, None)
    # One learning rate for every learner, as the transfer figures were measured; the default
    # staggers them (learning_rate_spread: 2).
    assert transfer.learning_rate_spread == 1.0 and default.learning_rate_spread == 2.0
    assert t_kwargs.pop("per_agent") == {} and len(d_kwargs.pop("per_agent")) == default.n_agents
    # 10 passes over each rollout, as the transfer figures were measured; the default makes 5.
    assert (t_kwargs["hyperparams"].pop("n_epochs"), d_kwargs["hyperparams"].pop("n_epochs")) == (10, 5)
    # No bound: B = 50 belongs to paper-50's split territories.
    assert t_kwargs.pop("deploy_filter") is None
    assert d_kwargs.pop("deploy_filter") == {"neglect_bound": 50.0, "neglect_scope": "territory"}
    assert t_policy == d_policy and t_kwargs == d_kwargs and t_env == d_env
    # It names what it trains on without --env, a graph family; the default trains on the
    # command line's graph.
    assert (transfer.env, default.env) == ("family:er", None)


def test_ippo_transfer_split_is_the_transfer_config_before_planned_territories() -> None:
    """zoo/ippo_transfer_split.yml, the transfer config the earlier records measured: the same as
    zoo/ippo_transfer_prior4.yml but on split territories, with a prior of 2 and the calibrated bound."""
    transfer = load_config("ippo_transfer_prior4", "paper-50")
    split = load_config("ippo_transfer_split", "paper-50")
    t_kwargs, s_kwargs = transfer.team_kwargs(), split.team_kwargs()
    assert t_kwargs["hyperparams"]["policy_kwargs"].pop("advice_prior") == 4.0
    assert s_kwargs["hyperparams"]["policy_kwargs"].pop("advice_prior") == 2.0
    assert t_kwargs["env_kwargs"].pop("territories") == "planned"
    assert "territories" not in s_kwargs["env_kwargs"]
    assert t_kwargs.pop("deploy_filter") is None
    assert s_kwargs.pop("deploy_filter") == {"neglect_bound": "auto", "neglect_scope": "territory"}
    assert t_kwargs == s_kwargs and (transfer.env, split.env) == ("family:er", "family:er")


def test_a_config_env_is_what_train_uses_without_env(tmp_path: Path) -> None:
    from sb3_pm.zoo.config import default_env

    assert default_env("ippo_transfer") == "family:er" and default_env("ippo") is None
    bad = tmp_path / "bad.yml"
    bad.write_text("default:\n  env: [paper-50]\n  algo: dcbf_ppo\n")
    with pytest.raises(ConfigError, match=r"default.env: expected a graph or family name"):
        default_env(bad)
    with pytest.raises(ConfigError, match=r"default.env: expected a graph or family name"):
        load_config(bad, "paper-50")


def test_ippo_transfer_team_deploys_on_another_graph() -> None:
    from sb3_pm.agents.deployment.transfer import TransferredTeam
    from sb3_pm.agents.training.team import IndependentPPO

    config = load_config("ippo_transfer", "paper-50")
    config.hyperparams.update(TINY)
    config.n_envs = 1
    team = IndependentPPO.from_config(config, "paper-50", seed=0)
    assert isinstance(team.on_graph("rooms-4"), TransferredTeam)

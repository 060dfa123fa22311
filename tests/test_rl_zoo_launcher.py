"""``python -m sb3_pm.zoo``: rl-zoo's train, enjoy, record_video and optimize with our algorithms,
ids and configs, from a folder outside the repository."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import optuna
import pytest
from sb3_contrib import MaskablePPO

from sb3_pm.errors import UsageError
from sb3_pm.zoo.rl_zoo import (
    acting_with_observed_masks,
    register_rl_zoo_algos,
    resolve_config,
    shipped_config,
)
from sb3_pm.zoo.rl_zoo_search import dcbf_converter, dcbf_sampler
from sb3_pm.zoo.shipped import CONFIG_DIR

ENV_ID = "sb3_pm/PersistentMonitoring-paper50-v0"


def launch(cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    environment = {**os.environ, "OMP_NUM_THREADS": "1", "MPLBACKEND": "Agg"}
    return subprocess.run(
        [sys.executable, "-m", "sb3_pm.zoo", *args],
        cwd=cwd,
        env=environment,
        capture_output=True,
        text=True,
        timeout=900,
    )


def run_commands(folder: Path, algo: str, optimize: bool) -> None:
    """Every command for ``algo``, in ``folder`` (outside the repository), each exiting 0."""
    small = ["--hyperparams", "n_steps:250"] if algo != "dcbf_ppo" else []
    steps = ["--algo", algo, "--env", ENV_ID, "-n", "500", "-f", "logs", "--seed", "0", *small]
    done = launch(folder, "train", *steps)
    assert done.returncode == 0, done.stderr[-2000:]
    assert f"Loading hyperparameters from: {CONFIG_DIR / f'{algo}.yml'}" in done.stdout  # ours, no -conf
    acting = ["--algo", algo, "--env", ENV_ID, "-f", "logs"]
    done = launch(folder, "enjoy", *acting, "-n", "60", "--no-render")
    assert done.returncode == 0, done.stderr[-2000:]
    done = launch(folder, "record_video", *acting, "-n", "10")
    assert done.returncode == 0, done.stderr[-2000:]
    assert list((folder / "logs" / algo).glob("*/videos/*.mp4"))
    if optimize:
        search = ["--n-trials", "1", "--n-jobs", "1", "--n-evaluations", "1", "--eval-episodes", "1"]
        done = launch(
            folder, "optimize", *steps, *search, "--no-optim-plots", "--env-kwargs", "max_cycles:60"
        )
        assert done.returncode == 0, done.stderr[-2000:]


def test_every_command_of_dcbf_ppo_runs_outside_the_repository(tmp_path: Path) -> None:
    run_commands(tmp_path, "dcbf_ppo", optimize=False)


@pytest.mark.slow
@pytest.mark.parametrize("algo", ["ppo", "maskable_ppo", "dcbf_ppo"])
def test_every_command_of_every_algorithm(tmp_path: Path, algo: str) -> None:
    run_commands(tmp_path, algo, optimize=True)


def test_a_bad_command_or_config_is_one_line(tmp_path: Path) -> None:
    for args, message in (
        (["trian", "--algo", "ppo"], "unknown command 'trian'"),
        (["train", "-conf", "nope"], "-conf 'nope'"),
    ):
        done = launch(tmp_path, *args)
        assert done.returncode == 2 and message in done.stderr and len(done.stderr.strip().splitlines()) == 1


def test_a_config_is_named_or_found_for_our_ids(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)  # outside the repository: zoo/ppo.yml is not a path here
    assert resolve_config(["-conf", "dcbf_ppo", "--algo", "dcbf_ppo"]) == [
        "-conf",
        str(shipped_config("dcbf_ppo")),
        "--algo",
        "dcbf_ppo",
    ]
    assert resolve_config(["--conf-file=zoo/ppo.yml"]) == [f"--conf-file={shipped_config('ppo')}"]
    assert resolve_config(["--algo", "maskable_ppo", "--env", ENV_ID])[-2:] == [
        "-conf",
        str(shipped_config("maskable_ppo")),
    ]
    assert resolve_config(["--algo", "ppo", "--env", "CartPole-v1"]) == [
        "--algo",
        "ppo",
        "--env",
        "CartPole-v1",
    ]
    with pytest.raises(UsageError, match="neither a file nor a shipped config"):
        resolve_config(["-conf", "nope"])


def test_acting_takes_the_masks_from_the_observation(monkeypatch: pytest.MonkeyPatch) -> None:
    """rl-zoo's enjoy passes no masks: the registered class reads the observation's."""
    from rl_zoo3.utils import ALGOS

    for name in ("dcbf_ppo", "maskable_ppo", "ppo_mask"):  # put back the plain classes afterwards
        if name in ALGOS:
            monkeypatch.setitem(ALGOS, name, ALGOS[name])
        else:
            monkeypatch.setitem(ALGOS, name, None)

    from sb3_pm.envs.single_agent import SingleAgentMonitoringEnv

    register_rl_zoo_algos(acting=True)
    assert issubclass(ALGOS["maskable_ppo"], MaskablePPO)
    env = SingleAgentMonitoringEnv("paper-50", max_cycles=30)
    model = ALGOS["maskable_ppo"]("MultiInputPolicy", env, n_steps=64, seed=0)
    plain = MaskablePPO("MultiInputPolicy", env, n_steps=64, seed=0)
    observation, _ = env.reset(seed=0)
    illegal = {"masked": 0, "plain": 0}
    for _ in range(30):
        allowed = observation["action_mask"].astype(bool)
        action, _ = model.predict(observation, deterministic=True)
        illegal["masked"] += int(not allowed[int(action)])
        plain_action, _ = plain.predict(observation, deterministic=True)
        illegal["plain"] += int(not allowed[int(plain_action)])
        observation, *_ = env.step(int(action))
    assert illegal["masked"] == 0 and illegal["plain"] > 0  # the plain class would move off the graph
    assert acting_with_observed_masks(MaskablePPO).__name__ == "MaskablePPO"


def test_the_dcbf_sampler_merges_into_the_configs_policy_kwargs() -> None:
    base = {"use_estimator": True, "hidden_dim": 32, "freeze_steps": 10}
    fixed = {
        "batch_size_pow": 6,
        "n_steps_pow": 8,
        "one_minus_gamma": 0.01,
        "one_minus_gae_lambda": 0.05,
        "learning_rate": 3e-4,
        "ent_coef": 0.01,
        "clip_range": 0.2,
        "n_epochs": 5,
        "max_grad_norm": 0.5,
        "net_arch": "small",
        "activation_fn": "tanh",
        "hidden_dim": 64,
        "gat_layers": 1,
        "gat_heads": 2,
        "estimator_lr": 1e-3,
        "estimator_epochs": 3,
        "eta": 0.2,
        "freeze_steps": 4,
        "avoid_collisions": True,
    }
    sampled = dcbf_sampler(base)(optuna.trial.FixedTrial(fixed), 50, 2, {})
    policy_kwargs = sampled["policy_kwargs"]
    assert policy_kwargs["use_estimator"] is True  # the config's, kept
    assert policy_kwargs["hidden_dim"] == 64 and policy_kwargs["gat_layers"] == 1  # searched
    assert policy_kwargs["net_arch"] == {"pi": [64, 64], "vf": [64, 64]}  # PPO's sampler's
    assert sampled["n_steps"] == 256 and sampled["gamma"] == pytest.approx(0.99)
    assert dcbf_converter(base)(fixed) == sampled  # a finished trial's params give the same
    assert np.isclose(policy_kwargs["eta"], 0.2)

"""``sb3-pm train`` end to end with a tiny budget."""

from __future__ import annotations

import torch as th
import yaml

from sb3_pm.cli import main

th.set_num_threads(1)


def test_train_writes_run_folder_and_refuses_overwrite(tiny_train, capsys) -> None:
    config, graph, out = tiny_train
    argv = [
        "train",
        "--config",
        str(config),
        "--env",
        str(graph),
        "--seed",
        "3",
        "--timesteps",
        "32",
        "--out",
        str(out),
        "--no-progress",
    ]
    assert main(argv) == 0
    assert "team saved to" in capsys.readouterr().out
    for name in (
        "config.yml",
        "args.yml",
        "command.txt",
        "team/manifest.json",
        "team/agent_0.zip",
        "team/agent_1.zip",
    ):
        assert (out / name).exists(), name
    resolved = yaml.safe_load((out / "config.yml").read_text())
    assert (
        resolved["entry"] == "default"
        and resolved["n_timesteps"] == 32
        and resolved["learning_rate"] == "lin_1e-3"
    )
    assert yaml.safe_load((out / "args.yml").read_text())["seed"] == 3
    assert "--timesteps 32" in (out / "command.txt").read_text()
    machine = yaml.safe_load((out / "machine.yml").read_text())  # what the run was computed on
    import torch

    assert machine["torch"] == str(torch.__version__) and machine["torch_threads"] == 1
    assert machine["cpu"] and machine["torch_cpu_capability"] == str(torch.backends.cpu.get_cpu_capability())
    assert any((out / "tb").iterdir())  # TensorBoard runs, one per agent

    from sb3_pm.agents.training.team import IndependentPPO

    team = IndependentPPO.load(out)  # the run folder loads (evaluate --policy RUN_DIR)
    assert team.num_timesteps == 32

    assert main(argv) == 2
    assert "already exists; pass --overwrite" in capsys.readouterr().err
    assert main([*argv, "--overwrite"]) == 0


def test_train_user_errors(tiny_train, capsys) -> None:
    config, graph, out = tiny_train
    assert main(["train", "--config", str(config), "--env", "nope", "--out", str(out)]) == 2
    assert "unknown graph" in capsys.readouterr().err
    bad = config.parent / "bad.yml"
    bad.write_text("default: {n_stepz: 3}\n")
    assert main(["train", "--config", str(bad), "--env", str(graph), "--out", str(out)]) == 2
    assert "unknown key 'n_stepz'" in capsys.readouterr().err
    assert (
        main(["train", "--config", str(config), "--env", str(graph), "--timesteps", "0", "--out", str(out)])
        == 2
    )


def test_train_overrides_rl_zoo_style(tiny_train, capsys) -> None:
    config, graph, out = tiny_train
    argv = ["train", "--config", str(config), "--env", str(graph), "--timesteps", "16", "--out", str(out)]
    # n_steps 32, over the file's 16: a rollout must hold the file's batch_size of 16
    overrides = ["--hyperparams", "learning_rate:5e-4", "n_steps:32", "--env-kwargs", "reward:reduction"]
    assert main([*argv, *overrides, "--no-progress"]) == 0
    resolved = yaml.safe_load((out / "config.yml").read_text())
    assert resolved["learning_rate"] == 5e-4 and resolved["n_steps"] == 32
    # env_kwargs merge key by key: the file's max_cycles stays.
    assert resolved["env_kwargs"] == {"max_cycles": 10, "reward": "reduction"}
    assert (
        "--hyperparams learning_rate:5e-4 n_steps:32 --env-kwargs reward:reduction"
        in (out / "command.txt").read_text()
    )
    capsys.readouterr()
    for bad, message in (
        (["--hyperparams", "n_stepz:3"], "unknown key 'n_stepz'"),
        (["--hyperparams", "n_steps"], "expected KEY:VALUE"),
        (["--hyperparams", "n_steps:[3"], "not valid YAML"),
        (["--env-kwargs", "rewardz:paper"], "unknown key 'rewardz'"),
    ):
        assert main([*argv, *bad, "--out", str(out.parent / "other")]) == 2
        assert message in capsys.readouterr().err


def test_train_threads_option(tiny_train, capsys) -> None:
    """--threads sets torch's thread count (default 1, the bit-for-bit reproducible setting)."""
    config, graph, out = tiny_train
    args = ["train", "--config", str(config), "--env", str(graph), "--timesteps", "16", "--no-progress"]
    try:
        assert main([*args, "--out", str(out / "two"), "--threads", "2"]) == 0
        assert th.get_num_threads() == 2
        assert "--threads 2" in (out / "two" / "command.txt").read_text()
        assert main([*args, "--out", str(out / "one")]) == 0
        assert th.get_num_threads() == 1
    finally:
        th.set_num_threads(1)
    assert main([*args, "--out", str(out / "zero"), "--threads", "0"]) == 2
    assert "--threads must be at least 1" in capsys.readouterr().err


def test_train_same_seed_same_parameters(tiny_train) -> None:
    """Two DCBF-PPO runs from the same seed save identical learners."""
    import zipfile

    config, graph, out = tiny_train
    args = ["train", "--config", str(config), "--env", str(graph), "--timesteps", "32", "--no-progress"]
    args += ["--hyperparams", "algo:dcbf_ppo", "policy_kwargs:{gat_heads: 1, hidden_dim: 8}"]
    for name in ("a", "b"):
        assert main([*args, "--out", str(out / name)]) == 0
    for agent in ("agent_0", "agent_1"):
        saved = [zipfile.ZipFile(out / name / "team" / f"{agent}.zip").read("policy.pth") for name in "ab"]
        assert saved[0] == saved[1]


def test_train_without_env_uses_the_configs_graph_family(tiny_train, capsys) -> None:
    import json

    config, _, out = tiny_train
    family_config = config.with_name("family.yml")
    family_config.write_text(
        config.read_text()
        .replace("default:\n", "default:\n  env: family:er\n", 1)
        .replace("algo: maskable_ppo", "algo: dcbf_ppo\n  policy_kwargs: {laplacian: none, hidden_dim: 8}")
    )
    argv = ["train", "--config", str(family_config), "--timesteps", "32", "--out", str(out), "--no-progress"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "on family:er (a new graph each episode, 20 to 60 nodes)" in printed
    assert "sb3-pm evaluate --policy" in printed and "--graph paper-50" in printed
    assert yaml.safe_load((out / "config.yml").read_text())["env"] == "family:er"
    assert "--env family:er" in (out / "command.txt").read_text()
    manifest = json.loads((out / "team" / "manifest.json").read_text())
    assert manifest["graph"]["family"]["kind"] == "erdos_renyi" and manifest["graph"]["n_nodes"] == 60
    # --env still wins over the config's.
    assert main([*argv[:-3], "--out", str(out.with_name("one")), "--env", "karate", "--no-progress"]) == 0
    assert yaml.safe_load((out.with_name("one") / "config.yml").read_text())["env"] == "karate"


def test_a_family_run_refuses_what_cannot_transfer_and_a_stray_env_override(tiny_train, capsys) -> None:
    config, _, out = tiny_train
    argv = ["train", "--config", str(config), "--env", "family:er", "--out", str(out), "--no-progress"]
    assert main(argv) == 2  # maskable_ppo's flat MultiInputPolicy reads fixed-size observations
    assert "must transfer: agent_0's policy (MaskableMultiInputActorCriticPolicy)" in capsys.readouterr().err
    assert not out.exists()
    assert main([*argv, "--hyperparams", "env:karate"]) == 2
    assert "--hyperparams env:... is not read; name the graph or family with --env" in capsys.readouterr().err


def test_a_run_folders_config_retrains_the_same_team(tiny_train) -> None:
    """``--config RUN/config.yml`` (one resolved entry) retrains that run bit for bit, on the graph
    it recorded, whatever the config it came from says now."""
    import zipfile

    config, graph, out = tiny_train
    args = ["--timesteps", "32", "--seed", "5", "--no-progress"]
    assert main(["train", "--config", str(config), "--env", str(graph), *args, "--out", str(out / "a")]) == 0
    config.write_text("default: {algo: nope}\n")  # the original is gone: the record must suffice
    assert main(["train", "--config", str(out / "a" / "config.yml"), *args, "--out", str(out / "b")]) == 0
    for agent in ("agent_0", "agent_1"):
        saved = [zipfile.ZipFile(out / name / "team" / f"{agent}.zip").read("policy.pth") for name in "ab"]
        assert saved[0] == saved[1]
    assert yaml.safe_load((out / "b" / "config.yml").read_text())["env"] == str(graph)


def test_train_prints_and_records_staggered_learning_rates(tiny_train, capsys) -> None:
    config, graph, out = tiny_train
    argv = ["train", "--config", str(config), "--env", str(graph), "--timesteps", "16", "--out", str(out)]
    assert main([*argv, "--hyperparams", "learning_rate_spread:4", "--no-progress"]) == 0
    # two learners, the fastest 4x the slowest around the file's lin_1e-3: starts 2e-3 and 5e-4
    assert "learning rates (learning_rate_spread 4): agent_0 lin_0.002, agent_1 lin_0.0005" in (
        capsys.readouterr().out
    )
    assert yaml.safe_load((out / "config.yml").read_text())["learning_rate_spread"] == 4.0
    from sb3_pm.agents.training.team import IndependentPPO

    team = IndependentPPO.load(out)
    try:
        assert [team.models[a].lr_schedule(1.0) for a in team.agents] == [2e-3, 5e-4]
    finally:
        team.close()


def test_update_device_is_checked_first_and_recorded(tiny_train, capsys, monkeypatch) -> None:
    config, graph, out = tiny_train
    argv = ["train", "--config", str(config), "--env", str(graph), "--timesteps", "32", "--no-progress"]
    monkeypatch.setattr(th.cuda, "is_available", lambda: False)
    assert main([*argv, "--out", str(out), "--update-device", "cuda"]) == 2
    error = capsys.readouterr().err
    assert "torch sees no CUDA device" in error and len(error.strip().splitlines()) == 1
    assert not out.exists()  # refused before the run folder was made

    assert main([*argv, "--out", str(out), "--update-device", "cpu:0"]) == 2  # the config's maskable_ppo
    assert "update_device needs dcbf_ppo learners; this team has MaskablePPO" in capsys.readouterr().err

    # cpu:0 is another device object than cpu: the update moves there and back (same arithmetic)
    config.write_text(config.read_text().replace("algo: maskable_ppo", "algo: dcbf_ppo"))
    assert main([*argv, "--out", str(out), "--update-device", "cpu:0"]) == 0
    assert yaml.safe_load((out / "args.yml").read_text())["update_device"] == "cpu:0"
    assert "--update-device cpu:0" in (out / "command.txt").read_text()
